"""
Check sim_node's parameters.

Each one changes what it should, between two steps; bad values are refused with a reason
and change nothing.
"""

import math

import numpy as np
import pytest

pytest.importorskip('rclpy', reason='ROS 2 wheels not installed (pip install -e .[ros])')

from geometry_msgs.msg import PoseArray  # noqa: E402, I100
from rcl_interfaces.msg import ParameterType  # noqa: E402
from rcl_interfaces.srv import DescribeParameters, SetParameters  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from sensor_msgs.msg import PointCloud2  # noqa: E402
from sm_ros.cloud import create_cloud  # noqa: E402
from sm_ros.params import NODE_PARAMS as PARAMS  # noqa: E402


INTERFACE_PARAMS = ('mode', 'alpha', 'beta', 'plasticity.yield', 'plasticity.creep',
                    'plasticity.max', 'clusters', 'dt', 'substeps', 'rate', 'gravity',
                    'ground.enabled', 'ground.height', 'ground.friction', 'ground.restitution',
                    'grab_radius', 'force_timeout', 'scene', 'frame_id', 'publish_clock',
                    'diagnostics_rate', 'max_points', 'cloud_in_mode', 'material_dt',
                    'contact.enabled', 'contact.friction', 'contact.restitution',
                    'contact.radius_scale', 'max_speed', 'max_turn', 'error_estimate.rate')
#: Parameters sm_ros adds to the interface (live view, recording, error estimate budget).
EXTRA_PARAMS = ('foxglove.port', 'foxglove.host', 'record.path', 'record.split_s',
                'contact.stacking', 'contact.rigid', 'contact.sleep', 'contact.sleep_speed',
                'contact.sleep_time')


def set_param(node, name, value):
    """Set one parameter the way the parameter service does; return the result."""
    return node.set_parameters([Parameter(name, value=value)])[0]


def refused(node, name, value, reason=None):
    """Check that a value is not accepted, with ``reason`` in the message, and changes nothing."""
    before = node.get_parameter(name).value
    result = set_param(node, name, value)
    assert not result.successful, f'{name}={value!r} was accepted'
    assert result.reason
    if reason:
        assert reason in result.reason, result.reason
    after = node.get_parameter(name).value
    if isinstance(before, float) and math.isnan(before):
        assert math.isnan(after)
    else:
        assert list(np.atleast_1d(after)) == list(np.atleast_1d(before))
    assert name not in node._pending
    return result.reason


def test_every_interface_parameter_is_declared_with_a_description(ros, cube_scene):
    node = ros.start(cube_scene)
    assert {p.name for p in PARAMS} == set(INTERFACE_PARAMS) | set(EXTRA_PARAMS)
    for p in PARAMS:
        d = node.describe_parameter(p.name)
        assert d.description, p.name
        if d.type == ParameterType.PARAMETER_DOUBLE and p.name not in ('ground.height',):
            assert d.floating_point_range, p.name
        if d.type == ParameterType.PARAMETER_INTEGER:
            lowest = 0 if p.name == 'foxglove.port' else 1
            assert d.integer_range and d.integer_range[0].from_value == lowest, p.name
    assert node.describe_parameter('alpha').floating_point_range[0].to_value == 1.0
    assert node.get_parameter('gravity').type_ == Parameter.Type.DOUBLE_ARRAY


def test_describe_and_set_through_the_parameter_services(ros, cube_scene):
    node = ros.start(cube_scene)
    res = ros.call(DescribeParameters, 'sim_node/describe_parameters',
                   DescribeParameters.Request(names=['alpha']))
    assert 'alpha' in res.descriptors[0].description.lower() or res.descriptors[0].description
    assert res.descriptors[0].floating_point_range[0].from_value == 0.0
    req = SetParameters.Request(parameters=[Parameter('alpha', value=1.5).to_parameter_msg()])
    res = ros.call(SetParameters, 'sim_node/set_parameters', req)
    assert not res.results[0].successful and 'alpha' in res.results[0].reason
    req = SetParameters.Request(parameters=[Parameter('alpha', value=0.9).to_parameter_msg()])
    assert ros.call(SetParameters, 'sim_node/set_parameters', req).results[0].successful
    node.tick()
    assert node.world.body('cube').params.alpha == 0.9


def test_alpha_applied_between_steps_to_bodies_without_override(ros, two_body_scene):
    node = ros.start(two_body_scene)
    soft, stiff = node.world.bodies
    assert set_param(node, 'alpha', 0.8).successful
    assert soft.params.alpha == 0.5                   # not in the middle: at the next tick
    node.tick()
    assert soft.params.alpha == 0.8
    assert stiff.params.alpha == 0.9                  # the scene overrides it
    refused(node, 'alpha', 1.5, 'out of range')
    refused(node, 'alpha', -0.1)
    refused(node, 'alpha', 'stiff', 'type')
    refused(node, 'alpha', 1, 'type')                # integer for a double
    node.tick()
    assert soft.params.alpha == 0.8


def test_beta(ros, cube_scene):
    node = ros.start(cube_scene)
    assert set_param(node, 'beta', 0.25).successful
    node.tick()
    assert node.world.bodies[0].params.beta == 0.25
    refused(node, 'beta', 2.0)


def test_mode(ros, two_body_scene):
    node = ros.start(two_body_scene)
    soft, stiff = node.world.bodies
    x = soft.x.copy()
    assert set_param(node, 'mode', 'quadratic').successful
    node.apply_pending()
    assert soft.params.mode == 'quadratic' and stiff.params.mode == 'rigid'
    np.testing.assert_array_equal(soft.x, x)          # rebuild keeps the positions
    assert 'rigid, linear, quadratic' in refused(node, 'mode', 'cubic')
    node.tick()
    assert soft.params.mode == 'quadratic'


def test_clusters(ros, scene_file):
    path = scene_file("""
        bodies:
          - {name: slab, shape: box, size: [0.4, 0.4, 0.1], spacing: 0.05, position: [0, 0, 1]}
    """)
    node = ros.start(path)
    body = node.world.bodies[0]
    assert body.num_clusters == 1
    node.tick()
    x, v = body.x.copy(), body.v.copy()
    assert set_param(node, 'clusters', 3).successful
    node.apply_pending()
    assert body.params.clusters == 3 and body.num_clusters > 1
    np.testing.assert_array_equal(body.x, x)
    np.testing.assert_array_equal(body.v, v)
    refused(node, 'clusters', 0)
    refused(node, 'clusters', 65)
    refused(node, 'clusters', 2.0, 'type')


@pytest.mark.parametrize('name, field', [('plasticity.yield', 'plastic_yield'),
                                         ('plasticity.creep', 'plastic_creep'),
                                         ('plasticity.max', 'plastic_max')])
def test_plasticity(ros, cube_scene, name, field):
    node = ros.start(cube_scene)
    assert set_param(node, name, 0.3).successful
    node.tick()
    assert getattr(node.world.bodies[0].params, field) == 0.3
    refused(node, name, -1.0)
    refused(node, name, float('nan'))


def test_plasticity_all_at_once_makes_a_body_plastic(ros, cube_scene):
    node = ros.start(cube_scene)
    results = node.set_parameters_atomically([Parameter('plasticity.yield', value=0.01),
                                              Parameter('plasticity.creep', value=5.0),
                                              Parameter('plasticity.max', value=0.5)])
    assert results.successful
    node.tick()
    assert node.world.bodies[0].params.plastic


def test_dt(ros, cube_scene):
    node = ros.start(cube_scene)
    assert set_param(node, 'dt', 0.004).successful
    node.tick()
    assert node.sim_time == pytest.approx(2 * 0.004)
    assert '> 0' in refused(node, 'dt', 0.0)
    refused(node, 'dt', -0.01)
    refused(node, 'dt', float('inf'))


def test_substeps(ros, cube_scene):
    node = ros.start(cube_scene, dt=0.01)
    assert set_param(node, 'substeps', 5).successful
    node.tick()
    assert node.world.time == pytest.approx(0.05)
    refused(node, 'substeps', 0)
    refused(node, 'substeps', 2.5, 'type')


def test_rate(ros, cube_scene):
    node = ros.start(cube_scene)
    assert abs(node.tick_timer.timer_period_ns - 1e9 / 60.0) < 1.0
    assert set_param(node, 'rate', 200.0).successful
    node.apply_pending()
    assert node.tick_timer.timer_period_ns == 5_000_000
    assert node.solver_status().values[8].value == '200'      # rate_target_hz
    refused(node, 'rate', 0.0)
    refused(node, 'rate', -5.0)


def test_gravity(ros, cube_scene):
    node = ros.start(cube_scene)
    assert set_param(node, 'gravity', [1.0, 0.0, -2.0]).successful
    node.tick()
    np.testing.assert_array_equal(node.world.gravity, [1.0, 0.0, -2.0])
    assert '3 values' in refused(node, 'gravity', [0.0, -9.81])
    refused(node, 'gravity', [0.0, 0.0, float('nan')], 'finite')
    refused(node, 'gravity', [0.0, 0.0, 1e300])
    refused(node, 'gravity', [0, 0, -9], 'type')              # integer array
    node.tick()
    np.testing.assert_array_equal(node.world.gravity, [1.0, 0.0, -2.0])


def test_ground_parameters(ros, cube_scene):
    node = ros.start(cube_scene)          # the cube scene disables its ground ...
    assert node.world.ground is None
    path = cube_scene.replace('scene0', 'scene_g')
    with open(cube_scene) as f:
        text = f.read().replace('ground: false', 'boxes: []')
    with open(path, 'w') as f:
        f.write(text)
    node2 = ros.start(path, name='with_ground')   # ... this one takes the node's ground
    assert node2.world.ground is not None and node2.world.ground.height == 0.0
    ok = node2.set_parameters_atomically([Parameter('ground.height', value=0.5),
                                          Parameter('ground.friction', value=0.8),
                                          Parameter('ground.restitution', value=0.3)])
    assert ok.successful
    node2.tick()
    g = node2.world.ground
    assert (g.height, g.friction, g.restitution) == (0.5, 0.8, 0.3)
    assert set_param(node2, 'ground.enabled', False).successful
    node2.tick()
    assert node2.world.ground is None
    refused(node2, 'ground.friction', -0.1)
    refused(node2, 'ground.restitution', 1.5)
    refused(node2, 'ground.height', float('nan'))
    refused(node2, 'ground.enabled', 'yes', 'type')


def test_contact_parameters(ros, scene_file):
    path = scene_file("""
        contact: {restitution: 0.25}
        bodies:
          - {name: a, shape: box, size: [0.1, 0.1, 0.1], spacing: 0.05, position: [0, 0, 0.1]}
          - {name: b, shape: box, size: [0.1, 0.1, 0.1], spacing: 0.05, position: [0, 0, 0.3],
             contact_radius: 0.03}
    """)
    node = ros.start(path)
    c = node.world.contact_params
    assert (c.enabled, c.friction, c.restitution) == (True, 0.5, 0.25)   # scene wins
    assert node.world.contact_radius('a') == pytest.approx(0.025)
    ok = node.set_parameters_atomically([Parameter('contact.friction', value=0.8),
                                         Parameter('contact.restitution', value=0.5),
                                         Parameter('contact.radius_scale', value=2.0)])
    assert ok.successful
    node.tick()
    c = node.world.contact_params
    assert (c.friction, c.restitution, c.radius_scale) == (0.8, 0.25, 2.0)
    assert node.world.contact_radius('a') == pytest.approx(0.05)
    assert node.world.contact_radius('b') == 0.03          # given in the scene: kept
    assert c.stacking                                       # the default
    assert set_param(node, 'contact.stacking', False).successful
    node.tick()
    assert node.world.contact_params.stacking is False
    refused(node, 'contact.stacking', 'yes', 'type')
    refused(node, 'contact.stacking', 1, 'type')
    assert c.sleep and (c.sleep_speed, c.sleep_time) == (0.01, 0.5)    # the defaults
    assert set_param(node, 'contact.sleep', False).successful
    assert set_param(node, 'contact.sleep_speed', 0.05).successful
    assert set_param(node, 'contact.sleep_time', 2.0).successful
    node.tick()
    c = node.world.contact_params
    assert (c.sleep, c.sleep_speed, c.sleep_time) == (False, 0.05, 2.0)
    refused(node, 'contact.sleep', 'no', 'type')
    refused(node, 'contact.sleep_speed', -0.01)
    refused(node, 'contact.sleep_time', float('inf'))
    assert set_param(node, 'contact.enabled', False).successful
    node.tick()
    assert node.world.contact is None
    refused(node, 'contact.friction', -0.1)
    refused(node, 'contact.restitution', 1.5)
    refused(node, 'contact.radius_scale', 0.0)
    refused(node, 'contact.friction', float('nan'))


def test_ground_stops_a_falling_body(ros, scene_file):
    path = scene_file("""
        bodies:
          - {name: b, shape: box, size: [0.1, 0.1, 0.1], spacing: 0.05, position: [0, 0, 0.1]}
    """)
    node = ros.start(path, ground__height=0.02)
    for _ in range(60):
        node.tick()
    assert node.world.bodies[0].x[:, 2].min() >= 0.02 - 1e-9


def test_grab_radius(ros, cube_scene):
    from geometry_msgs.msg import PoseStamped
    node = ros.start(cube_scene)
    assert set_param(node, 'grab_radius', 0.051).successful
    node.tick()
    body = node.world.bodies[0]
    msg = PoseStamped()
    msg.header.frame_id = 'g'
    msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = (float(c)
                                                                     for c in body.com())
    msg.pose.orientation.w = 1.0
    assert ros.send(PoseStamped, 'grab', msg, until=lambda: 'g' in node.grippers)
    assert node.grippers['g'][0].indices.size == 7        # centre and its 6 neighbours
    refused(node, 'grab_radius', 0.0)


def test_force_timeout(ros, cube_scene):
    node = ros.start(cube_scene)
    assert set_param(node, 'force_timeout', 2.5).successful
    node.tick()
    assert node._p['force_timeout'] == 2.5
    refused(node, 'force_timeout', -1.0)


def test_scene_reload_and_bad_scene(ros, cube_scene, two_body_scene, scene_file):
    node = ros.start(cube_scene)
    assert set_param(node, 'scene', two_body_scene).successful
    assert [b.name for b in node.world.bodies] == ['cube']     # applied at the next tick
    node.tick()
    assert [b.name for b in node.world.bodies] == ['soft', 'stiff']
    assert [m.name for m in node.metas] == ['soft', 'stiff']
    bad = scene_file("""
        bodies:
          - {name: sponge, shape: box, size: [0.1, 0.1, 0.1], spacing: -1}
    """)
    reason = refused(node, 'scene', bad)
    assert bad in reason and 'sponge' in reason and 'spacing' in reason
    reason = refused(node, 'scene', '/no/such/scene.yaml')
    assert 'no such scene' in reason
    node.tick()
    assert [b.name for b in node.world.bodies] == ['soft', 'stiff']


def test_body_parameter_set_right_after_a_scene_change_is_applied(ros, cube_scene,
                                                                  two_body_scene):
    """Set scene, then alpha, then tick: the new scene's bodies have the new alpha."""
    node = ros.start(cube_scene)
    assert set_param(node, 'scene', two_body_scene).successful
    assert set_param(node, 'alpha', 0.8).successful
    assert set_param(node, 'mode', 'quadratic').successful
    node.tick()
    soft, stiff = node.world.body('soft'), node.world.body('stiff')
    assert (soft.params.alpha, soft.params.mode) == (0.8, 'quadratic')
    assert (stiff.params.alpha, stiff.params.mode) == (0.9, 'rigid')    # the scene's own


def test_scene_reload_keeps_state_of_unchanged_bodies(ros, two_body_scene):
    node = ros.start(two_body_scene)
    for _ in range(5):
        node.tick()
    x = [b.x.copy() for b in node.world.bodies]
    assert set_param(node, 'scene', two_body_scene).successful
    old = node.world
    node.apply_pending()
    assert node.world is not old
    for b, xb in zip(node.world.bodies, x):
        np.testing.assert_array_equal(b.x, xb)


def test_bundled_scene_by_name(ros):
    node = ros.start('rope')
    assert len(node.world.bodies) >= 1
    assert node.get_parameter('scene').value == 'rope'


def test_frame_id(ros, cube_scene):
    node = ros.start(cube_scene)
    clouds = ros.subscribe(PointCloud2, 'points')
    poses = ros.subscribe(PoseArray, 'poses')     # poses are built only when consumed
    assert set_param(node, 'frame_id', 'map').successful
    node.tick()
    assert ros.spin_until(lambda: clouds and poses)
    assert clouds[-1].header.frame_id == 'map'
    assert poses[-1].header.frame_id == 'map'
    refused(node, 'frame_id', '', 'empty')


def test_diagnostics_rate(ros, cube_scene):
    node = ros.start(cube_scene)
    assert node.diagnostics_timer.timer_period_ns == 1_000_000_000
    assert set_param(node, 'diagnostics_rate', 4.0).successful
    node.apply_pending()
    assert node.diagnostics_timer.timer_period_ns == 250_000_000
    assert set_param(node, 'diagnostics_rate', 0.0).successful
    node.apply_pending()
    assert node.diagnostics_timer is None
    refused(node, 'diagnostics_rate', -1.0)


def test_publish_clock_parameter(ros, cube_scene):
    node = ros.start(cube_scene)
    assert node.pub_clock is None
    assert set_param(node, 'publish_clock', True).successful
    node.tick()
    assert node.pub_clock is not None
    refused(node, 'publish_clock', 1, 'type')


def test_max_points(ros, cube_scene):
    node = ros.start(cube_scene)
    assert set_param(node, 'max_points', 50).successful
    node.tick()
    pts = np.random.default_rng(2).uniform(0.0, 0.2, (2000, 3))
    assert ros.send(PointCloud2, 'cloud_in', create_cloud(pts),
                    until=lambda: node.world.bodies[0].name == 'cloud_in')
    assert node.world.bodies[0].n <= 50
    refused(node, 'max_points', 0)


def test_cloud_in_mode(ros, cube_scene):
    node = ros.start(cube_scene)
    assert set_param(node, 'cloud_in_mode', 'add').successful
    node.tick()
    assert node._p['cloud_in_mode'] == 'add'
    assert 'replace, add' in refused(node, 'cloud_in_mode', 'merge')


def test_unknown_body_parameter_combination_is_refused_atomically(ros, cube_scene):
    node = ros.start(cube_scene)
    result = node.set_parameters_atomically([Parameter('alpha', value=0.7),
                                             Parameter('beta', value=7.0)])
    assert not result.successful
    node.tick()
    assert node.world.bodies[0].params.alpha == 0.5


def test_record_split_s_is_zero_or_a_second_and_more(ros, cube_scene):
    """record.split_s: 0 (one file) or 1 s to a day; a file per message and below is refused."""
    node = ros.start(cube_scene)
    refused(node, 'record.split_s', -1.0)
    refused(node, 'record.split_s', 0.5, 'record.split_s must be 0 (one file) or >= 1 s')
    refused(node, 'record.split_s', 86401.0)
    for good in (0.0, 1.0, 30.0):
        assert set_param(node, 'record.split_s', good).successful
