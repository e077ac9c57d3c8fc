"""The passes fused into the particle pass (damping, the next step's sums) against the NumPy
reference and the compiled world step against stepping bodies one by one."""

import numba
import numpy as np
import pytest

from sm_ros.core import BodyParams, Ground, World, tuning
from sm_ros.core.reference import ReferenceBody
from twins import on_ground


def lattice(n, spacing=0.02):
    g = np.arange(n) * spacing
    return np.stack(np.meshgrid(g, g, g, indexing='ij'), axis=-1).reshape(-1, 3)


@pytest.mark.parametrize('mode,clusters,plastic,parallel', [
    ('rigid', 1, False, False), ('linear', 1, True, True), ('quadratic', 1, False, False),
    ('linear', 8, False, True), ('quadratic', 8, True, False), ('rigid', 27, False, False)])
def test_damped_body_matches_the_numpy_reference(monkeypatch, mode, clusters, plastic,
                                                 parallel):
    """Damping inside the particle pass (each set's field from the sums the last pass
    took) gives the states of the NumPy reference, which damps towards each cluster's rigid
    motion from the state itself: on the ground, under a wrench, with plasticity, grabbed
    particles and a state set by hand."""
    monkeypatch.setattr(tuning, 'PARALLEL_MIN_WORK', 0 if parallel else 1 << 40)
    rng = np.random.default_rng(3)
    x0 = lattice(6) + 0.002 * rng.standard_normal((216, 3)) + (0.0, 0.0, 0.03)
    m = 0.01 + 0.02 * rng.random(len(x0))
    kw = dict(plastic_yield=0.01, plastic_creep=20.0, plastic_max=0.3) if plastic else {}
    params = BodyParams(mode=mode, clusters=clusters, alpha=0.3, beta=0.4, damping=0.3, **kw)
    ground = Ground(height=0.0, friction=0.4, restitution=0.2)
    v0 = rng.normal(scale=0.3, size=x0.shape)
    world, body, ref = on_ground(x0, m, params, v0, ground)
    for b in (body, ref):
        b.set_wrench((0.02, 0.0, 0.1), (0.0, 0.001, 0.002))
    assert body._parallel == parallel
    h = 1.0 / 200.0
    for step in range(40):
        if step == 10:
            for b in (body, ref):
                b.set_kinematic(np.array([0, 5]), body.x[[0, 5]] + (0.0, 0.0, 0.01))
        if step == 20:
            body.set_state(v=0.5 * body.v)
            ref.v = 0.5 * ref.v
        world.step(h)
        ref.step(h, world.gravity, ground, radius=body._collider_radius)
        assert np.abs(body.x - ref.x).max() < 1e-9, step
        assert np.abs(body.v - ref.v).max() < 1e-9 / h, step
    # the damping acted: 10 steps of an undamped twin end elsewhere
    ends = []
    for damping in (0.0, 0.3):
        twin = ReferenceBody(x0, m, BodyParams(mode=mode, clusters=clusters, alpha=0.3,
                                               beta=0.4, damping=damping, **kw))
        twin.v = v0.copy()
        twin.set_wrench((0.02, 0.0, 0.1), (0.0, 0.001, 0.002))
        for _ in range(10):
            twin.step(h, world.gravity, ground, radius=body._collider_radius)
        ends.append(twin.v)
    assert np.abs(ends[1] - ends[0]).max() > 0.1 * np.abs(v0).max()


def test_fused_damping_keeps_momentum(monkeypatch):
    """Damping alone (no gravity, no goals' net force) keeps linear and angular momentum."""
    world = World(gravity=(0.0, 0.0, 0.0))
    rng = np.random.default_rng(0)
    x0 = lattice(5)
    body = world.add_body(x0, masses=0.5 + rng.random(len(x0)),
                          params=BodyParams(mode='linear', clusters=8, damping=0.5,
                                            max_turn=0.0),   # the turn limit changes L
                          velocities=rng.standard_normal(x0.shape))
    p0, l0 = body.momentum(), body.angular_momentum()
    e0 = float(np.sum(body.m[:, None] * body.v ** 2))
    for _ in range(50):
        world.step(0.01)
    assert np.allclose(body.momentum(), p0, atol=1e-12 * np.abs(p0).max())
    assert np.allclose(body.angular_momentum(), l0, atol=1e-10 * np.abs(l0).max())
    assert float(np.sum(body.m[:, None] * body.v ** 2)) < 0.5 * e0     # it does damp


@pytest.mark.parametrize('mode,clusters', [('rigid', 1), ('linear', 1), ('linear', 8)])
def test_plastic_refresh_at_cluster_cost_matches_the_particle_pass(mode, clusters):
    """The rigid/linear rest data after plastic flow, from the rest moments kept since the
    build (per cluster), equal the particle pass ``kernels.moments`` to round-off."""
    from sm_ros.core import kernels as K
    world = World(gravity=(0.0, 0.0, 0.0))
    x0 = lattice(6)
    body = world.add_body(x0, masses=1.0 + np.arange(len(x0)) % 3,
                          params=BodyParams(mode=mode, clusters=clusters, plastic_yield=0.01,
                                            plastic_creep=50.0, plastic_max=0.4))
    body.set_state(v=np.random.default_rng(2).standard_normal(x0.shape))
    for _ in range(20):
        world.step(0.005)
    assert np.abs(body.plastic_state - np.eye(3)).max() > 0.01      # it flowed
    sum_q, mom3 = np.zeros_like(body._sum_q), np.zeros_like(body._mom3)
    K.moments(body._x0, body._m, (body._ptr, body._cluster_ids), (body._rest_lin, body._rest_off),
              body._wsum, np.ones(body.num_clusters, dtype=np.bool_), (True, False),
              (sum_q, mom3, np.zeros((1, 9, 9))), np.zeros(9))
    scale = np.abs(mom3).max()
    assert np.abs(body._mom3 - mom3).max() <= 1e-12 * scale
    assert np.abs(body._sum_q - sum_q).max() <= 1e-12 * np.sqrt(scale * body._wsum.max())
    # NumPy twins of the rest maps G = S^P / s, -G cm0 and of A_qq = (sum w q q^T)^+
    g = body.plastic_state / body._scale[:, None, None]
    assert np.abs(body._rest_lin - g).max() <= 1e-15 * np.abs(g).max()
    assert np.abs(body._rest_off + np.einsum('kij,kj->ki', g, body._cm0)).max() <= 1e-15
    aqq = np.linalg.pinv(mom3, hermitian=True)
    assert np.abs(body._aqq3 - aqq).max() <= 1e-9 * np.abs(aqq).max()


def _many_world(compiled):
    """Small and large one-cluster and set-layout bodies (damped and undamped; rigid,
    linear, quadratic), a plastic one, colliders, a force."""
    world = World()
    world.compiled_step = compiled
    world.set_colliders(ground=Ground(height=0.0, friction=0.5, restitution=0.2))
    rng = np.random.default_rng(5)
    specs = [('rigid', 1, 0.0, 4), ('linear', 1, 0.05, 4), ('linear', 1, 0.05, 11),
             ('rigid', 1, 0.05, 11), ('linear', 8, 0.05, 5), ('quadratic', 1, 0.05, 5),
             ('linear', 8, 0.05, 11), ('quadratic', 8, 0.0, 11)]
    for i, (mode, clusters, damping, n) in enumerate(specs):
        x0 = lattice(n) + (0.3 * i, 0.0, 0.05)
        plastic = dict(plastic_yield=0.01, plastic_creep=5.0, plastic_max=0.3) if i == 4 else {}
        world.add_body(x0, masses=0.01, name=f'b{i}', velocities=rng.standard_normal(x0.shape),
                       params=BodyParams(mode=mode, clusters=clusters, damping=damping,
                                         max_speed=3.0, **plastic))
    world.bodies[1].set_wrench((0.0, 0.01, 0.02))
    return world


@pytest.mark.parametrize('parallel', [False, True])
def test_compiled_world_step_equals_stepping_bodies_one_by_one(monkeypatch, parallel):
    """One compiled call for the bodies it covers gives the states of ``Body._step``
    called body by body (the same kernels in the same order: bit for bit), through
    parameter changes, a state set by hand, a torque (the body leaves the compiled step
    and comes back), a new body and two step sizes."""
    states = []
    for compiled in (True, False):
        # the records on the helper threads
        monkeypatch.setattr(tuning, 'RECORDS_PARALLEL_MIN_WORK', 0 if parallel else 1 << 40)
        world = _many_world(compiled)
        for step in range(40):
            world.step(1.0 / 240.0 if step < 20 else 1.0 / 120.0)
            if step == 5:
                world.bodies[2].set_params(alpha=0.3)
            if step == 10:
                world.bodies[3].set_state(v=0.5 * world.bodies[3].v)
                world.bodies[0].set_wrench((0.0, 0.0, 0.0), (0.0, 0.0, 1e-3))
            if step == 15:
                world.bodies[0].clear_wrench()
                world.add_body(lattice(3) + (0.0, 0.5, 0.1), masses=0.01, name='late')
        if compiled:
            pack, records, slow, helpers = world._split_bodies(1.0 / 120.0)
            assert helpers == (parallel and numba.get_num_threads() > 1)
            assert len(pack) == 5 and len(records) == 4 and slow == []   # b4 plastic
            assert world.body('b7')._sets is not None and world.body('b4')._sets is not None
        states.append([(b.x.copy(), b.v.copy(), b.shape_error_rms(), b._limit_counts.copy())
                       for b in world.bodies])
    for got, want in zip(*states):
        assert np.array_equal(got[0], want[0]) and np.array_equal(got[1], want[1])
        assert got[2] == want[2] and np.array_equal(got[3], want[3])


@pytest.mark.parametrize('mode,clusters', [('rigid', 1), ('linear', 8), ('quadratic', 8)])
def test_held_and_turned_bodies_step_alike_in_one_call_and_in_phases_on_threads(
        monkeypatch, mode, clusters):
    """A body with grabbed particles, a pinned one and one under a torque, a plastic one:
    stepped by the records in one compiled call, and built for threads (the record step's
    phases one by one, the particle passes on helper threads), they agree to round-off."""

    def run():
        world = World(gravity=(0.0, 0.0, -9.81))
        world.set_colliders(ground=Ground(height=0.0, friction=0.5))
        rng = np.random.default_rng(4)
        params = BodyParams(mode=mode, clusters=clusters, alpha=0.4, beta=0.5, damping=0.1)
        plastic = BodyParams(mode=mode, clusters=clusters, alpha=0.4, beta=0.5, damping=0.1,
                             plastic_yield=0.01, plastic_creep=20.0, plastic_max=0.3)
        held, pinned, turned, _ = (
            world.add_body(lattice(5) + (0.3 * i, 0.0, 0.05), name=name,
                           params=plastic if name == 'plastic' else params,
                           masses=0.01 + 0.01 * rng.random(125),
                           pinned=[0, 4] if name == 'pinned' else None)
            for i, name in enumerate(('held', 'pinned', 'turned', 'plastic')))
        held.set_kinematic(np.array([3, 60]), held.x[[3, 60]] + (0.0, 0.01, 0.03))
        turned.set_wrench((0.0, 0.0, 0.0), (0.0, 0.0, 2e-3))
        for step in range(40):
            if step == 20:
                held.set_kinematic(np.array([3, 60]), held.x[[3, 60]] + (0.01, 0.0, 0.0))
            world.step(1.0 / 240.0)
        return world

    got = run()
    pack, records, slow, _ = got._split_bodies(1.0 / 240.0)
    assert pack is None and len(records) == 4 and not slow
    monkeypatch.setattr(numba, 'get_num_threads', lambda: 2)
    monkeypatch.setattr(tuning, 'PARALLEL_MIN_WORK', 0)
    want = run()
    assert len(want._split_bodies(1.0 / 240.0)[2]) == 4      # in phases, on threads
    assert all(len(b._sets.part) == 2 for b in want.bodies)
    # the phases compiled on their own may round differently under fast math: round-off
    # growing over 40 steps, where a wrong phase would differ by millimetres
    for g, w in zip(got.bodies, want.bodies):
        for a, b in ((g.x, w.x), (g.v, w.v)):
            assert np.abs(a - b).max() <= 1e-9 * np.abs(b).max()
    turn = got.body('turned')
    assert abs(turn.angular_momentum()[2]) > 1e-5              # the torque turned it
    assert np.abs(got.body('pinned').x[[0, 4]] - got.body('pinned').x_init[[0, 4]]).max() == 0.0
    assert np.abs(got.body('plastic').plastic_state - np.eye(3)).max() > 1e-3   # it flowed
