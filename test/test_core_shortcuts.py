"""Shortcuts of the bodies' step kernels against the computation they stand in for.

Each shortcut skips work only where it provably gives the answer of the full
computation: the collider bounds test (``_range_reach``), the adjugate solve of a
well-posed inertia (``sym3_solve``), the norm bounds of the stretch test (``_stretch_ok``)
and the Newton top eigenvector of Horn's matrix (``extract_rotation``).
"""

import numpy as np
import pytest

from sm_ros.core import kernels as K
from sm_ros.core.kernels.colliders import _range_reach
from sm_ros.core.kernels.linalg import sym3_solve

RNG = np.random.default_rng


def _collide_each(x, v, col):
    """``collide_point`` on every particle (what ``_collide_range`` must give)."""
    x, v = x.copy(), v.copy()
    for i in range(len(x)):
        out = K.collide_point(*x[i], *v[i], col)
        x[i], v[i] = out[:3], out[3:]
    return x, v


def _scene(rng, nbox, nsph):
    boxes = np.zeros((nbox, 8))
    lo = rng.uniform(-1.0, 1.0, (nbox, 3))
    boxes[:, :3] = lo
    boxes[:, 3:6] = lo + rng.uniform(0.05, 0.6, (nbox, 3))
    boxes[:, 6:] = rng.uniform(0.0, 1.0, (nbox, 2))
    spheres = np.zeros((nsph, 6))
    spheres[:, :3] = rng.uniform(-1.0, 1.0, (nsph, 3))
    spheres[:, 3] = rng.uniform(0.05, 0.4, nsph)
    spheres[:, 4:] = rng.uniform(0.0, 1.0, (nsph, 2))
    ground = np.array([1.0, rng.uniform(-1.0, 0.0), 0.5, 0.3])
    return ground, boxes, spheres


@pytest.mark.parametrize('nbox,nsph', [(0, 0), (4, 0), (0, 3), (5, 4)])
def test_collide_range_equals_collide_point_on_every_particle(nbox, nsph):
    """Blobs of particles near, far from, below and inside colliders (and one nan
    particle): the culled range pass gives exactly the per-particle results."""
    rng = RNG(nbox * 10 + nsph)
    seen = set()
    for trial in range(60):
        ground, boxes, spheres = _scene(rng, nbox, nsph)
        centre = rng.uniform(-1.5, 1.5, 3)
        x = centre + rng.normal(scale=rng.choice([0.02, 0.2, 0.6]), size=(50, 3))
        v = rng.normal(size=(50, 3))
        if trial % 7 == 0:
            x[3] = np.nan
        if trial % 5 == 0:
            ground[0] = 0.0
        radius = rng.choice([0.0, 0.03])      # particles as points and as spheres
        step = rng.choice([0.0, 0.05])        # not swept, and swept over a step of 50 ms
        col = K.Colliders(True, ground, boxes, spheres, 0.05, radius, step)
        reach = _range_reach(0, len(x), x, v, col)
        seen.add(reach)
        want_x, want_v = _collide_each(x, v, col)
        got_x, got_v = x.copy(), v.copy()
        K._collide_range(0, len(x), got_x, got_v, col)
        np.testing.assert_array_equal(got_x, want_x)
        np.testing.assert_array_equal(got_v, want_v)
    # the trials took every path: skipped, ground only, full
    assert (False, False) in seen and (True, False) in seen
    if nbox or nsph:
        assert any(r[1] for r in seen)


@pytest.mark.parametrize('end', [0.485, 0.472, 0.40])
def test_a_step_past_a_thin_plate_leaves_it_by_the_face_it_entered(end):
    """A 2 cm plate (a plain box, top at 0.5 m) and a particle of radius 1 cm that the
    step carried down from 0.6 m: ending just below the plate's middle, near its bottom
    or past it altogether, it goes back onto the top face (0.51 m) with its downward
    speed gone, in the compiled pass and in the NumPy reference alike; without the step
    (h = 0) a particle inside leaves by the nearest face, one outside is left alone."""
    from sm_ros.core.reference import collide
    from sm_ros.core import Box
    plate = Box(lo=(-0.5, -0.5, 0.48), hi=(0.5, 0.5, 0.5), friction=0.5, restitution=0.0)
    boxes = np.array([plate.row()], dtype=float)
    h, p = 1.0 / 120.0, np.array([0.1, 0.0, end])
    v = (p - [0.1, 0.0, 0.6]) / h
    for step, want in ((h, 0.51), (0.0, 0.47 if end > 0.47 else end)):
        col = K.Colliders(True, np.zeros(4), boxes, np.zeros((0, 6)), 0.05, 0.01, step)
        x_out = K.collide_point(*p, *v, col)
        ref_x, ref_v = collide(p, v, None, [plate], [], 0.05, 0.01, step)
        np.testing.assert_allclose(x_out[:3], ref_x, atol=1e-15)
        np.testing.assert_allclose(x_out[3:], ref_v, atol=1e-12)
        assert x_out[2] == pytest.approx(want)
        if step:
            assert x_out[5] == pytest.approx(0.0)


@pytest.mark.parametrize('end', [-0.005, -0.03])
def test_a_step_past_a_small_sphere_leaves_it_on_the_side_it_came_from(end):
    """A 5 mm static sphere and a particle of radius 1 cm that the step carried down from
    3 cm above its centre to just below it or past it: it goes back onto the tangent plane
    above (1.5 cm) with its downward speed gone, compiled and NumPy reference alike."""
    from sm_ros.core.reference import collide
    from sm_ros.core import Sphere
    ball = Sphere(center=(0.0, 0.0, 0.0), radius=0.005, friction=0.5, restitution=0.0)
    spheres = np.array([ball.row()], dtype=float)
    h, p = 1.0 / 120.0, np.array([0.002, 0.0, end])
    v = (p - [0.002, 0.0, 0.03]) / h
    col = K.Colliders(True, np.zeros(4), np.zeros((0, 8)), spheres, 0.05, 0.01, h)
    x_out = K.collide_point(*p, *v, col)
    ref_x, ref_v = collide(p, v, None, [], [ball], 0.05, 0.01, h)
    np.testing.assert_allclose(x_out[:3], ref_x, atol=1e-15)
    np.testing.assert_allclose(x_out[3:], ref_v, atol=1e-12)
    assert x_out[2] > 0.0 and x_out[5] == pytest.approx(0.0, abs=1e-9)


def test_collide_range_culls_a_body_in_the_air():
    ground = np.array([1.0, 0.0, 0.5, 0.0])
    boxes = np.array([[-1.35, -1.35, 0.0, -1.25, 1.35, 1.5, 0.6, 0.0]])
    col = K.Colliders(True, ground, boxes, np.zeros((0, 6)), 0.05, 0.02, 0.0)
    x, v = np.array([[0.0, 0.0, 0.5], [0.1, 0.0, 0.6]]), np.zeros((2, 3))
    assert _range_reach(0, 2, x, v, col) == (False, False)
    x[0, 2] = 0.015                         # within its radius of the ground: the ground only
    assert _range_reach(0, 2, x, v, col) == (True, False)
    x[1, 0] = -1.24                         # within its radius of the wall
    assert _range_reach(0, 2, x, v, col) == (True, True)


def test_sym3_solve_equals_the_pseudo_inverse():
    """Well-posed, ill-posed, rank-deficient, indefinite-by-rounding and nan matrices."""
    rng = RNG(7)
    scratch = [np.zeros((3, 3)) for _ in range(3)]
    for trial in range(400):
        q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        lam = np.exp(rng.uniform(-3.0, 1.0, 3))
        kind = trial % 5
        if kind == 1:
            lam[0] *= 1e-8                  # ill-posed: pseudo-inverse path
        elif kind == 2:
            lam[0] = 0.0                    # flat
        elif kind == 3:
            lam[:2] = 0.0                   # line-like
        elif kind == 4:
            lam[0] = -1e-14 * lam.max()     # indefinite by rounding
        m = (q * lam) @ q.T
        m = 0.5 * (m + m.T)
        b = rng.normal(size=3)
        got = np.array(sym3_solve(m, b[0], b[1], b[2], 1e-12, *scratch))
        pinv = np.zeros((3, 3))
        K.pinv_sym(m, pinv, np.zeros((3, 3)), np.zeros((3, 3)), 1e-12)
        want = pinv @ b
        scale = np.abs(pinv).max() * np.abs(b).max()
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-9 * scale)
    m = np.eye(3)
    m[1, 1] = np.nan
    got = sym3_solve(m, 1.0, 1.0, 1.0, 1e-12, *scratch)     # nan: as the pseudo-inverse
    pinv = np.zeros((3, 3))
    K.pinv_sym(m, pinv, np.zeros((3, 3)), np.zeros((3, 3)), 1e-12)
    np.testing.assert_array_equal(np.array(got), pinv @ np.ones(3))


def _stretch_eig(w, limit):
    s = np.linalg.svd(w, compute_uv=False)
    return bool(s.min() >= 1.0 / limit and s.max() <= limit)


def test_stretch_ok_decides_as_the_singular_values():
    rng = RNG(11)
    work, wa, wv = np.zeros((3, 3)), np.zeros((3, 3)), np.zeros((3, 3))
    answers = set()
    for trial in range(600):
        rot = np.linalg.qr(rng.normal(size=(3, 3)))[0]
        if np.linalg.det(rot) < 0:
            rot[:, 0] *= -1.0
        b = rot @ (np.eye(3) + rng.normal(scale=rng.choice([0.05, 0.3, 1.0]), size=(3, 3)))
        t = rng.uniform(0.0, 1.0) if trial % 2 else 1.0
        w = rot + t * (b - rot)
        s = np.linalg.svd(w, compute_uv=False)
        if np.min(np.abs(np.log(s) - np.log([[0.5], [2.0]]))) < 1e-9:
            continue                        # on the boundary: rounding decides
        got = K._stretch_ok(b, rot, t, work, wa, wv, 2.0)
        assert got == _stretch_eig(w, 2.0)
        answers.add(got)
    assert answers == {True, False}


def _horn(a, q0):
    """Horn's matrix of ``a`` relative to the rotation q0, as ``extract_rotation`` builds it."""
    r0 = np.zeros((3, 3))
    K.quat_to_mat(q0, r0)
    b = r0.T @ a
    s = b.T
    return np.array([
        [s[0, 0] + s[1, 1] + s[2, 2], s[1, 2] - s[2, 1], s[2, 0] - s[0, 2], s[0, 1] - s[1, 0]],
        [s[1, 2] - s[2, 1], s[0, 0] - s[1, 1] - s[2, 2], s[0, 1] + s[1, 0], s[2, 0] + s[0, 2]],
        [s[2, 0] - s[0, 2], s[0, 1] + s[1, 0], -s[0, 0] + s[1, 1] - s[2, 2], s[1, 2] + s[2, 1]],
        [s[0, 1] - s[1, 0], s[2, 0] + s[0, 2], s[1, 2] + s[2, 1], -s[0, 0] - s[1, 1] + s[2, 2]]])


def test_newton_top_eigenvector_equals_jacobi():
    """Warm starts near and far from the answer, well and badly conditioned matches, flat
    and line-like ones: where the Newton path accepts, it returns Jacobi's eigenvector;
    it accepts the usual case (a warm start within a few degrees)."""
    from sm_ros.core.kernels.rotation import _top_jacobi, _top_newton
    rng = RNG(13)
    accepted = near = 0
    for trial in range(800):
        kind = trial % 4
        a = np.linalg.qr(rng.normal(size=(3, 3)))[0] @ np.diag(rng.uniform(0.2, 2.0, 3))
        if kind == 2:
            a[:, 2] = 0.0                          # flat cluster
        elif kind == 3:
            a = np.outer(rng.normal(size=3), rng.normal(size=3))    # line-like
        r_best = np.zeros((3, 3))
        q_best = np.array([1.0, 0.0, 0.0, 0.0])
        K.extract_rotation(a.copy(), q_best, r_best, np.zeros((4, 4)), np.zeros((4, 4)))
        # a warm start a small or a large rotation away from the answer
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        ang = rng.choice([1e-4, 0.05, 0.5, 2.5])
        dq = np.concatenate([[np.cos(ang / 2)], np.sin(ang / 2) * axis])
        w0, x0, y0, z0 = q_best
        w1, x1, y1, z1 = dq
        q0 = np.array([w0 * w1 - x0 * x1 - y0 * y1 - z0 * z1,
                       w0 * x1 + x0 * w1 + y0 * z1 - z0 * y1,
                       w0 * y1 - x0 * z1 + y0 * w1 + z0 * x1,
                       w0 * z1 + x0 * y1 - y0 * x1 + z0 * w1])
        n4 = _horn(a, q0)
        scale = np.abs(n4).max()
        ok, *u = _top_newton(n4.copy(), scale)
        want = np.array(_top_jacobi(n4.copy(), np.zeros((4, 4)), scale))
        if ok:
            accepted += 1
            np.testing.assert_allclose(np.array(u), want, rtol=0, atol=1e-9)
            lam = np.linalg.eigvalsh(n4)
            assert lam[-1] - lam[-2] > 1e-6 * scale        # the isolation it relies on
        if kind < 2 and ang < 0.1:
            near += 1
            assert ok
    assert 0 < accepted < 800 and near > 100


def test_jacobi3_equals_the_general_jacobi():
    """The register 3x3 Jacobi: eigen-pairs of random, repeated-eigenvalue and diagonal
    matrices, as ``jacobi_eigh`` and NumPy give them."""
    from sm_ros.core.kernels.linalg import jacobi3
    rng = RNG(17)
    for trial in range(300):
        q = np.linalg.qr(rng.normal(size=(3, 3)))[0]
        lam = rng.normal(size=3)
        if trial % 3 == 1:
            lam[1] = lam[0]                         # a repeated eigenvalue
        elif trial % 3 == 2:
            q = np.eye(3)                           # already diagonal
        a = (q * lam) @ q.T
        a = 0.5 * (a + a.T)
        wa, wv = a.copy(), np.zeros((3, 3))
        jacobi3(wa, wv, 50)
        got = np.diag(wa)
        np.testing.assert_allclose(np.sort(got), np.linalg.eigvalsh(a), rtol=0, atol=1e-13)
        np.testing.assert_allclose(wv @ np.diag(got) @ wv.T, a, rtol=0, atol=1e-13)
        np.testing.assert_allclose(wv.T @ wv, np.eye(3), rtol=0, atol=1e-13)
        ga, gv = a.copy(), np.zeros((3, 3))
        K.jacobi_eigh(ga, gv, 50)
        np.testing.assert_allclose(np.sort(got), np.sort(np.diag(ga)), rtol=0, atol=1e-13)
