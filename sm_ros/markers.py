"""
The deformed surface meshes as one pre-serialised MarkerArray.

``Marker.points`` is a list of ``geometry_msgs/Point`` objects, so the ordinary way costs a
Python object per triangle corner and a Python-level serialisation each tick, which grows
with the mesh and would dominate the tick. Instead, a template MarkerArray with the right
number of points is serialised once; the byte offsets of each marker's points and stamp in
that CDR buffer are found, and each tick the corners are written into the buffer with NumPy
and the bytes are published as they are (``Publisher.publish`` takes serialised bytes). The
template is rebuilt only when the set of bodies, their face counts or the frame change.
"""

import struct
from typing import List, Optional, Sequence, Tuple

from geometry_msgs.msg import Point
import numpy as np
from rclpy.serialization import serialize_message
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import Marker, MarkerArray

#: Colour of the surfaces (RGBA).
SURFACE_COLOR = (0.85, 0.45, 0.2, 1.0)

_SENTINEL = 7.0e301          # an improbable coordinate marks where a marker's points are
_STAMP_SEC = 1_234_567_890   # an improbable stamp marks where a marker's stamp is
_STAMP_NSEC = 987_654_321


class MarkerBuffer:
    """A serialised MarkerArray of TRIANGLE_LIST markers, refilled in place each tick."""

    def __init__(self):
        """Start without a template; ``fill`` builds one."""
        self._key: Optional[Tuple] = None
        self._frame: Optional[str] = None
        self._buf = bytearray()
        self._points: List[np.ndarray] = []
        self._stamps: List[int] = []
        self._little = True
        self.rebuilds = 0

    @property
    def key(self) -> Optional[Tuple]:
        """Return the (ns, id, corners) of the current template's markers (None: none yet)."""
        return self._key

    def _build(self, key: Tuple, frame_id: str, delete_all: bool) -> None:
        """Serialise a template for ``key`` = ((ns, id, corners), ...) and find the slots."""
        markers = []
        if delete_all:
            markers.append(Marker(action=Marker.DELETEALL))
        for i, (ns, marker_id, corners) in enumerate(key):
            m = Marker()
            m.header.frame_id = frame_id
            m.header.stamp.sec = _STAMP_SEC + i
            m.header.stamp.nanosec = _STAMP_NSEC
            m.ns = ns
            m.id = marker_id
            m.type = Marker.TRIANGLE_LIST
            m.action = Marker.ADD
            m.pose.orientation.w = 1.0
            m.scale.x = m.scale.y = m.scale.z = 1.0
            m.color = ColorRGBA(r=SURFACE_COLOR[0], g=SURFACE_COLOR[1], b=SURFACE_COLOR[2],
                                a=SURFACE_COLOR[3])
            s = _SENTINEL + i * 1e290
            m.points = [Point(x=s, y=s, z=s) for _ in range(corners)]
            markers.append(m)
        data = serialize_message(MarkerArray(markers=markers))
        # CDR encapsulation header: byte 1 is 0x01 for little endian, 0x00 for big endian
        self._little = data[1] == 1
        order = '<' if self._little else '>'
        self._buf = bytearray(data)
        self._points, self._stamps = [], []
        for i, (_, _, corners) in enumerate(key):
            s = _SENTINEL + i * 1e290
            start = data.find(struct.pack(order + 'ddd', s, s, s) * max(corners, 1))
            stamp = data.find(struct.pack(order + 'iI', _STAMP_SEC + i, _STAMP_NSEC))
            if start < 0 or stamp < 0:
                raise RuntimeError('marker template: points or stamp not found')
            view = np.ndarray((corners, 3), dtype=np.dtype(order + 'f8'), buffer=self._buf,
                              offset=start)
            self._points.append(view)
            self._stamps.append(stamp)
        self._key = key
        self._frame = frame_id
        self.rebuilds += 1

    def fill(self, surfaces: Sequence[Tuple[str, int, np.ndarray]], frame_id: str,
             sec: int, nanosec: int) -> bytes:
        """
        Return the serialised MarkerArray for ``surfaces`` = [(ns, id, corners (K, 3))].

        A DELETEALL marker leads the array whenever the set of markers changed, so that
        markers of removed bodies disappear from RViz.
        """
        key = tuple((ns, int(i), int(c.shape[0])) for ns, i, c in surfaces)
        first = (key, frame_id) != (self._key, self._frame)
        if first:
            self._build(key, frame_id, delete_all=True)
        order = '<' if self._little else '>'
        for view, offset, (_, _, corners) in zip(self._points, self._stamps, surfaces):
            view[...] = corners
            struct.pack_into(order + 'iI', self._buf, offset, int(sec), int(nanosec))
        out = bytes(self._buf)
        if first:
            # later ticks need no DELETEALL: rebuild the template without it, same slots
            self._build(key, frame_id, delete_all=False)
        return out
