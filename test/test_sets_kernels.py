"""The set layout's per-cluster kernels and the warm-started eigen-solves against NumPy.

``sets_reduce`` re-expands each set's sums about its clusters' rest centres and maps them
to the features once per cluster; ``sets_maps`` builds the quadratic goal polynomials once
per cluster and re-expands them per set; ``jacobi3_warm`` / ``nearest_unit_det_warm``
start from the last step's eigenvectors; ``_jacobi_angle`` takes a series for small
rotations.  Each is compared with a plain NumPy twin (``sm_ros.core.reference``) to
round-off, on bodies with several clusters a particle.
"""

import numpy as np
import pytest
from numba.typed import List

from sm_ros.core import BodyParams, Ground, World
from sm_ros.core import kernels as K
from sm_ros.core import reference
from sm_ros.core.kernels.linalg import _jacobi_angle

H = 1.0 / 120.0


def _body(monkeypatch, mode, clusters, seed=2):
    rng = np.random.default_rng(seed)
    g = np.stack(np.meshgrid(*[np.arange(6)] * 3, indexing='ij'), axis=-1).reshape(-1, 3)
    x0 = g * 0.04 + rng.uniform(-0.008, 0.008, g.shape) + (0.3, -0.2, 0.5)
    world = World(gravity=(0.0, 0.0, -9.81))
    world.set_colliders(ground=Ground(friction=0.5))
    body = world.add_body(x0, rng.uniform(0.5, 2.0, len(x0)),
                          BodyParams(mode=mode, alpha=0.7, beta=0.4, clusters=clusters,
                                     damping=0.1))
    assert body._sets is not None and body.num_clusters > 1
    body.set_state(v=rng.normal(scale=0.5, size=x0.shape))
    for _ in range(5):                     # deformed, rotated, moving: sums far from rest
        world.step(H)
    return body


@pytest.mark.parametrize('mode', ['linear', 'quadratic'])
def test_sets_reduce_matches_the_per_particle_sums(monkeypatch, mode):
    """The per-cluster accumulators from the per-set sums equal the sums over the
    particles of w (x - ref_k) and w (x - ref_k) q^T (q~ in the quadratic mode)."""
    body = _body(monkeypatch, mode, 2)
    st, quad = body._sets, body._quad
    x = body._x
    K.sets_accumulate_chunks(claim=np.zeros(1, dtype=np.int64),
                             quad=quad, x=x, y0=st.rest_local, mass=body._m, sid=st.sid,
                             runs=st.runs, sref=st.ref, part=st.part)
    ref = body._ref + np.array([0.01, -0.02, 0.015])      # any reference point
    out = np.zeros_like(body._part)
    pairs = K.SetClusters(st.ptr, st.cluster_ids, st.cnt, st.phi, st.pair_offsets, st.org)
    K.sets_reduce(st.part, pairs, st.ref, body._rest_lin, ref, quad, out, (st.work, st.quad_map))
    twin = reference.cluster_sums(np.asarray(x), np.asarray(body._x0), body._m, body._ptr,
                                  body._cluster_ids, body._rest_lin, body._rest_off, ref, quad)
    scale = np.abs(twin).max(axis=0)
    assert np.abs(out[0] - twin).max() <= 1e-12 * scale.max()
    np.testing.assert_allclose(out[0], twin, rtol=1e-9, atol=1e-13 * scale.max())


@pytest.mark.parametrize('mode', ['linear', 'quadratic'])
def test_sets_maps_give_the_mean_of_the_clusters_goals(monkeypatch, mode):
    """Each set's goal polynomial, at each of its particles' rest offsets, equals the mean
    over the particle's clusters of their goals (Eq. 23)."""
    body = _body(monkeypatch, mode, 3)
    st, quad = body._sets, body._quad
    sref = np.zeros_like(st.ref)
    gm = np.zeros_like(st.goal_maps)
    pairs = K.SetClusters(st.ptr, st.cluster_ids, st.cnt, st.phi, st.pair_offsets, st.org)
    K.sets_maps(pairs, body._rest_lin, (body._trans, body._goal_lin, body._goal_off), body._ref,
                quad, (gm, sref), (st.quad_map, st.cluster_maps))
    y = np.asarray(st.rest_local)
    phi = np.stack([np.ones(len(y)), y[:, 0], y[:, 1], y[:, 2], y[:, 0] ** 2, y[:, 1] ** 2,
                    y[:, 2] ** 2, y[:, 0] * y[:, 1], y[:, 1] * y[:, 2], y[:, 2] * y[:, 0]], 1)
    got = np.einsum('iaf,if->ia', gm[st.sid], phi[:, :gm.shape[2]])   # 4 or 10 terms
    twin = reference.set_goals(np.asarray(body._x0), body._ptr, body._cluster_ids, body._rest_lin,
                               body._rest_off, body._trans, body._goal_lin, body._goal_off,
                               quad)
    assert np.abs(got - twin).max() < 1e-13
    # the sets' reference points: the mean of their clusters' centres
    for s in range(len(st.cnt)):
        ks = st.cluster_ids[st.ptr[s]:st.ptr[s + 1]]
        np.testing.assert_allclose(sref[s], body._ref[ks].mean(axis=0), rtol=0, atol=1e-15)


def test_small_rotation_series_equals_the_closed_form():
    """``_jacobi_angle``'s series branch (|a_pq| <= 1e-4 |a_qq - a_pp|) against the closed
    form in extended precision, and the closed-form branch just above the threshold."""
    rng = np.random.default_rng(0)
    for _ in range(300):
        app, aqq = rng.uniform(-2, 2, 2)
        gap = aqq - app
        r = rng.choice([-1.0, 1.0]) * 10.0 ** rng.uniform(-14, -4)
        apq = r * gap
        a, b, c, s = _jacobi_angle(app, aqq, apq)
        theta = np.longdouble(gap) / (2 * np.longdouble(apq))
        t = np.sign(theta) / (abs(theta) + np.sqrt(theta * theta + 1))
        cl = 1 / np.sqrt(t * t + 1)
        assert abs(c - cl) <= 2.3e-16 and abs(s - t * cl) <= 4.5e-16 * abs(t * cl)   # 2 ulp
        assert abs(a - (app - t * apq)) <= 4e-16 * (abs(app) + abs(apq))
        assert abs(b - (aqq + t * apq)) <= 4e-16 * (abs(aqq) + abs(apq))


def _check_eigen(mat, vals, vecs):
    np.testing.assert_allclose(vecs.T @ vecs, np.eye(3), atol=1e-14)
    np.testing.assert_allclose(vecs @ np.diag(vals) @ vecs.T, mat,
                               atol=1e-14 * np.abs(mat).max())
    np.testing.assert_allclose(np.sort(vals), np.linalg.eigvalsh(mat),
                               atol=1e-14 * np.abs(mat).max())


def test_warm_jacobi_matches_numpy_and_keeps_its_start_orthonormal():
    """From the eigenvectors of a nearby matrix, from a start with rounding drift, from the
    identity and from garbage (reset to the identity): eigenvalues and vectors of the
    matrix itself, and the start left orthonormal for the next call."""
    rng = np.random.default_rng(5)
    for trial in range(50):
        a = rng.normal(size=(3, 3))
        mat = a.T @ a + 0.1 * np.eye(3)
        near = mat + 1e-4 * (lambda e: e + e.T)(rng.normal(size=(3, 3)))
        warm = np.linalg.eigh(near)[1].copy()
        if trial % 4 == 1:
            warm *= 1.0 + 1e-9                 # drifted from orthonormality
        elif trial % 4 == 2:
            warm = np.full((3, 3), np.nan)     # never set / a non-finite state went through
        elif trial % 4 == 3:
            warm = np.eye(3)
        w, vecs, work = mat.copy(), np.zeros((3, 3)), np.zeros((3, 3))
        K.jacobi3_warm(w, vecs, warm, work)
        _check_eigen(mat, np.diag(w), vecs)
        np.testing.assert_array_equal(warm, vecs)
        cold, cvecs = mat.copy(), np.zeros((3, 3))
        K.jacobi3(cold, cvecs, 50)
        np.testing.assert_allclose(np.sort(np.diag(w)), np.sort(np.diag(cold)),
                                   rtol=1e-14)


def test_warm_nearest_unit_det_matches_the_reference_over_a_trajectory():
    """The unit-determinant match warm-started from its own last eigenvectors, over a
    slowly deforming sequence, equals the NumPy twin (and the cold kernel) to round-off."""
    rng = np.random.default_rng(9)
    vw = np.eye(3)
    f = np.eye(3) + 0.2 * rng.normal(size=(3, 3))
    if np.linalg.det(f) < 0:
        f[:, 0] *= -1
    drift = 0.01 * rng.normal(size=(3, 3))
    for step in range(40):
        f = f + drift * np.sin(0.3 * step)
        out, wa, wv = np.zeros((3, 3)), np.zeros((3, 3)), np.zeros((3, 3))
        assert K.nearest_unit_det_warm(f, out, wa, wv, vw, True)
        twin = reference.nearest_unit_det(f)
        np.testing.assert_allclose(out, twin, atol=1e-13)
        cold = np.zeros((3, 3))
        assert K.nearest_unit_det(f, cold, np.zeros((3, 3)), np.zeros((3, 3)))
        np.testing.assert_allclose(out, cold, atol=1e-14)
        assert abs(np.linalg.det(out) - 1.0) < 1e-13
    # a matrix of non-positive determinant is refused warm as cold, and vw is not touched
    keep = vw.copy()
    assert not K.nearest_unit_det_warm(np.diag([1.0, 1.0, -1.0]), np.zeros((3, 3)),
                                       np.zeros((3, 3)), np.zeros((3, 3)), vw, True)
    np.testing.assert_array_equal(vw, keep)


def test_records_share_the_body_buffers_and_either_path_steps_alike(monkeypatch):
    """A body's compiled-step records hold its own buffers (readers see what the step
    writes; a second record shares them); stepping by ``World.step`` and by
    ``Body._step`` in turn equals ``World.step`` alone."""
    from sm_ros.core import body_build

    def make():
        return _body(monkeypatch, 'linear', 2, seed=4)

    a, b = make(), make()
    rec = a._fast_record(H)
    held = [a._quat, a._ref, a._sets.goal_maps, a._sets.part]
    assert all(any(r is arr for r in rec) or any(
        isinstance(r, np.ndarray) and np.shares_memory(r, arr) for r in rec) for arr in held)
    again = a._fast_record(H)

    def leaves(record):                      # the arrays, those of nested tuples too
        for item in record:
            yield from (leaves(item) if isinstance(item, tuple) else (item,))
    for r0, r1 in zip(leaves(rec), leaves(again)):
        if r1 is a._fstate:                  # per record (parameters at this h)
            continue
        assert r0 is r1 or r0.size == 0 or (np.shares_memory(r0, r1) and r0.shape == r1.shape)
    # the same trajectory whichever path steps the body (the records share the buffers)
    gravity, ground = np.array([0.0, 0.0, -9.81]), np.array([1.0, 0.0, 0.5, 0.0])
    none8, none6 = np.zeros((0, 8)), np.zeros((0, 6))
    a._build()
    b._build()
    for body in (a, b):
        body.set_state(x=b.x, v=np.full((body.n, 3), 0.2))
    for step in range(12):
        K.step_single_bodies(body_build.one_record(b, H), H, gravity, True, ground, none8,
                             none6, 1e-3)
        if step % 2:
            a._step(H, gravity, True, ground, none8, none6, 1e-3)
        else:
            K.step_single_bodies(List([a._fast_record(H)]), H, gravity, True, ground, none8,
                                 none6, 1e-3)
    np.testing.assert_array_equal(a.x, b.x)
    np.testing.assert_array_equal(a.v, b.v)
