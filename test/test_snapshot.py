"""Saving a world's state and putting it back (``sm_ros.core.snapshot``): after a save,
steps at other step sizes and a load, the world steps bit for bit as a twin that never
took part; this catches solver state the snapshot misses wherever it is added."""

import numpy as np
import pytest

from sm_ros.core.snapshot import Snapshot


def _stack():
    """Four stiff boxes dropped on one another (stacking: warm-started impulses; they fall
    asleep after about 0.5 s at rest), one of them plastic and one on records."""
    from sm_ros.bench.common import cube_lattice
    from sm_ros.core import BodyParams, Ground, World
    world = World()
    world.set_colliders(ground=Ground(friction=0.6))
    for k in range(4):
        params = BodyParams(mode='linear', alpha=0.9, clusters=2 if k == 1 else 1,
                            plastic_yield=0.01 if k == 2 else 0.0,
                            plastic_creep=5.0 if k == 2 else 0.0)
        world.add_body(cube_lattice(4, 0.1, (0.01 * k, 0.0, 0.02 + 0.11 * k)), 0.01, params,
                       name=f'box{k}')
    return world


def _twins(scene):
    if scene == 'stack':
        return [_stack(), _stack()], 1.0 / 120.0
    from sm_ros.sim import Simulation
    sims = [Simulation({'scene': scene, 'error_estimate.rate': 0.0}) for _ in range(2)]
    return [s.world for s in sims], float(sims[0].params['dt'])


def _state(world):
    return [(b.name, np.array(b.x), np.array(b.v), b.plastic_state, b.asleep,
             b.limit_counts, b.shape_error_rms()) for b in world.bodies]


def _assert_same(a, b):
    for sa, sb in zip(_state(a), _state(b)):
        for u, v in zip(sa, sb):
            if isinstance(u, np.ndarray):
                assert u.tobytes() == v.tobytes(), sa[0]
            else:
                assert u == v, sa[0]


@pytest.mark.parametrize('scene,lead', [('default', 30), ('many', 120), ('grasp', 20),
                                        ('plastic', 40), ('sheet_rod', 20),
                                        ('stack', 12), ('stack', 150)])
def test_save_steps_load_leave_the_world_as_a_twin_that_never_took_part(scene, lead):
    """Bodies packed, on records or stepped alone, contact with warm starts, sleep,
    plasticity, kinematic colliders and their wrenches: everything a later step reads."""
    (world, twin), h = _twins(scene)
    for w in (world, twin):
        for _ in range(lead):
            w.step(h)
    snap = Snapshot()
    for rounds in range(2):                 # the second save reuses the first walk
        snap.save(world)
        for _ in range(3):
            world.step(0.5 * h)             # another step size: packs and records rebuilt
        world.step(h)
        moved = _state(world)
        snap.load(world)
        assert not all(u.tobytes() == v.tobytes() for u, v in
                       zip([s[1] for s in moved], [s[1] for s in _state(world)]))
        _assert_same(world, twin)
        for w in (world, twin):
            for _ in range(5):
                w.step(h)
        _assert_same(world, twin)
    wrenches, theirs = world.take_collider_wrenches(), twin.take_collider_wrenches()
    assert wrenches.keys() == theirs.keys()
    for name, (force, torque) in wrenches.items():
        assert force.tobytes() == theirs[name][0].tobytes(), name
        assert torque.tobytes() == theirs[name][1].tobytes(), name
    assert world.time == twin.time


def test_a_snapshot_loads_only_into_its_own_world():
    (world, twin), h = _twins('default')
    snap = Snapshot()
    snap.save(world)
    with pytest.raises(ValueError):
        snap.load(twin)
