"""Small dense linear algebra written by hand (3x3, 4x4, 9x9): no equation of its own.

Supports Eq. 10-11 (the pseudo-inverses A_qq, A~_qq of Eq. 10 and 21, the eigenvectors of
Horn's matrix for Eq. 11) and the 2-norms of Eq. 24-27.  ``numpy.linalg`` inside Numba
needs SciPy's LAPACK and is slow for tiny matrices ("Practical requirements" of the
write-up), so these routines are used instead; each writes into caller-provided buffers.
"""

import numpy as np
from numba import njit

from .jit import FLOAT_MAX, JIT, JIT_NO_REFCOUNT


@njit(**JIT_NO_REFCOUNT)
def jacobi_eigh(mat, vecs, max_sweeps=50):
    """Diagonalise the symmetric matrix ``a`` in place by cyclic Jacobi rotations.

    On return the diagonal of ``a`` holds the eigenvalues and the columns of ``v`` the
    eigenvectors (``a_in = v diag(a) v^T``).  Works for any small n (used with 3, 4, 9).
    """
    n = mat.shape[0]
    for i in range(n):
        for j in range(n):
            vecs[i, j] = 1.0 if i == j else 0.0
    for _ in range(max_sweeps):
        off = 0.0
        diag = 0.0
        for i in range(n):
            diag += mat[i, i] * mat[i, i]
            for j in range(i + 1, n):
                off += mat[i, j] * mat[i, j]
        if off <= 1e-32 * diag or off == 0.0:
            break
        for p in range(n - 1):
            for q in range(p + 1, n):
                apq = mat[p, q]
                if apq == 0.0:
                    continue
                theta = (mat[q, q] - mat[p, p]) / (2.0 * apq)
                if theta >= 0.0:
                    t = 1.0 / (theta + np.sqrt(theta * theta + 1.0))
                else:
                    t = -1.0 / (-theta + np.sqrt(theta * theta + 1.0))
                c = 1.0 / np.sqrt(t * t + 1.0)
                s = t * c
                for k in range(n):
                    akp = mat[k, p]
                    akq = mat[k, q]
                    mat[k, p] = c * akp - s * akq
                    mat[k, q] = s * akp + c * akq
                for k in range(n):
                    apk = mat[p, k]
                    aqk = mat[q, k]
                    mat[p, k] = c * apk - s * aqk
                    mat[q, k] = s * apk + c * aqk
                for k in range(n):
                    vkp = vecs[k, p]
                    vkq = vecs[k, q]
                    vecs[k, p] = c * vkp - s * vkq
                    vecs[k, q] = s * vkp + c * vkq


#: ``_jacobi_angle`` takes its series for rotations with |a_pq| below this fraction of
#: |a_qq - a_pp| (|r| <= 1e-4: the terms left out are below 6 r^6 <= 6e-24, relative).
SMALL_ANGLE = 1e-4


@njit(inline='always', **JIT)
def _jacobi_angle(app, aqq, apq):
    """One Jacobi rotation zeroing a_pq: (new a_pp, new a_qq, c, s), as ``jacobi_eigh``.

    t = tan(phi) solves t^2 + 2 theta t - 1 = 0 (theta = (a_qq - a_pp) / (2 a_pq)), the
    root of smaller magnitude.  A small rotation (r = a_pq / (a_qq - a_pp), |r| <=
    ``SMALL_ANGLE``: the last sweep of a decomposition, every sweep of a warm-started one,
    ``jacobi3_warm``) takes the series t = r (1 - r^2 + 2 r^4), c = 1 - t^2 / 2 + 3 t^4 / 8,
    equal to the closed form to far below rounding (the first terms left out are 5 r^7
    and t^6 / 3): one division instead of three and two square roots, in a chain.
    """
    gap = aqq - app
    if abs(apq) <= SMALL_ANGLE * abs(gap):
        r = apq / gap
        r2 = r * r
        t = r * (1.0 - r2 * (1.0 - 2.0 * r2))
        t2 = t * t
        c = 1.0 - t2 * (0.5 - 0.375 * t2)
        return app - t * apq, aqq + t * apq, c, t * c
    theta = gap / (2.0 * apq)
    if theta >= 0.0:
        t = 1.0 / (theta + np.sqrt(theta * theta + 1.0))
    else:
        t = -1.0 / (-theta + np.sqrt(theta * theta + 1.0))
    c = 1.0 / np.sqrt(t * t + 1.0)
    return app - t * apq, aqq + t * apq, c, t * c


@njit(inline='always', **JIT)
def _rotate_columns(vecs, p, q, c, s):
    for k in range(3):
        vkp = vecs[k, p]
        vkq = vecs[k, q]
        vecs[k, p] = c * vkp - s * vkq
        vecs[k, q] = s * vkp + c * vkq


@njit(**JIT_NO_REFCOUNT)
def jacobi3(mat, vecs, max_sweeps=50):
    """``jacobi_eigh`` for a symmetric 3x3 ``mat``: the same cyclic rotations and stopping
    rule, on the six distinct entries held in registers (the rotated pair's diagonal by
    a_pp - t a_pq, a_qq + t a_pq) instead of full row and column sweeps of the array:
    less memory traffic, equal to rounding.  Diagonal of ``mat`` <- eigenvalues,
    columns of ``vecs`` <- eigenvectors."""
    a00, a11, a22 = mat[0, 0], mat[1, 1], mat[2, 2]
    a01, a02, a12 = mat[0, 1], mat[0, 2], mat[1, 2]
    for i in range(3):
        for j in range(3):
            vecs[i, j] = 1.0 if i == j else 0.0
    for _ in range(max_sweeps):
        off = a01 * a01 + a02 * a02 + a12 * a12
        diag = a00 * a00 + a11 * a11 + a22 * a22
        if off <= 1e-32 * diag or off == 0.0:
            break
        if a01 != 0.0:                          # (p, q) = (0, 1), r = 2
            a00, a11, c, s = _jacobi_angle(a00, a11, a01)
            a01 = 0.0
            a02, a12 = c * a02 - s * a12, s * a02 + c * a12
            _rotate_columns(vecs, 0, 1, c, s)
        if a02 != 0.0:                          # (0, 2), r = 1
            a00, a22, c, s = _jacobi_angle(a00, a22, a02)
            a02 = 0.0
            a01, a12 = c * a01 - s * a12, s * a01 + c * a12
            _rotate_columns(vecs, 0, 2, c, s)
        if a12 != 0.0:                          # (1, 2), r = 0
            a11, a22, c, s = _jacobi_angle(a11, a22, a12)
            a12 = 0.0
            a01, a02 = c * a01 - s * a02, s * a01 + c * a02
            _rotate_columns(vecs, 1, 2, c, s)
    mat[0, 0], mat[1, 1], mat[2, 2] = a00, a11, a22
    mat[0, 1] = mat[1, 0] = a01
    mat[0, 2] = mat[2, 0] = a02
    mat[1, 2] = mat[2, 1] = a12


@njit(**JIT_NO_REFCOUNT)
def jacobi3_warm(mat, vecs, warm, work):
    """``jacobi3`` of a symmetric 3x3 ``mat`` started from the orthonormal ``warm`` (in/out:
    the eigenvectors of a nearby matrix, such as the same cluster's last step): Jacobi on
    W^T mat W, nearly diagonal, takes one or two sweeps of small rotations (the series of
    ``_jacobi_angle``) instead of three or four from the identity.  ``vecs`` <- W V (the
    eigenvectors of ``mat``, columns; the diagonal of ``mat`` <- the eigenvalues), and
    ``warm`` <- them for the next call.  Equal to ``jacobi3`` to rounding (the same
    stopping rule, on a matrix similar to ``mat`` by an orthonormal W).

    ``warm`` is kept orthonormal: one Newton-Schulz step W (3 I - W^T W) / 2 a call (the
    products of rotations drift from orthonormality by rounding, step after step); a
    ``warm`` that is not finite or not orthonormal within 1e-6 (never set, or a
    non-finite state went through it) is replaced by the identity: a cold start.
    ``work`` (3x3 scratch) is not written: every product is on scalar locals.
    """
    # on scalar locals throughout (the same operations as through ``work``, ``warm``,
    # ``vecs`` and ``jacobi3``: every store into one of those could alias the next loads,
    # and each rotation of a sweep waited on its stores)
    w00, w01, w02, w10, w11, w12, w20, w21, w22 = _orthonormal_start(warm)
    a = _similar_upper(mat, (w00, w01, w02, w10, w11, w12, w20, w21, w22))
    a00, a01, a02, a11, a12, a22, v00, v01, v02, v10, v11, v12, v20, v21, v22 = _sweeps(a)
    mat[0, 0], mat[1, 1], mat[2, 2] = a00, a11, a22
    mat[0, 1] = mat[1, 0] = a01
    mat[0, 2] = mat[2, 0] = a02
    mat[1, 2] = mat[2, 1] = a12
    # W V: the eigenvectors of ``mat``, and the next call's warm start
    e00 = w00 * v00 + w01 * v10 + w02 * v20
    e01 = w00 * v01 + w01 * v11 + w02 * v21
    e02 = w00 * v02 + w01 * v12 + w02 * v22
    e10 = w10 * v00 + w11 * v10 + w12 * v20
    e11 = w10 * v01 + w11 * v11 + w12 * v21
    e12 = w10 * v02 + w11 * v12 + w12 * v22
    e20 = w20 * v00 + w21 * v10 + w22 * v20
    e21 = w20 * v01 + w21 * v11 + w22 * v21
    e22 = w20 * v02 + w21 * v12 + w22 * v22
    vecs[0, 0], vecs[0, 1], vecs[0, 2] = e00, e01, e02
    vecs[1, 0], vecs[1, 1], vecs[1, 2] = e10, e11, e12
    vecs[2, 0], vecs[2, 1], vecs[2, 2] = e20, e21, e22
    warm[0, 0], warm[0, 1], warm[0, 2] = e00, e01, e02
    warm[1, 0], warm[1, 1], warm[1, 2] = e10, e11, e12
    warm[2, 0], warm[2, 1], warm[2, 2] = e20, e21, e22


@njit(inline='always', **JIT)
def _orthonormal_start(warm):
    """``jacobi3_warm``'s start W from ``warm`` (9 values, row by row): one Newton-Schulz
    step W (I - (W^T W - I) / 2), or the identity when ``warm`` is not finite or not
    orthonormal within 1e-6."""
    w00, w01, w02 = warm[0, 0], warm[0, 1], warm[0, 2]
    w10, w11, w12 = warm[1, 0], warm[1, 1], warm[1, 2]
    w20, w21, w22 = warm[2, 0], warm[2, 1], warm[2, 2]
    # G = W^T W - I
    g00 = w00 * w00 + w10 * w10 + w20 * w20 - 1.0
    g01 = w00 * w01 + w10 * w11 + w20 * w21
    g02 = w00 * w02 + w10 * w12 + w20 * w22
    g10 = w01 * w00 + w11 * w10 + w21 * w20
    g11 = w01 * w01 + w11 * w11 + w21 * w21 - 1.0
    g12 = w01 * w02 + w11 * w12 + w21 * w22
    g20 = w02 * w00 + w12 * w10 + w22 * w20
    g21 = w02 * w01 + w12 * w11 + w22 * w21
    g22 = w02 * w02 + w12 * w12 + w22 * w22 - 1.0
    err = (g00 * g00 + g01 * g01 + g02 * g02 + g10 * g10 + g11 * g11 + g12 * g12
           + g20 * g20 + g21 * g21 + g22 * g22)
    if not (err < 1e-12):
        w00, w01, w02 = 1.0, 0.0, 0.0
        w10, w11, w12 = 0.0, 1.0, 0.0
        w20, w21, w22 = 0.0, 0.0, 1.0
    else:
        # W <- W (I - (W^T W - I) / 2)
        h00, h01, h02 = 1.0 - 0.5 * g00, 0.0 - 0.5 * g01, 0.0 - 0.5 * g02
        h10, h11, h12 = 0.0 - 0.5 * g10, 1.0 - 0.5 * g11, 0.0 - 0.5 * g12
        h20, h21, h22 = 0.0 - 0.5 * g20, 0.0 - 0.5 * g21, 1.0 - 0.5 * g22
        w00, w01, w02 = (w00 * h00 + w01 * h10 + w02 * h20, w00 * h01 + w01 * h11 + w02 * h21,
                         w00 * h02 + w01 * h12 + w02 * h22)
        w10, w11, w12 = (w10 * h00 + w11 * h10 + w12 * h20, w10 * h01 + w11 * h11 + w12 * h21,
                         w10 * h02 + w11 * h12 + w12 * h22)
        w20, w21, w22 = (w20 * h00 + w21 * h10 + w22 * h20, w20 * h01 + w21 * h11 + w22 * h21,
                         w20 * h02 + w21 * h12 + w22 * h22)
    return w00, w01, w02, w10, w11, w12, w20, w21, w22


@njit(inline='always', **JIT)
def _similar_upper(mat, w):
    """The upper triangle (a00 a01 a02 a11 a12 a22) of W^T mat W (``w``: W row by row)."""
    w00, w01, w02, w10, w11, w12, w20, w21, w22 = w
    m00, m01, m02 = mat[0, 0], mat[0, 1], mat[0, 2]
    m10, m11, m12 = mat[1, 0], mat[1, 1], mat[1, 2]
    m20, m21, m22 = mat[2, 0], mat[2, 1], mat[2, 2]
    k00 = m00 * w00 + m01 * w10 + m02 * w20
    k01 = m00 * w01 + m01 * w11 + m02 * w21
    k02 = m00 * w02 + m01 * w12 + m02 * w22
    k10 = m10 * w00 + m11 * w10 + m12 * w20
    k11 = m10 * w01 + m11 * w11 + m12 * w21
    k12 = m10 * w02 + m11 * w12 + m12 * w22
    k20 = m20 * w00 + m21 * w10 + m22 * w20
    k21 = m20 * w01 + m21 * w11 + m22 * w21
    k22 = m20 * w02 + m21 * w12 + m22 * w22
    a00 = w00 * k00 + w10 * k10 + w20 * k20
    a01 = w00 * k01 + w10 * k11 + w20 * k21
    a02 = w00 * k02 + w10 * k12 + w20 * k22
    a11 = w01 * k01 + w11 * k11 + w21 * k21
    a12 = w01 * k02 + w11 * k12 + w21 * k22
    a22 = w02 * k02 + w12 * k12 + w22 * k22
    return a00, a01, a02, a11, a12, a22


@njit(inline='always', **JIT)
def _sweeps(a):
    """``jacobi3``'s sweeps on the upper triangle ``a`` (a00 a01 a02 a11 a12 a22): the
    triangle after them and the eigenvectors V (9 values, row by row)."""
    a00, a01, a02, a11, a12, a22 = a
    v00, v01, v02 = 1.0, 0.0, 0.0
    v10, v11, v12 = 0.0, 1.0, 0.0
    v20, v21, v22 = 0.0, 0.0, 1.0
    for _ in range(50):
        off = a01 * a01 + a02 * a02 + a12 * a12
        diag = a00 * a00 + a11 * a11 + a22 * a22
        if off <= 1e-32 * diag or off == 0.0:
            break
        if a01 != 0.0:                          # (p, q) = (0, 1)
            a00, a11, c, sn = _jacobi_angle(a00, a11, a01)
            a01 = 0.0
            a02, a12 = c * a02 - sn * a12, sn * a02 + c * a12
            v00, v01 = c * v00 - sn * v01, sn * v00 + c * v01
            v10, v11 = c * v10 - sn * v11, sn * v10 + c * v11
            v20, v21 = c * v20 - sn * v21, sn * v20 + c * v21
        if a02 != 0.0:                          # (0, 2)
            a00, a22, c, sn = _jacobi_angle(a00, a22, a02)
            a02 = 0.0
            a01, a12 = c * a01 - sn * a12, sn * a01 + c * a12
            v00, v02 = c * v00 - sn * v02, sn * v00 + c * v02
            v10, v12 = c * v10 - sn * v12, sn * v10 + c * v12
            v20, v22 = c * v20 - sn * v22, sn * v20 + c * v22
        if a12 != 0.0:                          # (1, 2)
            a11, a22, c, sn = _jacobi_angle(a11, a22, a12)
            a12 = 0.0
            a01, a02 = c * a01 - sn * a02, sn * a01 + c * a02
            v01, v02 = c * v01 - sn * v02, sn * v01 + c * v02
            v11, v12 = c * v11 - sn * v12, sn * v11 + c * v12
            v21, v22 = c * v21 - sn * v22, sn * v21 + c * v22
    return a00, a01, a02, a11, a12, a22, v00, v01, v02, v10, v11, v12, v20, v21, v22


@njit(**JIT_NO_REFCOUNT)
def pinv_sym(mat, out, wa, wv, rcond):
    """Pseudo-inverse of the symmetric positive semi-definite matrix ``m`` into ``out``.

    Eigenvalues at or below ``rcond`` times the largest are treated as zero, so planar,
    line-like and single-point clusters (singular A_qq) get the least-squares inverse.
    ``wa`` and ``wv`` are n x n scratch buffers.
    """
    n = mat.shape[0]
    for i in range(n):
        for j in range(n):
            wa[i, j] = mat[i, j]
    jacobi_eigh(wa, wv, 50)
    lmax = 0.0
    for i in range(n):
        if abs(wa[i, i]) > lmax:
            lmax = abs(wa[i, i])
    tol = rcond * lmax
    for i in range(n):
        for j in range(n):
            out[i, j] = 0.0
    for k in range(n):
        lam = wa[k, k]
        if lam > tol and lam > 0.0:
            inv = 1.0 / lam
            for i in range(n):
                vik = wv[i, k] * inv
                for j in range(n):
                    out[i, j] += vik * wv[j, k]


@njit(**JIT_NO_REFCOUNT)
def det3(a):
    """Determinant of a 3x3 matrix."""
    return (a[0, 0] * (a[1, 1] * a[2, 2] - a[1, 2] * a[2, 1])
            - a[0, 1] * (a[1, 0] * a[2, 2] - a[1, 2] * a[2, 0])
            + a[0, 2] * (a[1, 0] * a[2, 1] - a[1, 1] * a[2, 0]))


@njit(**JIT_NO_REFCOUNT)
def matmul(a, b, out):
    """``out = a @ b`` for small matrices (no aliasing between ``out`` and inputs)."""
    n, k = a.shape
    mass = b.shape[1]
    for i in range(n):
        for j in range(mass):
            s = 0.0
            for t in range(k):
                s += a[i, t] * b[t, j]
            out[i, j] = s


@njit(**JIT_NO_REFCOUNT)
def norm2(mat, wa, wv):
    """Spectral norm (largest singular value) of the 3x3 matrix ``m``."""
    for i in range(3):
        for j in range(3):
            s = 0.0
            for t in range(3):
                s += mat[t, i] * mat[t, j]
            wa[i, j] = s
    jacobi_eigh(wa, wv, 50)
    lmax = 0.0
    for i in range(3):
        if wa[i, i] > lmax:
            lmax = wa[i, i]
    return np.sqrt(lmax)


#: ``sym3_solve`` inverts by the adjugate when the smallest eigenvalue is provably above
#: this fraction of the largest (det > WELL_POSED tr^3 for a positive definite matrix).
WELL_POSED = 1e-6


@njit(**JIT_NO_REFCOUNT)
def sym3_solve(mat, b0, b1, b2, rcond, wout, wa, wv):
    """``pinv_sym(mat, rcond) @ b`` for a symmetric positive semi-definite 3x3 ``mat``.

    Where Sylvester's criterion shows ``mat`` positive definite and det > ``WELL_POSED``
    tr^3 (then lambda_min >= det / tr^2 > 1e-6 lambda_max, far above any ``rcond`` used,
    so the pseudo-inverse is the inverse) it solves by the adjugate: no eigen-solve.
    Otherwise (flat, line-like or indefinite by rounding) ``pinv_sym`` into ``wout``
    (scratch ``wa``, ``wv``).  Both agree to rounding times the condition number.
    """
    m00, m01, m02 = mat[0, 0], mat[0, 1], mat[0, 2]
    m11, m12, m22 = mat[1, 1], mat[1, 2], mat[2, 2]
    c00 = m11 * m22 - m12 * m12
    c01 = m02 * m12 - m01 * m22
    c02 = m01 * m12 - m02 * m11
    det = m00 * c00 + m01 * c01 + m02 * c02
    tr = m00 + m11 + m22
    if (m00 > 0.0 and m00 * m11 - m01 * m01 > 0.0 and det > WELL_POSED * tr * tr * tr
            and det < FLOAT_MAX):
        c11 = m00 * m22 - m02 * m02
        c12 = m01 * m02 - m00 * m12
        c22 = m00 * m11 - m01 * m01
        inv = 1.0 / det
        return ((c00 * b0 + c01 * b1 + c02 * b2) * inv,
                (c01 * b0 + c11 * b1 + c12 * b2) * inv,
                (c02 * b0 + c12 * b1 + c22 * b2) * inv)
    pinv_sym(mat=mat, out=wout, wa=wa, wv=wv, rcond=rcond)
    return (wout[0, 0] * b0 + wout[0, 1] * b1 + wout[0, 2] * b2,
            wout[1, 0] * b0 + wout[1, 1] * b1 + wout[1, 2] * b2,
            wout[2, 0] * b0 + wout[2, 1] * b1 + wout[2, 2] * b2)


@njit(inline='always', **JIT)
def add_moments(lin, k, w, r, u):
    """A particle's share of cluster k's angular momentum and inertia about a centre:
    lin[k, 4:7] += w r x u and lin[k, 7:13] += w (|r|^2 - r_a^2 on the diagonal xx yy zz,
    -r_a r_b off it xy yz zx), with r its offset from the centre and u its velocity."""
    r0, r1, r2 = r
    u0, u1, u2 = u
    rr = r0 * r0 + r1 * r1 + r2 * r2
    lin[k, 4] += w * (r1 * u2 - r2 * u1)
    lin[k, 5] += w * (r2 * u0 - r0 * u2)
    lin[k, 6] += w * (r0 * u1 - r1 * u0)
    lin[k, 7] += w * (rr - r0 * r0)
    lin[k, 8] += w * (rr - r1 * r1)
    lin[k, 9] += w * (rr - r2 * r2)
    lin[k, 10] -= w * r0 * r1
    lin[k, 11] -= w * r1 * r2
    lin[k, 12] -= w * r2 * r0


#: Twelve zeros: the start of ``add_outer``'s sums.
ZERO12 = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)


@njit(inline='always', **JIT)
def add_outer(sums, d0, d1, d2, a0, a1, a2):
    """``sums`` (sum d (3), then sum d a^T row by row (9)) with one more pair d, a: the
    shape match's sums of a particle loop, kept in registers when the loop carries them."""
    s0, s1, s2, c00, c01, c02, c10, c11, c12, c20, c21, c22 = sums
    return (s0 + d0, s1 + d1, s2 + d2, c00 + d0 * a0, c01 + d0 * a1, c02 + d0 * a2,
            c10 + d1 * a0, c11 + d1 * a1, c12 + d1 * a2, c20 + d2 * a0, c21 + d2 * a1,
            c22 + d2 * a2)


#: Sixteen zeros: the start of ``add_damping``'s sums.
ZERO16 = ZERO12 + (0.0, 0.0, 0.0, 0.0)


@njit(inline='always', **JIT)
def add_damping(sums, w, d0, d1, d2, v0, v1, v2):
    """``sums`` (sum w d (3), sum w v (3), sum w d x v (3), the six second moments sum w
    d_a d_b as xx yy zz xy yz zx, sum w) with one more particle of weight w, offset d from
    the point the sums are taken about and velocity v: what the damping needs of a loop."""
    u0, u1, u2 = w * v0, w * v1, w * v2
    wd0, wd1, wd2 = w * d0, w * d1, w * d2
    return (sums[0] + wd0, sums[1] + wd1, sums[2] + wd2, sums[3] + u0, sums[4] + u1,
            sums[5] + u2, sums[6] + (d1 * u2 - d2 * u1), sums[7] + (d2 * u0 - d0 * u2),
            sums[8] + (d0 * u1 - d1 * u0), sums[9] + wd0 * d0, sums[10] + wd1 * d1,
            sums[11] + wd2 * d2, sums[12] + wd0 * d1, sums[13] + wd1 * d2,
            sums[14] + wd2 * d0, sums[15] + w)
