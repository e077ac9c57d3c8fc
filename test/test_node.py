"""
sim_node in-process: every published topic, subscribed topic and service of interface.md.

The node starts paused (see conftest.RosHarness.start) and the tests advance it with
``node.tick()`` or the ``step`` service, so values do not depend on wall time.
"""

import math

import numpy as np
import pytest

pytest.importorskip('rclpy', reason='ROS 2 wheels not installed (pip install -e .[ros])')

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus  # noqa: E402, I100
from geometry_msgs.msg import PoseArray, PoseStamped, WrenchStamped  # noqa: E402
from rosgraph_msgs.msg import Clock  # noqa: E402
from sensor_msgs.msg import PointCloud2  # noqa: E402
from sm_ros.cloud import create_cloud, read_xyz, structured_view  # noqa: E402
from sm_ros.diagnostics import KEYS  # noqa: E402
from sm_ros.node import SimNode  # noqa: E402
from sm_ros.rotations import matrix_from_quaternion, quaternion_from_matrix  # noqa: E402
from std_msgs.msg import String  # noqa: E402
from std_srvs.srv import SetBool, Trigger  # noqa: E402
from visualization_msgs.msg import Marker, MarkerArray  # noqa: E402


ZERO_G = [0.0, 0.0, 0.0]
INTERFACE_KEYS = ('points', 'bodies', 'clusters', 'mode', 'step_ms_mean', 'step_ms_max',
                  'publish_ms_mean', 'tick_ms_max', 'rate_target_hz', 'rate_achieved_hz',
                  'real_time_factor', 'overruns', 'shape_error_rms_m', 'momentum_drift')


def wrench(frame='', force=(0.0, 0.0, 0.0), torque=(0.0, 0.0, 0.0)):
    """Return a WrenchStamped."""
    msg = WrenchStamped()
    msg.header.frame_id = frame
    w = msg.wrench
    w.force.x, w.force.y, w.force.z = (float(c) for c in force)
    w.torque.x, w.torque.y, w.torque.z = (float(c) for c in torque)
    return msg


def pose(gripper, position, quaternion=(0.0, 0.0, 0.0, 1.0)):
    """Return a PoseStamped for a gripper."""
    msg = PoseStamped()
    msg.header.frame_id = gripper
    p, q = msg.pose.position, msg.pose.orientation
    p.x, p.y, p.z = (float(c) for c in position)
    q.x, q.y, q.z, q.w = (float(c) for c in quaternion)
    return msg


def diag_values(status):
    """Return the KeyValue list of a status as a dict."""
    return {kv.key: kv.value for kv in status.values}


# ----------------------------------------------------------------------------------------
# Helpers
# ----------------------------------------------------------------------------------------

def test_quaternion_matrix_roundtrip():
    rng = np.random.default_rng(3)
    for q in rng.normal(size=(50, 4)):
        q /= np.linalg.norm(q)
        r = matrix_from_quaternion(*q)
        np.testing.assert_allclose(matrix_from_quaternion(*quaternion_from_matrix(r)), r,
                                   atol=1e-12)
    assert quaternion_from_matrix(np.eye(3)) == (0.0, 0.0, 0.0, 1.0)
    half_turn = np.diag([-1.0, -1.0, 1.0])
    np.testing.assert_allclose(quaternion_from_matrix(half_turn), (0, 0, 1, 0), atol=1e-12)


# ----------------------------------------------------------------------------------------
# Published topics
# ----------------------------------------------------------------------------------------

def test_points_carry_every_particle_with_body_index(ros, two_body_scene):
    node = ros.start(two_body_scene, frame_id='lab')
    clouds = ros.subscribe(PointCloud2, 'points')
    node.tick()
    node.tick()
    assert ros.spin_until(lambda: len(clouds) == 2)
    msg = clouds[-1]
    soft, stiff = node.world.bodies
    assert msg.width == soft.n + stiff.n and msg.height == 1
    assert msg.header.frame_id == 'lab'
    assert [f.name for f in msg.fields] == ['x', 'y', 'z', 'body']
    np.testing.assert_allclose(read_xyz(msg), np.vstack([soft.x, stiff.x]), atol=1e-6)
    body = structured_view(msg, names=('body',))['body']
    np.testing.assert_array_equal(body, [0] * soft.n + [1] * stiff.n)
    # stamp = simulation time: 2 ticks x 2 substeps x dt
    stamp = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
    assert stamp == pytest.approx(4 * node.get_parameter('dt').value, abs=1e-8)
    assert node.cloud.rebuilds == 2       # the empty start buffer, then once for this scene


def test_poses_are_com_and_shape_match_rotation(ros, cube_scene):
    node = ros.start(cube_scene, gravity=ZERO_G, mode='rigid', alpha=1.0)
    poses = ros.subscribe(PoseArray, 'poses')
    body = node.world.body('cube')
    assert ros.send(WrenchStamped, 'force', wrench('cube', (0.5, 0, 0), (0, 0, 0.02)),
                    until=lambda: 'cube' in node._forces)
    for _ in range(10):
        node.tick()
    assert ros.spin_until(lambda: len(poses) == 10)
    msg = poses[-1]
    assert len(msg.poses) == 1 and msg.header.frame_id == 'world'
    p, q = msg.poses[0].position, msg.poses[0].orientation
    np.testing.assert_allclose([p.x, p.y, p.z], body.com(), atol=1e-12)
    r = matrix_from_quaternion(q.x, q.y, q.z, q.w)
    np.testing.assert_allclose(r, body.rotation(), atol=1e-9)
    angle = math.degrees(2 * math.acos(min(1.0, abs(q.w))))
    assert angle > 0.1 and abs(q.z) > 10 * max(abs(q.x), abs(q.y))   # turned about z


def test_diagnostics_report_every_key(ros, two_body_scene):
    node = ros.start(two_body_scene, diagnostics_rate=50.0, name='diag_node')
    diags = ros.subscribe(DiagnosticArray, '/diagnostics')
    for _ in range(3):
        node.tick()

    def ours():
        return [s for m in diags for s in m.status if s.name == 'diag_node: solver']
    assert ros.spin_until(lambda: ours())
    status = ours()[-1]
    assert status.hardware_id == 'sm_ros'
    # OK, or WARN only because a tick overran its period on a loaded machine (on shared
    # cores the first tick after the start can take longer than the period)
    assert status.level == DiagnosticStatus.OK or (
        status.level == DiagnosticStatus.WARN and 'overran' in status.message), status
    values = diag_values(status)
    assert set(INTERFACE_KEYS) <= set(values) and list(values) == list(KEYS)
    assert values['points'] == str(node.num_points) == '54'
    assert values['bodies'] == '2'
    assert values['clusters'] == '2'
    assert values['mode'] == 'linear,rigid'
    assert values['rate_target_hz'] == '60'
    for key in INTERFACE_KEYS:
        if key != 'mode':
            float(values[key])        # plain decimal strings
            assert 'e' not in values[key].lower()
    assert float(values['step_ms_max']) > 0.0
    assert float(values['shape_error_rms_m']) >= 0.0


def test_diagnostics_warn_on_overrun(ros, cube_scene):
    node = ros.start(cube_scene, rate=1000.0, substeps=400)
    node.tick()                        # 400 steps cannot fit in a 1 ms period
    status = node.solver_status()
    assert status.level == DiagnosticStatus.WARN
    assert 'overran' in status.message
    assert int(diag_values(status)['overruns']) >= 1


def test_diagnostics_momentum_drift_without_external_force(ros, cube_scene):
    node = ros.start(cube_scene, gravity=ZERO_G, alpha=0.3, clusters=2)
    body = node.world.body('cube')
    v = np.zeros((body.n, 3))
    v[:, 0] = 1.0
    v[0] = (0.0, 3.0, -1.0)              # a deformation mode: particles move apart
    body.set_state(v=v)
    for _ in range(20):
        node.tick()
    values = diag_values(node.solver_status())
    assert values['momentum_drift_measured'] == 'true'
    assert float(values['momentum_drift']) < 1e-9


def test_clock_when_publish_clock(ros, cube_scene):
    node = ros.start(cube_scene, publish_clock=True)
    clocks = ros.subscribe(Clock, '/clock')
    node.tick()
    node.tick()
    assert ros.spin_until(lambda: len(clocks) == 2)
    t = clocks[-1].clock.sec + 1e-9 * clocks[-1].clock.nanosec
    assert t == pytest.approx(node.sim_time) and node.sim_time > 0.0
    # off: the publisher goes away at the next tick
    from rclpy.parameter import Parameter
    node.set_parameters([Parameter('publish_clock', value=False)])
    node.tick()
    assert node.pub_clock is None
    assert node.count_publishers('/clock') == 0


def test_markers_follow_mesh_surface(ros, scene_file):
    pytest.importorskip('trimesh')
    from pathlib import Path
    mesh = Path(__file__).resolve().parent.parent / 'config' / 'meshes' / 'torus.stl'
    path = scene_file(f"""
        bodies:
          - name: ring
            shape: mesh
            file: {mesh}
            fill: vertices
            mass: 1.0
            position: [0.0, 0.0, 1.0]
          - name: block
            shape: box
            size: [0.1, 0.1, 0.1]
            spacing: 0.05
            position: [1.0, 0.0, 1.0]
    """)
    node = ros.start(path)
    markers = ros.subscribe(MarkerArray, 'markers')
    assert ros.spin_until(lambda: node.pub_markers.get_subscription_count() > 0)
    node.tick()
    assert ros.spin_until(lambda: markers)
    adds = [m for m in markers[-1].markers if m.action == Marker.ADD]
    assert len(adds) == 1                       # only the mesh body has a surface
    m = adds[0]
    assert m.type == Marker.TRIANGLE_LIST and m.ns == 'ring' and m.header.frame_id == 'world'
    ring, meta = node.world.body('ring'), node.metas[0]
    faces = meta.surface.faces
    assert len(m.points) == 3 * len(faces)
    expected = np.asarray(meta.surface.vertices(ring.x))[faces].reshape(-1, 3)
    got = np.array([[p.x, p.y, p.z] for p in m.points])
    np.testing.assert_allclose(got, expected, atol=1e-12)


# ----------------------------------------------------------------------------------------
# Subscribed topics
# ----------------------------------------------------------------------------------------

def test_force_moves_com_by_expected_amount(ros, cube_scene):
    node = ros.start(cube_scene, gravity=ZERO_G)
    body = node.world.body('cube')
    c0 = body.com()
    assert ros.send(WrenchStamped, 'force', wrench('cube', (1.0, -2.0, 0.5)),
                    until=lambda: 'cube' in node._forces)
    ticks = 6
    for _ in range(ticks):
        node.tick()
    n = ticks * node.get_parameter('substeps').value
    h = node.get_parameter('dt').value
    a = np.array([1.0, -2.0, 0.5]) / 2.0                 # F / M, M = 2 kg
    # symplectic Euler: x_n - x_0 = h^2 a n (n + 1) / 2
    np.testing.assert_allclose(body.com() - c0, h * h * a * n * (n + 1) / 2, rtol=1e-9)


def test_torque_changes_angular_momentum(ros, cube_scene):
    node = ros.start(cube_scene, gravity=ZERO_G, mode='rigid', alpha=1.0)
    body = node.world.body('cube')
    assert ros.send(WrenchStamped, 'force', wrench('cube', torque=(0.0, 0.0, 0.01)),
                    until=lambda: 'cube' in node._forces)
    node.tick()
    t = node.sim_time
    l_com = body.angular_momentum(about=body.com())
    np.testing.assert_allclose(l_com, [0.0, 0.0, 0.01 * t], rtol=0.05, atol=1e-6)
    np.testing.assert_allclose(body.momentum(), 0.0, atol=1e-12)


def test_force_empty_frame_acts_on_every_body_and_zero_clears(ros, two_body_scene):
    node = ros.start(two_body_scene, gravity=ZERO_G, ground__enabled=False)
    assert ros.send(WrenchStamped, 'force', wrench('', (0.0, 0.0, 3.0)),
                    until=lambda: len(node._forces) == 2)
    for body in node.world.bodies:
        np.testing.assert_array_equal(body.wrench[0], [0.0, 0.0, 3.0])
    assert ros.send(WrenchStamped, 'force', wrench('soft'),
                    until=lambda: 'soft' not in node._forces)
    soft, stiff = node.world.bodies
    np.testing.assert_array_equal(soft.wrench[0], 0.0)
    np.testing.assert_array_equal(stiff.wrench[0], [0.0, 0.0, 3.0])


def test_force_timeout_clears_a_stale_force(ros, cube_scene):
    node = ros.start(cube_scene, gravity=ZERO_G, force_timeout=0.05)
    body = node.world.body('cube')
    import time
    sent = time.monotonic()
    assert ros.send(WrenchStamped, 'force', wrench('cube', (1.0, 0.0, 0.0)),
                    until=lambda: 'cube' in node._forces)
    node.tick()
    assert body.wrench[0][0] == 1.0          # held while fresh

    def cleared():
        node.tick()
        return not body.wrench[0].any()
    assert ros.spin_until(cleared, timeout=5.0)
    assert time.monotonic() - sent >= 0.05


def test_force_held_without_timeout(ros, cube_scene):
    node = ros.start(cube_scene, gravity=ZERO_G, force_timeout=0.0)
    body = node.world.body('cube')
    assert ros.send(WrenchStamped, 'force', wrench('cube', (1.0, 0.0, 0.0)),
                    until=lambda: 'cube' in node._forces)
    node._forces['cube'] -= 3600.0             # as if sent an hour ago
    node.tick()
    assert body.wrench[0][0] == 1.0


def test_grab_attaches_particles_within_radius_and_moves_them(ros, cube_scene):
    node = ros.start(cube_scene, gravity=ZERO_G, grab_radius=0.06)
    body = node.world.body('cube')
    corner = body.x[np.argmax(body.x.sum(axis=1))].copy()       # (+, +, +) corner
    near = np.flatnonzero(np.linalg.norm(body.x - corner, axis=1) <= 0.06)
    assert 1 < near.size < body.n
    assert ros.send(PoseStamped, 'grab', pose('hand', corner),
                    until=lambda: 'hand' in node.grippers)
    np.testing.assert_array_equal(np.sort(node.grippers['hand'][0].indices), near)
    np.testing.assert_array_equal(body.kinematic_indices, near)
    rest = body.x[near].copy()
    # move 5 cm up and turn 90 degrees about z around the gripper
    s = math.sqrt(0.5)
    target = corner + (0.0, 0.0, 0.05)
    assert ros.send(PoseStamped, 'grab', pose('hand', target, (0.0, 0.0, s, s)),
                    until=lambda: np.allclose(node.grippers['hand'][0].targets[0],
                                              target + (rest[0] - corner) @ np.array(
                                                  [[0, 1, 0], [-1, 0, 0], [0, 0, 1]])))
    node.tick()
    rz = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    np.testing.assert_allclose(body.x[near], target + (rest - corner) @ rz.T, atol=1e-12)
    others = np.setdiff1d(np.arange(body.n), near)
    assert body.x[others, 2].mean() > 0.99        # the rest follows through shape matching


def test_two_grippers_on_one_body(ros, cube_scene):
    node = ros.start(cube_scene, gravity=ZERO_G, grab_radius=0.01)
    body = node.world.body('cube')
    lo, hi = body.x[0].copy(), body.x[-1].copy()
    assert ros.send(PoseStamped, 'grab', pose('left', lo), until=lambda: 'left' in node.grippers)
    assert ros.send(PoseStamped, 'grab', pose('right', hi),
                    until=lambda: 'right' in node.grippers)
    np.testing.assert_array_equal(body.kinematic_indices, [0, body.n - 1])
    assert ros.send(String, 'release', String(data='left'),
                    until=lambda: 'left' not in node.grippers)
    np.testing.assert_array_equal(body.kinematic_indices, [body.n - 1])


def test_release_all_frees_particles(ros, cube_scene):
    node = ros.start(cube_scene, gravity=[0.0, 0.0, -9.81], grab_radius=0.2)
    body = node.world.body('cube')
    assert ros.send(PoseStamped, 'grab', pose('hand', body.com()),
                    until=lambda: 'hand' in node.grippers)
    node.tick()
    z_held = body.com()[2]
    node.tick()
    assert body.com()[2] == pytest.approx(z_held)             # held against gravity
    assert ros.send(String, 'release', String(data=''), until=lambda: not node.grippers)
    assert body.kinematic_indices.size == 0
    node.tick()
    node.tick()
    assert body.com()[2] < z_held - 1e-4                       # falls again


@pytest.mark.parametrize('mode', ['replace', 'add'])
def test_cloud_in_builds_a_body_where_the_cloud_was(ros, two_body_scene, mode):
    node = ros.start(two_body_scene, cloud_in_mode=mode, max_points=1000)
    pts = np.random.default_rng(5).uniform(-0.05, 0.05, (400, 3)) + (2.0, 1.0, 0.5)
    pts[::50] = np.nan                                          # 8 NaN points dropped
    cloud = create_cloud(pts, 'world')
    assert ros.send(PointCloud2, 'cloud_in', cloud,
                    until=lambda: 'cloud_in' in [b.name for b in node.world.bodies])
    names = [b.name for b in node.world.bodies]
    assert names == (['cloud_in'] if mode == 'replace' else ['soft', 'stiff', 'cloud_in'])
    body = node.world.body('cloud_in')
    finite = pts[np.isfinite(pts).all(axis=1)].astype(np.float32)
    assert body.n == len(finite) == 392
    np.testing.assert_allclose(body.com(), finite.mean(axis=0), atol=1e-6)
    assert len(node.metas) == len(names)
    clouds = ros.subscribe(PointCloud2, 'points')
    node.tick()
    assert ros.spin_until(lambda: clouds)
    assert clouds[-1].width == node.num_points


def test_cloud_in_is_downsampled_to_max_points(ros, cube_scene):
    node = ros.start(cube_scene, max_points=100)
    pts = np.random.default_rng(6).uniform(0.0, 0.3, (5000, 3))
    assert ros.send(PointCloud2, 'cloud_in', create_cloud(pts),
                    until=lambda: node.world.bodies[0].name == 'cloud_in')
    body = node.world.bodies[0]
    assert 1 < body.n <= 100
    assert np.all(body.x >= -1e-9) and np.all(body.x <= 0.3 + 1e-9)


def test_cloud_in_add_twice_gets_new_names(ros, cube_scene):
    node = ros.start(cube_scene, cloud_in_mode='add')
    pts = np.random.default_rng(8).uniform(0.0, 0.1, (30, 3))
    for k in (2, 3):
        assert ros.send(PointCloud2, 'cloud_in', create_cloud(pts),
                        until=lambda k=k: len(node.world.bodies) == k)
    assert [b.name for b in node.world.bodies] == ['cube', 'cloud_in', 'cloud_in_2']


# ----------------------------------------------------------------------------------------
# Services
# ----------------------------------------------------------------------------------------

def test_reset_restores_initial_state_and_releases(ros, cube_scene):
    node = ros.start(cube_scene, grab_radius=0.03)
    body = node.world.body('cube')
    x0 = body.x.copy()
    assert ros.send(WrenchStamped, 'force', wrench('cube', (5.0, 0, 0)),
                    until=lambda: node._forces)
    assert ros.send(PoseStamped, 'grab', pose('hand', body.com() + (0, 0, 0.01)),
                    until=lambda: node.grippers)
    for _ in range(5):
        node.tick()
    assert not np.allclose(body.x, x0)
    t = node.sim_time
    res = ros.call(Trigger, 'sim_node/reset')
    assert res.success
    np.testing.assert_array_equal(body.x, x0)
    np.testing.assert_array_equal(body.v, 0.0)
    assert not node.grippers and not node._forces
    assert not body.wrench[0].any() and body.kinematic_indices.size == 0
    assert node.sim_time == t                     # stamps never go backwards


def test_reset_clears_plastic_state(ros, scene_file):
    path = scene_file("""
        colliders: {ground: false}
        bodies:
          - {name: clay, shape: box, size: [0.1, 0.1, 0.1], spacing: 0.05, mass: 1.0,
             position: [0, 0, 1], plasticity: {yield: 0.0, creep: 50.0, max: 1.0}}
    """)
    node = ros.start(path, gravity=ZERO_G, grab_radius=0.01)
    body = node.world.body('clay')
    corner = body.x[-1].copy()
    assert ros.send(PoseStamped, 'grab', pose('hand', corner), until=lambda: node.grippers)
    assert ros.send(PoseStamped, 'grab', pose('hand', corner + (0.05, 0.05, 0.05)),
                    until=lambda: node.grippers['hand'][0].targets[0][0] > corner[0])
    for _ in range(10):
        node.tick()
    assert not np.allclose(body.plastic_state, np.eye(3))
    assert ros.call(Trigger, 'sim_node/reset').success
    np.testing.assert_allclose(body.plastic_state, np.eye(3)[None].repeat(
        body.num_clusters, 0), atol=1e-12)


def test_pause_stops_the_clock_and_resume_restarts_it(ros, cube_scene):
    node = ros.start(cube_scene, paused=False, rate=200.0)
    assert ros.spin_until(lambda: node.sim_time > 0.0)
    res = ros.call(SetBool, 'sim_node/pause', SetBool.Request(data=True))
    assert res.success and node.paused
    t = node.sim_time
    calls = node.timer_calls
    assert ros.spin_until(lambda: node.timer_calls >= calls + 5)
    assert node.sim_time == t
    res = ros.call(SetBool, 'sim_node/pause', SetBool.Request(data=False))
    assert res.success and not node.paused
    assert ros.spin_until(lambda: node.sim_time > t)


def test_step_advances_exactly_one_tick_while_paused(ros, cube_scene):
    node = ros.start(cube_scene, substeps=3, dt=0.01)
    clouds = ros.subscribe(PointCloud2, 'points')
    assert ros.call(SetBool, 'sim_node/pause', SetBool.Request(data=True)).success
    res = ros.call(Trigger, 'sim_node/step')
    assert res.success
    assert node.sim_time == pytest.approx(0.03)
    assert node.world.time == pytest.approx(0.03)
    assert ros.spin_until(lambda: len(clouds) == 1)
    np.testing.assert_allclose(read_xyz(clouds[0]), node.world.bodies[0].x, atol=1e-6)


def test_step_refused_while_running(ros, cube_scene):
    node = ros.start(cube_scene, paused=False, rate=1.0)  # first tick only after 1 s
    t = node.sim_time
    res = ros.call(Trigger, 'sim_node/step')
    assert not res.success and 'not paused' in res.message
    assert node.sim_time == t


def test_wall_clock_timer_ticks_at_rate(ros, cube_scene):
    node = ros.start(cube_scene, paused=False, rate=100.0, substeps=1, dt=0.001)
    import time
    t0 = time.monotonic()
    assert ros.spin_until(lambda: node.timer_calls >= 20)
    elapsed = time.monotonic() - t0
    assert 0.15 < elapsed < 2.0
    assert node.sim_time == pytest.approx(node.timer_calls * 0.001, abs=1e-9)


def test_node_default_name_and_relative_topics(ros, cube_scene):
    node = ros.start(cube_scene)
    assert node.get_name() == 'sim_node'
    ns = ros.namespace
    topics = dict(node.get_topic_names_and_types())
    for name, kind in [('points', 'sensor_msgs/msg/PointCloud2'),
                       ('poses', 'geometry_msgs/msg/PoseArray'),
                       ('markers', 'visualization_msgs/msg/MarkerArray'),
                       ('force', 'geometry_msgs/msg/WrenchStamped'),
                       ('grab', 'geometry_msgs/msg/PoseStamped'),
                       ('release', 'std_msgs/msg/String'),
                       ('cloud_in', 'sensor_msgs/msg/PointCloud2')]:
        assert topics[f'{ns}/{name}'] == [kind]
    assert topics['/diagnostics'] == ['diagnostic_msgs/msg/DiagnosticArray']
    services = dict(node.get_service_names_and_types())
    assert services[f'{ns}/sim_node/reset'] == ['std_srvs/srv/Trigger']
    assert services[f'{ns}/sim_node/pause'] == ['std_srvs/srv/SetBool']
    assert services[f'{ns}/sim_node/step'] == ['std_srvs/srv/Trigger']


def test_publishers_are_reliable_and_overridable(ros, cube_scene):
    from rclpy.parameter import Parameter
    from rclpy.qos import ReliabilityPolicy
    node = ros.start(cube_scene)
    for pub in (node.pub_points, node.pub_poses, node.pub_diagnostics, node.pub_markers):
        assert pub.qos_profile.reliability == ReliabilityPolicy.RELIABLE
    ns = ros.namespace
    assert node.has_parameter(f'qos_overrides.{ns}/points.publisher.reliability')
    other = SimNode('other', paused=True, context=ros.context, namespace=ns + '_b',
                    parameter_overrides=[
                        Parameter('scene', value=cube_scene),
                        Parameter(f'qos_overrides.{ns}_b/points.publisher.reliability',
                                  value='best_effort')])
    try:
        assert other.pub_points.qos_profile.reliability == ReliabilityPolicy.BEST_EFFORT
    finally:
        other.destroy_node()


def test_default_scene_runs_without_arguments(ros):
    node = ros.start()
    assert node.get_parameter('scene').value == ''
    assert len(node.world.bodies) >= 1 and node.num_points > 100
    z0 = node.world.bodies[0].com()[2]
    for _ in range(5):
        node.tick()
    assert node.world.bodies[0].com()[2] < z0          # it drops


def test_marker_buffer_serialises_in_place():
    from rclpy.serialization import deserialize_message
    from sm_ros.markers import MarkerBuffer
    buf = MarkerBuffer()
    rng = np.random.default_rng(9)
    a, b = rng.random((6, 3)), rng.random((3, 3))
    first = deserialize_message(buf.fill([('a', 0, a), ('b', 2, b)], 'map', 4, 5), MarkerArray)
    assert [m.action for m in first.markers] == [Marker.DELETEALL, Marker.ADD, Marker.ADD]
    a2 = rng.random((6, 3))
    later = deserialize_message(buf.fill([('a', 0, a2), ('b', 2, b)], 'map', 6, 7),
                                MarkerArray)
    assert [m.action for m in later.markers] == [Marker.ADD, Marker.ADD]
    m = later.markers[0]
    assert (m.ns, m.id, m.type, m.header.frame_id) == ('a', 0, Marker.TRIANGLE_LIST, 'map')
    assert (m.header.stamp.sec, m.header.stamp.nanosec) == (6, 7)
    np.testing.assert_array_equal([[p.x, p.y, p.z] for p in m.points], a2)
    np.testing.assert_array_equal([[p.x, p.y, p.z] for p in later.markers[1].points], b)
    rebuilds = buf.rebuilds
    gone = deserialize_message(buf.fill([('b', 2, b)], 'map', 8, 0), MarkerArray)
    assert gone.markers[0].action == Marker.DELETEALL and buf.rebuilds > rebuilds


def test_timer_runs_on_steady_clock_even_with_use_sim_time(ros, cube_scene):
    # with a ROS-time timer and use_sim_time, no /clock would mean no tick ever
    node = ros.start(cube_scene, paused=False, rate=100.0, use_sim_time=True)
    assert node.get_clock().ros_time_is_active
    assert ros.spin_until(lambda: node.timer_calls >= 5)
    assert node.sim_time > 0.0
