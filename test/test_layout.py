"""The bodies' per-component state layout and the API kept on top of it.

A body stores x, v and its rest positions as (3, N) C-contiguous blocks; ``body.x`` and
``body.v`` stay (N, 3) read-only views of the live state (F-contiguous).  These tests fail
if the views stop being views, stop following the state, lose the layout on a copy, or if
the compiled world step cannot hold bodies whose views type differently (one particle).
"""

import pickle

import numpy as np
import pytest

from sm_ros.core import BodyParams, Ground, World
from twins import on_ground


H = 1.0 / 120.0


def _lattice(n, spacing=0.1):
    g = np.stack(np.meshgrid(*[np.arange(n)] * 3, indexing='ij'), axis=-1).reshape(-1, 3)
    return g * spacing


def _layout_ok(body):
    """x, v, x0 are (N, 3) arrays over (3, N) C-contiguous blocks."""
    for a in (body._x, body._v, body._x0):
        assert a.shape == (body.n, 3) and a.T.flags.c_contiguous
    if body._sets is not None:
        assert body._sets.rest_local.T.flags.c_contiguous


def test_views_are_column_major_read_only_and_follow_the_state():
    world = World(gravity=(0.0, 0.0, -9.81))
    pts = _lattice(4) + (0.0, 0.0, 1.0)
    # one cluster: stored in the caller's order, so x and v are views of the state
    body = world.add_body(pts, params=BodyParams(mode='linear', clusters=1, damping=0.05))
    assert body._perm is None
    _layout_ok(body)
    x, v = body.x, body.v
    assert x.shape == (64, 3) and x.flags.f_contiguous and x.T.flags.c_contiguous
    assert np.shares_memory(x, body._x) and np.shares_memory(v, body._v)
    assert np.array_equal(x, pts)                # row i is particle i, as before
    with pytest.raises(ValueError):
        x[0, 0] = 5.0                            # read-only
    world.step(H)
    assert np.array_equal(x, body.x) and x[0, 2] < 1.0 and v[0, 2] < 0.0   # a live view
    rows = np.arange(192, dtype=float).reshape(64, 3)   # C-ordered input
    body.set_state(x=rows, v=-rows)
    assert np.array_equal(x, rows) and np.array_equal(v, -rows)
    assert x.flags.f_contiguous and np.array_equal(np.ascontiguousarray(x).reshape(-1),
                                                   np.arange(192.0))
    _layout_ok(body)


def test_compiled_world_step_takes_a_one_particle_body():
    """A one-particle body's (1, 3) view is C- and F-contiguous at once; its particle
    arrays go into the same typed list as the others' (``packed.Pack``) and it steps as it
    does alone (bit for bit)."""
    def run(names):
        world = World(gravity=(0.0, 0.0, -9.81))
        world.set_colliders(ground=Ground(height=0.0))
        if 'dot' in names:
            world.add_body([[0.0, 0.0, 0.05]], name='dot',
                           velocities=[[0.3, 0.0, 0.0]], params=BodyParams(damping=0.05))
        if 'cube' in names:
            world.add_body(_lattice(4) + (1.0, 0.0, 0.3), name='cube',
                           params=BodyParams(mode='linear', damping=0.05))
        for _ in range(30):
            world.step(H)
        return {b.name: (b.x.copy(), b.v.copy()) for b in world.bodies}, world

    both, world = run(('dot', 'cube'))
    pack, records, slow, _ = world._split_bodies(H)
    assert len(pack) == 2 and len(records) == 0 and not slow      # one-cluster: packed
    for name in ('dot', 'cube'):
        alone, _ = run((name,))
        assert np.array_equal(both[name][0], alone[name][0])
        assert np.array_equal(both[name][1], alone[name][1])
    assert both['dot'][0][0, 2] >= 0.0           # the ground held it


@pytest.mark.parametrize('copy', ['pickle', 'copy_world'])
def test_copies_keep_the_layout_and_the_trajectory(copy, copy_world):
    world = World(gravity=(0.0, 0.0, -9.81))
    world.set_colliders(ground=Ground(height=0.0))
    world.add_body(_lattice(5) + (0.0, 0.0, 0.2), name='a',
                   params=BodyParams(mode='linear', clusters=4, damping=0.05))
    world.add_body(_lattice(3) + (1.0, 0.0, 0.2), name='b', params=BodyParams(mode='rigid'))
    for _ in range(5):
        world.step(H)
    twin = pickle.loads(pickle.dumps(world)) if copy == 'pickle' else copy_world(world)
    for b in twin.bodies:
        _layout_ok(b)
    for _ in range(20):
        world.step(H)
        twin.step(H)
    for a, b in zip(world.bodies, twin.bodies):
        assert np.array_equal(a.x, b.x) and np.array_equal(a.v, b.v)


@pytest.mark.parametrize('mode,clusters', [('rigid', 1), ('linear', 1), ('linear', 3)])
def test_compiled_step_on_the_layout_matches_the_numpy_twin(monkeypatch, mode, clusters):
    """The compiled world step (the body's record) on the per-component layout
    against the NumPy reference (row-major (N, 3) arrays) to round-off, with the ground
    (the set layout, whose rest offsets y0 are stored per component)."""
    rng = np.random.default_rng(3)
    x0 = _lattice(4) + rng.uniform(-0.02, 0.02, (64, 3)) + (0.0, 0.0, 0.12)
    m = rng.uniform(0.5, 2.0, len(x0))
    params = BodyParams(mode=mode, alpha=0.4, beta=0.6, clusters=clusters)
    ground = Ground(height=0.0, friction=0.3, restitution=0.2)
    world, body, ref = on_ground(x0, m, params, rng.normal(scale=0.3, size=x0.shape), ground)
    assert len(world._split_bodies(H)[1]) == 1          # a record
    _layout_ok(body)
    landed = False
    for _ in range(40):
        world.step(H)
        ref.step(H, world.gravity, ground, radius=body._collider_radius)
        assert np.abs(body.x - ref.x).max() < 1e-9
        assert np.abs(body.v - ref.v).max() < 1e-9 / H
        # the ground put a particle's sphere onto it
        landed = landed or body.x[:, 2].min() == body._collider_radius > 0.0
    assert landed


@pytest.mark.parametrize('n_side, clusters', [(1, 1), (3, 1), (4, 1), (5, 2)])
def test_state_blocks_start_on_a_cache_line(n_side, clusters):
    """x, v, the rest positions and the set offsets start on a 64-byte boundary
    (``body_build.soa``: the vectorised loops' loads cost 7-10 % more off a 32-byte one),
    hold the values given, and keep both after a rebuild; with N a multiple of 4 every
    column starts on a 32-byte boundary."""
    world = World(gravity=(0.0, 0.0, -9.81))
    pts = _lattice(n_side) + (0.3, -0.2, 1.0)
    vel = np.arange(pts.size, dtype=float).reshape(pts.shape) * 1e-3
    body = world.add_body(pts, params=BodyParams(mode='linear', clusters=clusters),
                          velocities=vel)
    for rebuilt in (False, True):
        if rebuilt:
            body.set_params(mode='quadratic')            # new rest data, same state
        blocks = [body._x, body._v, body._x0]
        if body._sets is not None:
            blocks.append(body._sets.rest_local)
        for a in blocks:
            assert a.ctypes.data % 64 == 0 and a.flags.f_contiguous
            if body.n % 4 == 0:
                assert all(a[:, j].ctypes.data % 32 == 0 for j in range(3))
        order_ = body._perm if body._perm is not None else np.arange(body.n)
        assert np.array_equal(body.x, pts) and np.array_equal(body.v, vel)
        assert np.allclose(body._x0, pts[order_] - pts.mean(axis=0), atol=1e-12)
