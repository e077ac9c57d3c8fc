"""
The live view's point cloud: the protobuf bytes of a foxglove.PointCloud around the
published cloud's own bytes (``sm_ros.live``), so that the cloud is never re-encoded.

Only the header (stamp, frame, pose, the fields' layout) is encoded here; the message is
that header followed by the cloud's raw bytes (x, y, z float32 and the body index uint32,
16 bytes a point). ``test/test_live.py`` checks it against the SDK's own encoding.
"""

import struct

#: PackedElementFieldNumericType values of foxglove.PackedElementField.
_UINT32 = 5
_FLOAT32 = 7


def _varint(number: int) -> bytes:
    """Protobuf's base-128 varint (a negative number as its 64-bit two's complement)."""
    out = bytearray()
    number = int(number)
    if number < 0:
        number += 1 << 64
    while True:
        low = number & 0x7F
        number >>= 7
        if number:
            out.append(low | 0x80)
        else:
            out.append(low)
            return bytes(out)


def _key(field: int, wire: int) -> bytes:
    return _varint((field << 3) | wire)


def _len_field(field: int, payload: bytes) -> bytes:
    return _key(field, 2) + _varint(len(payload)) + payload


def _timestamp(ns: int) -> bytes:
    sec, nsec = divmod(int(ns), 1_000_000_000)
    body = (_key(1, 0) + _varint(sec) if sec else b'') + \
        (_key(2, 0) + _varint(nsec) if nsec else b'')
    return body


def _packed_field(name: str, offset: int, numeric_type: int) -> bytes:
    body = _len_field(1, name.encode('utf-8'))
    if offset:
        body += _key(2, 5) + struct.pack('<I', offset)
    body += _key(3, 0) + _varint(numeric_type)
    return body


#: The published cloud's layout with ``body`` listed first (Foxglove colours a cloud by
#: its first field when it has no colour field).
CLOUD_FIELDS = (('body', 12, _UINT32), ('x', 0, _FLOAT32), ('y', 4, _FLOAT32),
                ('z', 8, _FLOAT32))
CLOUD_POINT_STEP = 16


def point_cloud_header(stamp_ns: int, frame_id: str, nbytes: int,
                       fields=CLOUD_FIELDS, point_step: int = CLOUD_POINT_STEP) -> bytes:
    """
    Return the protobuf bytes of a foxglove.PointCloud up to (not including) its data.

    Appending ``nbytes`` bytes of point data gives the whole message. The pose is the
    identity (orientation w = 1), as the points are in ``frame_id``.
    """
    out = [_len_field(1, _timestamp(stamp_ns))]
    if frame_id:
        out.append(_len_field(2, frame_id.encode('utf-8')))
    identity = _len_field(1, b'') + _len_field(2, _key(4, 1) + struct.pack('<d', 1.0))
    out.append(_len_field(3, identity))
    out.append(_key(4, 5) + struct.pack('<I', point_step))
    for name, offset, numeric_type in fields:
        out.append(_len_field(5, _packed_field(name, offset, numeric_type)))
    if nbytes:
        out.append(_key(6, 2) + _varint(nbytes))
    return b''.join(out)


def encode_point_cloud(data, stamp_ns: int, frame_id: str) -> bytes:
    """Return a foxglove.PointCloud (protobuf) holding ``data`` (the cloud's raw bytes)."""
    view = memoryview(data).cast('B')
    return b''.join((point_cloud_header(stamp_ns, frame_id, view.nbytes), view))
