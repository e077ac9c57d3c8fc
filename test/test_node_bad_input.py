"""
Check sim_node's handling of bad input (interface.md, 'Bad input').

Every rule refused with a reason, the state unchanged, one throttled warn line naming the
topic; non-finite bodies recover.
"""

import array
import math

import numpy as np
import pytest

pytest.importorskip('rclpy', reason='ROS 2 wheels not installed (pip install -e .[ros])')

from diagnostic_msgs.msg import DiagnosticStatus  # noqa: E402, I100
from geometry_msgs.msg import PoseStamped, WrenchStamped  # noqa: E402
from rcl_interfaces.msg import Log  # noqa: E402
from sensor_msgs.msg import PointCloud2, PointField  # noqa: E402
from sm_ros.cloud import create_cloud, read_xyz  # noqa: E402
from std_msgs.msg import String  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402

from test_node import pose, wrench  # noqa: E402


NAN, INF = float('nan'), float('inf')


def snapshot(node):
    """Everything a refused input must leave alone."""
    return {
        'bodies': [b.name for b in node.world.bodies],
        'x': [b.x.copy() for b in node.world.bodies],
        'v': [b.v.copy() for b in node.world.bodies],
        'wrench': [np.concatenate(b.wrench) for b in node.world.bodies],
        'kinematic': [b.kinematic_indices for b in node.world.bodies],
        'forces': dict(node._forces),
        'grippers': {k: [a.indices.tolist() for a in v] for k, v in node.grippers.items()},
        'params': [b.params for b in node.world.bodies],
        'world': node.world,
    }


def assert_unchanged(node, before):
    """Compare a snapshot with the node's state now."""
    after = snapshot(node)
    assert after['world'] is before['world']
    assert after['bodies'] == before['bodies']
    for key in ('x', 'v', 'wrench', 'kinematic'):
        for a, b in zip(after[key], before[key]):
            np.testing.assert_array_equal(a, b)
    for key in ('forces', 'grippers', 'params'):
        assert after[key] == before[key], key


@pytest.fixture
def node(ros, two_body_scene):
    """Return a paused node on the two-body scene with a held force and a gripper."""
    n = ros.start(two_body_scene, grab_radius=0.03)
    assert ros.send(WrenchStamped, 'force', wrench('soft', (0.0, 0.0, 1.0)),
                    until=lambda: 'soft' in n._forces)
    com = n.world.body('stiff').com()
    assert ros.send(PoseStamped, 'grab', pose('hand', com), until=lambda: 'hand' in n.grippers)
    n.tick()
    return n


# ----------------------------------------------------------------------------------------
# force
# ----------------------------------------------------------------------------------------

@pytest.mark.parametrize('force, torque', [
    ((NAN, 0.0, 0.0), (0.0, 0.0, 0.0)),
    ((0.0, INF, 0.0), (0.0, 0.0, 0.0)),
    ((0.0, 0.0, 0.0), (0.0, 0.0, -INF)),
    ((0.0, 0.0, 0.0), (NAN, NAN, NAN)),
])
def test_force_non_finite(ros, node, force, torque):
    before = snapshot(node)
    reason = ros.refusal(node, 'force', lambda: ros.publisher(WrenchStamped, 'force').publish(
        wrench('soft', force, torque)))
    assert 'NaN or Inf' in reason
    assert_unchanged(node, before)


def test_force_out_of_range(ros, node):
    before = snapshot(node)
    reason = ros.refusal(node, 'force', lambda: ros.publisher(WrenchStamped, 'force').publish(
        wrench('soft', (1e12, 0.0, 0.0))))
    assert 'out of range' in reason
    assert_unchanged(node, before)


def test_force_unknown_body(ros, node):
    before = snapshot(node)
    reason = ros.refusal(node, 'force', lambda: ros.publisher(WrenchStamped, 'force').publish(
        wrench('nobody', (1.0, 0.0, 0.0))))
    assert "unknown body 'nobody'" in reason and 'soft' in reason
    assert_unchanged(node, before)


# ----------------------------------------------------------------------------------------
# grab / release
# ----------------------------------------------------------------------------------------

@pytest.mark.parametrize('position, quaternion, why', [
    ((NAN, 0.0, 0.5), (0.0, 0.0, 0.0, 1.0), 'NaN or Inf'),
    ((0.0, 0.0, 0.5), (0.0, 0.0, INF, 1.0), 'NaN or Inf'),
    ((0.0, 0.0, 0.5), (0.0, 0.0, 0.0, 0.0), 'not a rotation'),
    ((1e9, 0.0, 0.5), (0.0, 0.0, 0.0, 1.0), 'beyond'),
])
@pytest.mark.parametrize('gripper', ['hand', 'new'])
def test_grab_bad_pose(ros, node, position, quaternion, why, gripper):
    before = snapshot(node)
    reason = ros.refusal(node, 'grab', lambda: ros.publisher(PoseStamped, 'grab').publish(
        pose(gripper, position, quaternion)))
    assert why in reason
    assert_unchanged(node, before)


def test_grab_empty_gripper_name(ros, node):
    before = snapshot(node)
    reason = ros.refusal(node, 'grab', lambda: ros.publisher(PoseStamped, 'grab').publish(
        pose('', (0.0, 0.0, 0.5))))
    assert 'empty gripper name' in reason
    assert_unchanged(node, before)


def test_grab_nothing_within_radius(ros, node):
    before = snapshot(node)
    reason = ros.refusal(node, 'grab', lambda: ros.publisher(PoseStamped, 'grab').publish(
        pose('far', (10.0, 10.0, 10.0))))
    assert 'no particle within grab_radius' in reason
    assert_unchanged(node, before)
    assert 'far' not in node.grippers


def test_release_unknown_gripper(ros, node):
    before = snapshot(node)
    reason = ros.refusal(node, 'release', lambda: ros.publisher(String, 'release').publish(
        String(data='nobody')))
    assert "unknown gripper 'nobody'" in reason and 'hand' in reason
    assert_unchanged(node, before)


# ----------------------------------------------------------------------------------------
# cloud_in
# ----------------------------------------------------------------------------------------

def _cloud():
    return create_cloud(np.random.default_rng(4).uniform(0.0, 0.1, (20, 3)), 'world')


def _malformed():
    no_z = _cloud()
    no_z.fields = no_z.fields[:2]
    step = _cloud()
    step.point_step = 8
    short = _cloud()
    short.data = array.array('B', bytes(short.data)[:-4])
    wide = _cloud()
    wide.width = 21
    empty = PointCloud2()
    empty.fields = _cloud().fields
    empty.point_step = 12
    dtype = _cloud()
    dtype.fields = [PointField(name=f.name, offset=f.offset, datatype=99, count=1)
                    for f in dtype.fields]
    all_nan = create_cloud(np.full((5, 3), NAN))
    return [('no z field', no_z, 'no field z'),
            ('point_step', step, 'past point_step'),
            ('truncated data', short, 'does not match'),
            ('width mismatch', wide, 'does not match'),
            ('empty', empty, 'empty cloud'),
            ('unknown datatype', dtype, 'unknown datatype'),
            ('all NaN', all_nan, 'no finite point'),
            ('huge coordinates', create_cloud(np.full((3, 3), 1e9)), 'beyond')]


@pytest.mark.parametrize('case', _malformed(), ids=lambda c: c[0])
def test_cloud_in_malformed(ros, node, case):
    _, msg, why = case
    before = snapshot(node)
    reason = ros.refusal(node, 'cloud_in', lambda: ros.publisher(
        PointCloud2, 'cloud_in').publish(msg))
    assert why in reason
    assert_unchanged(node, before)


def test_refusal_logs_one_throttled_warn_line_naming_topic(ros, node):
    lines = ros.subscribe(Log, '/rosout', qos=100)
    assert ros.spin_until(lambda: ros.probe.count_publishers('/rosout') > 0)
    node._refusal_logged.clear()
    pub = ros.publisher(WrenchStamped, 'force')
    before = node.refused.get('force', 0)
    for _ in range(5):
        pub.publish(wrench('ghost', (1.0, 0.0, 0.0)))
    assert ros.spin_until(lambda: node.refused.get('force', 0) == before + 5)
    assert ros.spin_until(lambda: any('ghost' in m.msg for m in lines))
    ours = [m for m in lines if m.name.endswith('sim_node') and 'ghost' in m.msg]
    assert len(ours) == 1
    assert ours[0].level == Log.WARN
    assert ours[0].msg.startswith('force: refused: ') and "unknown body 'ghost'" in ours[0].msg


# ----------------------------------------------------------------------------------------
# Recovery from a non-finite body
# ----------------------------------------------------------------------------------------

def test_non_finite_body_is_reset_and_reported(ros, two_body_scene):
    node = ros.start(two_body_scene)
    clouds = ros.subscribe(PointCloud2, 'points')
    for _ in range(3):
        node.tick()
    soft, stiff = node.world.bodies
    node.tick()
    stiff_x = stiff.x.copy()
    # test hook: poison the live state the way a numerical blow-up would
    soft._x[3, 1] = math.nan
    soft._v[0, 0] = math.inf
    stiff_next = None
    node.tick()
    assert soft.is_finite()
    np.testing.assert_array_equal(soft.x, soft.x_init)
    assert not np.array_equal(stiff.x, stiff_x)            # the other body stepped on
    stiff_next = stiff.x.copy()
    status = node.solver_status()
    assert status.level == DiagnosticStatus.ERROR
    assert "'soft'" in status.message and 'reset' in status.message
    assert {kv.key: kv.value for kv in status.values}['nonfinite_resets'] == '1'
    assert ros.spin_until(lambda: len(clouds) >= 5)
    assert np.isfinite(read_xyz(clouds[-1])).all() and clouds[-1].width == node.num_points
    node.diagnostics_callback()                            # report sent: next window is OK
    node.tick()
    assert node.solver_status().level == DiagnosticStatus.OK
    assert not np.array_equal(stiff.x, stiff_next)


def test_unforeseen_error_in_a_callback_is_refused_not_fatal(ros, node, monkeypatch):
    def broken(*args, **kwargs):
        raise RuntimeError('boom')
    monkeypatch.setattr(node.world.body('soft'), 'set_wrench', broken)
    reason = ros.refusal(node, 'force', lambda: ros.publisher(WrenchStamped, 'force').publish(
        wrench('soft', (0.0, 1.0, 0.0))))
    assert 'RuntimeError' in reason and 'boom' in reason
    node.tick()                                      # still running
    assert ros.call(Trigger, 'sim_node/reset').success


# ----------------------------------------------------------------------------------------
# a scene parameter naming a file that is no scene
# ----------------------------------------------------------------------------------------

def test_scene_parameter_naming_a_file_of_secrets_answers_without_its_text(ros, node,
                                                                            tmp_path):
    """``ros2 param set /sim_node scene /etc/passwd`` from another node: refused with the
    path, the line and the kind of value; the file's text is in no reply and no log line,
    and the scene is left as it was."""
    from rcl_interfaces.msg import Parameter as ParameterMsg, ParameterType, ParameterValue
    from rcl_interfaces.srv import SetParameters
    secret = 'hunter2-s3cr3t'
    logs = ros.subscribe(Log, '/rosout')
    before = snapshot(node)
    for text in (f'root:x:0:0:root:/root:/bin/bash\nadmin:{secret}:1000\n',
                 f'password: {secret}\n', f'token: "{secret}\n'):
        path = tmp_path / 'passwd'
        path.write_text(text)
        value = ParameterValue(type=ParameterType.PARAMETER_STRING, string_value=str(path))
        request = SetParameters.Request(parameters=[ParameterMsg(name='scene', value=value)])
        result = ros.call(SetParameters, f'{node.get_fully_qualified_name()}/set_parameters',
                          request).results[0]
        assert not result.successful
        assert result.reason.startswith(f'scene: {path}: ')
        assert 'line 1' in result.reason or 'line 2' in result.reason
        assert secret not in result.reason and 'bash' not in result.reason
    ros.spin_for(0.2)
    node.apply_pending()
    assert_unchanged(node, before)
    assert all(secret not in m.msg for m in logs)
