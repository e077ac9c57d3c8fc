"""Writing a world's state into an earlier copy of it (``sm_ros.world_sync``): the copy then
steps exactly as a fresh deep copy would; a copy of another make is refused."""

import numpy as np
import pytest

from sm_ros.error_estimate import ErrorEstimate, copy_world, estimate
from sm_ros.sim import Simulation
from sm_ros.stats import ErrorEstimateSchedule
from sm_ros.world_sync import Twin, copy_blocks, sync_world


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


@pytest.mark.parametrize('scene', ['grasp', 'many', 'paper_8_clusters'])
def test_compiled_replay_writes_what_the_python_replay_writes(scene):
    world, dt = _world(scene)
    for _ in range(4):
        world.step(dt)
    twins = [Twin(copy_world(world)), Twin(copy_world(world))]
    for twin in twins:
        twin.world.step(dt)
        assert twin.sync(world)               # the walk: plans made
    twins[1]._plan.compiled = False           # np.copyto block by block
    for _ in range(3):
        for twin in twins:
            twin.world.step(dt)
        world.step(dt)
        plans = [t._plan for t in twins]
        assert all(t.sync(world) for t in twins)
        assert [t._plan for t in twins] == plans   # replayed, not walked again
        assert len(twins[0]._plan._blocks) > 20
        assert _same(twins[0].world, twins[1].world) and _same(twins[0].world, world)
        for twin in twins:
            twin.world.step(dt)
        assert _same(twins[0].world, twins[1].world)


def test_copy_blocks_copies_as_numpy():
    rng = np.random.default_rng(3)
    src = [rng.random(n) for n in (1, 7, 1000)] + [rng.integers(0, 9, (4, 5)).T,
                                                   np.arange(6, dtype=np.uint8)]
    dst = [np.zeros_like(a) for a in src]
    addr = lambda arrs: np.array([a.ctypes.data for a in arrs], dtype=np.int64)  # noqa: E731
    copy_blocks(addr(dst), addr(src), np.array([a.nbytes for a in src], dtype=np.int64))
    for d, s in zip(dst, src):
        assert np.array_equal(d, s) and d.strides == s.strides


def _stepped_twin(name):
    """A world of scene ``name`` and a twin of it, each stepped on its own since the copy
    was made (so a sync has state to write): (world, twin, dt)."""
    world, dt = _world(name)
    world.step(dt)
    twin = Twin(copy_world(world))
    twin.world.step(dt)
    world.step(dt)
    return world, twin, dt


def test_a_replaced_array_on_either_side_is_walked_again():
    world, twin, dt = _stepped_twin('many')
    assert twin.sync(world)
    plan = twin._plan
    b = twin.world.bodies[3]
    b._grab_tgt = np.zeros((0, 3))            # the copy's own place holds another array
    assert twin.sync(world) and twin._plan is not plan
    plan = twin._plan
    assert twin.sync(world) and twin._plan is plan
    world.bodies[5]._grab_tgt = np.zeros((2, 3))    # the source's: of another shape
    assert not twin.sync(world)
    assert twin.refused.endswith('_grab_tgt: array'), twin.refused


def test_a_plain_place_that_holds_an_array_is_refused():
    world, twin, dt = _stepped_twin('many')
    assert twin.sync(world) and twin.sync(world)
    world.bodies[0]._shape_err = np.zeros(1)  # was a float (or None): a plain value
    assert not twin.sync(world)
    assert 'Body._shape_err' in twin.refused, twin.refused


def test_a_synced_copy_keeps_its_flag_list_and_coupling_flags():
    world, twin, dt = _stepped_twin('many')
    for _ in range(2):                        # the walk, then a replay
        assert twin.sync(world)
        fl, key = twin.world._flat._fl, twin.world._coupling_key
        assert fl is not None and key == world._coupling_key
        twin.world.step(dt)
        assert twin.world._flat._fl is fl and twin.world._coupling_key is key
        world.step(dt)
