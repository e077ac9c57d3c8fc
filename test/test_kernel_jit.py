"""The packed step's compiled entry (``packed.Pack._resolve``) and a pack's refusal to be
copied."""

import numpy as np
import pytest

import sm_ros.core.packed as packed
from sm_ros.core import Ground, World


def _world():
    world = World()
    world.set_colliders(ground=Ground(height=0.0, friction=0.5, restitution=0.2))
    g = np.arange(6) * 0.02
    x0 = np.stack(np.meshgrid(g, g, g, indexing='ij'), axis=-1).reshape(-1, 3) + 0.01
    world.add_body(x0, masses=0.01, velocities=np.tile((0.0, 0.0, -1.0), (len(x0), 1)))
    return world


def test_pack_entry_follows_the_colliders_and_steps_as_the_dispatcher():
    """The pack step calls ``step_packed``'s compiled entry resolved for the
    world's collider arrays and gravity; replacing the colliders resolves it again, and
    the states are bit for bit those of calls through Numba's dispatcher."""
    from sm_ros.core import Box
    h = 1.0 / 240.0
    got, want = _world(), _world()
    # the reference world's pack calls the dispatcher itself (typed at every call)
    ref_pack = want._split_bodies(h)[0]
    ref_pack._resolve = lambda g, gr, bx, sp: (packed.step_packed, g, gr, bx, sp)
    want.step(h)
    assert ref_pack._entry[0] is packed.step_packed
    got.step(h)
    pack = got._split_bodies(h)[0]
    entry = pack._entry
    assert entry[0] is not packed.step_packed and callable(entry[0])
    assert entry[2] is got._ground_row and entry[3] is got._box_rows
    for step in range(1, 40):
        if step == 20:
            for w in (got, want):
                # a step under the half x < 0.05 of the body, which rests on the ground
                w.set_colliders(ground=Ground(height=0.0, friction=0.5, restitution=0.2),
                                boxes=[Box(lo=(-1.0, -1.0, -0.1), hi=(0.05, 1.0, 0.03))])
        got.step(h)
        want.step(h)
        if step == 20:
            assert pack._entry is not entry and pack._entry[3] is got._box_rows
            assert len(got._box_rows) == 1
    assert ref_pack._entry[0] is packed.step_packed and want._split_bodies(h)[0] is ref_pack
    b, r = got.bodies[0], want.bodies[0]
    assert np.array_equal(b.x, r.x) and np.array_equal(b.v, r.v)
    assert b.shape_error_rms() == r.shape_error_rms()
    assert r.x[r.x[:, 0] < 0.04, 2].min() > 0.02      # the box lifted that half


def test_a_copied_world_steps_its_own_bodies_and_a_pack_is_not_copied():
    """A pack holds its bodies' particle arrays (``Pack.arrays``): copying
    it is refused, and a deep copy of a stepped world packs its own bodies again, so that
    stepping the copy leaves the original's state as it was (and both step alike)."""
    import copy
    h = 1.0 / 240.0
    world = _world()
    for _ in range(3):
        world.step(h)
    pack = world._split_bodies(h)[0]
    with pytest.raises(TypeError, match='particle arrays'):
        copy.deepcopy(pack)
    twin = copy.deepcopy(world)
    x, v = world.bodies[0].x.copy(), world.bodies[0].v.copy()
    for _ in range(5):
        twin.step(h)
    assert np.array_equal(world.bodies[0].x, x) and np.array_equal(world.bodies[0].v, v)
    assert twin._split_bodies(h)[0] is not pack
    for _ in range(5):
        world.step(h)
    assert np.array_equal(world.bodies[0].x, twin.bodies[0].x)
    assert not np.array_equal(world.bodies[0].x, x)
