"""
collider_pose and collider_wrench through sim_node.

Refused poses (unknown or static collider, NaN, zero or non-unit quaternion, out of range)
change nothing; a good pose is reached at the end of the next tick; the grasp scene's
fingers lift the ball and the published wrenches' vertical components add up to its
weight; per-body contact counts in /diagnostics.
"""

import math

import numpy as np
import pytest

pytest.importorskip('rclpy', reason='ROS 2 wheels not installed (pip install -e .[ros])')

from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402, I100
from geometry_msgs.msg import PoseStamped, WrenchStamped  # noqa: E402

from test_node import diag_values, pose  # noqa: E402

NAN, INF = float('nan'), float('inf')

SCENE = """
    colliders:
      ground: false
      boxes:
        - {name: table, center: [0, 0, -0.1], size: [1, 1, 0.2]}
      capsules:
        - {name: finger, kinematic: true, center: [0.5, 0, 0.5], radius: 0.02,
           length: 0.1, orientation: [0, 0, 0, 1]}
    bodies:
      - name: cube
        shape: box
        size: [0.1, 0.1, 0.1]
        spacing: 0.05
        mass: 1.0
        position: [0.0, 0.0, 0.06]
        damping: 0.2
"""


@pytest.fixture
def node(ros, scene_file):
    return ros.start(scene_file(SCENE))


def _state(node):
    w = node.world
    return (w.collider_pose('finger'), list(w._cset.motion), w._cset.rows.copy(),
            [b.x.copy() for b in w.bodies])


def _ticks(ros, node, got, n):
    """Tick ``n`` times, receiving each tick's two wrenches before the next (QoS depth)."""
    for k in range(n):
        node.tick()
        want = 2 * (k + 1)
        assert ros.spin_until(lambda want=want: len(got) >= want)


@pytest.mark.parametrize('frame, position, quaternion, why', [
    ('ghost', (0, 0, 0), (0, 0, 0, 1), "unknown collider 'ghost' (named colliders: finger, "
                                       'table)'),
    ('', (0, 0, 0), (0, 0, 0, 1), 'unknown collider'),
    ('table', (0, 0, 0), (0, 0, 0, 1), 'static'),
    ('finger', (NAN, 0, 0), (0, 0, 0, 1), 'position must be 3 finite numbers'),
    ('finger', (0, INF, 0), (0, 0, 0, 1), 'position must be 3 finite numbers'),
    ('finger', (0, 0, 0), (NAN, 0, 0, 1), 'quaternion of 4 finite numbers'),
    ('finger', (0, 0, 0), (0, 0, 0, 0), 'zero quaternion'),
    ('finger', (0, 0, 0), (0, 0, 0, 0.5), 'unit quaternion, its norm is 0.5'),
    ('finger', (0, 0, 2e6), (0, 0, 0, 1), 'beyond'),
])
def test_collider_pose_refused_and_nothing_changes(ros, node, frame, position, quaternion,
                                                   why):
    node.tick()
    before = _state(node)
    reason = ros.refusal(node, 'collider_pose', lambda: ros.publisher(
        PoseStamped, 'collider_pose').publish(pose(frame, position, quaternion)))
    assert why in reason
    after = _state(node)
    for a, b in zip(before[0], after[0]):
        np.testing.assert_array_equal(a, b)
    assert before[1] == after[1]
    np.testing.assert_array_equal(before[2], after[2])
    for a, b in zip(before[3], after[3]):
        np.testing.assert_array_equal(a, b)


def test_collider_pose_reached_by_the_end_of_the_next_tick(ros, node):
    q = (0.0, 0.0, math.sin(0.25), math.cos(0.25))        # 0.5 rad about z
    msg = pose('finger', (0.4, 0.1, 0.5), q)
    refused = sum(node.refused.values())
    assert ros.send(PoseStamped, 'collider_pose', msg,
                    until=lambda: node.world._cset.motion[1] is not None)
    assert sum(node.refused.values()) == refused
    np.testing.assert_allclose(node.world.collider_pose('finger')[0], (0.5, 0, 0.5))
    node.tick()
    p, got = node.world.collider_pose('finger')
    np.testing.assert_allclose(p, (0.4, 0.1, 0.5), atol=1e-12)
    np.testing.assert_allclose(got, q, atol=1e-12)


def test_collider_wrench_and_contact_diagnostics(ros, node):
    """The table carries the cube: its wrench is the cube's weight; the finger touches
    nothing (zero wrench); /diagnostics counts the cube's contacts."""
    got = ros.subscribe(WrenchStamped, 'collider_wrench')
    diags = ros.subscribe(DiagnosticArray, '/diagnostics')
    assert ros.spin_until(lambda: node.pub_collider_wrench.get_subscription_count() > 0)
    _ticks(ros, node, got, 240)
    last = {m.header.frame_id: m for m in got[-60:]}
    assert set(last) == {'table', 'finger'}
    fz = np.mean([m.wrench.force.z for m in got[-120:] if m.header.frame_id == 'table'])
    assert fz == pytest.approx(-9.81, rel=0.02)
    assert last['finger'].wrench.force.z == 0.0
    node.diagnostics_callback()
    assert ros.spin_until(lambda: any(s.name.endswith(': contacts')
                                      for d in diags for s in d.status))
    status = [s for d in diags for s in d.status if s.name.endswith(': contacts')][-1]
    values = diag_values(status)
    assert int(values['cube.contacts']) >= 9            # the bottom layer of 3 x 3
    assert 0.0 < float(values['cube.penetration_max_m']) < 0.01


def test_grasp_scene_published_wrenches_carry_the_ball(ros):
    """The bundled grasp scene through the node: once the fingers have lifted the ball,
    the vertical components of the two fingers' published wrenches add up to the ball's
    weight within 5 % (averaged over 1 s of ticks)."""
    node = ros.start('grasp')
    got = ros.subscribe(WrenchStamped, 'collider_wrench')
    assert ros.spin_until(lambda: node.pub_collider_wrench.get_subscription_count() > 0)
    ticks = int(round(node.sim.params['rate'] * 3.0))
    per_s = int(round(node.sim.params['rate']))
    _ticks(ros, node, got, ticks)
    ball = node.world.body('ball')
    assert ball.x[:, 2].min() > 0.05                     # held in the air
    last = got[-2 * per_s:]
    fz = sum(m.wrench.force.z for m in last) / per_s     # both fingers, mean per tick
    assert fz == pytest.approx(-ball.total_mass * 9.81, rel=0.05)
