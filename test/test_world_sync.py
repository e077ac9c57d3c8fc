"""Writing a world's state into an earlier copy of it (``sm_ros.world_sync``): the copy then
steps exactly as a fresh deep copy would; a copy of another make is refused."""

import numpy as np
import pytest

from sm_ros.error_estimate import ErrorEstimate, copy_world, estimate
from sm_ros.sim import Simulation
from sm_ros.stats import ErrorEstimateSchedule
from sm_ros.world_sync import Twin, sync_world


def _world(scene):
    sim = Simulation({'scene': scene})
    return sim.world, float(sim.params['dt'])


def _same(a, b):
    return a.time == b.time and all(
        np.array_equal(p.x, q.x) and np.array_equal(p.v, q.v)
        and np.array_equal(p.plastic_state, q.plastic_state)
        for p, q in zip(a.bodies, b.bodies))


# grasp: kinematic capsules, contact, grabs by friction; plastic: plastic bodies on a
# bump; many: 64 packed bodies; sheet_rod: self-collision; paper_8_clusters: set layout
@pytest.mark.parametrize('scene', ['grasp', 'plastic', 'many', 'sheet_rod',
                                   'paper_8_clusters'])
def test_synced_copy_steps_as_a_fresh_copy_bit_for_bit(scene):
    world, dt = _world(scene)
    for _ in range(5):
        world.step(dt)
    twin = Twin(copy_world(world))
    for rnd in range(3):                     # the first sync walks, the later replay
        for _ in range(3):                   # the copy and the world go apart
            twin.world.step(dt)
        for _ in range(2):
            world.step(dt)
        before = copy_world(world)
        assert twin.sync(world)
        assert _same(world, before)          # the source is only read
        assert twin._plan is not None
        fresh = copy_world(world)
        for _ in range(4):
            twin.world.step(dt)
            fresh.step(dt)
        assert _same(twin.world, fresh), (scene, rnd)


def test_a_copy_of_another_make_is_refused():
    world, dt = _world('many')
    twin = Twin(copy_world(world))
    world.step(dt)
    assert not twin.sync(world)              # buffers a first step makes: the copy has none
    assert twin.refused.endswith('missing'), twin.refused
    twin = Twin(copy_world(world))
    twin.world.step(dt)
    world.step(dt)
    assert twin.sync(world)
    world.add_body(np.zeros((8, 3)) + np.arange(8)[:, None] * 0.01 + (0.0, 0.0, 2.0),
                   masses=0.1, name='extra')
    assert not twin.sync(world)              # a body more (the plan's check, then the walk)
    assert twin.refused == 'World._bodies: dict keys', twin.refused
    assert not sync_world(copy_world(_world('grasp')[0]), world)
    assert not sync_world(twin.world, object())


def test_estimates_reuse_the_last_copies_and_give_the_fresh_copies_value():
    world, dt = _world('grasp')
    for _ in range(3):
        world.step(dt)
    first = ErrorEstimate(world, dt, 1, window=0.05)
    first.advance(first.n)
    spares = first.spares()
    for _ in range(4):
        world.step(dt)
    second = ErrorEstimate(world, dt, 1, window=0.05, spares=spares)
    assert second.coarse is spares['coarse'].world and second.fine is spares['fine'].world
    second.advance(second.n)
    assert second.result['error_m'] == estimate(world, dt, 1, window=0.05)['error_m']


def test_schedule_hands_the_copies_on_and_drops_them_when_off():
    world, dt = _world('many')
    sched, now = ErrorEstimateSchedule(), [0.0]

    def clock():
        now[0] += 1.0
        return now[0]
    sched.advance(world, dt, 1, 1e9, clock)
    first = sched.running
    while sched.running is not None:
        sched.advance(world, dt, 1, 1e9, clock)
    coarse = first.spares()['coarse'].world
    sched.advance(world, dt, 1, 1e9, clock)            # the next estimate: same copies
    assert sched.running.coarse is coarse
    sched.advance(world, dt, 1, 0.0, clock)            # off
    assert sched._spares == {} and sched.running is None
