"""
Property-based bad input for sim_node (interface.md, 'Bad input').

Hypothesis draws clouds with random layouts and random bytes, wrenches and poses with NaN,
Inf, huge and subnormal values, gripper and body names, and parameter values of every type
(arrays of the wrong length included). For every example:

- the input is refused with a reason of its own (never the node's catch-all 'unexpected
  ...' of a callback that raised), or handled as interface.md says;
- a refused input changes nothing: bodies, positions, velocities, wrenches, grippers,
  kinematic particles, body parameters, gravity, colliders, the declared parameter values
  and the changes queued for the next tick;
- the node keeps running: it ticks and publishes afterwards.

The callbacks are called directly (one node, many examples, no DDS round trip per example);
a few examples go over the real topics. Recovery: a body whose state is made non-finite
through the test hook (writing into ``body._x`` / ``body._v``: ``set_state`` refuses NaN)
is reset on its own, diagnostics report ERROR naming it, the other bodies step on exactly
as they would have, and the published cloud stays finite.

``SM_BAD_INPUT_EXAMPLES`` scales the number of examples (default: CI-sized).
"""

import array
import copy
import math
import os

import numpy as np
import pytest

pytest.importorskip('rclpy', reason='ROS 2 wheels not installed (pip install -e .[ros])')
hypothesis = pytest.importorskip('hypothesis')

from diagnostic_msgs.msg import DiagnosticStatus  # noqa: E402, I100
from geometry_msgs.msg import PoseStamped, WrenchStamped  # noqa: E402
from hypothesis import HealthCheck, settings, strategies as st  # noqa: E402
from rcl_interfaces.msg import ParameterType  # noqa: E402
from rclpy.exceptions import (InvalidParameterTypeException,  # noqa: E402
                              InvalidParameterValueException, ParameterException)
from rclpy.parameter import Parameter  # noqa: E402
from sensor_msgs.msg import PointCloud2, PointField  # noqa: E402
from sm_ros.cloud import CloudError, create_cloud, read_xyz  # noqa: E402
from std_msgs.msg import String  # noqa: E402

SCALE = float(os.environ.get('SM_BAD_INPUT_EXAMPLES', '1'))


def examples(n: int) -> settings:
    """Return hypothesis settings: about n examples, scaled by SM_BAD_INPUT_EXAMPLES."""
    return settings(max_examples=max(1, int(n * SCALE)), deadline=None, derandomize=SCALE == 1,
                    database=None, suppress_health_check=[HealthCheck.function_scoped_fixture,
                                                          HealthCheck.too_slow,
                                                          HealthCheck.data_too_large])


NAN, INF = float('nan'), float('inf')
MAX_WRENCH = 1e9
MAX_COORDINATE = 1e6

#: Any float: NaN, +-Inf, huge, subnormal, zero, and the range limits just inside/outside.
ANY_FLOAT = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([0.0, -0.0, NAN, INF, -INF, 1e308, -1e308, 5e-324, MAX_WRENCH,
                     -MAX_WRENCH, MAX_WRENCH * (1 + 1e-12), 1e6, 1e6 * (1 + 1e-12)]),
    st.floats(-10.0, 10.0))
NAMES = st.one_of(st.sampled_from(['', 'soft', 'stiff', 'ghost', 'soft ', 'SOFT']),
                  st.text(max_size=12))


# ----------------------------------------------------------------------------------------
# Node state: what a refused input must leave alone
# ----------------------------------------------------------------------------------------

def snapshot(node) -> dict:
    """Return a deep copy of everything an input could change."""
    w = node.world
    return {
        'world': w,
        'bodies': [b.name for b in w.bodies],
        'x': [b.x.copy() for b in w.bodies],
        'v': [b.v.copy() for b in w.bodies],
        'wrench': [np.concatenate(b.wrench) for b in w.bodies],
        'kinematic': [b.kinematic_indices for b in w.bodies],
        'params': [b.params for b in w.bodies],
        'gravity': w.gravity,
        'colliders': (w.ground, w.boxes, w.spheres),
        'forces': sorted(node._forces),
        'grippers': {k: [(a.body, a.indices.tolist(), None if a.targets is None
                          else a.targets.tolist()) for a in v]
                     for k, v in node.grippers.items()},
        'declared': {name: _value(node.get_parameter(name).value)
                     for name in node._p},
        'applied': copy.deepcopy(node._p),
        'pending': copy.deepcopy(node._pending),
        'pending_scene': node._pending_scene,
    }


def _value(v):
    return list(v) if isinstance(v, (list, tuple, array.array)) else v


def assert_unchanged(node, before: dict) -> None:
    """Assert that the node's state equals the snapshot ``before`` (NaN-safe)."""
    after = snapshot(node)
    assert after['world'] is before['world']
    for key in ('x', 'v', 'wrench', 'kinematic'):
        for a, b in zip(after[key], before[key]):
            np.testing.assert_array_equal(a, b, err_msg=key)
    np.testing.assert_array_equal(after['gravity'], before['gravity'])
    for key in ('bodies', 'params', 'colliders', 'forces', 'grippers', 'applied', 'pending',
                'pending_scene'):
        assert after[key] == before[key], key
    assert after['declared'].keys() == before['declared'].keys()
    for name, value in before['declared'].items():
        assert repr(after['declared'][name]) == repr(value), name


def refused(node, topic: str, call) -> bool:
    """Run ``call()``; return whether ``node`` refused one more input on ``topic``."""
    count = node.refused.get(topic, 0)
    call()
    done = node.refused.get(topic, 0)
    assert done in (count, count + 1)
    if done > count:
        reason = node.last_refusal[topic]
        assert not reason.startswith('unexpected'), f'{topic}: unforeseen error: {reason}'
        return True
    return False


def still_running(node) -> None:
    """Tick once: the node steps, stays finite and publishes."""
    node.tick()
    assert all(b.is_finite() for b in node.world.bodies)


@pytest.fixture
def node(ros, two_body_scene):
    """Return a paused node on the two-body scene (bodies 'soft' and 'stiff')."""
    return ros.start(two_body_scene, grab_radius=0.03)


# ----------------------------------------------------------------------------------------
# PointCloud2: the parser directly (many examples), then cloud_in
# ----------------------------------------------------------------------------------------

DATATYPE_SIZE = {1: 1, 2: 1, 3: 2, 4: 2, 5: 4, 6: 4, 7: 4, 8: 8}


@st.composite
def garbage_clouds(draw):
    """Draw any PointCloud2: random fields, offsets, types, counts, sizes, data bytes."""
    fields = []
    for _ in range(draw(st.integers(0, 5))):
        fields.append(PointField(
            name=draw(st.one_of(st.sampled_from(['x', 'y', 'z', 'rgb', 'intensity', '']),
                                st.text(max_size=4))),
            offset=draw(st.one_of(st.integers(0, 40), st.just(2**32 - 1))),
            datatype=draw(st.integers(0, 255)),
            count=draw(st.one_of(st.integers(0, 3), st.just(2**32 - 1)))))
    msg = PointCloud2()
    msg.fields = fields
    msg.point_step = draw(st.one_of(st.integers(0, 48), st.just(2**32 - 1)))
    msg.width = draw(st.one_of(st.integers(0, 20), st.just(2**32 - 1)))
    msg.height = draw(st.one_of(st.integers(0, 4), st.just(2**31)))
    msg.is_bigendian = draw(st.booleans())
    msg.row_step = draw(st.one_of(st.just(msg.width * msg.point_step % 2**32),
                                  st.integers(0, 2**32 - 1)))
    exact = msg.width * msg.height * msg.point_step
    size = draw(st.one_of(st.just(exact), st.integers(0, 1200)))
    size = min(size, 1 << 16)
    seed = draw(st.integers(0, 2**32 - 1))
    data = np.random.default_rng(seed).integers(0, 256, size, dtype=np.uint8)
    if draw(st.booleans()) and size >= 4:                 # sprinkle NaN / Inf float32s
        words = data[: size // 4 * 4].view(np.float32)
        words[::draw(st.integers(1, 7))] = draw(st.sampled_from([NAN, INF, -INF]))
    msg.data = array.array('B', data.tobytes())
    return msg


@st.composite
def good_clouds(draw):
    """Draw a well-formed cloud (any layout) with some NaN/Inf rows, and its points."""
    n = draw(st.integers(1, 40))
    height = draw(st.sampled_from([h for h in (1, 2, 4) if n % h == 0]))
    names = draw(st.permutations(['x', 'y', 'z', 'rgb']))
    fields, offset = [], 0
    for name in names:
        offset += draw(st.integers(0, 4))
        datatype = draw(st.sampled_from([PointField.FLOAT32, PointField.FLOAT64]))
        count = draw(st.integers(1, 2))
        fields.append(PointField(name=name, offset=offset, datatype=datatype, count=count))
        offset += DATATYPE_SIZE[datatype] * count
    point_step = offset + draw(st.integers(0, 5))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    pts = np.round(rng.uniform(-256.0, 256.0, (n, 3))) / 256.0   # exact in float32
    bad = rng.random(n) < draw(st.sampled_from([0.0, 0.2, 1.0]))
    pts[bad, rng.integers(0, 3, n)[bad]] = rng.choice([NAN, INF, -INF], int(bad.sum()))
    msg = create_cloud(pts, 'world', fields=fields, point_step=point_step,
                       is_bigendian=draw(st.booleans()), height=height)
    return msg, pts


@examples(400)
@hypothesis.given(garbage_clouds())
def test_parser_reads_or_refuses_any_bytes(msg):
    """Any message: an (N, 3) finite array of at most width * height points, or CloudError."""
    try:
        xyz = read_xyz(msg)
    except CloudError:
        return
    assert xyz.dtype == np.float64 and xyz.ndim == 2 and xyz.shape[1] == 3
    assert 1 <= xyz.shape[0] <= msg.width * msg.height
    assert np.isfinite(xyz).all()


@examples(200)
@hypothesis.given(good_clouds())
def test_parser_keeps_exactly_the_finite_points(case):
    msg, pts = case
    finite = np.isfinite(pts).all(axis=1)
    if not finite.any():
        with pytest.raises(CloudError, match='no finite point'):
            read_xyz(msg)
        return
    np.testing.assert_array_equal(read_xyz(msg), pts[finite])


def corrupted(draw, msg):
    """Break a good cloud in one of the ways interface.md lists."""
    how = draw(st.sampled_from(['truncate', 'extend', 'width', 'height', 'point_step',
                                'no_field', 'datatype', 'empty']))
    data = bytes(msg.data)
    if how == 'truncate':
        msg.data = array.array('B', data[:draw(st.integers(0, max(0, len(data) - 1)))])
    elif how == 'extend':
        msg.data = array.array('B', data + bytes(draw(st.integers(1, 9))))
    elif how == 'width':
        msg.width = msg.width + draw(st.integers(1, 5))
    elif how == 'height':
        msg.height = msg.height + draw(st.integers(1, 3))
    elif how == 'point_step':
        msg.point_step = draw(st.integers(0, max(0, msg.point_step - 1)))
    elif how == 'no_field':
        drop = draw(st.sampled_from('xyz'))
        msg.fields = [f for f in msg.fields if f.name != drop]
    elif how == 'datatype':
        msg.fields = [PointField(name=f.name, offset=f.offset, datatype=draw(
            st.sampled_from([0, 9, 200])), count=f.count) for f in msg.fields]
    else:
        msg.width = 0
        msg.data = array.array('B')
    return msg


@st.composite
def cloud_inputs(draw):
    """Draw a cloud for cloud_in: garbage, a corrupted good one, or a good one."""
    kind = draw(st.sampled_from(['garbage', 'corrupted', 'corrupted', 'good', 'huge']))
    if kind == 'garbage':
        return draw(garbage_clouds())
    msg, pts = draw(good_clouds())
    if kind == 'corrupted':
        return corrupted(draw, msg)
    if kind == 'huge':
        return create_cloud(np.where(np.isfinite(pts), pts, 0.0) * draw(
            st.sampled_from([1e7, 1e30, 3e38])), 'world')
    return msg


@examples(60)
@hypothesis.given(cloud_inputs())
def test_cloud_in_refuses_or_builds(node, msg):
    """A refused cloud changes nothing; an accepted one becomes a finite body."""
    before = snapshot(node)
    try:
        points = read_xyz(msg)
        readable = bool(np.abs(points).max() <= MAX_COORDINATE)
    except CloudError:
        readable = False
    if refused(node, 'cloud_in', lambda: node.cloud_in_callback(msg)):
        assert_unchanged(node, before)
    else:
        assert readable, 'a cloud the parser refuses was accepted'
        body = node.world.body('cloud_in')
        assert body.is_finite() and 1 <= body.n <= node._p['max_points']
    still_running(node)


@examples(8)
@hypothesis.given(cloud_inputs())
def test_cloud_in_over_the_topic(ros, node, msg):
    """The same through DDS: the node handles the message and keeps running."""
    before = snapshot(node)
    handled = (node.refused.get('cloud_in', 0), node._cloud_count)
    ros.publisher(PointCloud2, 'cloud_in').publish(msg)
    assert ros.spin_until(lambda: (node.refused.get('cloud_in', 0),
                                   node._cloud_count) != handled)
    if node.refused.get('cloud_in', 0) > handled[0]:
        assert not node.last_refusal['cloud_in'].startswith('unexpected')
        assert_unchanged(node, before)
    still_running(node)


def test_cloud_in_huge_cloud_is_downsampled_not_fatal(node):
    """A million points in an organised cloud: capped at max_points, node alive."""
    pts = np.random.default_rng(0).uniform(-0.5, 0.5, (1_000_000, 3))
    node.cloud_in_callback(create_cloud(pts, 'world', height=1000))
    body = node.world.body('cloud_in')
    assert 1 <= body.n <= node._p['max_points']
    still_running(node)


# ----------------------------------------------------------------------------------------
# force
# ----------------------------------------------------------------------------------------

def wrench_msg(name, f, t) -> WrenchStamped:
    msg = WrenchStamped()
    msg.header.frame_id = name
    msg.wrench.force.x, msg.wrench.force.y, msg.wrench.force.z = f
    msg.wrench.torque.x, msg.wrench.torque.y, msg.wrench.torque.z = t
    return msg


@examples(150)
@hypothesis.given(NAMES, st.tuples(ANY_FLOAT, ANY_FLOAT, ANY_FLOAT),
                  st.tuples(ANY_FLOAT, ANY_FLOAT, ANY_FLOAT))
def test_force_any_wrench(node, name, f, t):
    before = snapshot(node)
    msg = wrench_msg(name, f, t)
    w = np.array(f + t)
    bodies = {b.name for b in node.world.bodies}
    valid = (np.isfinite(w).all() and np.abs(w).max() <= MAX_WRENCH
             and (name == '' or name in bodies))
    if refused(node, 'force', lambda: node.force_callback(msg)):
        assert not valid, node.last_refusal['force']
        assert_unchanged(node, before)
    else:
        assert valid
        targets = [node.world.body(name)] if name else node.world.bodies
        for body in targets:
            got = np.concatenate(body.wrench)
            np.testing.assert_array_equal(got, w)
            assert (body.name in node._forces) == bool(w.any())
        node.force_callback(wrench_msg('', (0.0,) * 3, (0.0,) * 3))   # clear for the next
    still_running(node)


# ----------------------------------------------------------------------------------------
# grab / release
# ----------------------------------------------------------------------------------------

def pose_msg(name, p, q) -> PoseStamped:
    msg = PoseStamped()
    msg.header.frame_id = name
    msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = p
    (msg.pose.orientation.x, msg.pose.orientation.y, msg.pose.orientation.z,
     msg.pose.orientation.w) = q
    return msg


@st.composite
def grab_inputs(draw):
    """Draw a gripper name, a position (often at a body) and a quaternion."""
    name = draw(st.one_of(st.sampled_from(['', 'hand', 'left']), st.text(max_size=8)))
    near = draw(st.sampled_from([None, 'soft', 'stiff']))
    if near is None:
        p = draw(st.tuples(ANY_FLOAT, ANY_FLOAT, ANY_FLOAT))
    else:
        p = tuple(draw(st.floats(-0.02, 0.02)) for _ in range(3))
    q = draw(st.one_of(st.tuples(ANY_FLOAT, ANY_FLOAT, ANY_FLOAT, ANY_FLOAT),
                       st.just((0.0, 0.0, 0.0, 1.0)), st.just((0.0, 0.0, 0.0, 0.0))))
    return name, near, p, q


@examples(120)
@hypothesis.given(grab_inputs(), st.booleans())
def test_grab_any_pose(node, grab, again):
    name, near, p, q = grab
    if near is not None:
        p = tuple(float(c) for c in node.world.body(near).com() + p)
    before = snapshot(node)
    pos, quat = np.array(p), np.array(q)
    norm = float(np.linalg.norm(quat)) if np.isfinite(quat).all() else NAN
    well_formed = (name != '' and np.isfinite(pos).all() and np.isfinite(quat).all()
                   and np.abs(pos).max() <= MAX_COORDINATE and 1e-6 < norm < 1e6)
    if refused(node, 'grab', lambda: node.grab_callback(pose_msg(name, p, q))):
        if well_formed:       # the only other reason: nothing within grab_radius
            assert 'no particle within grab_radius' in node.last_refusal['grab']
        assert_unchanged(node, before)
    else:
        assert well_formed
        assert name in node.grippers
        for a in node.grippers[name]:
            body = node.world.body(a.body)
            assert set(a.indices) <= set(body.kinematic_indices)
            assert np.isfinite(a.targets).all()
        if again:             # a bad pose for a gripper that holds: refused, nothing moves
            held = snapshot(node)
            assert refused(node, 'grab', lambda: node.grab_callback(
                pose_msg(name, (NAN, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0))))
            assert_unchanged(node, held)
        still_running(node)
        node.release_callback(String(data=name))
        assert name not in node.grippers
    still_running(node)


@examples(60)
@hypothesis.given(st.one_of(st.text(max_size=10), st.sampled_from(['hand', 'Hand', ' '])))
def test_release_any_name(node, name):
    com = node.world.body('soft').com()
    node.grab_callback(pose_msg('hand', tuple(float(c) for c in com), (0.0, 0.0, 0.0, 1.0)))
    assert 'hand' in node.grippers
    before = snapshot(node)
    if refused(node, 'release', lambda: node.release_callback(String(data=name))):
        assert name not in ('', 'hand')
        assert_unchanged(node, before)
    else:
        assert name in ('', 'hand') and not node.grippers
    node.release_callback(String(data=''))
    still_running(node)


# ----------------------------------------------------------------------------------------
# Parameters: any name, any value, any type
# ----------------------------------------------------------------------------------------

VALUES = st.one_of(
    st.booleans(),
    st.integers(-2**63, 2**63 - 1), st.sampled_from([0, 1, 2, 64, 65, -1, 10_000_000]),
    ANY_FLOAT, st.sampled_from([0.5, 1.0, 1.0000005, -1e-7, 1e-3, 60.0, 1000.0]),
    st.text(max_size=8), st.sampled_from(['rigid', 'linear', 'quadratic', 'add', 'replace',
                                          'nope', 'no_such_scene', '/nonexistent.yaml']),
    st.lists(ANY_FLOAT, max_size=5), st.lists(st.floats(-20.0, 20.0), min_size=3, max_size=3),
    st.lists(st.integers(-5, 5), max_size=4), st.lists(st.booleans(), min_size=1, max_size=3),
    st.lists(st.text(max_size=3), min_size=1, max_size=3), st.binary(min_size=1, max_size=4))


def make_parameter(name, value):
    """Return a rclpy Parameter holding ``value`` with the type rclpy infers from it."""
    if isinstance(value, bytes):
        return Parameter(name, Parameter.Type.BYTE_ARRAY, [bytes([b]) for b in value])
    if isinstance(value, list) and not value:
        return Parameter(name, Parameter.Type.DOUBLE_ARRAY, [])
    return Parameter(name, value=value)


def expected_ok(node, name, param) -> bool:
    """Oracle: whether interface.md lets ``param`` through (None: either is right)."""
    from sm_ros.params import BY_NAME, MIN_DT, MIN_TIMER_RATE, TIMER_RATES
    spec = BY_NAME[name]
    if param.type_.value != spec.ros_type:
        return False
    value = param.value
    if spec.ros_type == ParameterType.PARAMETER_DOUBLE_ARRAY:
        value = list(value)
        return len(value) == 3 and all(math.isfinite(v) and abs(v) <= MAX_COORDINATE
                                       for v in value)
    if spec.ros_type == ParameterType.PARAMETER_DOUBLE:
        if not math.isfinite(value) or not spec.lo <= value <= spec.hi:
            return False
        if name in TIMER_RATES and 0.0 < value < MIN_TIMER_RATE:
            return False                  # the timer period would not fit in int64 ns
        if name == 'dt' and 0.0 < value < MIN_DT:
            return False                  # rounding noise / dt: absurd speeds
        return not (spec.positive and value <= spec.lo)
    if spec.ros_type == ParameterType.PARAMETER_INTEGER:
        return spec.lo <= value <= spec.hi and not (spec.positive and value <= spec.lo)
    if spec.ros_type == ParameterType.PARAMETER_STRING:
        if spec.choices:
            return value in spec.choices
        if name == 'frame_id':
            return bool(value.strip())
        if name == 'scene':
            return None
        return True
    return True


PARAM_NAMES = ['scene', 'mode', 'alpha', 'beta', 'plasticity.yield', 'plasticity.creep',
               'plasticity.max', 'clusters', 'dt', 'substeps', 'rate', 'gravity',
               'ground.enabled', 'ground.height', 'ground.friction', 'ground.restitution',
               'grab_radius', 'force_timeout', 'frame_id', 'publish_clock',
               'diagnostics_rate', 'max_points', 'cloud_in_mode']


@examples(200)
@hypothesis.given(st.sampled_from(PARAM_NAMES), VALUES)
def test_parameters_any_value_and_type(node, name, value):
    """Refused: nothing changes; accepted: applied at the next tick."""
    if name == 'scene' and not (isinstance(value, str) and value in (
            'no_such_scene', '/nonexistent.yaml', 'nope')):
        value = 'no_such_scene'         # loading real scenes belongs to the node's tests
    param = make_parameter(name, value)
    want = expected_ok(node, name, param)
    before = snapshot(node)
    try:
        result = node.set_parameters([param])[0]
        ok = result.successful
        assert ok or result.reason
    except (InvalidParameterTypeException, InvalidParameterValueException,
            ParameterException):
        ok = False
    if want is not None:
        assert ok == want, f'{name} = {value!r}: {"accepted" if ok else "refused"}'
    if not ok:
        assert_unchanged(node, before)
        still_running(node)
        return
    node.tick()
    got = node._p[name]
    expect = list(param.value) if param.type_ == Parameter.Type.DOUBLE_ARRAY else param.value
    assert repr(_value(got)) == repr(expect), name
    assert all(b.is_finite() for b in node.world.bodies)
    node.set_parameters([Parameter(name, value=before['applied'][name])])    # restore
    node.tick()


@examples(40)
@hypothesis.given(st.lists(st.tuples(st.sampled_from(PARAM_NAMES), VALUES), min_size=2,
                           max_size=4))
def test_parameter_batch_with_one_bad_value_changes_nothing(node, batch):
    """set_parameters_atomically: one refused value refuses the whole batch."""
    params = [make_parameter(n, 'no_such_scene' if n == 'scene' else v) for n, v in batch]
    if all(expected_ok(node, p.name, p) for p in params):
        return
    before = snapshot(node)
    try:
        ok = node.set_parameters_atomically(params).successful
    except (InvalidParameterTypeException, InvalidParameterValueException,
            ParameterException):
        ok = False
    assert not ok
    assert_unchanged(node, before)
    still_running(node)


# ----------------------------------------------------------------------------------------
# Recovery from a non-finite body
# ----------------------------------------------------------------------------------------

CLOUDS = {}


@examples(25)
@hypothesis.given(st.integers(0, 1), st.integers(0, 10_000), st.integers(0, 2),
                  st.sampled_from(['_x', '_v']), st.sampled_from([NAN, INF, -INF]))
def test_non_finite_body_is_reset_and_the_rest_goes_on(ros, node, which, particle, axis,
                                                       array_name, value):
    clouds = CLOUDS.setdefault(id(node), ros.subscribe(PointCloud2, 'points'))
    node.tick()
    bodies = node.world.bodies
    sick = bodies[which]
    twin = copy.deepcopy(node.world)                 # what the healthy bodies must do
    getattr(sick, array_name)[particle % sick.n, axis] = value
    node.tick()
    for _ in range(int(node._p['substeps'])):
        twin.step(float(node._p['dt']))
    assert sick.is_finite()
    np.testing.assert_array_equal(sick.x, sick.x_init)
    for body, healthy in zip(bodies, twin.bodies):
        if body is not sick:
            np.testing.assert_array_equal(body.x, healthy.x)
            np.testing.assert_array_equal(body.v, healthy.v)
    status = node.solver_status()
    assert status.level == DiagnosticStatus.ERROR
    assert repr(sick.name) in status.message
    count = len(clouds)
    node.tick()
    assert ros.spin_until(lambda: len(clouds) > count)
    assert np.isfinite(read_xyz(clouds[-1])).all()
    assert clouds[-1].width * clouds[-1].height == node.num_points
    node.diagnostics_callback()                      # the report went out: next window OK
    node.tick()
    assert node.solver_status().level == DiagnosticStatus.OK
