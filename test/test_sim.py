"""
Check sm_ros.sim.Simulation without ROS.

Pending parameter changes wait for the next tick, a scene swap keeps changes queued after
it, forces time out, grippers hold particles, and a body that goes non-finite is reset.
"""

import math
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from sm_ros.inputs import InputError
from sm_ros.sim import ConfigError, ParameterError, Simulation

CUBE = """
    colliders:
      ground: false
    bodies:
      - {name: cube, shape: box, size: [0.1, 0.1, 0.1], spacing: 0.05, mass: 2.0,
         position: [0.0, 0.0, 1.0]}
"""
TWO = """
    bodies:
      - {name: soft, shape: box, size: [0.1, 0.1, 0.1], spacing: 0.05, position: [0, 0, 0.5]}
      - {name: stiff, shape: box, size: [0.1, 0.1, 0.1], spacing: 0.05,
         position: [0.5, 0, 0.5], alpha: 0.9, mode: rigid}
"""


class FakeClock:
    """A clock the test advances by hand."""

    def __init__(self):
        self.now = 100.0

    def __call__(self):
        return self.now


@pytest.fixture
def scene(tmp_path):
    """Return a function that writes a scene YAML and returns its path."""
    def write(text, name='scene'):
        path = tmp_path / f'{name}.yaml'
        path.write_text(textwrap.dedent(text))
        return str(path)
    return write


@pytest.fixture
def clock():
    """A FakeClock."""
    return FakeClock()


@pytest.fixture
def cube(scene, clock):
    """A Simulation of a 27-particle cube in space (no gravity, no ground)."""
    return Simulation({'scene': scene(CUBE), 'gravity': [0.0, 0.0, 0.0]}, clock=clock)


def test_simulation_needs_no_ros():
    code = ('import sys, sm_ros.sim, sm_ros.inputs, sm_ros.stats, sm_ros.rotations; '
            "print([m for m in sys.modules if m.split('.')[0] in ('rclpy', 'rcl_interfaces')])")
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                         check=True).stdout
    assert out.strip() == '[]'


def test_bad_start_values_are_refused(scene):
    with pytest.raises(ConfigError, match='alpha must be in'):
        Simulation({'scene': scene(CUBE), 'alpha': 2.0})
    with pytest.raises(ConfigError, match='no such scene'):
        Simulation({'scene': 'no_such_scene'})


def test_changes_wait_for_the_next_tick(cube):
    body = cube.world.body('cube')
    cube.set_params({'alpha': 0.8, 'substeps': 3})
    assert body.params.alpha == 0.5 and cube.params['substeps'] == 2
    assert cube.latest()['alpha'] == 0.8
    cube.tick()
    assert body.params.alpha == 0.8 and cube.params['substeps'] == 3 and not cube.pending
    assert cube.sim_ns == 3 * int(round(1e9 / 120.0))


def test_a_refused_change_changes_nothing(cube):
    cube.set_params({'beta': 0.3})
    before = (dict(cube.params), dict(cube.pending))
    for changes in ({'alpha': 1.5}, {'mode': 'soft'}, {'dt': 1e-12},
                    {'beta': 0.9, 'clusters': 0}, {'scene': 'no_such_scene'}):
        with pytest.raises(ParameterError):
            cube.set_params(changes)
        assert (cube.params, cube.pending) == before
    cube.tick()
    assert cube.world.body('cube').params.beta == 0.3


def test_body_change_queued_after_a_scene_change_applies_to_the_new_scene(cube, scene):
    cube.set_params({'scene': scene(TWO, 'two')})
    cube.set_params({'alpha': 0.8})
    cube.set_params({'mode': 'quadratic', 'gravity': [0.0, 0.0, -1.0]})
    cube.tick()
    soft, stiff = cube.world.body('soft'), cube.world.body('stiff')
    assert (soft.params.alpha, soft.params.mode) == (0.8, 'quadratic')
    assert (stiff.params.alpha, stiff.params.mode) == (0.9, 'rigid')    # the scene's own
    np.testing.assert_array_equal(cube.world.gravity, [0.0, 0.0, -1.0])


def test_body_change_queued_before_a_scene_change_builds_the_scene(cube, scene):
    cube.set_params({'alpha': 0.7})
    cube.set_params({'scene': scene(TWO, 'two')})
    assert cube.pending_scene.values['alpha'] == 0.7
    cube.tick()
    assert cube.world.body('soft').params.alpha == 0.7


def test_scene_swap_keeps_unchanged_bodies_and_clears_inputs(scene, clock):
    sim = Simulation({'scene': scene(TWO)}, clock=clock)
    for _ in range(3):
        sim.tick()
    x = sim.world.body('soft').x.copy()
    sim.set_force('soft', [1.0, 0, 0], [0, 0, 0])
    sim.set_params({'scene': scene(TWO)})
    sim.apply_pending()
    np.testing.assert_array_equal(sim.world.body('soft').x, x)
    assert not sim.forces


def test_force_is_held_then_times_out(cube, clock):
    cube.set_params({'force_timeout': 0.5})
    cube.set_force('cube', [2.0, 0.0, 0.0], [0.0, 0.0, 0.0])
    assert cube.forces == {'cube': clock.now}
    cube.tick()
    h = 2 / 120.0
    # 2 N on 2 kg for two steps of 1/120 s: 1 m/s^2 x h x 2 (momentum of 2 kg)
    np.testing.assert_allclose(cube.world.body('cube').momentum(), [2 * h, 0, 0], atol=1e-12)
    clock.now += 0.4
    cube.tick()
    assert 'cube' in cube.forces
    clock.now += 0.2
    cube.tick()                                      # expired before this tick's steps
    assert not cube.forces
    p = cube.world.body('cube').momentum().copy()
    cube.tick()
    np.testing.assert_allclose(cube.world.body('cube').momentum(), p, atol=1e-12)


def test_zero_wrench_clears_and_bad_wrenches_are_refused(cube):
    cube.set_force('', [1.0, 0, 0], [0, 0, 0.1])
    assert set(cube.forces) == {'cube'}
    cube.set_force('cube', [0, 0, 0], [0, 0, 0])
    assert not cube.forces
    with pytest.raises(InputError, match=r"unknown body 'x' \(bodies: cube\)"):
        cube.set_force('x', [1.0, 0, 0], [0, 0, 0])
    with pytest.raises(InputError, match='NaN or Inf'):
        cube.set_force('cube', [math.nan, 0, 0], [0, 0, 0])
    with pytest.raises(InputError, match='out of range'):
        cube.set_force('cube', [2e9, 0, 0], [0, 0, 0])
    assert not cube.forces


def test_grippers_hold_and_release(cube):
    cube.set_params({'grab_radius': 0.06})
    cube.apply_pending()
    corner = cube.world.body('cube').x[0].copy()
    cube.grab('hand', corner, [0, 0, 0, 1])
    held = cube.grippers['hand'][0].indices
    assert 0 in held and len(held) == 4          # the corner and its 3 neighbours
    cube.grab('hand', corner + [0.1, 0, 0], [0, 0, 0, 1])
    cube.tick()
    np.testing.assert_allclose(cube.world.body('cube').x[0], corner + [0.1, 0, 0], atol=1e-9)
    with pytest.raises(InputError, match='no particle within grab_radius'):
        cube.grab('far', [5.0, 5.0, 5.0], [0, 0, 0, 1])
    with pytest.raises(InputError, match='not a rotation'):
        cube.grab('hand', corner, [0, 0, 0, 0])
    with pytest.raises(InputError, match="unknown gripper 'x'"):
        cube.release('x')
    cube.release('')
    assert not cube.grippers


def test_nonfinite_body_is_reset_and_loses_its_inputs(scene, clock):
    sim = Simulation({'scene': scene(TWO)}, clock=clock)
    soft = sim.world.body('soft')
    sim.set_force('soft', [1.0, 0, 0], [0, 0, 0])
    sim.grab('g', soft.x[0], [0, 0, 0, 1])
    sim.tick()
    soft._x[3, 1] = math.nan
    sim.tick()
    assert soft.is_finite()
    np.testing.assert_array_equal(soft.x, soft.x_init)
    assert sim.stats.nonfinite_total == 1 and sim.stats.nonfinite == ['soft']
    assert 'soft' not in sim.forces and 'g' not in sim.grippers
    assert sim.momentum.drift is None


def test_cloud_replaces_or_joins(cube):
    pts = np.random.default_rng(0).uniform(-0.1, 0.1, (200, 3)) + [0, 0, 2]
    assert cube.add_cloud(pts)[0] == 'cloud_in'
    assert [b.name for b in cube.world.bodies] == ['cloud_in']
    cube.set_params({'cloud_in_mode': 'add'})
    cube.apply_pending()
    assert cube.add_cloud(pts)[0] == 'cloud_in_2'
    with pytest.raises(InputError, match='beyond'):
        cube.add_cloud(pts * 1e7)
    assert cube.cloud_count == 2 and len(cube.world.bodies) == 2


def test_momentum_drift_is_measured_without_external_force(cube):
    cube.world.body('cube').set_state(v=np.tile([0.1, 0.0, 0.0], (27, 1)))
    cube.tick()
    cube.tick()
    assert cube.momentum.drift is not None and cube.momentum.drift < 1e-12
    cube.set_force('cube', [1.0, 0, 0], [0, 0, 0])
    cube.tick()
    assert cube.momentum.drift is None
    assert cube.status_values()['momentum_drift'] is None


def test_momentum_is_summed_once_per_run_and_when_read(cube):
    """Not twice per tick: once for the reference, then only when the drift is read."""
    body = cube.world.body('cube')
    body.set_state(v=np.tile([0.1, 0.0, 0.0], (27, 1)) + np.linspace(0, 0.05, 27)[:, None])
    p0 = body.momentum().copy()
    for _ in range(50):
        cube.tick()
    assert cube.momentum.sums == 1
    drift = cube.momentum.drift
    assert cube.momentum.sums == 2
    scale = float(np.dot(body.m, np.linalg.norm(body.v, axis=1)))
    assert drift == pytest.approx(np.linalg.norm(body.momentum() - p0) / scale, abs=1e-15)
    assert cube.momentum.drift == drift and cube.momentum.sums == 2     # not summed again
    cube.tick()
    assert cube.status_values()['momentum_drift'] is not None and cube.momentum.sums == 3


def test_hooks_see_ticks_and_changes(cube):
    ticks, changes = [], []
    cube.add_tick_listener(lambda sim: ticks.append(sim.sim_ns))
    cube.on_change(['rate', 'frame_id'], changes.append)
    cube.tick()
    cube.set_params({'rate': 30.0, 'alpha': 0.6})
    cube.tick()
    assert ticks == [cube.sim_ns // 2, cube.sim_ns]
    assert changes == [{'rate': 30.0}]
    assert cube.stats.ticks == 2 and cube.stats.publishes == 2


def test_reset_restores_bodies_and_clears_inputs(cube):
    cube.set_force('cube', [1.0, 0, 0], [0, 0, 0])
    cube.tick()
    cube.reset()
    body = cube.world.body('cube')
    np.testing.assert_array_equal(body.x, body.x_init)
    assert not cube.forces and not cube.grippers


def test_world_remove_body(scene):
    sim = Simulation({'scene': scene(TWO)})
    sim.world.remove_body('soft')
    assert [b.name for b in sim.world.bodies] == ['stiff']
    with pytest.raises(KeyError):
        sim.world.remove_body('soft')
    sim.world.step(1.0 / 120.0)
