"""The packed world step (``sm_ros.core.packed``) gives the states of the bodies' own steps."""


import numpy as np
import pytest

import sm_ros.core.body as body_mod
import sm_ros.core.packed as packed
from sm_ros.core import BodyParams, Box, Ground, World, tuning
from twins import on_ground



def lattice(n, spacing=0.02):
    g = np.arange(n) * spacing
    return np.stack(np.meshgrid(g, g, g, indexing='ij'), axis=-1).reshape(-1, 3)


def _world(compiled=True):
    """Damped and undamped rigid/linear one-cluster bodies (packed; two of them larger than
    a block of the pass), a set-layout body, a quadratic one (records) and a plastic one
    (stepped alone), on a ground and a box; spinning and fast enough to hit both limits."""
    world = World()
    world.compiled_step = compiled
    world.set_colliders(ground=Ground(height=0.0, friction=0.5, restitution=0.3),
                        boxes=[Box(lo=(0.3, -0.1, 0.0), hi=(0.5, 0.2, 0.04))])
    rng = np.random.default_rng(11)
    specs = [('rigid', 1, 0.1, 4), ('linear', 1, 0.05, 5), ('linear', 1, 0.0, 7),
             ('rigid', 1, 0.2, 8), ('linear', 1, 0.3, 3), ('linear', 8, 0.05, 5),
             ('quadratic', 1, 0.05, 4), ('linear', 1, 0.05, 4)]
    for i, (mode, clusters, damping, n) in enumerate(specs):
        x0 = lattice(n) + (0.25 * i, 0.0, 0.03 + 0.02 * i)
        c = x0.mean(axis=0)
        spin = np.cross(rng.standard_normal(3) * 40.0, x0 - c)      # up to ~1 rad/step
        plastic = dict(plastic_yield=0.01, plastic_creep=5.0, plastic_max=0.3) if i == 7 \
            else {}
        world.add_body(x0, masses=0.01 + 0.002 * i, name=f'b{i}',
                       velocities=spin + rng.standard_normal(x0.shape),
                       params=BodyParams(mode=mode, clusters=clusters, damping=damping,
                                         alpha=0.4, beta=0.6, max_speed=2.5, max_turn=0.05,
                                         **plastic))
    world.bodies[1].set_wrench((0.0, 0.01, 0.03))
    return world


def _states(world):
    return [(b.x.copy(), b.v.copy(), b.shape_error_rms(), b._limit_counts.copy(),
             b.cluster_rotations) for b in world.bodies]


def _run(world, ticks, substeps=2, dt=1.0 / 120.0, events=True):
    for tick in range(ticks):
        for _ in range(substeps):
            world.step(dt / substeps)
        if not events:
            continue
        if tick == 3:
            world.bodies[3].set_state(v=0.5 * world.bodies[3].v)
            world.bodies[4].set_params(damping=0.0)
        if tick == 5:
            world.bodies[0].set_wrench((0.0, 0.0, 0.0), (0.0, 0.0, 1e-4))   # leaves the pack
            world.bodies[4].set_params(damping=0.1)
        if tick == 7:
            world.bodies[0].clear_wrench()                                    # comes back
            world.add_body(lattice(3) + (0.0, 0.6, 0.2), masses=0.02, name='late',
                           params=BodyParams(damping=0.05))
    return world


@pytest.mark.parametrize('parallel', [False, True])
def test_packed_step_equals_stepping_bodies_one_at_a_time(monkeypatch, parallel):
    """World.step over the packed rows (one compiled call, 2 substeps a tick, threads or
    not) gives bit for bit the states of ``Body._step`` called body by body, through a
    state set by hand, damping switched off and on, a torque (the body leaves the pack and
    comes back) and a new body; the limits and colliders are hit.  ``parallel``: the
    records on the helper threads (the pack is stepped meanwhile)."""
    monkeypatch.setattr(tuning, 'RECORDS_PARALLEL_MIN_WORK', 0 if parallel else 1 << 40)
    got = _run(_world(True), 12)
    want = _run(_world(False), 12)
    pack, records, slow, _ = got._split_bodies(1.0 / 240.0)
    assert [b.name for b in pack.bodies] == ['b0', 'b1', 'b2', 'b3', 'b4', 'late']
    assert len(records) == 3 and slow == []        # b5, b6: sets; b7 plastic
    counts = np.array([s[3] for s in _states(got)])
    assert counts[:5, 0].sum() > 0 and counts[:5, 1].sum() > 0        # both limits acted
    assert got.bodies[2].n > 256 and got.bodies[3].n > 256               # several blocks
    for g, w in zip(_states(got), _states(want)):
        assert np.array_equal(g[0], w[0]) and np.array_equal(g[1], w[1])
        assert g[2] == w[2] and np.array_equal(g[3], w[3]) and np.array_equal(g[4], w[4])


def test_packed_step_matches_the_record_step(monkeypatch):
    """The packed step (damping fused into the particle pass, the speed limit inside it)
    gives the states of the records' step (one set, the damping field from its own sums,
    the speed limit run by run) to round-off."""
    got = _run(_world(True), 4, events=False)
    monkeypatch.setattr(body_mod.Body, '_packed_ok', lambda self: False)
    want = _run(_world(True), 4, events=False)
    assert want._split_bodies(1.0 / 240.0)[0] is None
    for g, w in zip(_states(got), _states(want)):
        for a, b in ((g[0], w[0]), (g[1], w[1])):
            assert np.abs(a - b).max() <= 1e-11 * np.abs(b).max()
        assert np.array_equal(g[3], w[3])
        assert abs(g[2] - w[2]) <= 1e-9 * w[2]


@pytest.mark.parametrize('ground', [False, True])
def test_packed_damping_of_bodies_of_one_mass_matches_the_record_step(monkeypatch, ground):
    """The packed pass sums the damping of a body whose particles all have one mass
    unweighted and scales the sums once a block (``packed._pass``): such bodies (rigid and
    linear, several blocks, with and without a collider pass) step as the records' step
    (the set layout's weighted sums) to round-off; a body of varied masses is not
    packed (it steps outside the pack, weighted)."""
    def build(damping=0.2):
        world = World()
        if ground:
            world.set_colliders(ground=Ground(height=0.0, friction=0.5, restitution=0.3))
        rng = np.random.default_rng(5)
        for i, (mode, uniform) in enumerate((('rigid', True), ('linear', True),
                                              ('rigid', False))):
            x0 = lattice(11) + (0.4 * i, 0.0, 0.02)
            spin = np.cross(rng.standard_normal(3) * 20.0, x0 - x0.mean(axis=0))
            masses = 0.01 if uniform else 0.01 + 0.01 * rng.random(len(x0))
            world.add_body(x0, masses=masses, name=f'u{i}', velocities=spin,
                           params=BodyParams(mode=mode, damping=damping, alpha=0.4))
        return world

    got = _run(build(), 4, events=False)
    pack = got._split_bodies(1.0 / 240.0)[0]
    assert [b.name for b in pack.bodies] == ['u0', 'u1']
    assert [row[packed.C_WUNI] for row in pack.rows] == [0.01, 0.01]
    monkeypatch.setattr(body_mod.Body, '_packed_ok', lambda self: False)
    want = _run(build(), 4, events=False)
    assert want._split_bodies(1.0 / 240.0)[0] is None
    for g, w in zip(_states(got), _states(want)):
        for a, b in ((g[0], w[0]), (g[1], w[1])):
            assert np.abs(a - b).max() <= 1e-11 * np.abs(b).max()
        assert abs(g[2] - w[2]) <= 1e-9 * w[2]
    # the damping sums matter to what is compared: undamped, every body steps elsewhere
    free = _run(build(damping=0.0), 4, events=False)
    for g, f in zip(_states(got), _states(free)):
        assert np.abs(g[1] - f[1]).max() > 1e-4 * np.abs(f[1]).max()


def test_packed_bodies_read_their_state_from_the_pack(copy_world):
    """A packed body's attributes are views of its row: what the step wrote is what the
    body reports (rotation, shape error, counts), a body stepped on its own in between is
    packed again (not left stale in the world's rows), and a copied world steps as the
    original."""
    world = _run(_world(True), 2, events=False)
    body = world.body('b1')
    pack = world._split_bodies(1.0 / 240.0)[0]
    assert np.shares_memory(body._quat, pack.rows) and np.shares_memory(body._part, pack.rows)
    r = body.cluster_rotations[0]
    assert np.allclose(r @ r.T, np.eye(3), atol=1e-12) and not np.allclose(r, np.eye(3))
    # copy_world, not copy.deepcopy: a deep copy's arrays are all writeable, so the copies
    # would step through a second (read-only flags differ) specialisation of the packed
    # kernels, compiled on its own; under fast math it may round differently (it did in a
    # fresh clone whose cache held only the warm-up's specialisation)
    twin = copy_world(world)
    ref = _run(copy_world(world), 2, events=False)
    # body b1 alone: packed on its own, then the world packs it again
    gargs = (world._gravity, world._has_col, world._ground_row, world._box_rows,
             world._sphere_rows, 1e-3)
    body._step(1.0 / 240.0, *gargs)
    assert not np.shares_memory(body._quat, pack.rows)
    twin.body('b1')._step(1.0 / 240.0, *gargs)
    _run(world, 2, events=False)
    _run(twin, 2, events=False)
    for g, w in zip(_states(world), _states(twin)):
        assert np.array_equal(g[0], w[0]) and np.array_equal(g[1], w[1])
    moved = [not np.array_equal(g[0], w[0]) for g, w in zip(_states(world), _states(ref))]
    assert moved[1] and not any(moved[:1] + moved[2:])


def test_packed_linear_bodies_keep_the_minimisers_warm_start_in_their_rows():
    """A packed linear body's eigenvectors of its last unit-determinant match (``_udv``,
    the warm start of the next) are a view of its row that the step updates, and the warm
    start changes no result: the same body with its ``_udv`` reset to the identity before
    every step (a cold start) steps to the same states, to round-off."""
    def build():
        world = World()
        rng = np.random.default_rng(3)
        for i, mode in enumerate(('linear', 'rigid')):
            x0 = lattice(4) + (0.3 * i, 0.0, 0.5)
            spin = np.cross(rng.standard_normal(3) * 20.0, x0 - x0.mean(axis=0))
            world.add_body(x0 + 0.002 * rng.standard_normal(x0.shape), name=f'u{i}',
                           masses=0.01, velocities=spin, params=BodyParams(
                               mode=mode, damping=0.05, alpha=0.4, beta=0.6))
        return world

    warm, cold = build(), build()
    h = 1.0 / 240.0
    for _ in range(30):
        cold.step(h)
        for body in cold.bodies:
            body._udv[:] = np.eye(3)
        warm.step(h)
    pack = warm._split_bodies(h)[0]
    lin = warm.body('u0')
    assert np.shares_memory(lin._udv, pack.rows)
    v = lin._udv[0]
    assert np.allclose(v.T @ v, np.eye(3), atol=1e-9) and not np.allclose(np.abs(v), np.eye(3))
    assert np.array_equal(warm.body('u1')._udv[0], np.eye(3))      # rigid: never used
    for g, w in zip(_states(warm), _states(cold)):
        for a, b in ((g[0], w[0]), (g[1], w[1])):
            assert np.abs(a - b).max() <= 1e-11 * np.abs(b).max()


def test_a_force_command_reaches_the_packed_row_without_repacking():
    """A force set between steps acts from the next step on (momentum changes by (F + M g)
    h: goals and damping keep it) and does not rebuild the world's split (a re-split of
    384 bodies costs tens of milliseconds of Python); a torque does (the body leaves the
    pack)."""
    world = World(gravity=(0.0, 0.0, -9.81))
    for i in range(3):
        world.add_body(lattice(4) + (0.3 * i, 0.0, 1.0), masses=0.01, name=f'b{i}',
                       params=BodyParams(mode='linear', damping=0.1),
                       velocities=np.random.default_rng(i).standard_normal((64, 3)))
    h = 1.0 / 240.0
    world.step(h)
    split = world._split
    body = world.body('b1')
    f = np.array([0.3, -0.2, 0.5])
    body.set_wrench(f)
    p0 = body.momentum()
    world.step(h)
    assert world._split is split                                   # no re-split
    want = p0 + (f + body.total_mass * world.gravity) * h
    assert np.allclose(body.momentum(), want, rtol=0.0, atol=1e-12 * np.abs(want).max())
    body.set_wrench(f, (0.0, 0.0, 1e-4))
    world.step(h)
    assert world._split is not split and body not in world._split[1].bodies


def test_two_worlds_stepped_in_turn_keep_their_packs(copy_world):
    """Two worlds stepping in turn (the live error estimate's coarse and fine copies, a
    user's second world) keep their packs and splits: a pack is rebuilt only when one of
    its own bodies was packed elsewhere (re-packing both worlds at every turn would cost
    many times the step), and each world's states are bit for bit those of stepping it
    alone."""
    a = _run(_world(True), 1, events=False)
    b = copy_world(a)
    a_alone, b_alone = copy_world(a), copy_world(a)
    h = 1.0 / 240.0
    a.step(h)
    b.step(h)
    split_a, split_b = a._split, b._split
    for _ in range(4):
        a.step(h)
        b.step(h)
    assert a._split is split_a and b._split is split_b
    for _ in range(5):
        a_alone.step(h)
    for _ in range(5):
        b_alone.step(h)
    for w, alone in ((a, a_alone), (b, b_alone)):
        for g, r in zip(_states(w), _states(alone)):
            assert np.array_equal(g[0], r[0]) and np.array_equal(g[1], r[1])
    # a body of a stepped on its own leaves a's pack: only a re-splits
    a.body('b1')._step(h, a._gravity, a._has_col, a._ground_row, a._box_rows,
                       a._sphere_rows, 1e-3)
    assert split_a[1].stale and not split_b[1].stale
    a.step(h)
    b.step(h)
    assert a._split is not split_a and b._split is split_b


@pytest.mark.parametrize('mode', ['rigid', 'linear'])
def test_a_body_leaving_and_joining_the_pack_follows_the_numpy_reference(mode):
    """A packed body grabbed (it leaves the pack for the set layout's step), released (it
    joins again), turned by a torque and let go: each step takes its sums afresh where it
    changed hands (``flags.SUMS_PACKED``), so the states follow the NumPy reference to 1e-9."""
    rng = np.random.default_rng(8)
    x0 = lattice(6) + 0.002 * rng.standard_normal((216, 3)) + (0.0, 0.0, 0.05)
    params = BodyParams(mode=mode, alpha=0.4, beta=0.5, damping=0.1)
    ground = Ground(height=0.0, friction=0.4, restitution=0.2)
    world, body, ref = on_ground(x0, 0.01, params, rng.normal(scale=0.3, size=x0.shape), ground)
    h = 1.0 / 240.0
    packed_at = []
    for step in range(60):
        if step == 10:
            for b in (body, ref):
                b.set_kinematic(np.array([3, 7]), body.x[[3, 7]] + (0.0, 0.0, 0.02))
        if step == 25:
            body.clear_kinematic()
            ref.set_kinematic(np.zeros(0, dtype=int), np.zeros((0, 3)))
        if step == 35:
            for b in (body, ref):
                b.set_wrench((0.0, 0.0, 0.0), (0.0, 0.0, 2e-3))
        if step == 45:
            body.clear_wrench()
            ref.set_wrench((0.0, 0.0, 0.0))
        world.step(h)
        ref.step(h, world.gravity, ground, radius=body._collider_radius)
        packed_at.append(body._packed_ok())
        assert np.abs(body.x - ref.x).max() < 1e-9, step
        assert np.abs(body.v - ref.v).max() < 1e-9 / h, step
    assert packed_at[:10] == [True] * 10 and not any(packed_at[10:25])
    assert all(packed_at[25:35]) and not any(packed_at[35:45]) and all(packed_at[45:])
