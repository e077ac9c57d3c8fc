"""PointCloud2 reading and writing (sm_ros.cloud): layouts, padding, endianness, refusals."""

import array
import sys

import numpy as np
import pytest

pytest.importorskip('sensor_msgs.msg', reason='ROS message wheels not installed')

from rclpy.serialization import deserialize_message, serialize_message  # noqa: E402, I100
from sensor_msgs.msg import PointCloud2, PointField  # noqa: E402
from sm_ros.cloud import (CloudBuffer, CloudError, create_cloud, dtype_from_fields,  # noqa
                          POINT_STEP, read_xyz, structured_view)


F32, F64, I16, U8, U32 = (PointField.FLOAT32, PointField.FLOAT64, PointField.INT16,
                          PointField.UINT8, PointField.UINT32)


def field(name, offset, datatype, count=1):
    """Shorthand for a PointField."""
    return PointField(name=name, offset=offset, datatype=datatype, count=count)


@pytest.fixture
def pts():
    """Twelve seeded points."""
    return np.random.default_rng(7).uniform(-2.0, 2.0, (12, 3))


def roundtrip(msg):
    """Serialise and deserialise, as a subscriber receives it."""
    return deserialize_message(serialize_message(msg), PointCloud2)


def test_packed_float32_roundtrip(pts):
    got = read_xyz(roundtrip(create_cloud(pts, 'map')))
    assert got.dtype == np.float64 and got.shape == (12, 3)
    np.testing.assert_allclose(got, pts.astype(np.float32))


@pytest.mark.parametrize('bigendian', [False, True])
def test_any_order_offset_padding_endianness(pts, bigendian):
    # z first as float64, then padding, a colour, x as float32, y as float64 with count 2
    fields = [field('z', 0, F64), field('rgb', 8, F32), field('x', 16, F32),
              field('y', 24, F64, count=2)]
    msg = roundtrip(create_cloud(pts, fields=fields, point_step=48, is_bigendian=bigendian))
    assert msg.is_bigendian == bigendian
    np.testing.assert_allclose(read_xyz(msg), pts, rtol=1e-6)


def test_integer_fields_are_converted():
    p = np.array([[1, -2, 3], [400, 5, -600]], dtype=np.float64)
    fields = [field('x', 0, I16), field('y', 2, I16), field('z', 4, I16)]
    np.testing.assert_array_equal(read_xyz(create_cloud(p, fields=fields)), p)


def test_organised_cloud_and_padded_rows(pts):
    msg = create_cloud(pts, height=3)
    assert (msg.height, msg.width) == (3, 4)
    np.testing.assert_allclose(read_xyz(msg), pts.astype(np.float32))
    # rows padded to 64 bytes: row_step > width * point_step
    raw = np.frombuffer(msg.data, np.uint8).reshape(3, 4 * 12)
    padded = np.zeros((3, 64), np.uint8)
    padded[:, :48] = raw
    msg.row_step = 64
    msg.data = array.array('B', padded.tobytes())
    np.testing.assert_allclose(read_xyz(msg), pts.astype(np.float32))


def test_nan_and_inf_points_are_dropped(pts):
    bad = pts.copy()
    bad[2, 0] = np.nan
    bad[5, 2] = np.inf
    got = read_xyz(create_cloud(bad))
    assert got.shape == (10, 3)
    np.testing.assert_allclose(got, np.delete(pts, [2, 5], axis=0).astype(np.float32))


def test_read_is_a_view_not_a_copy(pts):
    msg = create_cloud(pts)
    view = structured_view(msg)
    assert np.shares_memory(view, np.frombuffer(msg.data, np.uint8))


@pytest.mark.parametrize('mutate, reason', [
    (lambda m: setattr(m, 'fields', [field('x', 0, F32), field('y', 4, F32)]), 'no field z'),
    (lambda m: setattr(m, 'fields', []), 'no field x'),
    (lambda m: setattr(m, 'point_step', 8), 'past point_step'),
    (lambda m: setattr(m, 'point_step', 0), 'point_step must be > 0'),
    (lambda m: setattr(m, 'width', m.width + 1), 'does not match'),
    (lambda m: setattr(m, 'height', 2), 'does not match'),
    (lambda m: setattr(m, 'data', m.data[:-1]), 'does not match'),
    (lambda m: setattr(m, 'width', 0), 'empty cloud'),
    (lambda m: m.fields.__setitem__(1, field('y', 4, 42)), 'unknown datatype'),
    (lambda m: m.fields.append(field('x', 0, F32)), 'duplicate field'),
    (lambda m: m.fields.__setitem__(0, field('x', 0, F32, count=0)), 'count 0'),
])
def test_malformed_clouds_are_refused(pts, mutate, reason):
    msg = create_cloud(pts)
    msg.fields = list(msg.fields)
    mutate(msg)
    with pytest.raises(CloudError, match=reason):
        read_xyz(msg)


def test_all_nan_cloud_is_refused():
    with pytest.raises(CloudError, match='no finite point'):
        read_xyz(create_cloud(np.full((4, 3), np.nan)))


def test_cloud_error_is_a_value_error():
    assert issubclass(CloudError, ValueError)


def test_dtype_selects_names():
    dt = dtype_from_fields([field('x', 0, F32), field('i', 4, U8), field('y', 8, F32)], 16,
                           names=('x', 'y'))
    assert dt.names == ('x', 'y') and dt.itemsize == 16


class TestCloudBuffer:
    """The published cloud: layout, values and buffer reuse."""

    def test_layout(self):
        buf = CloudBuffer('map')
        a = np.arange(9.0).reshape(3, 3)
        b = -np.arange(6.0).reshape(2, 3)
        msg = buf.fill([a, b])
        assert [(f.name, f.offset, f.datatype, f.count) for f in msg.fields] == [
            ('x', 0, F32, 1), ('y', 4, F32, 1), ('z', 8, F32, 1), ('body', 12, U32, 1)]
        assert (msg.width, msg.height, msg.point_step, msg.row_step) == (5, 1, POINT_STEP, 80)
        assert msg.is_bigendian == (sys.byteorder == 'big')
        assert msg.header.frame_id == 'map'
        assert isinstance(msg.data, array.array) and len(msg.data) == 80
        got = roundtrip(msg)
        np.testing.assert_array_equal(read_xyz(got), np.vstack([a, b]))
        body = structured_view(got, names=('body',))['body']
        np.testing.assert_array_equal(body, [0, 0, 0, 1, 1])

    def test_buffer_is_reused_until_sizes_change(self):
        buf = CloudBuffer()
        rng = np.random.default_rng(1)
        msg = buf.fill([rng.random((4, 3)), rng.random((2, 3))])
        data = msg.data
        rebuilds = buf.rebuilds
        new = [rng.random((4, 3)), rng.random((2, 3))]
        assert buf.fill(new) is msg and msg.data is data and buf.rebuilds == rebuilds
        np.testing.assert_allclose(read_xyz(msg), np.vstack(new), rtol=1e-6)
        buf.fill([rng.random((3, 3)), rng.random((3, 3))])     # same total, other split
        assert buf.rebuilds == rebuilds + 1
        np.testing.assert_array_equal(buf.body, [0, 0, 0, 1, 1, 1])
        buf.fill([rng.random((7, 3))])
        assert buf.rebuilds == rebuilds + 2 and buf.msg.width == 7

    def test_views_alias_the_message_buffer(self):
        buf = CloudBuffer()
        msg = buf.fill([np.ones((3, 3))])
        raw = np.frombuffer(msg.data, np.uint8)
        assert np.shares_memory(buf.xyz, raw) and np.shares_memory(buf.body, raw)

    def test_stamp(self):
        from builtin_interfaces.msg import Time
        msg = CloudBuffer().fill([np.zeros((1, 3))], Time(sec=3, nanosec=5))
        assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (3, 5)


# ----------------------------------------------------------------------------------------
# Property: any layout is read right, any corruption is a CloudError (never another error)
# ----------------------------------------------------------------------------------------

hypothesis = pytest.importorskip('hypothesis')
st = hypothesis.strategies
SIZES = {PointField.INT16: 2, PointField.INT32: 4, PointField.FLOAT32: 4,
         PointField.FLOAT64: 8}


@st.composite
def layouts(draw):
    """Draw points and a random layout: field order, types, gaps, endianness, rows."""
    n = draw(st.integers(1, 30))
    height = draw(st.sampled_from([h for h in (1, 2, 3) if n % h == 0]))
    names = draw(st.permutations(['x', 'y', 'z', 'rgb']))
    fields, offset = [], 0
    for name in names:
        offset += draw(st.integers(0, 5))
        datatype = draw(st.sampled_from(sorted(SIZES)))
        fields.append(field(name, offset, datatype))
        offset += SIZES[datatype]
    point_step = offset + draw(st.integers(0, 7))
    rng = np.random.default_rng(draw(st.integers(0, 2**16)))
    pts = np.round(rng.uniform(-100, 100, (n, 3)))          # exact in every datatype
    return pts, fields, point_step, draw(st.booleans()), height


@hypothesis.settings(max_examples=150, deadline=None)
@hypothesis.given(layouts(), st.integers(0, 3), st.integers(-9, 9))
def test_random_layouts_and_corruptions(layout, corruption, amount):
    pts, fields, point_step, bigendian, height = layout
    msg = create_cloud(pts, fields=fields, point_step=point_step, is_bigendian=bigendian,
                       height=height)
    if corruption == 0:
        np.testing.assert_array_equal(read_xyz(roundtrip(msg)), pts)
        return
    if corruption == 1:
        cut = max(0, len(msg.data) + amount) if amount else len(msg.data) - 1
        msg.data = array.array('B', bytes(msg.data)[:cut])
    elif corruption == 2:
        msg.width = max(0, msg.width + amount)
    else:
        msg.point_step = max(0, msg.point_step + amount)
    try:
        got = read_xyz(msg)
    except CloudError:
        return
    assert got.shape[1] == 3 and np.isfinite(got).all()
