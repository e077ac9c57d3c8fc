"""The one-loop passes: the set layout's (``kernels.sets._sets_fused_lin``) against a NumPy
twin and against the two-loop pass it replaces on long runs, and the one-cluster one
(``packed._pass``) on a ground against the NumPy reference.

A rigid/linear body stored set by set (as the core stores it) without torque is stepped run by
run in one loop: damping towards the set's field, Eq. 13-14, the speed count, the set's
sums of the new state and, damped, the damping sums, all about one point per set (where
the set goes); a run the ground (or a speed over the cap) may have moved is projected,
capped and summed again.  These tests fail if a sum, the damping point, the unweighted sums
of a one-mass body, the speed cap, the colliders or the choice of pass changes.
"""

from unittest import mock

import numpy as np
import pytest

from sm_ros.core import BodyParams, Ground, World
from sm_ros.core import body_build
from sm_ros.core import kernels as K
from sm_ros.core.kernels import sets as KS
from sm_ros.core.packed import FUSED_BLOCK
from twins import on_ground

H = 1.0 / 120.0


def _lattice(n, spacing=0.04):
    g = np.stack(np.meshgrid(*[np.arange(n)] * 3, indexing='ij'), axis=-1).reshape(-1, 3)
    return g * spacing


def _fused(body):
    """Whether ``body``'s pass takes the one-loop pass (``sets._fused_pass``: long runs,
    every particle of one mass)."""
    return KS.long_runs(body._sets.runs) and body._wuni > 0.0


def _world(n, order, masses, damping, max_speed=100.0, seed=4, ground=False):
    """A world with one jittered lattice body; ``order`` None keeps the lattice order in
    storage (the core's set order turned off), so its runs are a few particles long."""
    rng = np.random.default_rng(seed)
    x0 = _lattice(n) + rng.uniform(-0.006, 0.006, (n ** 3, 3)) + (0.2, -0.1, 0.6)
    m = 1.5 if masses == 'one' else rng.uniform(0.5, 2.0, len(x0))
    world = World(gravity=(0.0, 0.0, -9.81))
    if ground:                             # reached within the first steps
        world.set_colliders(ground=Ground(height=0.5, friction=0.4, restitution=0.3))
    params = BodyParams(mode='linear', alpha=0.6, beta=0.5, clusters=2, damping=damping,
                        max_speed=max_speed)
    if order == 'set':
        body = world.add_body(x0, m, params)
    else:
        with mock.patch.object(body_build, 'set_order', lambda *args: (None, None)):
            body = world.add_body(x0, m, params)
    v = rng.normal(scale=0.6, size=x0.shape) + np.cross((0.0, 0.0, 3.0), x0 - x0.mean(0))
    body.set_state(v=v)
    return world, body


def _twin(x, v, y0, mass, wuni, sid, runs, gm, sref, alpha, h, acc, damp, k_damp, dmp, v_max,
          nsets):
    """NumPy twin of ``_sets_fused_lin`` over all particles: returns (x, v, set sums
    (S, 12), damping rows (S, 20), sum |g - x|^2, capped)."""
    x, v = x.copy(), v.copy()
    sums = np.zeros((nsets, 12))
    dsums = np.zeros((nsets, K.NDAMP))
    err2, capped = 0.0, 0
    for r in range(len(runs) - 1):
        i, j = runs[r], runs[r + 1]
        s = sid[i]
        p, y = x[i:j], y0[i:j]
        g = gm[s, :, 0] + y @ gm[s, :, 1:4].T
        point = sref[s].copy()
        u = v[i:j]
        if damp:
            c, o = dmp[s, :3], dmp[s, 3:]
            u = u + k_damp * (c + np.cross(o, p - sref[s]) - u)
            point = sref[s] + h * (c + h * acc)
        vn = u + (alpha / h) * (g - p) + h * acc
        xn = p + h * vn
        err2 += ((g - p) ** 2).sum()
        speed = np.linalg.norm(vn, axis=1)
        over = speed > v_max
        if over.any():
            f = v_max / speed[over]
            xn[over] -= (h * (1.0 - f))[:, None] * vn[over]
            vn[over] *= f[:, None]
            capped += int(over.sum())
        x[i:j], v[i:j] = xn, vn
        d = mass[i:j, None] * (xn - point)
        for a in range(3):
            sums[s, 4 * a] += d[:, a].sum()
            sums[s, 4 * a + 1:4 * a + 4] += d[:, a] @ y
        if damp:
            e = xn - point
            w = mass[i:j]
            row = dsums[s]
            row[0:3] += d.sum(axis=0)
            row[3:6] += w @ vn
            row[6:9] += (w[:, None] * np.cross(e, vn)).sum(axis=0)
            row[9:12] += w @ (e * e)
            row[12:15] += w @ (e * np.roll(e, -1, axis=1))
            row[15:18] = point
            row[18] = 1.0
            row[19] += w.sum()
    return x, v, sums, dsums, err2, capped


@pytest.mark.parametrize('cap', [2.0, 100.0])
@pytest.mark.parametrize('damping', [0.0, 0.08])
def test_fused_set_pass_matches_its_numpy_twin(damping, cap):
    """One call over a whole body (one block) against the twin: positions, velocities, the
    set sums, the damping rows (their point where the set goes), the error sum and the
    capped speeds.  With a cap low enough to catch some particles (their runs summed again
    after the cap) and with none capped (every sum the loop's own)."""
    world, body = _world(10, 'set', 'one', damping, max_speed=2.0)
    for _ in range(3):
        world.step(H)                      # moving, deformed: sums, fields, maps of a step
    assert _fused(body)
    st = body._sets
    rng = np.random.default_rng(9)
    v = np.array(body._v)
    if cap < 100.0:
        v[rng.choice(body.n, 25, replace=False)] *= 4.0      # over the cap
    body.set_state(v=v)
    x0, v0 = np.array(body._x), np.array(body._v)
    nsets = len(st.cnt)
    dmp = rng.normal(scale=0.3, size=(nsets, 6)) if damping else np.zeros((nsets, 6))
    acc = np.array([0.3, -0.2, -9.81])
    sums = np.zeros((nsets, 12))
    dsums = np.zeros((nsets, K.NDAMP))
    wuni = body._wuni
    assert wuni == 1.5
    err2, capped = KS._sets_fused_lin(
        0, body.n, K.BodyParticles(body._x, body._v, st.rest_local, body._m),
        K.Sets(st.sid, st.runs, st.goal_maps, st.ref, wuni),
        K.SetMotion(0.6, H, acc, np.zeros(3), np.zeros(3), cap),
        K.FusedDamping(damping > 0.0, damping, dmp, dsums[None]), sums, dsums,
        K.Colliders(False, np.zeros(4), np.zeros((0, 8)), np.zeros((0, 6)), 1e-3, 0.0, 0.0))
    tx, tv, tsums, tds, terr, tcapped = _twin(
        x0, v0, np.asarray(st.rest_local), body._m, wuni, st.sid, st.runs, st.goal_maps, st.ref,
        0.6, H, acc, damping > 0.0, damping, dmp, cap, nsets)
    assert capped == tcapped and (capped > 0) == (cap < 100.0)
    np.testing.assert_allclose(body._x, tx, rtol=0, atol=1e-13)
    np.testing.assert_allclose(body._v, tv, rtol=0, atol=1e-11)
    assert err2 == pytest.approx(terr, rel=1e-10)
    np.testing.assert_allclose(sums, tsums, rtol=1e-9, atol=1e-12 * np.abs(tsums).max())
    np.testing.assert_allclose(dsums, tds, rtol=1e-9, atol=1e-12 * np.abs(tds).max())


@pytest.mark.parametrize('ground', [False, True])
@pytest.mark.parametrize('damping', [0.0, 0.05])
@pytest.mark.parametrize('masses', ['one', 'many'])
def test_fused_set_pass_steps_as_the_two_loop_pass(masses, damping, ground):
    """The same body stored set by set (long runs: the one-loop pass) and in the given
    order (runs of a few particles: the two-loop pass) agree to round-off over 40 steps,
    a few speeds capped on the way, and count the same capped speeds; with a ground the
    body lands on it (the runs it reaches summed again after the colliders)."""
    a_world, a = _world(10, 'set', masses, damping, max_speed=2.0, ground=ground)
    b_world, b = _world(10, None, masses, damping, max_speed=2.0, ground=ground)
    # the one loop sums unweighted: a body of several masses takes the two-loop pass
    assert _fused(a) == (masses == 'one') and not _fused(b)
    for _ in range(40):
        a_world.step(H)
        b_world.step(H)
    if ground:
        # on the ground, on its particles' spheres
        assert a.x[:, 2].min() == pytest.approx(0.5 + a._collider_radius, abs=0.02)
        assert len(a_world._split_bodies(H)[1]) == 1       # stepped by its record
    np.testing.assert_allclose(a.x, b.x, rtol=0, atol=1e-10)
    np.testing.assert_allclose(a.v, b.v, rtol=0, atol=1e-8)
    assert a.limit_counts == b.limit_counts and a.limit_counts[0] > 0


@pytest.mark.parametrize('order', ['set', None])
def test_capped_and_collided_runs_leave_the_set_sums_valid(order):
    """Both passes cap each block's speeds (and project onto the colliders) before they sum
    it, so after a step that capped speeds on the ground the stored sums are those of the
    state (not marked stale)."""
    world, body = _world(10, order, 'one', 0.05, max_speed=1.0, ground=True)
    body.set_state(x=body.x - (0.0, 0.0, 0.11))          # the lowest layer under the ground
    world.step(H)
    assert body.limit_counts[0] > 0 and not body._dirty
    assert _fused(body) == (order == 'set')
    st = body._sets
    fresh = np.zeros_like(st.part)
    K.sets_accumulate_chunks(claim=np.zeros(1, dtype=np.int64),
                             quad=False, x=body._x, y0=st.rest_local, mass=body._m, sid=st.sid,
                             runs=st.runs, sref=st.ref, part=fresh)
    np.testing.assert_allclose(st.part, fresh, rtol=1e-10,
                               atol=1e-12 * np.abs(fresh).max())


def test_damping_of_a_set_layout_body_flying_far_out_at_huge_speed():
    """The one-loop pass takes its damping sums about where each set goes: 1e6 N on 1,000
    particles of 1e-6 kg, 20 steps of 0.1 s (2e9 m/s, 2e9 m out); the deformation then
    decays and the body keeps its size (sums about the last step's reference would lose
    the second moments to rounding)."""
    x0 = _lattice(10, 0.02)
    world = World(gravity=(0.0, 0.0, 0.0))
    body = world.add_body(x0, masses=1e-6,
                          params=BodyParams(mode='linear', alpha=0.01, beta=0.0, clusters=2,
                                            damping=0.1, material_dt=0.1, max_speed=0.0))
    assert _fused(body)
    body.set_state(x=body.x + np.random.default_rng(1).uniform(-0.004, 0.004, x0.shape))
    body.set_wrench((6e5, -6.4e5, 4.8e5))
    for _ in range(20):
        world.step(0.1)
    body.clear_wrench()
    world.step(0.1)
    start = body.shape_error_rms()
    for _ in range(200):
        world.step(0.1)
    assert np.abs(body.com()).max() > 1e9
    assert body.shape_error_rms() < 0.1 * start
    spread = np.ptp(body.x - body.com(), axis=0).max()
    assert spread < 2.0 * np.ptp(x0, axis=0).max()


@pytest.mark.parametrize('mode', ['rigid', 'linear'])
def test_one_cluster_body_landing_on_the_ground_matches_the_numpy_twin(mode):
    """The packed one-cluster pass on a body of two blocks (4,913 particles, stored layer by
    layer from the bottom) landing on a ground: the lower block, which the ground reaches,
    is projected and summed again, the upper one keeps the loop's sums; the states follow
    the NumPy reference to round-off."""
    rng = np.random.default_rng(5)
    x0 = _lattice(17)[:, ::-1] + rng.uniform(-0.004, 0.004, (17 ** 3, 3)) + (0.0, 0.0, 0.03)
    m = 0.7                                  # one mass: the one-loop pass
    params = BodyParams(mode=mode, alpha=0.5, beta=0.5)
    ground = Ground(height=0.0, friction=0.4, restitution=0.2)
    world, body, ref = on_ground(x0, m, params, rng.normal(scale=0.2, size=x0.shape), ground)
    assert body._packed_ok() and FUSED_BLOCK < body.n <= 2 * FUSED_BLOCK
    # the upper block lies above every particle of the lower one
    assert x0[FUSED_BLOCK:, 2].min() > x0[:FUSED_BLOCK, 2].min() + 0.4
    for _ in range(60):
        world.step(H)
        ref.step(H, world.gravity, ground, radius=body._collider_radius)
    assert np.abs(body.x - ref.x).max() < 1e-9
    assert np.abs(body.v - ref.v).max() < 1e-9 / H
    assert body.x[:, 2].min() == pytest.approx(body._collider_radius, abs=1e-12)   # on it
    assert body.x[FUSED_BLOCK:, 2].min() > 0.3                   # the upper block above it


def _sums_about(x, v, x0, w, k):
    """NumPy: the 12 shape sums (sum w d, sum w d x0^T, d = x - k) and the damping sums
    (sum w v, sum w d x v, sum w d d^T as xx, yy, zz, xy, yz, zx)."""
    d = x - k
    wd = w[:, None] * d
    shape = np.concatenate([wd.sum(axis=0), (wd.T @ x0).reshape(-1)])
    damp = np.concatenate([w @ v, (w[:, None] * np.cross(d, v)).sum(axis=0),
                           (wd * d).sum(axis=0), (wd * np.roll(d, -1, axis=1)).sum(axis=0)])
    return shape, damp


def test_damping_sums_of_one_mass_match_numpy():
    """``fused.damp_sums_uniform`` (a moved block's damping sums, every particle of one
    mass) against NumPy on a sub-range of F-ordered state: sum w v, sum w d x v, the six
    second moments, W; the particles outside the range count for nothing."""
    from sm_ros.core.kernels.fused import damp_sums_uniform
    rng = np.random.default_rng(12)
    n, lo, hi, wuni = 500, 37, 461, 0.7
    x = np.asfortranarray(rng.uniform(-0.5, 0.5, (n, 3)) + (2.0, -1.0, 0.3))
    v = np.asfortranarray(rng.normal(scale=2.0, size=(n, 3)))
    k = np.array([2.1, -0.9, 0.2])
    got = np.array(damp_sums_uniform(lo, hi, x, v, wuni, k[0], k[1], k[2]))
    _, want = _sums_about(x[lo:hi], v[lo:hi], np.zeros((hi - lo, 3)), np.full(hi - lo, wuni), k)
    np.testing.assert_allclose(got[:12], want, rtol=1e-12, atol=1e-12 * np.abs(want).max())
    assert got[12] == pytest.approx(wuni * (hi - lo), rel=1e-15)


@pytest.mark.parametrize('damp', [False, True])
def test_ground_projection_corrects_the_sums_it_changes(damp):
    """``colliders.ground_range_sums`` projects the particles below the ground as
    ``ground_range`` does and returns what that changed in the sums the one-loop pass took
    before it: sums before + its deltas = the sums of the projected state (NumPy), and
    nothing for the damping sums without ``damp``."""
    from sm_ros.core.kernels.colliders import Colliders, ground_range, ground_range_sums
    rng = np.random.default_rng(11)
    n = 300
    x = np.asfortranarray(rng.uniform(-0.5, 0.5, (n, 3)) + (3.0, -2.0, 0.4))
    v = np.asfortranarray(rng.normal(scale=1.5, size=(n, 3)))
    x0 = np.asfortranarray(rng.uniform(-0.5, 0.5, (n, 3)))
    w = np.full(n, 1.5)
    ground = np.array([1.0, 0.35, 0.4, 0.3])             # on, height, friction, restitution
    k = np.array([3.1, -1.9, 0.5])
    col = Colliders(True, ground, np.zeros((0, 8)), np.zeros((0, 6)), 1e-3, 0.02, 0.0)
    below = x[:, 2] < ground[1] + 0.02                  # the particles' spheres of 2 cm
    assert 20 < below.sum() < n - 20
    shape0, damp0 = _sums_about(x, v, x0, w, k)
    xr, vr = np.asfortranarray(x.copy()), np.asfortranarray(v.copy())
    ground_range(0, n, xr, vr, col)
    g = np.array(ground_range_sums(0, n, x, v, x0, 1.5, col, (k[0], k[1], k[2]), damp))
    assert np.array_equal(x, xr) and np.array_equal(v, vr)   # the same projection
    shape1, damp1 = _sums_about(x, v, x0, w, k)
    want = shape1 - shape0
    assert np.all(want[[0, 1, 3, 4, 5, 6, 7, 8]] == 0.0)      # x, y and their rows unchanged
    np.testing.assert_allclose(g[:4], want[[2, 9, 10, 11]], rtol=1e-12, atol=1e-12)
    if damp:
        assert np.all((damp1 - damp0)[[6, 7, 9]] == 0.0)     # d_x^2, d_y^2, d_x d_y
        assert np.all(g[4:][[6, 7, 9]] == 0.0)
        # the deltas in damp_sums_range's order, the rows they are added to
        np.testing.assert_allclose(g[4:], damp1 - damp0, rtol=1e-11, atol=1e-11)
        assert np.abs(g[4:][[0, 1, 2, 3, 4, 5, 8, 10, 11]]).min() > 0.0
    else:
        assert np.all(g[4:] == 0.0)



@pytest.mark.parametrize('layout', ['packed', 'sets'])
def test_sums_stay_those_of_the_state_on_the_ground(layout):
    """A damped body landing on the ground, no speed capped: the one-loop passes take the
    shape and damping sums in their loop and correct them for what the ground's
    projection moved (``ground_range_sums``), so after every step the stored sums equal
    the sums of the state taken afresh (one-cluster pack: two blocks, the lower one on the
    ground; set layout: the runs of the lower sets)."""
    from sm_ros.core.kernels.damping import damp_acc_range
    from sm_ros.core.kernels.packed_pass import one_cluster_sums
    rng = np.random.default_rng(6)
    side = 17 if layout == 'packed' else 10
    x0 = _lattice(side)[:, ::-1] + rng.uniform(-0.004, 0.004, (side ** 3, 3)) + (0, 0, 0.02)
    m = 1.3                                  # one mass: the one-loop passes
    world = World(gravity=(0.0, 0.0, -9.81))
    world.set_colliders(ground=Ground(height=0.0, friction=0.4, restitution=0.2))
    params = BodyParams(mode='linear', alpha=0.5, beta=0.5, damping=0.05,
                        clusters=1 if layout == 'packed' else 2)
    body = world.add_body(x0, m, params)
    body.set_state(v=rng.normal(scale=0.3, size=x0.shape) + (0.0, 0.0, -0.5))
    assert body._packed_ok() == (layout == 'packed')
    assert layout == 'packed' or _fused(body)
    projected = 0
    for _ in range(12):
        world.step(H)
        assert body.limit_counts[0] == 0
        on = int((body.x[:, 2] == body._collider_radius).sum())
        projected += on
        if layout == 'packed':
            shape = np.zeros((1, 12))
            one_cluster_sums(start=0, end=body.n, x=body._x, x0=body._x0, mass=body._m,
                             rest_lin=body._rest_lin, rest_off=body._rest_off, ref=body._ref,
                             sums=shape)
            stored = body._part[0]
            sid = np.zeros(0, dtype=np.int32)
        else:
            st = body._sets
            shape = np.zeros_like(st.part)
            K.sets_accumulate_chunks(claim=np.zeros(1, dtype=np.int64),
                                     quad=False, x=body._x, y0=st.rest_local, mass=body._m,
                                     sid=st.sid, runs=st.runs, sref=st.ref, part=shape)
            stored, sid = st.part, st.sid
        np.testing.assert_allclose(stored, shape, rtol=1e-10, atol=1e-12 * np.abs(shape).max())
        # the damping rows, chunk by chunk (a chunk's rows sum its particles about its points)
        nch = body._dpart.shape[0]
        for c in range(nch):
            lo, hi = c * body.n // nch, (c + 1) * body.n // nch
            dstored = body._dpart[c]
            fresh = np.zeros_like(dstored)
            fresh[:, 15:19] = dstored[:, 15:19]           # about the same points
            damp_acc_range(lo, hi, body._x, body._v, body._m, sid, fresh)
            np.testing.assert_allclose(dstored, fresh, rtol=1e-10,
                                       atol=1e-12 * np.abs(fresh).max())
    assert projected > 100                                # the ground moved particles
