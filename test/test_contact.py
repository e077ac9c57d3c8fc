"""Body-body contact and self-collision (sm_ros.core.contact): kernels, invariants, scenes."""

import math

import numpy as np
import pytest

from sm_ros.core import BodyParams, Ground, World
from sm_ros.core import contact as C, tuning
from sm_ros.core.contact import BodyContact, ContactParams
from sm_ros.core.contact_state import (NO_WALLS, ContactLaw, ContactParticles, PairList,
                                      carried_bodies_for, pair_sweep_for, report_for)
from sm_ros.core.kernels.colliders import Colliders

S = 0.02                                           # lattice spacing of the test bodies
NO_COLLIDERS = Colliders(False, np.zeros(4), np.zeros((0, 8)), np.zeros((0, 6)), 0.0,
                         np.zeros(8), 0.0)


def lattice(nx, ny, nz, s=S, center=(0.0, 0.0, 0.0)):
    """An nx x ny x nz lattice of spacing s centred on ``center``."""
    g = np.stack(np.meshgrid(np.arange(nx), np.arange(ny), np.arange(nz), indexing='ij'),
                 -1).reshape(-1, 3) * s
    return g - g.mean(axis=0) + np.asarray(center, dtype=float)


def min_distance(a, b):
    """Smallest distance between a point of a (N, 3) and a point of b (M, 3)."""
    d = a[:, None, :] - b[None, :, :]
    return float(np.sqrt(np.einsum('ijk,ijk->ij', d, d).min()))


def brute_pairs(x, r, body, act, selfc, x0, cutoff_extra):
    """The candidate pairs ``build_pairs`` must find, by NumPy over all pairs."""
    n = len(x)
    i, j = np.triu_indices(n, 1)
    d = np.linalg.norm(x[i] - x[j], axis=1)
    cut = r[i] + r[j]
    ok = act[body[i]] & act[body[j]] & (d < cut + cutoff_extra)
    same = body[i] == body[j]
    rest = np.linalg.norm(x0[i] - x0[j], axis=1)
    ok &= ~same | (selfc[body[i]] & (rest > tuning.SELF_REST_FACTOR * cut))
    return set(zip(i[ok].tolist(), j[ok].tolist()))


# ---------------------------------------------------------------------------------------
# Kernels against NumPy
# ---------------------------------------------------------------------------------------

def build_with(X, R, B, act, selfc, X0, cell, skin, cap, table=None):
    """Run the pair-list builder; (m, pi, pj) with the table sized as ``Contact`` does
    (or of ``table`` cells)."""
    n = X.shape[1]
    pi = np.zeros(cap, np.int32)
    pj = np.zeros(cap, np.int32)
    table = table or 1 << max(5, int(np.ceil(np.log2(4 * n))))
    src = C.PairSource(X, R, B, act, selfc, X0, cell, skin, tuning.SELF_REST_FACTOR)
    grid = C.GridScratch(np.zeros(n, np.int64), np.zeros(table + 1, np.int64),
                         np.zeros(n, np.int64), np.zeros((n, 4)), np.zeros(n, np.int32),
                         np.zeros(table, np.int32))
    return C.build_pairs_grid(src, grid, pi, pj), pi, pj


def built_set(m, pi, pj):
    """The unordered pairs of a build, checking that none is listed twice."""
    got = {(min(a, b), max(a, b)) for a, b in zip(pi[:m].tolist(), pj[:m].tolist())}
    assert len(got) == m
    return got


#: Tables of the grid: as ``Contact`` sizes it, and small ones that make it wrap around
#: (the smallest a world gets: 32 cells).
TABLES = [None, 32, 100]


@pytest.mark.parametrize('table', TABLES)
def test_pair_build_matches_brute_force(table):
    rng = np.random.default_rng(4)
    n, nb = 600, 7
    X = np.ascontiguousarray(rng.uniform(-0.2, 0.2, (3, n)))
    X0 = np.ascontiguousarray(X + rng.normal(0.0, 0.05, X.shape))
    B = rng.integers(0, nb, n).astype(np.int32)
    R = np.array([0.01, 0.02, 0.015, 0.01, 0.012, 0.01, 0.03])[B]
    act = np.array([True, True, True, False, True, True, True])
    selfc = np.array([False, True, False, True, False, True, False])
    skin = 0.005
    m, pi, pj = build_with(X, R, B, act, selfc, X0, 2 * R.max() + skin, skin, 10 * n, table)
    want = brute_pairs(X.T, R, B, act, selfc, X0.T, skin)
    assert built_set(m, pi, pj) == want
    assert any(B[a] == B[b] for a, b in want)              # self pairs were tested too


@pytest.mark.parametrize('table', TABLES)
@pytest.mark.parametrize('spread', [(1e3, 0.0, 0.0), (0.0, 50.0, -70.0), (3.0, 2.0, 1.0)])
def test_pair_build_wraps_a_box_larger_than_its_table(spread, table):
    """Bodies far apart (along x, along y and z, along a diagonal) make a box of far more
    cells than the table: the grid wraps around and still lists exactly brute force's
    pairs, each once, with particles of far-apart places sharing cells."""
    X, R, B, act, selfc, X0 = heap_of_lattices(6, n_bodies=8)
    far = B >= 5                                            # three bodies moved far away
    X = X.copy()
    X[:, far] += np.array(spread)[:, None] * (B[far] - 4)
    skin = 0.25 * S
    cell = 2 * R.max() + skin
    extent = np.prod(np.floor(np.ptp(X, axis=1) / cell) + 1)
    n = X.shape[1]
    assert extent > 8 * (table or 8 * n)
    m, pi, pj = build_with(X, R, B, act, selfc, X0, cell, skin, 16 * n, table)
    want = brute_pairs(X.T, R, B, act, selfc, X0.T, skin)
    assert len(want) > 500
    assert built_set(m, pi, pj) == want


def test_pair_build_wraps_a_diagonal_self_colliding_cable():
    """A cable along the box's diagonal (a few hundred particles, a box of millions of
    cells), curled so that it meets itself: every pair brute force finds, once."""
    t = np.linspace(0.0, 1.0, 400)
    X = np.ascontiguousarray(np.stack([t, t, t]) * 8.0)
    X[:, 300:] = X[:, 100:200][:, ::-1] + np.array([[0.012], [0.0], [0.0]])
    X0 = np.ascontiguousarray(np.stack([t, t, t]) * 8.0)
    B = np.zeros(400, np.int32)
    R = np.full(400, 0.01)
    act, selfc = np.ones(1, bool), np.ones(1, bool)
    m, pi, pj = build_with(X, R, B, act, selfc, X0, 0.025, 0.005, 4000)
    want = brute_pairs(X.T, R, B, act, selfc, X0.T, 0.005)
    assert len(want) > 50
    assert built_set(m, pi, pj) == want


def heap_of_lattices(seed, n_bodies=14, side=5, selfc_body=3, off_body=5):
    """Lattice blocks, rotated at random, thrown into a small box so that they overlap (the
    pair list's hard case: cells shared by several bodies next to cells of one)."""
    rng = np.random.default_rng(seed)
    g = lattice(side, side, side)
    xs, x0s, bs = [], [], []
    for b in range(n_bodies):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        w, x, y, z = q
        rot = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
        xs.append(g @ rot.T * rng.uniform(0.9, 1.1) + rng.uniform(-0.1, 0.1, 3))
        x0s.append(g * (3.0 if b == selfc_body else 1.0) + 10.0 * b)  # self: spread at rest
        bs.append(np.full(len(g), b))
    B = np.concatenate(bs).astype(np.int32)
    X = np.ascontiguousarray(np.concatenate(xs).T)
    X0 = np.ascontiguousarray(np.concatenate(x0s).T)
    R = np.where(B % 2 == 0, 0.5 * S, 0.4 * S)
    act = np.ones(n_bodies, bool)
    act[off_body] = False
    selfc = np.zeros(n_bodies, bool)
    selfc[selfc_body] = True
    return X, R, B, act, selfc, X0


@pytest.mark.parametrize('seed', [0, 1, 2])
def test_pair_builders_agree_on_a_heap_of_bodies(seed):
    """The builder lists the same pairs as brute force on overlapping rotated blocks, in a
    grid that fits and in one that wraps around; ``sort_pairs`` orders by the lower index,
    stably."""
    X, R, B, act, selfc, X0 = heap_of_lattices(seed)
    skin = 0.25 * S
    want = brute_pairs(X.T, R, B, act, selfc, X0.T, skin)
    assert len(want) > 500 and any(B[a] == B[b] for a, b in want)
    n = X.shape[1]
    lists = {}
    for kernel in TABLES:
        m, pi, pj = build_with(X, R, B, act, selfc, X0, 2 * R.max() + skin, skin, 8 * n,
                               kernel)
        assert m == len(want), kernel
        lists[kernel] = (pi[:m].copy(), pj[:m].copy())
        C.sort_pairs(pi, pj, m, n, np.zeros(n + 1, np.int64), np.zeros_like(pi),
                     np.zeros_like(pj))
        assert set(zip(pi[:m].tolist(), pj[:m].tolist())) == want, kernel
        assert np.all(pi[:m] < pj[:m]) and np.all(np.diff(pi[:m]) >= 0)
        low = np.minimum(*lists[kernel])
        stable = np.argsort(low, kind='stable')            # the same as a stable sort
        np.testing.assert_array_equal(pj[:m], np.maximum(*lists[kernel])[stable])


def test_builder_counts_past_a_full_list():
    """With too small a list, the builder fills it and counts on (the caller grows it),
    then, given room, lists every pair in the same order."""
    X, R, B, act, selfc, X0 = heap_of_lattices(5)
    skin = 0.25 * S
    m_full, pi_f, pj_f = build_with(X, R, B, act, selfc, X0, 2 * R.max() + skin, skin,
                                    16 * X.shape[1])
    m, pi, pj = build_with(X, R, B, act, selfc, X0, 2 * R.max() + skin, skin, 64)
    assert m == m_full > 64
    np.testing.assert_array_equal(pi, pi_f[:64])
    np.testing.assert_array_equal(pj, pj_f[:64])


def test_far_apart_bodies_get_the_same_pairs():
    """A body a kilometre away makes the grid's box larger than its table: the grid wraps
    around and lists the same pairs of the touching bodies."""
    def world(far):
        w = World(gravity=(0, 0, 0))
        w.add_body(lattice(4, 4, 4), 0.01, BodyParams(mode='rigid'), 'a')
        w.add_body(lattice(4, 4, 4, center=(3.9 * S, 0.3 * S, 0.0)), 0.01,
                   BodyParams(mode='rigid'), 'b')
        if far:
            w.add_body(lattice(2, 2, 2, center=(1e3, 0.0, 0.0)), 0.01,
                       BodyParams(mode='rigid'), 'far')
        w.step(1 / 240)
        c = w.contact
        c.invalidate()
        c._build()
        pairs = set(zip(c._pair_i[:c.npairs].tolist(), c._pair_j[:c.npairs].tolist()))
        return c, pairs
    near, near_pairs = world(False)
    far, far_pairs = world(True)
    assert far._cell_body.shape[0] < 1e3 / far.cell           # the grid cannot span the box
    assert near._cell_body.shape[0] > 1.0 / near.cell         # ... and could without the far body
    assert near.npairs > 0 and far_pairs == near_pairs


def test_wrapped_dims_fit_the_table():
    """A box that fits keeps its cells; one that does not wraps its longer axes to 3 cells
    or more, keeps the short ones, and never needs more cells than the table."""
    from sm_ros.core.kernels.pair_grid import wrapped_dims
    dims = np.zeros(6, np.int64)
    wrapped_dims((4.0, 5.0, 6.0), 128, dims)
    assert dims.tolist() == [4, 5, 6, 0, 0, 0]
    rng = np.random.default_rng(2)
    for _ in range(300):
        extent = tuple(float(e) for e in np.floor(10.0 ** rng.uniform(0, 6, 3)) + 1)
        table = int(2 ** rng.integers(5, 21))
        wrapped_dims(extent, table, dims)
        n, wraps = dims[:3], dims[3:] > 0
        if np.prod(extent) <= table:
            assert not wraps.any() and n.tolist() == [int(e) for e in extent]
            continue
        assert np.prod(n) <= table and wraps.any()
        assert np.all(n[wraps] >= 3) and np.all(n[wraps] < np.array(extent)[wraps])
        assert np.all(n[~wraps] == np.array(extent)[~wraps])


def test_grid_sort_refuses_a_dims_array_of_another_size():
    """``grid_sort`` writes six values (cells per axis, which axes wrap): a shorter array is
    refused before anything is written."""
    X = np.zeros((3, 2))
    src = C.PairSource(X, np.full(2, 0.01), np.zeros(2, np.int32), np.ones(1, bool),
                       np.zeros(1, bool), X, 0.03, 0.01, 2.0)
    grid = C.GridScratch(np.full(2, 7, np.int64), np.zeros(33, np.int64), np.zeros(2, np.int64),
                         np.zeros((2, 4)), np.zeros(2, np.int32), np.zeros(32, np.int32))
    from sm_ros.core.contact_build import grid_sort
    with pytest.raises(ValueError, match='6 values'):
        grid_sort(src, grid, np.zeros(3, np.int64))
    assert (grid.particle_cell == 7).all()


def test_pair_response_conserves_momentum_and_separates():
    rng = np.random.default_rng(1)
    X = np.ascontiguousarray(np.array([[0.0, 0.015], [0.0, 0.004], [0.0, -0.002]]))
    V = np.ascontiguousarray(rng.normal(size=(3, 2)))
    W = np.array([1.0 / 0.3, 1.0 / 0.7])
    R = np.full(2, 0.01)
    B = np.array([0, 1], np.int32)
    p0 = V @ (1.0 / W)
    lever = X - 1e-3 * V                                  # positions at the step's start
    l0 = np.cross(lever.T, V.T * (1.0 / W)[:, None]).sum(axis=0)
    report = report_for(2)
    found = C.solve_pairs(ContactParticles(X, V, W, R, B, np.zeros(2, np.uint8)),
                          PairList(np.array([0], np.int32), np.array([1], np.int32), 1),
                          ContactLaw(0.0, 0.0, 0.0, 1e-3, 1, 0.0, 0.0), report, NO_COLLIDERS)
    assert found == 1 and report.touched.all()
    assert np.linalg.norm(X[:, 0] - X[:, 1]) >= 0.02 - 1e-12
    np.testing.assert_allclose(V @ (1.0 / W), p0, atol=1e-14)
    l1 = np.cross((X - 1e-3 * V).T, V.T * (1.0 / W)[:, None]).sum(axis=0)
    np.testing.assert_allclose(l1, l0, atol=1e-14)
    np.testing.assert_allclose(X - 1e-3 * V, lever, atol=1e-15)   # start of step kept


def test_pinned_particles_are_infinite_mass():
    X = np.ascontiguousarray(np.array([[0.0, 0.015], [0.0, 0.0], [0.0, 0.0]]))
    V = np.zeros((3, 2))
    W = np.array([0.0, 2.0])
    before = X[:, 0].copy()
    C.solve_pairs(ContactParticles(X, V, W, np.full(2, 0.01), np.array([0, 1], np.int32),
                                   np.zeros(2, np.uint8)),
                  PairList(np.array([0], np.int32), np.array([1], np.int32), 1),
                  ContactLaw(0.5, 0.0, 0.0, 0.01, 1, 0.0, 0.0), report_for(2), NO_COLLIDERS)
    np.testing.assert_array_equal(X[:, 0], before)
    assert X[0, 1] == pytest.approx(0.02)


def test_default_radius_is_half_the_spacing():
    assert C.default_radius(lattice(5, 4, 3, 0.03)) == pytest.approx(0.015)
    assert C.default_radius(lattice(40, 30, 2, 0.01)) == pytest.approx(0.005)   # sampled
    assert C.default_radius(np.zeros((1, 3))) == 0.0


# ---------------------------------------------------------------------------------------
# One body: nothing to do
# ---------------------------------------------------------------------------------------

def _drop_world(contact=True, second=None):
    w = World()
    w.set_colliders(ground=Ground())
    w.contact_params = ContactParams(enabled=contact)
    w.add_body(lattice(5, 5, 5, center=(0, 0, 0.2)), 0.01, BodyParams(damping=0.05), 'a',
               velocities=np.tile([0.3, 0.0, 0.0], (125, 1)))
    if second is not None:
        w.add_body(lattice(3, 3, 3, center=(1.0, 0, 0.2)), 0.01, None, 'b', contact=second)
    return w


@pytest.mark.parametrize('second', [None, BodyContact(collide=False)])
def test_one_colliding_body_without_self_collision_is_a_no_op(second):
    on, off = _drop_world(True, second), _drop_world(False, second)
    assert on.contact is None
    for _ in range(60):
        on.step(1 / 120)
        off.step(1 / 120)
    for a, b in zip(on.bodies, off.bodies):
        np.testing.assert_array_equal(a.x, b.x)
        np.testing.assert_array_equal(a.v, b.v)
    assert not on._flat.X.any()                     # never gathered


def test_self_collision_needs_no_second_body():
    w = World()
    w.add_body(lattice(3, 3, 3), 1.0, None, 'a', contact=BodyContact(self_collision=True))
    assert w.contact is not None


# ---------------------------------------------------------------------------------------
# Scenes
# ---------------------------------------------------------------------------------------

def test_box_dropped_onto_a_box_rests_on_it():
    w = World()
    w.set_colliders(ground=Ground())
    p = BodyParams(damping=0.2)
    a = w.add_body(lattice(6, 6, 3, center=(0, 0, 0.02)), 0.01, p, 'a')
    b = w.add_body(lattice(4, 4, 3, center=(0.007, 0.004, 0.1)), 0.01, p, 'b')
    for _ in range(360):
        w.step(1 / 120)
    assert min_distance(a.x, b.x) > 0.6 * S
    assert b.x[:, 2].min() > a.x[:, 2].max() - 0.5 * S         # on top, not beside
    assert abs(b.com()[0]) < 0.06 and np.abs(b.v).max() < 0.02


def _five_boxes(stagger, contact=None):
    w = World()
    if contact is not None:
        w.contact_params = contact
    w.set_colliders(ground=Ground())
    p = BodyParams(mode='rigid', alpha=0.99, damping=0.5)
    boxes = [w.add_body(lattice(4, 4, 3, center=(0.007 * (k % 2) * stagger,
                                                 0.004 * (k % 2) * stagger,
                                                 0.02 + 3 * S * k)), 0.01, p, f'b{k}')
             for k in range(5)]
    return w, boxes


def test_stack_of_five_boxes_falls_through_per_particle():
    # the per-particle path (stacking=False, kept for soft and many-cluster bodies and
    # zero gravity): the same stack sinks (the test above can fail)
    w, boxes = _five_boxes(1.0, ContactParams(stacking=False))
    top0 = boxes[-1].com()[2]
    for _ in range(4 * 120):
        w.step(1 / 120)
    assert boxes[-1].com()[2] < top0 - 0.01


@pytest.mark.parametrize('stagger', [0.0, 1.0])
def test_stack_of_five_boxes_stands(stagger):
    # at the node's step (dt 1/120 s, World.step as Simulation.tick calls it) with the
    # default contact (stacking): stiff one-cluster bodies carry their contacts as a whole
    # (doc/contact.md); per particle (stacking=False) the touching layer
    # alone gives way and these boxes fall through one another (the next test).  Stacked
    # exactly (lattices particle on particle) and with every other box put a little off
    w, boxes = _five_boxes(stagger)
    assert w.contact_params.stacking
    h = 1 / 120
    for _ in range(4 * 120):                                  # settle 4 s
        w.step(h)
    assert w.contact.coupling[:5].all()
    top = []
    for _ in range(int(10 / h)):
        w.step(h)
        top.append(boxes[-1].com()[2])
    top = np.array(top)
    assert top[0] > 0.02 + 9 * S + 0.01                       # still five boxes high
    assert top[-1] > top[0] - 1e-3                            # no sinking
    assert top.max() - top.min() < 1e-3                       # no jitter
    for lo, hi in zip(boxes, boxes[1:]):
        assert min_distance(lo.x, hi.x) > 0.6 * S
        assert np.linalg.norm(hi.com()[:2] - lo.com()[:2]) < S            # not toppling


def test_box_resting_partly_over_an_edge_stays():
    # its centre of mass over the lower box, with stacking (the default): it stays where
    # it was put (per particle, stacking=False, the lattice bumps kick it off sideways)
    w = World()
    w.set_colliders(ground=Ground())
    p = BodyParams(mode='rigid', alpha=0.99, damping=0.2)
    a = w.add_body(lattice(6, 6, 3, center=(0, 0, 0.02)), 0.01, p, 'a')
    b = w.add_body(lattice(4, 4, 3, center=(0.03, 0.0, 0.08)), 0.01, p, 'b')
    for _ in range(240):
        w.step(1 / 120)
    assert abs(b.com()[0] - 0.03) < 0.005 and abs(b.com()[1]) < 0.005
    assert min_distance(a.x, b.x) > 0.6 * S and b.com()[2] > 0.07


@pytest.mark.parametrize('mode', ['rigid', 'soft'])
def test_sideways_collision_under_gravity_exchanges_momentum_exactly(mode):
    # with stacking (the default), bodies carrying their contacts as a whole (and, soft,
    # one per particle) exchange momentum equal and opposite
    w = World()
    n = 27
    a = w.add_body(lattice(3, 3, 3, center=(-0.05, 0, 1.0)), 0.01, BodyParams(mode='rigid'),
                   'a', velocities=np.tile([1.0, 0.0, 0.0], (n, 1)))
    b = w.add_body(lattice(3, 3, 3, center=(0.05, 0.01, 1.0)), 0.02,
                   BodyParams(mode='linear', alpha=1.0 if mode == 'rigid' else 0.3), 'b',
                   velocities=np.tile([-1.0, 0.1, 0.0], (n, 1)))
    p0 = a.momentum() + b.momentum()
    h = 1 / 120
    met = 0
    for _ in range(30):
        w.step(h)
        met += w.contact.found
    assert met > 0 and a.com()[0] < b.com()[0]
    assert w.contact.coupling[:2].tolist() == [True, mode == 'rigid']
    m = float(a.m.sum() + b.m.sum())
    expected = p0 + m * 30 * h * np.array([0.0, 0.0, -9.81])
    np.testing.assert_allclose(a.momentum() + b.momentum(), expected, atol=1e-12)


@pytest.mark.slow
@pytest.mark.parametrize('stacking', [False, True])
def test_pile_of_27_balls_heaps_up_and_settles(stacking):
    from sm_ros.bench.contact import ball_pile
    w, bodies = ball_pile(stacking)                      # 27 balls of 81 particles
    ball = bodies[0].x
    ke = []
    for _ in range(4 * 120):
        w.step(1 / 120)
        ke.append(sum(0.5 * float((b.m[:, None] * b.v ** 2).sum()) for b in bodies))
    x = np.concatenate([b.x for b in bodies])
    bid = np.repeat(np.arange(len(bodies)), len(ball))
    d = np.linalg.norm(x[:, None] - x[None], axis=-1)
    d[bid[:, None] == bid[None]] = np.inf
    assert (d.min(axis=1) < 0.5 * S).mean() < 0.02             # no overlapping layer
    assert x[:, 2].max() > 0.12                                  # heaped: 27 > one layer of 16
    # settles: per particle (stacking=False) a residual jitter of the resting contacts is left
    # (doc/contact.md), a few per cent of the peak kinetic energy; with stacking the heap
    # comes to rest, below 0.5 %
    m = float(sum(b.m.sum() for b in bodies))
    assert np.mean(ke[-60:]) < (0.005 if stacking else 0.05) * max(ke)
    if stacking:
        assert np.sqrt(2 * np.mean(ke[-60:]) / m) < 0.05


@pytest.mark.parametrize('mu', [0.0, 0.5])
def test_head_on_in_zero_gravity(mu):
    w = World(gravity=(0, 0, 0))
    w.contact_params = ContactParams(friction=mu)
    n = 125
    a = w.add_body(lattice(5, 5, 5, center=(-0.1, 0, 0)), 0.01, BodyParams(mode='linear'), 'a',
                   velocities=np.tile([1.0, 0.0, 0.1], (n, 1)))
    b = w.add_body(lattice(5, 5, 5, center=(0.1, 0, 0.03)), 0.02, BodyParams(mode='rigid'),
                   'b', velocities=np.tile([-1.0, 0.2, 0.0], (n, 1)))
    p0 = a.momentum() + b.momentum()
    l0 = a.angular_momentum() + b.angular_momentum()
    h = 1 / 240
    met = 0
    for _ in range(60):
        w.step(h)
        met += w.contact.found
        # x - h v: the positions the step started from, where the symplectic step keeps
        # angular momentum exactly
        assert (a.x[:, 0] - b.x[:, 0].min()).max() < 0.0 or \
            min_distance(a.x, b.x) > 0.5 * S               # never through each other
    assert met > 0
    assert a.com()[0] < b.com()[0] and a.v[:, 0].mean() < b.v[:, 0].mean()  # bounced apart
    np.testing.assert_allclose(a.momentum() + b.momentum(), p0, atol=1e-12)
    lx = a.angular_momentum() + b.angular_momentum()
    if mu == 0.0:
        np.testing.assert_allclose(lx, l0, atol=1e-12)
    else:
        assert np.abs(lx - l0).max() > 1e-6               # friction couples do act


def _sheet_and_ball(speed, h):
    """A pinned one-particle-thick sheet at z = 0 and a small ball moving at it."""
    w = World(gravity=(0, 0, 0))
    sheet = lattice(12, 12, 1)
    w.add_body(sheet, 0.01, BodyParams(mode='linear'), 'sheet', pinned=np.arange(len(sheet)))
    ball = lattice(3, 3, 3, center=(0.003, -0.005, 0.06))
    b = w.add_body(ball, 0.01, BodyParams(mode='rigid'), 'ball',
                   velocities=np.tile([0.0, 0.0, -speed], (len(ball), 1)))
    return w, b


@pytest.mark.parametrize('factor', [0.5, 0.95])
def test_below_the_tunnelling_speed_nothing_passes_a_thin_sheet(factor):
    h = 1 / 120
    r = S / 2
    w, ball = _sheet_and_ball(factor * r / h, h)
    for _ in range(60):
        w.step(h)
        assert ball.x[:, 2].min() > 0.0
    assert w.contact.fast_particles(h).sum() == 0


def test_above_the_tunnelling_speed_fast_particles_are_counted():
    h = 1 / 120
    r = S / 2
    w, ball = _sheet_and_ball(1.5 * r / h, h)
    w.step(h)
    fast = w.contact.fast_particles(h)
    assert fast.tolist() == [0, ball.n]


def test_pinned_body_does_not_move():
    w = World()
    plate = lattice(8, 8, 1, center=(0, 0, 0.3))
    pb = w.add_body(plate, 0.01, None, 'plate', pinned=np.arange(len(plate)))
    box = w.add_body(lattice(3, 3, 3, center=(0, 0, 0.4)), 0.01, BodyParams(damping=0.1), 'box')
    for _ in range(240):
        w.step(1 / 120)
    np.testing.assert_array_equal(pb.x, plate)
    assert box.x[:, 2].min() > 0.3 + 0.6 * S


@pytest.mark.parametrize('selfc', [True, False])
def test_self_collision_folded_sheet_does_not_cross_itself(selfc):
    # one soft body: two 20 x 6 sheets 0.1 m apart joined along one edge (a sheet folded
    # over), its halves thrown at each other in zero gravity
    w = World(gravity=(0, 0, 0))
    bot = lattice(20, 6, 1)
    edge = bot[:, 0].max() + S
    fold = np.array([[edge, y, z] for y in np.unique(bot[:, 1])
                     for z in np.arange(0.0, 0.1 + 1e-9, S)])
    x0 = np.vstack([bot, bot + [0.0, 0.0, 0.1], fold])
    n = len(bot)
    v = np.zeros_like(x0)
    v[:n, 2], v[n:2 * n, 2] = 0.5, -0.5
    body = w.add_body(x0, 0.001, BodyParams(mode='linear', alpha=0.3, beta=0.0, clusters=6,
                                            damping=0.05),
                      'sheet', velocities=v, contact=BodyContact(self_collision=selfc))
    crossed, gap = 0, np.inf
    away = bot[:, 0] < edge - 4 * S                     # off the fold
    for _ in range(240):
        w.step(1 / 240)
        x = body.x
        crossed = max(crossed, int((x[n:2 * n, 2] < x[:n, 2]).sum()))
        gap = min(gap, min_distance(x[:n][away], x[n:2 * n][away]))
    if selfc:
        assert crossed == 0 and gap > 0.9 * S
    else:
        assert crossed == n and gap < 0.1 * S          # the test can fail


# ---------------------------------------------------------------------------------------
# Bad input
# ---------------------------------------------------------------------------------------

@pytest.mark.parametrize('changes', [
    dict(friction=-0.1), dict(friction=math.nan), dict(restitution=1.5),
    dict(radius_scale=0.0), dict(radius_scale=math.inf), dict(enabled='yes'),
    dict(iterations=0), dict(iterations=2.5), dict(iterations=17), dict(friction='a'),
    dict(stacking='yes'),
])
def test_contact_params_refused(changes):
    w = World()
    before = w.contact_params
    with pytest.raises(ValueError):
        w.contact_params = ContactParams(**changes)
    assert w.contact_params == before


@pytest.mark.parametrize('bc', [BodyContact(radius=0.0), BodyContact(radius=-1.0),
                                BodyContact(radius=math.nan), BodyContact(collide=1),
                                BodyContact(self_collision='true')])
def test_body_contact_refused(bc):
    w = World()
    with pytest.raises(ValueError):
        w.add_body(lattice(2, 2, 2), 1.0, None, 'a', contact=bc)
    assert w.bodies == []
    w.add_body(lattice(2, 2, 2), 1.0, None, 'a')
    with pytest.raises(ValueError):
        w.set_body_contact('a', bc)
    assert w.body_contact('a') == BodyContact()
    with pytest.raises(ValueError):
        w.contact_params = 'on'


# ---------------------------------------------------------------------------------------
# Scene keys and the simulation
# ---------------------------------------------------------------------------------------

TWO_BODIES = """
bodies:
  - {name: a, shape: box, size: [0.1, 0.1, 0.1], spacing: 0.05, position: [0, 0, 0.1]}
  - {name: b, shape: box, size: [0.1, 0.1, 0.1], spacing: 0.05, position: [0, 0, 0.3]%s}
"""


def test_scene_contact_keys():
    from sm_ros.scene import build_world, parse_scene
    import yaml
    data = yaml.safe_load('contact: {friction: 0.2, restitution: 0.1, radius_scale: 1.5, '
                          'stacking: false}\n'
                          + TWO_BODIES % ', collide: false, contact_radius: 0.04, '
                          'self_collision: true')
    world, _ = build_world(parse_scene(data))
    c = world.contact_params
    assert (c.enabled, c.friction, c.restitution, c.radius_scale) == (True, 0.2, 0.1, 1.5)
    assert c.stacking is False
    plain, _ = build_world(parse_scene(yaml.safe_load(TWO_BODIES % '')))
    assert plain.contact_params.stacking is True                 # the default
    assert world.contact_radius('a') == pytest.approx(1.5 * 0.025)
    assert world.contact_radius('b') == 0.04
    assert world.body_contact('b') == BodyContact(collide=False, radius=0.04,
                                                  self_collision=True)
    assert world.contact is None                      # one colliding body, no self-collision


@pytest.mark.parametrize('top, body, message', [
    ('contact: {friction: -1}\n', '', 'contact.friction'),
    ('contact: {restitution: 2}\n', '', 'contact.restitution'),
    ('contact: {radius_scale: 0}\n', '', 'contact.radius_scale'),
    ("contact: {enabled: 'yes'}\n", '', 'contact.enabled'),
    ("contact: {friction: 'a'}\n", '', 'contact.friction'),
    ("contact: {stacking: 'yes'}\n", '', 'contact.stacking'),
    ('contact: {stacking: 1}\n', '', 'contact.stacking'),
    ('contact: {frictoin: 0.2}\n', '', 'frictoin'),
    ('contact: 3\n', '', 'contact'),
    ('', ', collide: 1', 'collide'),
    ('', ', self_collision: [true]', 'self_collision'),
    ('', ', contact_radius: -0.01', 'contact_radius'),
    ('', ", contact_radius: 'big'", 'contact_radius'),
])
def test_scene_contact_keys_refused(top, body, message):
    from sm_ros.scene import parse_scene, SceneError
    import yaml
    with pytest.raises(SceneError, match=message):
        parse_scene(yaml.safe_load(top + TWO_BODIES % body))


def test_simulation_counts_fast_particles(tmp_path):
    from sm_ros.sim import Simulation
    path = tmp_path / 'fast.yaml'
    # sideways, past the other body (falling onto it, it stops there within the tick:
    # the body below rests on the ground as a whole)
    path.write_text(TWO_BODIES % ', velocity: [10, 0, 0]')
    sim = Simulation({'scene': str(path)})
    sim.tick()
    assert sim.stats.contact_fast_max >= sim.world.body('b').n     # 10 m/s * h > r
    path.write_text(TWO_BODIES % '')
    slow = Simulation({'scene': str(path)})
    slow.tick()
    assert slow.stats.contact_fast_max == 0


@pytest.mark.slow
def test_paper_384_scene_pours_into_its_bin():
    from sm_ros.scene import build_world, load_scene
    spec = load_scene('paper_384')
    world, _ = build_world(spec)
    bodies = world.bodies
    assert len(bodies) == 384 and 54_000 < spec.n_points < 57_000
    assert sum(b.num_clusters for b in bodies) == 2400
    assert {b.params.mode for b in bodies} == {'rigid', 'linear', 'quadratic'}
    for _ in range(120):                                   # 1 s: the first layers land
        world.step(1 / 120)
    x = np.concatenate([b.x for b in bodies])
    assert np.isfinite(x).all() and x[:, 2].min() >= 0.0
    assert world.contact.found > 1000                      # they land on one another


def test_stacking_changes_nothing_without_gravity():
    # bodies carry their contacts as a whole only under gravity (where loads rest on
    # them): without it every pair acts per particle, bit for bit as without stacking
    states = []
    for stacking in (True, False):
        w = World(gravity=(0, 0, 0))
        w.contact_params = ContactParams(stacking=stacking)
        a = w.add_body(lattice(3, 3, 3, center=(-0.04, 0, 0)), 0.01, None, 'a',
                       velocities=np.tile([1.0, 0.0, 0.0], (27, 1)))
        b = w.add_body(lattice(3, 3, 3, center=(0.04, 0.01, 0)), 0.01, None, 'b')
        for _ in range(30):
            w.step(1 / 120)
        assert w.contact.coupling[:2].all()           # carried as a whole under gravity
        states.append(np.concatenate([a.x, b.x, a.v, b.v]))
    assert w.contact.builds > 0
    np.testing.assert_array_equal(states[0], states[1])


def test_which_bodies_carry_their_contacts_as_a_whole():
    w = World()
    assert w.contact_params.stacking                      # the default
    pts = lattice(3, 3, 3)
    w.add_body(pts, 0.01, BodyParams(mode='rigid', alpha=0.9), 'stiff')
    w.add_body(pts + 1.0, 0.01, BodyParams(mode='linear', alpha=0.3), 'soft')
    w.add_body(pts + 2.0, 0.01, BodyParams(mode='rigid', alpha=0.9, clusters=2), 'clustered')
    w.add_body(pts + 3.0, 0.01, BodyParams(mode='rigid'), 'pinned', pinned=[0])
    w.step(1 / 120)
    assert w.contact.coupling[:4].tolist() == [True, False, True, True]
    # a pinned particle makes the body per particle in the kernel (infinite mass)
    assert w.contact._body_inv_mass[3] == 0.0 and w.contact._body_inv_mass[0] > 0.0


def test_resting_pair_is_pushed_apart_without_speed():
    # two bodies carrying their contacts as a whole, overlapping at rest under gravity:
    # the overlap is removed by moving the bodies (equal and opposite position impulses),
    # not by giving them speed that the next step would turn into a bounce
    X = np.ascontiguousarray(np.array([[0.0, 0.0], [0.0, 0.0], [0.0, 0.015]]))
    V = np.zeros((3, 2))
    W = np.array([1 / 0.2, 1 / 0.6])
    B = np.array([0, 1], np.int32)
    off = np.array([0, 1, 2])
    bw = np.array([5.0, 1 / 0.6])
    x0 = X.copy()
    bodies = carried_bodies_for(off, bw, np.ones(2, np.bool_))
    bodies.centre[:] = X.T
    C.solve_bodies(ContactParticles(X, V, W, np.full(2, 0.01), B, np.zeros(2, np.uint8)),
                   PairList(np.array([0], np.int32), np.array([1], np.int32), 1),
                   pair_sweep_for(1), bodies, ContactLaw(0.5, 0.0, 0.1, 1 / 120, 8, 1e-3, 0.0),
                   NO_COLLIDERS, NO_WALLS, report_for(2))
    assert X[2, 1] - X[2, 0] == pytest.approx(0.02)
    np.testing.assert_array_equal(V, 0.0)
    moves = (X - x0) / W                                  # mass x move: equal, opposite
    np.testing.assert_allclose(moves[:, 0], -moves[:, 1], atol=1e-15)


@pytest.mark.slow
def test_pile_of_27_many_cluster_balls_comes_to_rest():
    # stiff balls of 8 clusters (linear, alpha 0.9, as paper_384's) carry their contacts
    # as a whole too: per particle they keep jittering (measured 1.1 % of the peak kinetic
    # energy after 4 s, 0.12 m/s RMS), carried 0.003 % (0.006 m/s)
    from sm_ros.bench.contact import ball_pile
    out = {}
    for stacking in (True, False):
        w, bodies = ball_pile(stacking, clusters=2)
        ke = []
        for _ in range(4 * 120):
            w.step(1 / 120)
            ke.append(sum(0.5 * float((b.m[:, None] * b.v ** 2).sum()) for b in bodies))
        assert bodies[0].num_clusters == 8 and w.contact.coupling[:27].all()
        m = float(sum(b.m.sum() for b in bodies))
        out[stacking] = (np.mean(ke[-60:]) / max(ke), np.sqrt(2 * np.mean(ke[-60:]) / m))
        x = np.concatenate([b.x for b in bodies])
        assert x[:, 2].max() > 0.12 and x[:, 2].min() >= 0.0             # heaped, above
    assert out[True][0] < 1e-3 and out[True][1] < 0.03
    assert out[False][0] > 1e-3                                          # per particle


def test_inverse_sym3_matches_numpy():
    rng = np.random.default_rng(3)
    for _ in range(20):
        a = rng.normal(size=(3, 3))
        a = a @ a.T + 0.1 * np.eye(3)
        out = np.zeros(9)
        C.inverse_sym3(a.reshape(-1).copy(), out)
        np.testing.assert_allclose(out.reshape(3, 3), np.linalg.inv(a), rtol=1e-9, atol=1e-9)
    out[:] = 1.0
    C.inverse_sym3(np.array([1.0, 0, 0, 0, 1, 0, 0, 0, 0]), out)       # singular: zero
    np.testing.assert_array_equal(out, 0.0)


def test_body_velocities_match_numpy():
    # centre of mass, its velocity, lowest particle, inverse inertia and spin of the bodies
    # carried as a whole, against the NumPy twin; bodies not carried get zero velocity
    rng = np.random.default_rng(4)
    n = [7, 11, 5]
    off = np.concatenate([[0], np.cumsum(n)])
    X = np.ascontiguousarray(rng.normal(size=(3, off[-1])) + 3.0)
    V = np.ascontiguousarray(rng.normal(size=(3, off[-1])))
    W = rng.uniform(0.5, 2.0, off[-1])
    X[2, 3] = X[2, 5] = X[2, :7].min() - 1.0     # two lowest: the first one's velocity
    cpl = np.array([True, True, False])
    bw = np.array([1 / (1 / W[off[b]:off[b + 1]]).sum() for b in range(3)])
    bodies = carried_bodies_for(off, bw, cpl)
    Xref = X + rng.normal(scale=0.01, size=X.shape)
    act = np.array([True, False, True])
    dbox = np.zeros(6)
    spread2 = C.body_velocities(X, V, 1.0 / W, bodies, Xref, act, dbox)
    vb, zlo, bc, bom, biv = (bodies.velocity, bodies.lowest, bodies.centre, bodies.spin,
                             bodies.inv_inertia)
    # the colliding bodies' displacements (body 1 does not collide), as moved_spread2
    assert spread2 == C.moved_spread2(X, Xref, off.astype(np.int64), act)
    keep = np.repeat(act, n)
    d = (X - Xref)[:, keep]
    e = 0.5 * (d.max(axis=1) - d.min(axis=1))
    assert spread2 == pytest.approx(e @ e, rel=1e-12)
    np.testing.assert_array_equal(dbox, np.concatenate([d.min(axis=1), d.max(axis=1)]))
    for b in range(2):
        s = slice(off[b], off[b + 1])
        m, x, v = 1 / W[s], X[:, s].T, V[:, s].T
        c = (m[:, None] * x).sum(0) / m.sum()
        r = x - c
        inertia = (m[:, None, None] * ((r * r).sum(1)[:, None, None] * np.eye(3)
                                        - r[:, :, None] * r[:, None, :])).sum(0)
        ang = (m[:, None] * np.cross(r, v)).sum(0)
        np.testing.assert_allclose(bc[b], c, rtol=1e-12)
        np.testing.assert_allclose(vb[b], (m[:, None] * v).sum(0) / m.sum(), rtol=1e-12)
        assert zlo[0, b] == x[:, 2].min() and zlo[1, b] == v[np.argmin(x[:, 2]), 2]
        np.testing.assert_allclose(biv[b].reshape(3, 3), np.linalg.inv(inertia), rtol=1e-9)
        np.testing.assert_allclose(bom[b], np.linalg.solve(inertia, ang), rtol=1e-9)
    np.testing.assert_array_equal(vb[2], 0.0)
    assert zlo[1, 0] == V[2, 3] != V[2, 5]


def test_spin_of_a_body_held_by_another_is_stopped():
    # a spinning box lands on a box, no stiff body in the world: carried bodies are not
    # turned by their contacts, and one held by another body does not keep spinning (a
    # spinning body in a heap would otherwise drive its neighbours sideways forever);
    # linear momentum stays exact
    w = World()
    w.set_colliders(ground=Ground())
    p = BodyParams(mode='linear', alpha=0.9, clusters=2)
    a = w.add_body(lattice(4, 4, 3, center=(0, 0, 0.02)), 0.01, p, 'a')
    pts = lattice(4, 4, 3, center=(0, 0, 0.079))         # 1 mm into it
    spin = np.cross([0.0, 0.0, 3.0], pts - pts.mean(axis=0))
    b = w.add_body(pts, 0.01, p, 'b', velocities=spin)
    w.step(1 / 120)
    assert w.contact.coupling[:2].all() and w.contact.count[1] > 0
    r = b.x - b.com()
    ang = (b.m[:, None] * np.cross(r, b.v - b.v.mean(axis=0))).sum(0)
    ang0 = (b.m[:, None] * np.cross(pts - pts.mean(axis=0), spin)).sum(0)
    assert abs(ang[2]) < 1e-3 * abs(ang0[2])
    # the pair's impulses are equal and opposite: only gravity and the ground changed the
    # total momentum, the ground only upwards (z)
    tot = a.momentum() + b.momentum()
    np.testing.assert_allclose(tot[:2], 0.0, atol=1e-12)


@pytest.mark.parametrize('friction', [0.5, 0.0])
def test_a_spinning_box_on_another_is_stopped_by_the_contact_friction(friction):
    # a box spinning about the vertical rests on a box: both carry their contacts as a
    # whole and a stiff body lies near, so their contact is the stiff pass's, which turns
    # them; its friction stops the spin within a few steps (a spinning body in a heap would
    # otherwise drive its neighbours sideways forever), and without friction nothing does
    w = World()
    w.set_colliders(ground=Ground())
    w.contact_params = ContactParams(friction=friction)
    p = BodyParams(mode='linear', alpha=0.9, clusters=2)
    w.add_body(lattice(4, 4, 3, center=(0, 0, 0.02)), 0.01, p, 'a')
    pts = lattice(4, 4, 3, center=(0, 0, 0.079))         # 1 mm into it
    spin = np.cross([0.0, 0.0, 3.0], pts - pts.mean(axis=0))
    b = w.add_body(pts, 0.01, p, 'b', velocities=spin)
    w.add_body(lattice(4, 4, 3, center=(1, 0, 0.02)), 0.01, BodyParams('rigid', 1.0), 'c')
    for _ in range(6):
        w.step(1 / 120)
    assert w.contact.coupling[:2].all() and w.contact.rigid[:3].all()
    assert w.contact_stats()['b'][0] > 0
    r = b.x - b.com()
    ang = (b.m[:, None] * np.cross(r, b.v - b.v.mean(axis=0))).sum(0)
    ang0 = (b.m[:, None] * np.cross(pts - pts.mean(axis=0), spin)).sum(0)
    if friction:
        assert abs(ang[2]) < 0.01 * abs(ang0[2])
    else:
        assert abs(ang[2]) > 0.9 * abs(ang0[2])


def _overlaps_numpy(X, off, act, selfc, rigid, grow):
    """The twin of ``body_overlaps``: grown boxes, every pair of bodies but two rigid
    ones compared."""
    nb = len(off) - 1
    lo = np.array([X[:, off[b]:off[b + 1]].min(axis=1) - grow[b] for b in range(nb)])
    hi = np.array([X[:, off[b]:off[b + 1]].max(axis=1) + grow[b] for b in range(nb)])
    out = np.array([bool(act[b] and selfc[b]) for b in range(nb)])
    for b in range(nb):
        for c in range(b + 1, nb):
            if rigid[b] and rigid[c]:
                continue
            if act[b] and act[c] and np.all(lo[b] <= hi[c]) and np.all(lo[c] <= hi[b]):
                out[b] = out[c] = True
    return out


@pytest.mark.parametrize('seed', [0, 1, 2])
def test_body_overlaps_matches_numpy(seed):
    rng = np.random.default_rng(seed)
    nb = 40
    counts = rng.integers(1, 30, nb)
    off = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    centres = rng.uniform(-1.0, 1.0, (nb, 3))
    X = np.ascontiguousarray(np.concatenate(
        [centres[b] + rng.uniform(-0.05, 0.05, (counts[b], 3)) for b in range(nb)]).T)
    act = rng.random(nb) > 0.1
    selfc = rng.random(nb) > 0.9
    rigid = rng.random(nb) > 0.5
    grow = rng.uniform(0.0, 0.2, nb)
    out = np.zeros(nb, np.bool_)
    C.body_overlaps(X, off, (act, selfc, rigid), grow, np.zeros((nb, 6)),
                    np.zeros(nb, np.int64), out)
    want = _overlaps_numpy(X, off, act, selfc, rigid, grow)
    np.testing.assert_array_equal(out, want)
    assert 0 < want.sum() < nb                             # some in, some out


def test_a_rigid_body_grabbed_beside_another_meets_it_per_particle_at_once():
    """Two rigid cubes face to face: their contact is the stiff pass's, so the pair list
    leaves them out. Once one is grabbed (no longer rigid in contact) and pushed 2 mm into
    the other, less than the skin that would rebuild the list, the list is built anew
    with their pairs at once and the other cube's face gives way."""
    w = World(gravity=(0.0, 0.0, 0.0))
    p = BodyParams(mode='rigid', alpha=1.0)
    a = w.add_body(lattice(4, 4, 4), 0.01, p, 'a')
    b = w.add_body(lattice(4, 4, 4, center=(4 * S, 0.0, 0.0)), 0.01, p, 'b')
    w.step(1 / 120)
    c = w.contact
    assert c.rigid[:2].all() and c.npairs == 0 and 2 * 0.002 < c.skin
    builds = c.builds
    a.set_kinematic(np.arange(a.n), a.x + [0.002, 0.0, 0.0])
    w.step(1 / 120)
    assert not c.rigid[0] and c.builds == builds + 1 and c.npairs > 0
    gap = b.x[:, 0].min() - a.x[:, 0].max()
    assert gap > 2 * S / 2 - 2e-4                    # the faces a contact distance apart


def test_broad_phase_keeps_every_pair_of_a_pour():
    # paper_384's pour (bodies in layers, most apart): the pair list built with the broad
    # phase is the builders' list over every colliding body, pair for pair
    from sm_ros.scene import build_world, load_scene
    w, _ = build_world(load_scene('paper_384'))
    left_out = []
    for steps in (1, 60, 150):
        for _ in range(steps):
            w.step(1 / 120)
        c, f = w.contact, w._flat
        c._build()
        got = set(zip(c._pair_i[:c.npairs].tolist(), c._pair_j[:c.npairs].tolist()))
        m, pi, pj = build_with(f.X, f.R, f.B, c.act, c.selfc, f.X0, c.cell, c.skin,
                               4 * f.n)
        C.sort_pairs(pi, pj, m, f.n, np.zeros(f.n + 1, np.int64), np.zeros_like(pi),
                     np.zeros_like(pj))
        assert got == set(zip(pi[:m].tolist(), pj[:m].tolist()))
        left_out.append(len(w.bodies) - int(c._act_eff[:len(w.bodies)].sum()))
    assert left_out[0] > 100                  # the case was exercised: layers apart


def _spread2_numpy(X, Xref, B, act):
    """``moved_spread2`` by NumPy: the squared half diagonal of the colliding particles'
    displacement box (inf when one is not finite, 0 when none collides)."""
    d = (X - Xref)[:, act[B]]
    if d.shape[1] == 0:
        return 0.0
    if not np.isfinite(d).all():
        return np.inf
    e = 0.5 * (d.max(axis=1) - d.min(axis=1))
    return float(e @ e)


def test_moved_spread_against_numpy():
    rng = np.random.default_rng(7)
    n, nb = 500, 6
    B = np.sort(rng.integers(0, nb, n)).astype(np.int32)
    act = np.array([True, True, False, True, False, True])
    off = np.searchsorted(B, np.arange(nb + 1)).astype(np.int64)
    Xref = rng.normal(size=(3, n))
    X = Xref + np.array([[0.3], [-2.0], [5.0]]) + rng.uniform(-0.01, 0.01, (3, n))
    got = C.moved_spread2(X, Xref, off, act)
    assert got == pytest.approx(_spread2_numpy(X, Xref, B, act), rel=1e-12, abs=1e-15)
    assert got < 3 * 0.01 ** 2                 # the common shift does not count
    X[:, B == 2] += 1.0                        # a body that does not collide: ignored
    assert C.moved_spread2(X, Xref, off, act) == pytest.approx(got, rel=1e-12)
    for bad in (np.nan, np.inf):
        Y = X.copy()
        Y[1, np.flatnonzero(B == 3)[0]] = bad
        assert C.moved_spread2(Y, Xref, off, act) == np.inf == _spread2_numpy(Y, Xref, B, act)
    assert C.moved_spread2(X, Xref, off, np.zeros(nb, np.bool_)) == 0.0


def test_pair_list_kept_for_a_common_motion_and_always_complete():
    # two boxes falling one above the other keep one pair list however far they fall
    # (only their relative motion counts); once the lower one lands and the upper one
    # falls onto its edge the list is rebuilt, and at every step it holds every pair in
    # contact
    w = World()
    w.set_colliders(ground=Ground(height=-0.3))
    p = BodyParams(alpha=0.4, damping=0.02)          # soft: its contact is this pass's
    w.add_body(lattice(3, 3, 3, 0.05, (0.0, 0.0, 0.0)), params=p, name='a')
    w.add_body(lattice(3, 3, 3, 0.05, (0.06, 0.0, 0.6)), params=p, name='b')
    w.step(1 / 120)
    c, f = w.contact, w._flat
    builds, z0 = c.builds, f.X[2].mean()
    for _ in range(20):                       # both fall freely: 20 steps, one list
        w.step(1 / 120)
    assert c.builds == builds
    assert z0 - f.X[2].mean() > 10 * c.skin   # though they fell far more than the skin
    met = 0
    for _ in range(240):
        w.step(1 / 120)
        touching = brute_pairs(f.X.T, f.R, f.B, c.act, c.selfc, f.X0.T, 0.0)
        listed = set(zip(c._pair_i[:c.npairs].tolist(), c._pair_j[:c.npairs].tolist()))
        assert touching <= listed
        met += len(touching)
    assert met > 0 and c.builds > builds + 2


@pytest.mark.parametrize('far', [1e6, 1e25, 1e200, 1e308])
def test_pair_build_keeps_its_pairs_with_bodies_flung_beyond_any_grid(far):
    """Bodies at a million to 1e308 m from a heap (a box of more cells than integers count,
    or wider than floats reach): the grid wraps, nothing is written out of bounds, and the
    heap's pairs are brute force's, each once."""
    X, R, B, act, selfc, X0 = heap_of_lattices(7, n_bodies=6)
    X = X.copy()
    X[:, B == 4] += np.array([[far], [0.0], [0.0]])
    X[:, B == 5] -= np.array([[far], [far], [0.0]])
    skin = 0.25 * S
    m, pi, pj = build_with(X, R, B, act, selfc, X0, 2 * R.max() + skin, skin, 16 * X.shape[1])
    with np.errstate(over='ignore'):                     # NumPy's distances overflow
        want = brute_pairs(X.T, R, B, act, selfc, X0.T, skin) if far < 1e300 else None
    got = built_set(m, pi, pj)
    if want is not None:
        assert got == want
    heap = {p for p in got if B[p[0]] < 4 and B[p[1]] < 4}
    assert len(heap) > 100 and all(B[a] < 4 and B[b] < 4 for a, b in got)
