"""
PointCloud2 conversion with NumPy: no Python loops over points.

Reading (``read_xyz``) is a zero-copy structured view over ``msg.data`` (any field order,
offset, padding, endianness and row padding), followed by one vectorised copy of x, y, z
into float64 and a finiteness filter. Malformed messages raise ``CloudError`` (a
ValueError) with a reason fit for a log line.

Writing (``CloudBuffer``) keeps one PointCloud2 message whose ``data`` is an
``array.array('B')`` (the setter's fast path, serialised with one memcpy) and a NumPy view
over that buffer; each tick the solver's positions are written straight into it. The
buffer is rebuilt only when the number of points per body changes.

Layout of published clouds: ``x y z`` float32 at offsets 0, 4, 8 and ``body`` uint32 (the
index of the body in the world's body list) at offset 12; point_step 16, height 1,
native byte order.

sensor_msgs_py is not on PyPI, so the few functions sm_ros needs are written here in its
style.
"""

import array
import sys
from typing import Iterable, Optional, Sequence, Tuple

import numpy as np
from sensor_msgs.msg import PointCloud2, PointField

# PointField.datatype -> NumPy scalar type (sensor_msgs/PointField constants 1..8).
DATATYPES = {
    PointField.INT8: np.dtype('i1'),
    PointField.UINT8: np.dtype('u1'),
    PointField.INT16: np.dtype('i2'),
    PointField.UINT16: np.dtype('u2'),
    PointField.INT32: np.dtype('i4'),
    PointField.UINT32: np.dtype('u4'),
    PointField.FLOAT32: np.dtype('f4'),
    PointField.FLOAT64: np.dtype('f8'),
}

# The published layout: x, y, z float32 and the body index uint32.
POINT_STEP = 16
BODY_FIELD = 'body'
NATIVE_BIGENDIAN = sys.byteorder == 'big'


class CloudError(ValueError):
    """A PointCloud2 that cannot be read: the message says why."""


def published_fields() -> list:
    """Return the PointFields of the clouds sm_ros publishes."""
    return [
        PointField(name='x', offset=0, datatype=PointField.FLOAT32, count=1),
        PointField(name='y', offset=4, datatype=PointField.FLOAT32, count=1),
        PointField(name='z', offset=8, datatype=PointField.FLOAT32, count=1),
        PointField(name=BODY_FIELD, offset=12, datatype=PointField.UINT32, count=1),
    ]


def dtype_from_fields(fields: Sequence[PointField], point_step: int,
                      is_bigendian: bool = NATIVE_BIGENDIAN,
                      names: Optional[Iterable[str]] = None) -> np.dtype:
    """
    Return the structured dtype of one point.

    Fields with ``count > 1`` become sub-arrays. Only the fields in ``names`` are included
    when it is given (the others are padding). Raises CloudError on unknown datatypes,
    duplicate names, a zero count or a field that does not fit in ``point_step``.
    """
    if point_step <= 0:
        raise CloudError(f'point_step must be > 0, got {point_step}')
    wanted = None if names is None else set(names)
    order = '>' if is_bigendian else '<'
    seen = set()
    out_names, formats, offsets = [], [], []
    for f in fields:
        if f.name in seen:
            raise CloudError(f"duplicate field '{f.name}'")
        seen.add(f.name)
        base = DATATYPES.get(f.datatype)
        if base is None:
            raise CloudError(f"field '{f.name}' has unknown datatype {f.datatype}")
        if f.count < 1:
            raise CloudError(f"field '{f.name}' has count {f.count}")
        end = f.offset + base.itemsize * f.count
        if end > point_step:
            raise CloudError(
                f"field '{f.name}' ends at byte {end}, past point_step {point_step}")
        if wanted is not None and f.name not in wanted:
            continue
        scalar = base.newbyteorder(order)
        out_names.append(f.name)
        formats.append(scalar if f.count == 1 else (scalar, (f.count,)))
        offsets.append(f.offset)
    return np.dtype({'names': out_names, 'formats': formats, 'offsets': offsets,
                     'itemsize': point_step})


def _as_bytes(data) -> np.ndarray:
    """Return ``msg.data`` as a flat uint8 array, without a copy where possible."""
    if isinstance(data, (array.array, bytes, bytearray, memoryview)):
        return np.frombuffer(data, dtype=np.uint8)
    if isinstance(data, np.ndarray):
        return data.reshape(-1).view(np.uint8)
    return np.asarray(data, dtype=np.uint8)


def structured_view(msg: PointCloud2, names: Optional[Iterable[str]] = None) -> np.ndarray:
    """
    Return the points of ``msg`` as a structured array of shape (height * width,).

    A zero-copy view over ``msg.data``. Rows may be padded (``row_step`` larger than
    ``width * point_step``). Raises CloudError if the layout does not match the data.
    """
    width, height, point_step = int(msg.width), int(msg.height), int(msg.point_step)
    if width * height == 0:
        raise CloudError(f'empty cloud (width {width}, height {height})')
    dtype = dtype_from_fields(msg.fields, point_step, bool(msg.is_bigendian), names)
    raw = _as_bytes(msg.data)
    row = width * point_step
    if raw.size == row * height:
        return np.ndarray((width * height,), dtype=dtype, buffer=raw)
    row_step = int(msg.row_step)
    if row_step > row and raw.size == row_step * height:
        rows = np.ndarray((height, width), dtype=dtype, buffer=raw,
                          strides=(row_step, point_step))
        return rows.reshape(-1)
    raise CloudError(
        f'data length {raw.size} does not match width*height*point_step '
        f'= {width}*{height}*{point_step} = {row * height} (row_step {row_step})')


def read_xyz(msg: PointCloud2) -> np.ndarray:
    """
    Return the finite x, y, z of ``msg`` as an (N, 3) float64 array.

    Points with a NaN or Inf coordinate are dropped. Raises CloudError when the message is
    malformed (no x/y/z, bad point_step, data length not matching the layout) or when no
    finite point is left.
    """
    present = {f.name for f in msg.fields}
    missing = [c for c in 'xyz' if c not in present]
    if missing:
        raise CloudError(f"no field {', '.join(missing)} (fields: {sorted(present)})")
    view = structured_view(msg, names='xyz')
    xyz = np.empty((view.shape[0], 3), dtype=np.float64)
    for i, c in enumerate('xyz'):
        col = view[c]
        xyz[:, i] = col if col.ndim == 1 else col[:, 0]
    finite = np.isfinite(xyz).all(axis=1)
    if not finite.all():
        xyz = xyz[finite]
    if xyz.shape[0] == 0:
        raise CloudError('no finite point in the cloud')
    return xyz


def create_cloud(points: np.ndarray, frame_id: str = '', fields: Optional[list] = None,
                 point_step: Optional[int] = None, is_bigendian: bool = NATIVE_BIGENDIAN,
                 height: int = 1, extra: Optional[dict] = None) -> PointCloud2:
    """
    Return a PointCloud2 holding ``points`` (N, 3) in an arbitrary layout.

    ``fields`` defaults to x, y, z float32 packed; pass other PointFields (any order,
    offsets, datatypes) and a larger ``point_step`` for padding. ``extra`` maps other field
    names to (N,) arrays. Mainly for tests and for nodes that feed ``cloud_in``.
    """
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if fields is None:
        fields = [PointField(name=c, offset=4 * i, datatype=PointField.FLOAT32, count=1)
                  for i, c in enumerate('xyz')]
    if point_step is None:
        point_step = max(f.offset + DATATYPES[f.datatype].itemsize * f.count for f in fields)
    n = points.shape[0]
    if n % height:
        raise ValueError(f'{n} points do not fill {height} rows')
    dtype = dtype_from_fields(fields, point_step, is_bigendian)
    buf = array.array('B', bytes(n * point_step))
    view = np.ndarray((n,), dtype=dtype, buffer=memoryview(buf))
    values = dict(extra or {})
    values.update({c: points[:, i] for i, c in enumerate('xyz')})
    for name, col in values.items():
        if name in dtype.names:
            target = view[name]
            if target.ndim == 1:
                target[:] = col
            else:
                target[:, 0] = col
    msg = PointCloud2()
    msg.header.frame_id = frame_id
    msg.height = height
    msg.width = n // height
    msg.fields = list(fields)
    msg.is_bigendian = bool(is_bigendian)
    msg.point_step = point_step
    msg.row_step = point_step * msg.width
    msg.is_dense = bool(np.isfinite(points).all())
    msg.data = buf
    return msg


class CloudBuffer:
    """
    One reusable PointCloud2 for the bodies' particles.

    ``fill(blocks, stamp)`` writes each body's (N_i, 3) positions into the message's buffer
    (float64 -> float32, one vectorised copy per column: x, y, z are each contiguous in a
    body's F-contiguous ``Body.x``) and returns the message. The buffer
    and the body index column are rebuilt only when the sizes of the blocks change.
    """

    def __init__(self, frame_id: str = 'world'):
        """Create an empty cloud in ``frame_id``."""
        self.msg = PointCloud2()
        self.msg.header.frame_id = frame_id
        self.msg.height = 1
        self.msg.fields = published_fields()
        self.msg.is_bigendian = NATIVE_BIGENDIAN
        self.msg.point_step = POINT_STEP
        self.msg.is_dense = True
        self._sizes: Tuple[int, ...] = ()
        self._offsets = np.zeros(1, dtype=np.int64)
        self.rebuilds = 0
        self._resize(())

    @property
    def frame_id(self) -> str:
        """Return the frame of the published cloud."""
        return self.msg.header.frame_id

    @frame_id.setter
    def frame_id(self, value: str) -> None:
        self.msg.header.frame_id = value

    @property
    def xyz(self) -> np.ndarray:
        """Return the (N, 3) float32 view of the positions in the message buffer."""
        return self._xyz

    @property
    def body(self) -> np.ndarray:
        """Return the (N,) uint32 view of the body index column in the message buffer."""
        return self._body

    def _resize(self, sizes: Tuple[int, ...]) -> None:
        n = int(sum(sizes))
        # The setter may copy what it is given (it does unless ROS_PYTHON_CHECK_FIELDS=1),
        # so the views are taken over the array the message holds afterwards.
        self.msg.data = array.array('B', bytes(n * POINT_STEP))
        self._buf = self.msg.data
        words = np.frombuffer(self._buf, dtype=np.float32).reshape(n, 4)
        self._xyz = words[:, :3]
        self._body = np.frombuffer(self._buf, dtype=np.uint32).reshape(n, 4)[:, 3]
        self._body[:] = np.repeat(np.arange(len(sizes), dtype=np.uint32),
                                  np.asarray(sizes, dtype=np.int64))
        self._offsets = np.concatenate(([0], np.cumsum(sizes, dtype=np.int64)))
        self._sizes = tuple(sizes)
        self.msg.width = n
        self.msg.row_step = n * POINT_STEP
        self.rebuilds += 1

    def fill(self, blocks: Sequence[np.ndarray], stamp=None) -> PointCloud2:
        """Write the blocks' positions into the buffer and return the message."""
        sizes = tuple(int(b.shape[0]) for b in blocks)
        if sizes != self._sizes:
            self._resize(sizes)
        offsets = self._offsets
        xyz = self._xyz
        for i, b in enumerate(blocks):
            rows = xyz[offsets[i]:offsets[i + 1]]
            # column by column: a body's positions are stored per component (``Body.x`` is
            # F-contiguous), so each column is read with unit stride
            for j in range(3):
                rows[:, j] = b[:, j]
        if stamp is not None:
            self.msg.header.stamp = stamp
        return self.msg
