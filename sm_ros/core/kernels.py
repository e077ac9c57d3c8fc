"""Numba kernels of the solver: small linear algebra and the per-step passes.

Everything jitted lives in this one module (Numba's cache does not notice edits to jitted
functions in other files).  Public kernels never raise and assume clean, contiguous input;
``sm_ros.core.body`` validates and owns every buffer, so nothing here allocates.

Small dense linear algebra is written by hand (3x3, 4x4, 9x9).

``numpy.linalg`` inside Numba needs SciPy's LAPACK and is slow for tiny matrices, so the
solver uses these routines instead (algorithm.md, "Practical requirements").  Every routine
writes into caller-provided buffers: nothing here allocates.

"""

import numpy as np
from numba import njit, prange

#: Fastmath flags used by every kernel (no ``nnan``/``ninf``: NaN checks must still work).
FASTMATH = {'nsz', 'arcp', 'contract', 'afn', 'reassoc'}
JIT = dict(cache=True, fastmath=FASTMATH, nogil=True)


@njit(**JIT)
def jacobi_eigh(a, v, max_sweeps=50):
    """Diagonalise the symmetric matrix ``a`` in place by cyclic Jacobi rotations.

    On return the diagonal of ``a`` holds the eigenvalues and the columns of ``v`` the
    eigenvectors (``a_in = v diag(a) v^T``).  Works for any small n (used with 3, 4, 9).
    """
    n = a.shape[0]
    for i in range(n):
        for j in range(n):
            v[i, j] = 1.0 if i == j else 0.0
    for _ in range(max_sweeps):
        off = 0.0
        diag = 0.0
        for i in range(n):
            diag += a[i, i] * a[i, i]
            for j in range(i + 1, n):
                off += a[i, j] * a[i, j]
        if off <= 1e-32 * diag or off == 0.0:
            break
        for p in range(n - 1):
            for q in range(p + 1, n):
                apq = a[p, q]
                if apq == 0.0:
                    continue
                theta = (a[q, q] - a[p, p]) / (2.0 * apq)
                if theta >= 0.0:
                    t = 1.0 / (theta + np.sqrt(theta * theta + 1.0))
                else:
                    t = -1.0 / (-theta + np.sqrt(theta * theta + 1.0))
                c = 1.0 / np.sqrt(t * t + 1.0)
                s = t * c
                for k in range(n):
                    akp = a[k, p]
                    akq = a[k, q]
                    a[k, p] = c * akp - s * akq
                    a[k, q] = s * akp + c * akq
                for k in range(n):
                    apk = a[p, k]
                    aqk = a[q, k]
                    a[p, k] = c * apk - s * aqk
                    a[q, k] = s * apk + c * aqk
                for k in range(n):
                    vkp = v[k, p]
                    vkq = v[k, q]
                    v[k, p] = c * vkp - s * vkq
                    v[k, q] = s * vkp + c * vkq


@njit(**JIT)
def pinv_sym(m, out, wa, wv, rcond):
    """Pseudo-inverse of the symmetric positive semi-definite matrix ``m`` into ``out``.

    Eigenvalues at or below ``rcond`` times the largest are treated as zero, so planar,
    line-like and single-point clusters (singular A_qq) get the least-squares inverse.
    ``wa`` and ``wv`` are n x n scratch buffers.
    """
    n = m.shape[0]
    for i in range(n):
        for j in range(n):
            wa[i, j] = m[i, j]
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


@njit(**JIT)
def quat_to_mat(q, r):
    """Rotation matrix of the unit quaternion ``q`` = (w, x, y, z) into ``r`` (3x3)."""
    w, x, y, z = q[0], q[1], q[2], q[3]
    r[0, 0] = 1.0 - 2.0 * (y * y + z * z)
    r[0, 1] = 2.0 * (x * y - w * z)
    r[0, 2] = 2.0 * (x * z + w * y)
    r[1, 0] = 2.0 * (x * y + w * z)
    r[1, 1] = 1.0 - 2.0 * (x * x + z * z)
    r[1, 2] = 2.0 * (y * z - w * x)
    r[2, 0] = 2.0 * (x * z - w * y)
    r[2, 1] = 2.0 * (y * z + w * x)
    r[2, 2] = 1.0 - 2.0 * (x * x + y * y)


@njit(**JIT)
def extract_rotation(a, q, r, n4, v4):
    """Least-squares rotation of ``a`` (3x3): the proper R maximising tr(R^T a).

    For det(a) > 0 this is the rotational factor of the polar decomposition a = R S
    (algorithm.md, Eq. 11 erratum); for det(a) <= 0 it is the nearest *proper* rotation
    (the SVD with the smallest singular vector flipped).  Horn's quaternion method: R's
    quaternion is the top eigenvector of a symmetric 4x4 matrix, found by Jacobi, so it
    never fails and is proper by construction.  Warm start: ``q`` (in/out) holds the
    previous rotation; the problem is solved relative to it and, where the answer is not
    unique (singular ``a``: planar, collinear, single or coincident points), the solution
    closest to the previous rotation is kept.  ``r`` receives the matrix; ``n4``/``v4`` are
    4x4 scratch buffers.
    """
    quat_to_mat(q, r)
    # b = R0^T a: the match relative to the previous rotation; horn's S = b^T.
    sxx = r[0, 0] * a[0, 0] + r[1, 0] * a[1, 0] + r[2, 0] * a[2, 0]
    sxy = r[0, 0] * a[0, 1] + r[1, 0] * a[1, 1] + r[2, 0] * a[2, 1]
    sxz = r[0, 0] * a[0, 2] + r[1, 0] * a[1, 2] + r[2, 0] * a[2, 2]
    syx = r[0, 1] * a[0, 0] + r[1, 1] * a[1, 0] + r[2, 1] * a[2, 0]
    syy = r[0, 1] * a[0, 1] + r[1, 1] * a[1, 1] + r[2, 1] * a[2, 1]
    syz = r[0, 1] * a[0, 2] + r[1, 1] * a[1, 2] + r[2, 1] * a[2, 2]
    szx = r[0, 2] * a[0, 0] + r[1, 2] * a[1, 0] + r[2, 2] * a[2, 0]
    szy = r[0, 2] * a[0, 1] + r[1, 2] * a[1, 1] + r[2, 2] * a[2, 1]
    szz = r[0, 2] * a[0, 2] + r[1, 2] * a[1, 2] + r[2, 2] * a[2, 2]
    # b[i, j] = s_ij above (row i of R0^T times column j of a); Horn uses S = b^T,
    # S_ab = b_ba.  Written out with S_ab -> b[b, a]:
    Sxx, Syy, Szz = sxx, syy, szz
    Sxy, Sxz = syx, szx
    Syx, Syz = sxy, szy
    Szx, Szy = sxz, syz
    n4[0, 0] = Sxx + Syy + Szz
    n4[0, 1] = Syz - Szy
    n4[0, 2] = Szx - Sxz
    n4[0, 3] = Sxy - Syx
    n4[1, 1] = Sxx - Syy - Szz
    n4[1, 2] = Sxy + Syx
    n4[1, 3] = Szx + Sxz
    n4[2, 2] = -Sxx + Syy - Szz
    n4[2, 3] = Syz + Szy
    n4[3, 3] = -Sxx - Syy + Szz
    for i in range(4):
        for j in range(i):
            n4[i, j] = n4[j, i]
    scale = 0.0
    for i in range(4):
        for j in range(4):
            if abs(n4[i, j]) > scale:
                scale = abs(n4[i, j])
    if not (scale > 0.0) or not np.isfinite(scale):
        # Zero or non-finite match: keep the previous rotation.
        return
    jacobi_eigh(n4, v4, 30)
    lmax = n4[0, 0]
    for k in range(1, 4):
        if n4[k, k] > lmax:
            lmax = n4[k, k]
    tol = 1e-9 * scale
    # Project e0 (no change) onto the top eigenspace: the closest optimal rotation.
    u0 = 0.0
    u1 = 0.0
    u2 = 0.0
    u3 = 0.0
    for k in range(4):
        if n4[k, k] >= lmax - tol:
            c = v4[0, k]
            u0 += c * v4[0, k]
            u1 += c * v4[1, k]
            u2 += c * v4[2, k]
            u3 += c * v4[3, k]
    nu = u0 * u0 + u1 * u1 + u2 * u2 + u3 * u3
    if nu < 1e-12:
        kbest = 0
        for k in range(1, 4):
            if n4[k, k] > n4[kbest, kbest]:
                kbest = k
        u0, u1, u2, u3 = v4[0, kbest], v4[1, kbest], v4[2, kbest], v4[3, kbest]
        nu = u0 * u0 + u1 * u1 + u2 * u2 + u3 * u3
    inv = 1.0 / np.sqrt(nu)
    if u0 < 0.0:
        inv = -inv
    u0 *= inv
    u1 *= inv
    u2 *= inv
    u3 *= inv
    # q <- q0 (x) u  (R = R0 R_u)
    w0, x0, y0, z0 = q[0], q[1], q[2], q[3]
    w = w0 * u0 - x0 * u1 - y0 * u2 - z0 * u3
    x = w0 * u1 + x0 * u0 + y0 * u3 - z0 * u2
    y = w0 * u2 - x0 * u3 + y0 * u0 + z0 * u1
    z = w0 * u3 + x0 * u2 - y0 * u1 + z0 * u0
    nq = 1.0 / np.sqrt(w * w + x * x + y * y + z * z)
    q[0] = w * nq
    q[1] = x * nq
    q[2] = y * nq
    q[3] = z * nq
    quat_to_mat(q, r)


@njit(**JIT)
def det3(a):
    """Determinant of a 3x3 matrix."""
    return (a[0, 0] * (a[1, 1] * a[2, 2] - a[1, 2] * a[2, 1])
            - a[0, 1] * (a[1, 0] * a[2, 2] - a[1, 2] * a[2, 0])
            + a[0, 2] * (a[1, 0] * a[2, 1] - a[1, 1] * a[2, 0]))


@njit(**JIT)
def matmul(a, b, out):
    """``out = a @ b`` for small matrices (no aliasing between ``out`` and inputs)."""
    n, k = a.shape
    m = b.shape[1]
    for i in range(n):
        for j in range(m):
            s = 0.0
            for t in range(k):
                s += a[i, t] * b[t, j]
            out[i, j] = s


@njit(**JIT)
def _logprod(s0, s1, s2, lam):
    """log prod_i (s_i + sqrt(s_i^2 + 4 lam)) / 2."""
    return (np.log(0.5 * (s0 + np.sqrt(max(s0 * s0 + 4.0 * lam, 0.0))))
            + np.log(0.5 * (s1 + np.sqrt(max(s1 * s1 + 4.0 * lam, 0.0))))
            + np.log(0.5 * (s2 + np.sqrt(max(s2 * s2 + 4.0 * lam, 0.0)))))


#: Largest stretch (and 1 / smallest) of the volume-preserving linear transform A'.
STRETCH_LIMIT = 2.0


@njit(**JIT)
def volume_preserving(a, out, wa, wv, limit):
    """A' = the det-1 matrix closest to ``a`` (3x3) with its singular vectors, into ``out``.

    Eq. 18 divides A by cbrt(det A).  That uniform rescaling is not the minimiser of any
    energy: a body flattened on impact (det A -> 0) gets goals far outside it, and the
    goal forces pump energy into a bouncing linear body until it flies apart.  Instead
    the singular values s_i of A are replaced by the closest x_i (least squares) with
    prod x_i = 1, i.e. x_i = (s_i + sqrt(s_i^2 + 4 lam)) / 2 with lam found by Newton's
    method (safeguarded by bisection), and then limited to [1 / limit, limit] so no goal
    shape is stretched without bound.  ``out[:, :3]`` receives A V diag(x / s) V^T.
    Returns False (no volume-preserving transform exists) for det A <= 0 or a flat A: the
    caller falls back to R.
    """
    for i in range(3):
        for j in range(3):
            s = 0.0
            for u in range(3):
                s += a[u, i] * a[u, j]
            wa[i, j] = s
    dt = det3(a)
    if not (dt > 1e-9) or not np.isfinite(dt):
        return False
    jacobi_eigh(wa, wv, 50)
    s0 = np.sqrt(max(wa[0, 0], 0.0))
    s1 = np.sqrt(max(wa[1, 1], 0.0))
    s2 = np.sqrt(max(wa[2, 2], 0.0))
    smin = min(s0, min(s1, s2))
    if not (smin > 0.0):
        return False
    # f(lam) = sum log x_i(lam) is increasing: bracket its root, then safeguarded Newton
    lo = -0.25 * smin * smin
    hi = 0.0
    if _logprod(s0, s1, s2, 0.0) < 0.0:
        lo, hi = 0.0, 1.0            # at lam = 1 every x_i >= 1
    ok = _logprod(s0, s1, s2, lo) <= 0.0
    lam = 0.5 * (lo + hi)
    x0 = x1 = x2 = 1.0
    for _ in range(100):
        if not ok:
            break
        r0 = np.sqrt(max(s0 * s0 + 4.0 * lam, 0.0))
        r1 = np.sqrt(max(s1 * s1 + 4.0 * lam, 0.0))
        r2 = np.sqrt(max(s2 * s2 + 4.0 * lam, 0.0))
        x0 = 0.5 * (s0 + r0)
        x1 = 0.5 * (s1 + r1)
        x2 = 0.5 * (s2 + r2)
        f = np.log(x0) + np.log(x1) + np.log(x2)
        if abs(f) < 1e-14 or hi - lo < 1e-15 * (1.0 + abs(lam)):
            break
        if f < 0.0:
            lo = lam
        else:
            hi = lam
        fp = 0.0
        if r0 > 0.0 and r1 > 0.0 and r2 > 0.0:
            fp = 1.0 / (x0 * r0) + 1.0 / (x1 * r1) + 1.0 / (x2 * r2)
        step = lam - f / fp if fp > 0.0 else lo - 1.0
        lam = step if lo < step < hi else 0.5 * (lo + hi)
    if not ok:                       # no root in reach: the uniform rescaling of Eq. 18
        c = 1.0 / np.cbrt(s0 * s1 * s2)
        x0, x1, x2 = s0 * c, s1 * c, s2 * c
    x0 = min(max(x0, 1.0 / limit), limit) / s0
    x1 = min(max(x1, 1.0 / limit), limit) / s1
    x2 = min(max(x2, 1.0 / limit), limit) / s2
    # out = a V diag(x / s) V^T
    for i in range(3):
        for j in range(3):
            s = 0.0
            for u in range(3):
                vv = (wv[u, 0] * x0 * wv[j, 0] + wv[u, 1] * x1 * wv[j, 1]
                      + wv[u, 2] * x2 * wv[j, 2])
                s += a[i, u] * vv
            out[i, j] = s
    return True


@njit(**JIT)
def _logx(s, r, minus):
    """log of x = (s + r) / 2, or of the minus root (s - r) / 2 = -mu / ((s + r) / 2)."""
    return np.log(0.5 * (s - r)) if minus else np.log(0.5 * (s + r))


@njit(**JIT)
def _unit_det_sum(s0, s1, s2, mu, kmin):
    """sum_i log x_i(mu) with the minus root for index ``kmin`` (-1: plus roots only)."""
    r0 = np.sqrt(max(s0 * s0 + 4.0 * mu, 0.0))
    r1 = np.sqrt(max(s1 * s1 + 4.0 * mu, 0.0))
    r2 = np.sqrt(max(s2 * s2 + 4.0 * mu, 0.0))
    return _logx(s0, r0, kmin == 0) + _logx(s1, r1, kmin == 1) + _logx(s2, r2, kmin == 2)


@njit(**JIT)
def nearest_unit_det(f, out, wa, wv):
    """C = argmin ||C - f||_F over det C = 1 (3x3), into ``out``; False if det f <= 0.

    C shares f's singular vectors; its singular values x_i solve x_i^2 - s_i x_i = mu with
    prod x_i = 1.  On the plus roots x_i = (s_i + sqrt(s_i^2 + 4 mu)) / 2 the product grows
    with mu from mu = -s_min^2 / 4 (safeguarded Newton); when it is above 1 already there,
    the root is on the minus root of the smallest s (a strongly flattened f; bisection).
    ``out`` = f V diag(x / s) V^T, so f out^T is symmetric to rounding whatever the
    accuracy of V.  NumPy twin: ``reference.nearest_unit_det``.
    """
    for i in range(3):
        for j in range(3):
            s = 0.0
            for u in range(3):
                s += f[u, i] * f[u, j]
            wa[i, j] = s
    d = det3(f)
    if not (d > 0.0) or not np.isfinite(d):
        return False
    jacobi_eigh(wa, wv, 50)
    s0 = np.sqrt(max(wa[0, 0], 0.0))
    s1 = np.sqrt(max(wa[1, 1], 0.0))
    s2 = np.sqrt(max(wa[2, 2], 0.0))
    smin = min(s0, min(s1, s2))
    if not (smin > 0.0):
        return False
    kmin = 0 if smin == s0 else (1 if smin == s1 else 2)
    lo = -0.25 * smin * smin
    x0 = x1 = x2 = 1.0
    if _unit_det_sum(s0, s1, s2, lo, -1) <= 0.0:
        hi = 0.0
        if _unit_det_sum(s0, s1, s2, 0.0, -1) < 0.0:
            lo, hi = 0.0, 1.0            # at mu = 1 every x_i >= 1
        mu = 0.5 * (lo + hi)
        for _ in range(100):
            r0 = np.sqrt(max(s0 * s0 + 4.0 * mu, 0.0))
            r1 = np.sqrt(max(s1 * s1 + 4.0 * mu, 0.0))
            r2 = np.sqrt(max(s2 * s2 + 4.0 * mu, 0.0))
            x0 = 0.5 * (s0 + r0)
            x1 = 0.5 * (s1 + r1)
            x2 = 0.5 * (s2 + r2)
            fv = np.log(x0) + np.log(x1) + np.log(x2)
            if abs(fv) < 1e-15 or hi - lo < 1e-16 * (1.0 + abs(mu)):
                break
            if fv < 0.0:
                lo = mu
            else:
                hi = mu
            fp = 0.0
            if r0 > 0.0 and r1 > 0.0 and r2 > 0.0:
                fp = 1.0 / (x0 * r0) + 1.0 / (x1 * r1) + 1.0 / (x2 * r2)
            step = mu - fv / fp if fp > 0.0 else lo - 1.0
            mu = step if lo < step < hi else 0.5 * (lo + hi)
    else:
        hi = 0.0                         # minus root of the smallest: sum falls to -inf
        for _ in range(200):
            mu = 0.5 * (lo + hi)
            if not (lo < mu < hi):
                break
            if _unit_det_sum(s0, s1, s2, mu, kmin) > 0.0:
                lo = mu
            else:
                hi = mu
        mu = 0.5 * (lo + hi)
        r0 = np.sqrt(max(s0 * s0 + 4.0 * mu, 0.0))
        r1 = np.sqrt(max(s1 * s1 + 4.0 * mu, 0.0))
        r2 = np.sqrt(max(s2 * s2 + 4.0 * mu, 0.0))
        x0 = 0.5 * (s0 - r0) if kmin == 0 else 0.5 * (s0 + r0)
        x1 = 0.5 * (s1 - r1) if kmin == 1 else 0.5 * (s1 + r1)
        x2 = 0.5 * (s2 - r2) if kmin == 2 else 0.5 * (s2 + r2)
    x0 /= s0
    x1 /= s1
    x2 /= s2
    for i in range(3):
        for j in range(3):
            s = 0.0
            for u in range(3):
                vv = (wv[u, 0] * x0 * wv[j, 0] + wv[u, 1] * x1 * wv[j, 1]
                      + wv[u, 2] * x2 * wv[j, 2])
                s += f[i, u] * vv
            out[i, j] = s
    return True


@njit(**JIT)
def _stretch_ok(b, r, t, w, wa, wv, limit):
    """Whether R + t (B - R) has every singular value in [1 / limit, limit]."""
    for i in range(3):
        for j in range(3):
            w[i, j] = r[i, j] + t * (b[i, j] - r[i, j])
    for i in range(3):
        for j in range(3):
            s = 0.0
            for u in range(3):
                s += w[u, i] * w[u, j]
            wa[i, j] = s
    jacobi_eigh(wa, wv, 50)
    lo2 = 1.0 / (limit * limit)
    hi2 = limit * limit
    for i in range(3):
        if not (lo2 <= wa[i, i] <= hi2):
            return False
    return True


@njit(**JIT)
def unit_det_match(apq, nmat, c_s, r, out, w1, w2, wa, wv, limit):
    """The linear mode's B = argmin sum w ||p - B q||^2 over det B = 1, into ``out``.

    ``apq`` = A_pq-hat (q in units of the cluster scale s), ``nmat`` = det(M)^(1/3) M^-1
    with M^2 = A_qq-hat (unit determinant, ``unit_det_frames``), ``c_s`` = s det(A_qq-hat)^(1/3).
    With C = B M the energy is ||C - A_pq M^-1||^2 + const and det C = det M: C is the
    nearest unit-determinant matrix to F = A_pq-hat N / c_s, scaled back, and B = C N.
    Stationarity makes A_pq B^T symmetric: no torque, and the goals derive from an energy.
    Stretches beyond [1 / limit, limit] are pulled back to R + t (B - R), which keeps
    A_pq B^T symmetric.  Returns False (use R) if det F <= 0.  Twin:
    ``reference.unit_det_match``.
    """
    inv = 1.0 / c_s
    for i in range(3):
        for j in range(3):
            w1[i, j] = (apq[i, 0] * nmat[0, j] + apq[i, 1] * nmat[1, j]
                        + apq[i, 2] * nmat[2, j]) * inv
    if not nearest_unit_det(w1, w2, wa, wv):
        return False
    matmul(w2, nmat, out)
    if _stretch_ok(out, r, 1.0, w1, wa, wv, limit):
        return True
    lo = 0.0
    hi = 1.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if _stretch_ok(out, r, mid, w1, wa, wv, limit):
            lo = mid
        else:
            hi = mid
    for i in range(3):
        for j in range(3):
            out[i, j] = r[i, j] + lo * (out[i, j] - r[i, j])
    return True


@njit(**JIT)
def unit_det_frames(which, mom3, nmat, cdet, wa, wv, rcond):
    """Per cluster: N = (A_qq-hat / c)^(-1/2) and c = det(A_qq-hat)^(1/3) (linear mode).

    A cluster whose A_qq-hat is singular (flat, line-like: eigenvalue at or below
    ``rcond`` times the largest) gets c = 0: its linear goal is the rotation.
    """
    for k in range(which.shape[0]):
        if not which[k]:
            continue
        for i in range(3):
            for j in range(3):
                wa[i, j] = mom3[k, i, j]
        jacobi_eigh(wa, wv, 50)
        l0, l1, l2 = wa[0, 0], wa[1, 1], wa[2, 2]
        lmax = max(l0, max(l1, l2))
        if not (min(l0, min(l1, l2)) > rcond * lmax) or not (lmax > 0.0):
            cdet[k] = 0.0
            for i in range(3):
                for j in range(3):
                    nmat[k, i, j] = 0.0
            continue
        c = np.cbrt(l0 * l1 * l2)
        cdet[k] = c
        e0 = np.sqrt(c / l0)
        e1 = np.sqrt(c / l1)
        e2 = np.sqrt(c / l2)
        for i in range(3):
            for j in range(3):
                nmat[k, i, j] = (wv[i, 0] * e0 * wv[j, 0] + wv[i, 1] * e1 * wv[j, 1]
                                 + wv[i, 2] * e2 * wv[j, 2])


@njit(**JIT)
def norm2(m, wa, wv):
    """Spectral norm (largest singular value) of the 3x3 matrix ``m``."""
    for i in range(3):
        for j in range(3):
            s = 0.0
            for t in range(3):
                s += m[t, i] * m[t, j]
            wa[i, j] = s
    jacobi_eigh(wa, wv, 50)
    lmax = 0.0
    for i in range(3):
        if wa[i, i] > lmax:
            lmax = wa[i, i]
    return np.sqrt(lmax)


# ---------------------------------------------------------------------------------------
# Per-particle helpers
# ---------------------------------------------------------------------------------------

@njit(**JIT)
def _contact_velocity(vx, vy, vz, nx, ny, nz, mu, e, thresh):
    """Velocity after a contact with unit normal n: restitution e, Coulomb friction mu."""
    vn = vx * nx + vy * ny + vz * nz
    if vn >= 0.0:
        return vx, vy, vz
    tx = vx - vn * nx
    ty = vy - vn * ny
    tz = vz - vn * nz
    vn_new = -e * vn if -vn > thresh else 0.0
    dvn = vn_new - vn
    tl = np.sqrt(tx * tx + ty * ty + tz * tz)
    if tl > 0.0:
        f = 1.0 - mu * dvn / tl
        if f < 0.0:
            f = 0.0
        tx *= f
        ty *= f
        tz *= f
    return tx + vn_new * nx, ty + vn_new * ny, tz + vn_new * nz


@njit(**JIT)
def collide_point(px, py, pz, vx, vy, vz, ground, boxes, spheres, thresh):
    """Project a particle out of the static colliders and correct its velocity.

    ``ground`` = [enabled, height, friction, restitution] (plane z = height, normal +z);
    ``boxes`` rows = [lo(3), hi(3), friction, restitution] (axis-aligned, solid);
    ``spheres`` rows = [centre(3), radius, friction, restitution] (solid).
    """
    if ground[0] > 0.5 and pz < ground[1]:
        pz = ground[1]
        vx, vy, vz = _contact_velocity(vx, vy, vz, 0.0, 0.0, 1.0, ground[2], ground[3], thresh)
    for b in range(boxes.shape[0]):
        if (px > boxes[b, 0] and px < boxes[b, 3] and py > boxes[b, 1] and py < boxes[b, 4]
                and pz > boxes[b, 2] and pz < boxes[b, 5]):
            best = px - boxes[b, 0]
            axis = 0
            sgn = -1.0
            d = boxes[b, 3] - px
            if d < best:
                best, axis, sgn = d, 0, 1.0
            d = py - boxes[b, 1]
            if d < best:
                best, axis, sgn = d, 1, -1.0
            d = boxes[b, 4] - py
            if d < best:
                best, axis, sgn = d, 1, 1.0
            d = pz - boxes[b, 2]
            if d < best:
                best, axis, sgn = d, 2, -1.0
            d = boxes[b, 5] - pz
            if d < best:
                best, axis, sgn = d, 2, 1.0
            nx = sgn if axis == 0 else 0.0
            ny = sgn if axis == 1 else 0.0
            nz = sgn if axis == 2 else 0.0
            if axis == 0:
                px = boxes[b, 3] if sgn > 0.0 else boxes[b, 0]
            elif axis == 1:
                py = boxes[b, 4] if sgn > 0.0 else boxes[b, 1]
            else:
                pz = boxes[b, 5] if sgn > 0.0 else boxes[b, 2]
            vx, vy, vz = _contact_velocity(vx, vy, vz, nx, ny, nz, boxes[b, 6], boxes[b, 7],
                                           thresh)
    for s in range(spheres.shape[0]):
        dx = px - spheres[s, 0]
        dy = py - spheres[s, 1]
        dz = pz - spheres[s, 2]
        rad = spheres[s, 3]
        d2 = dx * dx + dy * dy + dz * dz
        if d2 < rad * rad:
            d = np.sqrt(d2)
            if d > 0.0:
                nx, ny, nz = dx / d, dy / d, dz / d
            else:
                nx, ny, nz = 0.0, 0.0, 1.0
            px = spheres[s, 0] + rad * nx
            py = spheres[s, 1] + rad * ny
            pz = spheres[s, 2] + rad * nz
            vx, vy, vz = _contact_velocity(vx, vy, vz, nx, ny, nz, spheres[s, 4],
                                           spheres[s, 5], thresh)
    return px, py, pz, vx, vy, vz


@njit(**JIT)
def _collide_range(start, end, x, v, ground, boxes, spheres, thresh):
    """Colliders for particles start..end.

    A lone ground plane is tested inline: the call to ``collide_point``, not the test, is
    what costs (100k particles resting on the ground: 3.6 -> 1.9 ms/step skipping the call
    above the ground, -> 1.4 ms with the contact inlined too).
    """
    only_ground = boxes.shape[0] == 0 and spheres.shape[0] == 0
    gz = ground[1] if ground[0] > 0.5 else -np.inf
    if only_ground:
        # collide_point for the ground alone, inlined (a resting body has a whole layer
        # of particles in contact every step)
        mu, e = ground[2], ground[3]
        for i in range(start, end):
            if x[i, 2] < gz:
                x[i, 2] = gz
                v[i, 0], v[i, 1], v[i, 2] = _contact_velocity(v[i, 0], v[i, 1], v[i, 2], 0.0,
                                                              0.0, 1.0, mu, e, thresh)
        return
    for i in range(start, end):
        x[i, 0], x[i, 1], x[i, 2], v[i, 0], v[i, 1], v[i, 2] = collide_point(
            x[i, 0], x[i, 1], x[i, 2], v[i, 0], v[i, 1], v[i, 2], ground, boxes, spheres,
            thresh)


@njit(**JIT)
def _qhat(g, hv, c, a0, a1, a2):
    """q-hat = G_c x0 + h_c: the (plastic, scaled) rest offset of a particle in cluster c."""
    return (g[c, 0, 0] * a0 + g[c, 0, 1] * a1 + g[c, 0, 2] * a2 + hv[c, 0],
            g[c, 1, 0] * a0 + g[c, 1, 1] * a1 + g[c, 1, 2] * a2 + hv[c, 1],
            g[c, 2, 0] * a0 + g[c, 2, 1] * a1 + g[c, 2, 2] * a2 + hv[c, 2])


@njit(**JIT)
def quad_features(q0, q1, q2, f):
    """q~ = [qx, qy, qz, qx^2, qy^2, qz^2, qx qy, qy qz, qz qx] (Eq. 19) into ``f``."""
    f[0] = q0
    f[1] = q1
    f[2] = q2
    f[3] = q0 * q0
    f[4] = q1 * q1
    f[5] = q2 * q2
    f[6] = q0 * q1
    f[7] = q1 * q2
    f[8] = q2 * q0


@njit(**JIT)
def _acc_lin(a, w, d0, d1, d2, q0, q1, q2):
    """Add one particle's w (x - ref) and w (x - ref) q^T to the accumulator row ``a``."""
    d0 *= w
    d1 *= w
    d2 *= w
    a[0] += d0
    a[1] += d1
    a[2] += d2
    a[3] += d0 * q0
    a[4] += d0 * q1
    a[5] += d0 * q2
    a[6] += d1 * q0
    a[7] += d1 * q1
    a[8] += d1 * q2
    a[9] += d2 * q0
    a[10] += d2 * q1
    a[11] += d2 * q2


@njit(**JIT)
def _acc_quad(a, w, d0, d1, d2, q0, q1, q2):
    """Quadratic accumulator: w (x - ref) and w (x - ref) q~^T (3 + 27 entries)."""
    d0 *= w
    d1 *= w
    d2 *= w
    a[0] += d0
    a[1] += d1
    a[2] += d2
    f3 = q0 * q0
    f4 = q1 * q1
    f5 = q2 * q2
    f6 = q0 * q1
    f7 = q1 * q2
    f8 = q2 * q0
    a[3] += d0 * q0
    a[4] += d0 * q1
    a[5] += d0 * q2
    a[6] += d0 * f3
    a[7] += d0 * f4
    a[8] += d0 * f5
    a[9] += d0 * f6
    a[10] += d0 * f7
    a[11] += d0 * f8
    a[12] += d1 * q0
    a[13] += d1 * q1
    a[14] += d1 * q2
    a[15] += d1 * f3
    a[16] += d1 * f4
    a[17] += d1 * f5
    a[18] += d1 * f6
    a[19] += d1 * f7
    a[20] += d1 * f8
    a[21] += d2 * q0
    a[22] += d2 * q1
    a[23] += d2 * q2
    a[24] += d2 * f3
    a[25] += d2 * f4
    a[26] += d2 * f5
    a[27] += d2 * f6
    a[28] += d2 * f7
    a[29] += d2 * f8


@njit(**JIT)
def _goal_quad(t, c, q0, q1, q2):
    """T_c q~ (3x9 times the quadratic features of q-hat); the caller adds the centre."""
    f3 = q0 * q0
    f4 = q1 * q1
    f5 = q2 * q2
    f6 = q0 * q1
    f7 = q1 * q2
    f8 = q2 * q0
    out0 = (t[c, 0, 0] * q0 + t[c, 0, 1] * q1 + t[c, 0, 2] * q2 + t[c, 0, 3] * f3
            + t[c, 0, 4] * f4 + t[c, 0, 5] * f5 + t[c, 0, 6] * f6 + t[c, 0, 7] * f7
            + t[c, 0, 8] * f8)
    out1 = (t[c, 1, 0] * q0 + t[c, 1, 1] * q1 + t[c, 1, 2] * q2 + t[c, 1, 3] * f3
            + t[c, 1, 4] * f4 + t[c, 1, 5] * f5 + t[c, 1, 6] * f6 + t[c, 1, 7] * f7
            + t[c, 1, 8] * f8)
    out2 = (t[c, 2, 0] * q0 + t[c, 2, 1] * q1 + t[c, 2, 2] * q2 + t[c, 2, 3] * f3
            + t[c, 2, 4] * f4 + t[c, 2, 5] * f5 + t[c, 2, 6] * f6 + t[c, 2, 7] * f7
            + t[c, 2, 8] * f8)
    return out0, out1, out2



# ---------------------------------------------------------------------------------------
# Single-cluster fast paths: no gather, every cluster constant and accumulator held in
# registers (the general kernels below read-modify-write the per-cluster accumulators).
# ---------------------------------------------------------------------------------------

@njit(**JIT)
def _acc_single(start, end, quad, x, x0, m, g, hv, ref, pc):
    g00, g01, g02 = g[0, 0, 0], g[0, 0, 1], g[0, 0, 2]
    g10, g11, g12 = g[0, 1, 0], g[0, 1, 1], g[0, 1, 2]
    g20, g21, g22 = g[0, 2, 0], g[0, 2, 1], g[0, 2, 2]
    h0, h1, h2 = hv[0, 0], hv[0, 1], hv[0, 2]
    r0, r1, r2 = ref[0, 0], ref[0, 1], ref[0, 2]
    if quad:
        for i in range(start, end):
            a0, a1, a2 = x0[i, 0], x0[i, 1], x0[i, 2]
            _acc_quad(pc[0], m[i], x[i, 0] - r0, x[i, 1] - r1, x[i, 2] - r2,
                      g00 * a0 + g01 * a1 + g02 * a2 + h0,
                      g10 * a0 + g11 * a1 + g12 * a2 + h1,
                      g20 * a0 + g21 * a1 + g22 * a2 + h2)
        return
    # sum w d q^T = (sum w d x0^T) G^T + (sum w d) h^T: accumulate in rest coordinates
    # (9 multiply-adds per particle less) and map once per block
    s0 = s1 = s2 = 0.0
    c00 = c01 = c02 = c10 = c11 = c12 = c20 = c21 = c22 = 0.0
    for i in range(start, end):
        a0, a1, a2 = x0[i, 0], x0[i, 1], x0[i, 2]
        w = m[i]
        d0 = w * (x[i, 0] - r0)
        d1 = w * (x[i, 1] - r1)
        d2 = w * (x[i, 2] - r2)
        s0 += d0
        s1 += d1
        s2 += d2
        c00 += d0 * a0
        c01 += d0 * a1
        c02 += d0 * a2
        c10 += d1 * a0
        c11 += d1 * a1
        c12 += d1 * a2
        c20 += d2 * a0
        c21 += d2 * a1
        c22 += d2 * a2
    a = pc[0]
    a[0] += s0
    a[1] += s1
    a[2] += s2
    a[3] += g00 * c00 + g01 * c01 + g02 * c02 + h0 * s0
    a[4] += g10 * c00 + g11 * c01 + g12 * c02 + h1 * s0
    a[5] += g20 * c00 + g21 * c01 + g22 * c02 + h2 * s0
    a[6] += g00 * c10 + g01 * c11 + g02 * c12 + h0 * s1
    a[7] += g10 * c10 + g11 * c11 + g12 * c12 + h1 * s1
    a[8] += g20 * c10 + g21 * c11 + g22 * c12 + h2 * s1
    a[9] += g00 * c20 + g01 * c21 + g02 * c22 + h0 * s2
    a[10] += g10 * c20 + g11 * c21 + g12 * c22 + h1 * s2
    a[11] += g20 * c20 + g21 * c21 + g22 * c22 + h2 * s2


@njit(**JIT)
def _int_single_lin(start, end, x, v, x0, lm, lb, alpha, h, acc, ang, com):
    l00, l01, l02 = lm[0, 0, 0], lm[0, 0, 1], lm[0, 0, 2]
    l10, l11, l12 = lm[0, 1, 0], lm[0, 1, 1], lm[0, 1, 2]
    l20, l21, l22 = lm[0, 2, 0], lm[0, 2, 1], lm[0, 2, 2]
    b0, b1, b2 = lb[0, 0], lb[0, 1], lb[0, 2]
    w0, w1, w2 = ang[0], ang[1], ang[2]
    # acc + ang x (p - com) = (acc - ang x com) + ang x p
    ax = acc[0] - (w1 * com[2] - w2 * com[1])
    ay = acc[1] - (w2 * com[0] - w0 * com[2])
    az = acc[2] - (w0 * com[1] - w1 * com[0])
    ah = alpha / h
    e2 = 0.0
    if w0 == 0.0 and w1 == 0.0 and w2 == 0.0:
        # no torque: a uniform acceleration (6 multiply-adds per particle less)
        hx, hy, hz = h * ax, h * ay, h * az
        for i in range(start, end):
            a0, a1, a2 = x0[i, 0], x0[i, 1], x0[i, 2]
            p0, p1, p2 = x[i, 0], x[i, 1], x[i, 2]
            e0 = l00 * a0 + l01 * a1 + l02 * a2 + b0 - p0
            e1 = l10 * a0 + l11 * a1 + l12 * a2 + b1 - p1
            ee = l20 * a0 + l21 * a1 + l22 * a2 + b2 - p2
            e2 += e0 * e0 + e1 * e1 + ee * ee
            v0 = v[i, 0] + ah * e0 + hx
            v1 = v[i, 1] + ah * e1 + hy
            v2 = v[i, 2] + ah * ee + hz
            x[i, 0] = p0 + h * v0
            x[i, 1] = p1 + h * v1
            x[i, 2] = p2 + h * v2
            v[i, 0] = v0
            v[i, 1] = v1
            v[i, 2] = v2
        return e2
    for i in range(start, end):
        a0, a1, a2 = x0[i, 0], x0[i, 1], x0[i, 2]
        p0, p1, p2 = x[i, 0], x[i, 1], x[i, 2]
        e0 = l00 * a0 + l01 * a1 + l02 * a2 + b0 - p0
        e1 = l10 * a0 + l11 * a1 + l12 * a2 + b1 - p1
        ee = l20 * a0 + l21 * a1 + l22 * a2 + b2 - p2
        e2 += e0 * e0 + e1 * e1 + ee * ee
        v0 = v[i, 0] + ah * e0 + h * (ax + w1 * p2 - w2 * p1)
        v1 = v[i, 1] + ah * e1 + h * (ay + w2 * p0 - w0 * p2)
        v2 = v[i, 2] + ah * ee + h * (az + w0 * p1 - w1 * p0)
        p0 += h * v0
        p1 += h * v1
        p2 += h * v2
        x[i, 0] = p0
        x[i, 1] = p1
        x[i, 2] = p2
        v[i, 0] = v0
        v[i, 1] = v1
        v[i, 2] = v2
    return e2


# ---------------------------------------------------------------------------------------
# Accumulation pass (Eq. 7-9): per cluster sum w (x - ref) and sum w (x - ref) q^T.
# ``part`` is (chunks, clusters, 12 or 30): every chunk owns its slot, reduced in
# ``solve_clusters``.  ref is the previous centre of mass, so large coordinates do not
# cancel (A_pq = sum w (x - ref) q^T - (cm - ref)(sum w q)^T).
# ---------------------------------------------------------------------------------------

@njit(**JIT)
def _acc_range(start, end, quad, x, x0, m, ptr, cl, g, hv, ref, pc):
    """Add particles start..end to the accumulators ``pc`` (clusters, 12 or 30)."""
    if ptr.shape[0] == 0:
        _acc_single(start, end, quad, x, x0, m, g, hv, ref, pc)
        return
    for i in range(start, end):
        a0, a1, a2 = x0[i, 0], x0[i, 1], x0[i, 2]
        j0, j1 = ptr[i], ptr[i + 1]
        w = m[i] / (j1 - j0)
        for j in range(j0, j1):
            k = cl[j]
            q0, q1, q2 = _qhat(g, hv, k, a0, a1, a2)
            d0 = x[i, 0] - ref[k, 0]
            d1 = x[i, 1] - ref[k, 1]
            d2 = x[i, 2] - ref[k, 2]
            if quad:
                _acc_quad(pc[k], w, d0, d1, d2, q0, q1, q2)
            else:
                _acc_lin(pc[k], w, d0, d1, d2, q0, q1, q2)


@njit(**JIT)
def _acc_chunk(c, nch, quad, x, x0, m, ptr, cl, g, hv, ref, part):
    n = x.shape[0]
    pc = part[c]
    for k in range(pc.shape[0]):
        for j in range(pc.shape[1]):
            pc[k, j] = 0.0
    _acc_range((c * n) // nch, ((c + 1) * n) // nch, quad, x, x0, m, ptr, cl, g, hv, ref,
               pc)


@njit(**JIT)
def accumulate_serial(quad, x, x0, m, ptr, cl, g, hv, ref, part):
    """Accumulation pass, one thread."""
    nch = part.shape[0]
    for c in range(nch):
        _acc_chunk(c, nch, quad, x, x0, m, ptr, cl, g, hv, ref, part)


@njit(parallel=True, **JIT)
def accumulate_parallel(quad, x, x0, m, ptr, cl, g, hv, ref, part):
    """Accumulation pass, one chunk per thread."""
    nch = part.shape[0]
    for c in prange(nch):
        _acc_chunk(c, nch, quad, x, x0, m, ptr, cl, g, hv, ref, part)


# ---------------------------------------------------------------------------------------
# Integration pass (Eq. 13-14) fused with the colliders and with the accumulation for the
# next step, so that a step reads and writes every particle once.
# ---------------------------------------------------------------------------------------

#: Particles per block of the fused pass: integrated, then accumulated while in L1.
BLOCK = 256


@njit(**JIT)
def _int_range(start, end, quad, x, v, x0, ptr, cl, g, hv, t, lm, lb, alpha, h, acc, ang,
               com):
    """Eq. 13-14 for particles start..end; returns sum |g - x|^2."""
    single = ptr.shape[0] == 0
    if single and not quad:
        return _int_single_lin(start, end, x, v, x0, lm, lb, alpha, h, acc, ang, com)
    ah = alpha / h
    e2 = 0.0
    for i in range(start, end):
        a0, a1, a2 = x0[i, 0], x0[i, 1], x0[i, 2]
        if single:
            j0, j1 = 0, 1
        else:
            j0, j1 = ptr[i], ptr[i + 1]
        # goal: mean over the particle's clusters (Eq. 12, 18, 22; mass-weighted average)
        g0 = 0.0
        g1 = 0.0
        g2 = 0.0
        for j in range(j0, j1):
            k = 0 if single else cl[j]
            if quad:
                q0, q1, q2 = _qhat(g, hv, k, a0, a1, a2)
                o0, o1, o2 = _goal_quad(t, k, q0, q1, q2)
                g0 += o0 + lb[k, 0]
                g1 += o1 + lb[k, 1]
                g2 += o2 + lb[k, 2]
            else:
                g0 += lm[k, 0, 0] * a0 + lm[k, 0, 1] * a1 + lm[k, 0, 2] * a2 + lb[k, 0]
                g1 += lm[k, 1, 0] * a0 + lm[k, 1, 1] * a1 + lm[k, 1, 2] * a2 + lb[k, 1]
                g2 += lm[k, 2, 0] * a0 + lm[k, 2, 1] * a1 + lm[k, 2, 2] * a2 + lb[k, 2]
        if not single:
            inv = 1.0 / (j1 - j0)
            g0 *= inv
            g1 *= inv
            g2 *= inv
        p0, p1, p2 = x[i, 0], x[i, 1], x[i, 2]
        e0 = g0 - p0
        e1 = g1 - p1
        ee = g2 - p2
        e2 += e0 * e0 + e1 * e1 + ee * ee
        r0 = p0 - com[0]
        r1 = p1 - com[1]
        r2 = p2 - com[2]
        v0 = v[i, 0] + ah * e0 + h * (acc[0] + ang[1] * r2 - ang[2] * r1)
        v1 = v[i, 1] + ah * e1 + h * (acc[1] + ang[2] * r0 - ang[0] * r2)
        v2 = v[i, 2] + ah * ee + h * (acc[2] + ang[0] * r1 - ang[1] * r0)
        p0 += h * v0
        p1 += h * v1
        p2 += h * v2
        x[i, 0] = p0
        x[i, 1] = p1
        x[i, 2] = p2
        v[i, 0] = v0
        v[i, 1] = v1
        v[i, 2] = v2
    return e2


@njit(**JIT)
def _int_chunk(c, nch, quad, x, v, x0, m, ptr, cl, g, hv, t, lm, lb, ref, alpha, h, acc,
               ang, com, part, err, has_col, ground, boxes, spheres, thresh):
    """Integrate a chunk block by block; collide and accumulate each block for the next
    step while it is still in L1 (one pass over memory, short loops without spills)."""
    n = x.shape[0]
    start = (c * n) // nch
    end = ((c + 1) * n) // nch
    pc = part[c]
    for k in range(pc.shape[0]):
        for j in range(pc.shape[1]):
            pc[k, j] = 0.0
    e2 = 0.0
    for bs in range(start, end, BLOCK):
        be = min(bs + BLOCK, end)
        e2 += _int_range(bs, be, quad, x, v, x0, ptr, cl, g, hv, t, lm, lb, alpha, h, acc,
                         ang, com)
        if has_col:
            _collide_range(bs, be, x, v, ground, boxes, spheres, thresh)
        _acc_range(bs, be, quad, x, x0, m, ptr, cl, g, hv, ref, pc)
    err[c] = e2


@njit(**JIT)
def integrate_serial(quad, x, v, x0, m, ptr, cl, g, hv, t, lm, lb, ref, alpha, h, acc, ang,
                     com, part, err, has_col, ground, boxes, spheres, thresh):
    """Integration pass, one thread."""
    nch = part.shape[0]
    for c in range(nch):
        _int_chunk(c, nch, quad, x, v, x0, m, ptr, cl, g, hv, t, lm, lb, ref, alpha, h, acc,
                   ang, com, part, err, has_col, ground, boxes, spheres, thresh)


@njit(parallel=True, **JIT)
def integrate_parallel(quad, x, v, x0, m, ptr, cl, g, hv, t, lm, lb, ref, alpha, h, acc, ang,
                       com, part, err, has_col, ground, boxes, spheres, thresh):
    """Integration pass, one chunk per thread."""
    nch = part.shape[0]
    for c in prange(nch):
        _int_chunk(c, nch, quad, x, v, x0, m, ptr, cl, g, hv, t, lm, lb, ref, alpha, h, acc,
                   ang, com, part, err, has_col, ground, boxes, spheres, thresh)


# ---------------------------------------------------------------------------------------
# Per-cluster solve: centre of mass, A_pq, rotation, goal transform, plasticity.
# ---------------------------------------------------------------------------------------

@njit(**JIT)
def _cap_plastic(sp, c_max, m3, wa, wv):
    """Sp <- Sp / cbrt(det Sp), then pulled towards I until ||Sp - I||_2 <= c_max (Eq. 27).

    The write-up's cap ``I + c_max (Sp - I)/||Sp - I||`` followed by the volume
    normalisation can land slightly above c_max again; bisecting on the blend
    t in [0, 1] of ``normalise(I + t (Sp - I))`` keeps both det Sp = 1 and the cap exact.
    """
    for i in range(3):
        for j in range(3):
            m3[i, j] = sp[i, j] - (1.0 if i == j else 0.0)
    if norm2(m3, wa, wv) <= c_max:
        return
    lo = 0.0
    hi = 1.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        for i in range(3):
            for j in range(3):
                wa[i, j] = (1.0 if i == j else 0.0) + mid * (sp[i, j] - (1.0 if i == j else 0.0))
        dt = det3(wa)
        ok = False
        if dt > 0.0:
            s = 1.0 / np.cbrt(dt)
            for i in range(3):
                for j in range(3):
                    m3[i, j] = wa[i, j] * s - (1.0 if i == j else 0.0)
            ok = norm2(m3, wa, wv) <= c_max
        if ok:
            lo = mid
        else:
            hi = mid
    for i in range(3):
        for j in range(3):
            wa[i, j] = (1.0 if i == j else 0.0) + lo * (sp[i, j] - (1.0 if i == j else 0.0))
    s = 1.0 / np.cbrt(det3(wa))
    for i in range(3):
        for j in range(3):
            sp[i, j] = wa[i, j] * s


@njit(**JIT)
def _add_null_projector(aqq, out, wa, wv):
    """out += the projector onto the null space of the symmetric PSD ``aqq`` (3x3)."""
    for i in range(3):
        for j in range(3):
            wa[i, j] = aqq[i, j]
    jacobi_eigh(wa, wv, 50)
    lmax = max(wa[0, 0], max(wa[1, 1], wa[2, 2]))
    for e in range(3):
        if not (wa[e, e] > 1e-13 * lmax):
            for i in range(3):
                for j in range(3):
                    out[i, j] += wv[i, e] * wv[j, e]


@njit(**JIT)
def solve_clusters(part, wsum, sq, ref, quat, aqq3, aqq9, g, hv, scale, t, lm, lb, mode, beta,
                   apq, acc, m3a, m3b, m3c, m39, n4, v4, nmat, cdet):
    """Reduce the accumulators and build every cluster's goal transform.

    ``mode``: 0 rigid, 1 linear, 2 quadratic.  Outputs: ``ref`` <- centre of mass x_cm,
    ``quat`` <- rotation of A_pq, ``t`` (3x9; linear modes use the 3x3 block) and, for the
    rigid/linear modes, the affine goal map ``lm x0 + lb``; ``apq`` (clusters, 3, 3)
    <- A_pq-hat for ``plastic_update``; ``nmat``/``cdet``: ``unit_det_frames`` (linear).
    Plasticity is a kernel of its own, so a scene without it neither runs nor compiles it.
    """
    nch = part.shape[0]
    nk = part.shape[1]
    na = part.shape[2]
    nq = 9 if mode == 2 else 3
    for k in range(nk):
        for a in range(na):
            s = 0.0
            for c in range(nch):
                s += part[c, k, a]
            acc[a] = s
        inv_w = 1.0 / wsum[k]
        d0 = acc[0] * inv_w
        d1 = acc[1] * inv_w
        d2 = acc[2] * inv_w
        # A_pq-hat (3 x nq) = sum w (x - cm) q^T, stored in m39
        for i in range(3):
            di = d0 if i == 0 else (d1 if i == 1 else d2)
            for j in range(nq):
                m39[i, j] = acc[3 + i * nq + j] - di * sq[k, j]
        ref[k, 0] += d0
        ref[k, 1] += d1
        ref[k, 2] += d2
        for i in range(3):
            for j in range(3):
                m3a[i, j] = m39[i, j]
                apq[k, i, j] = m39[i, j]
        extract_rotation(m3a, quat[k], m3b, n4, v4)   # m3b = R
        s_k = scale[k]
        if mode == 2:
            for i in range(3):
                for j in range(9):
                    s = 0.0
                    for u in range(9):
                        s += m39[i, u] * aqq9[k, u, j]
                    rt = s_k * m3b[i, j] if j < 3 else 0.0
                    t[k, i, j] = beta * s + (1.0 - beta) * rt
            # centred features: goal = T (q~ - mean q~) + cm, so lb = cm - T mean q~
            for i in range(3):
                s = ref[k, i]
                for j in range(9):
                    s -= t[k, i, j] * sq[k, j] * inv_w
                lb[k, i] = s
        else:
            if mode == 1:
                matmul(m3a, aqq3[k], m3c)             # A * s = A_pq-hat A_qq-hat
                dt = det3(m3c) / (s_k * s_k * s_k)
                # B = the unit-determinant minimiser (Eq. 18, see unit_det_match), written
                # into t's 3x3 block; inverted, flat or line-like (det A <= 0): R
                if (dt > 1e-9 and np.isfinite(dt) and cdet[k] > 0.0
                        and unit_det_match(m3a, nmat[k], s_k * cdet[k], m3b, m3c,
                                           m39[:, 3:6], m39[:, 6:9], n4[:3, :3], v4[:3, :3],
                                           STRETCH_LIMIT)):
                    for i in range(3):
                        for j in range(3):
                            t[k, i, j] = s_k * (beta * m3c[i, j] + (1.0 - beta) * m3b[i, j])
                else:
                    for i in range(3):
                        for j in range(3):
                            t[k, i, j] = s_k * m3b[i, j]
            else:
                for i in range(3):
                    for j in range(3):
                        t[k, i, j] = s_k * m3b[i, j]
            # affine goal map in rest coordinates: goal = T (G x0 + h) + cm
            for i in range(3):
                for j in range(3):
                    lm[k, i, j] = (t[k, i, 0] * g[k, 0, j] + t[k, i, 1] * g[k, 1, j]
                                   + t[k, i, 2] * g[k, 2, j])
                lb[k, i] = (t[k, i, 0] * hv[k, 0] + t[k, i, 1] * hv[k, 1]
                            + t[k, i, 2] * hv[k, 2] + ref[k, i])


@njit(**JIT)
def plastic_update(apq, aqq3, scale, quat, sp, c_yield, c_creep, c_max, h, changed, q4, m3a,
                   m3b, m3c, n4, v4):
    """Plasticity (Eq. 24-27) of every cluster from this step's A_pq-hat (``apq``).

    Updates the plastic state ``sp``; ``changed`` marks the clusters whose rest shape
    must be refreshed.  Returns the number of changed clusters.
    """
    nchanged = 0
    for k in range(apq.shape[0]):
        changed[k] = False
        s_k = scale[k]
        for i in range(3):
            for j in range(3):
                m3a[i, j] = apq[k, i, j]
        # A = A_pq A_qq (linear part), its polar decomposition A = R_A S (Eq. 24-25)
        matmul(m3a, aqq3[k], m3c)
        for i in range(3):
            for j in range(3):
                m3c[i, j] /= s_k
        for i in range(4):
            q4[i] = quat[k, i]
        extract_rotation(m3c, q4, m3b, n4, v4)
        # S - I (symmetrised) into m3a
        for i in range(3):
            for j in range(3):
                s = 0.0
                for u in range(3):
                    s += m3b[u, i] * m3c[u, j]
                m3a[i, j] = s
        for i in range(3):
            for j in range(i, 3):
                avg = 0.5 * (m3a[i, j] + m3a[j, i])
                m3a[i, j] = avg
                m3a[j, i] = avg
            m3a[i, i] -= 1.0
        # A is blind along directions the rest shape does not span (flat, line-like,
        # single-point clusters: A_qq is a pseudo-inverse): S = I there, not 0, or
        # such a cluster flows plastically at rest
        _add_null_projector(aqq3[k], m3a, n4[:3, :3], v4[:3, :3])
        for i in range(3):
            for j in range(3):
                m3b[i, j] = m3a[i, j]
        nrm = norm2(m3b, n4[:3, :3], v4[:3, :3])
        if nrm > c_yield and c_creep > 0.0 and np.isfinite(nrm):
            tc = h * c_creep
            if tc > 1.0:
                tc = 1.0
            # Sp <- (I + h c_creep (S - I)) Sp
            for i in range(3):
                for j in range(3):
                    s = 0.0
                    for u in range(3):
                        s += ((1.0 if i == u else 0.0) + tc * m3a[i, u]) * sp[k, u, j]
                    m3c[i, j] = s
            dt = det3(m3c)
            if dt > 1e-12 and np.isfinite(dt):
                f = 1.0 / np.cbrt(dt)
                for i in range(3):
                    for j in range(3):
                        m3c[i, j] *= f
                _cap_plastic(m3c, c_max, m3a, n4[:3, :3], v4[:3, :3])
                for i in range(3):
                    for j in range(3):
                        sp[k, i, j] = m3c[i, j]
                changed[k] = True
                nchanged += 1
    return nchanged


# ---------------------------------------------------------------------------------------
# Rest-shape moments (A_qq, A~_qq): at build time and when the plastic state changes.
# ---------------------------------------------------------------------------------------

@njit(**JIT)
def moments(x0, m, ptr, cl, g, hv, wsum, which, need3, need9, sq, mom3, mom9, f9):
    """sum w q~ and the centred moments sum w (q - mean)(q - mean)^T for ``which``.

    The quadratic features q~ are centred per cluster (their squares have a non-zero
    mean): the goals then share the cluster's centre of mass, which keeps linear momentum,
    and an exactly quadratic deformation is reproduced.
    """
    nk = g.shape[0]
    for k in range(nk):
        if which[k]:
            for i in range(9):
                sq[k, i] = 0.0
                for j in range(9):
                    if need9:
                        mom9[k, i, j] = 0.0
            for i in range(3):
                for j in range(3):
                    if need3:
                        mom3[k, i, j] = 0.0
    single = ptr.shape[0] == 0
    n = x0.shape[0]
    for i in range(n):
        a0, a1, a2 = x0[i, 0], x0[i, 1], x0[i, 2]
        if single:
            j0, j1, w = 0, 1, m[i]
        else:
            j0, j1 = ptr[i], ptr[i + 1]
            w = m[i] / (j1 - j0)
        for j in range(j0, j1):
            k = 0 if single else cl[j]
            if not which[k]:
                continue
            q0, q1, q2 = _qhat(g, hv, k, a0, a1, a2)
            if need9:
                quad_features(q0, q1, q2, f9)
            else:                           # rigid/linear: no quadratic terms at all
                f9[0], f9[1], f9[2] = q0, q1, q2
            for u in range(9 if need9 else 3):
                sq[k, u] += w * f9[u]
            if need3:
                for u in range(3):
                    for z in range(3):
                        mom3[k, u, z] += w * f9[u] * f9[z]
            if need9:
                for u in range(9):
                    wu = w * f9[u]
                    for z in range(u, 9):
                        mom9[k, u, z] += wu * f9[z]
    for k in range(nk):
        if which[k]:
            inv_w = 1.0 / wsum[k]
            if need9:
                for u in range(9):
                    for z in range(u, 9):
                        mom9[k, u, z] -= sq[k, u] * sq[k, z] * inv_w
                    for z in range(u):
                        mom9[k, u, z] = mom9[k, z, u]
            if need3:
                for u in range(3):
                    for z in range(3):
                        mom3[k, u, z] -= sq[k, u] * sq[k, z] * inv_w


@njit(**JIT)
def invert_moments(which, need3, need9, mom3, mom9, aqq3, aqq9, w3a, w3b, w9a, w9b, rcond):
    """A_qq = (sum w q q^T)^+ and A~_qq = (sum w q~ q~^T)^+ (robust pseudo-inverses)."""
    for k in range(which.shape[0]):
        if which[k]:
            if need3:
                pinv_sym(mom3[k], aqq3[k], w3a, w3b, rcond)
            if need9:
                pinv_sym(mom9[k], aqq9[k], w9a, w9b, rcond)


# ---------------------------------------------------------------------------------------
# Kinematic particles, torque, damping, body pose
# ---------------------------------------------------------------------------------------

@njit(**JIT)
def gather_rows(src, idx, out):
    """out[p] = src[idx[p]] (used to remember kinematic particles' start positions)."""
    for p in range(idx.shape[0]):
        for j in range(3):
            out[p, j] = src[idx[p], j]


@njit(**JIT)
def apply_kinematic(quad, x, v, x0, m, ptr, cl, g, hv, ref, part, idx, tgt, prev, h):
    """Kinematic particles land exactly on their targets with velocity (target - prev)/h.

    The accumulators for the next step already hold these particles' integrated
    positions: their contribution is swapped for the one at the target.
    """
    single = ptr.shape[0] == 0
    for p in range(idx.shape[0]):
        i = idx[p]
        a0, a1, a2 = x0[i, 0], x0[i, 1], x0[i, 2]
        if single:
            j0, j1, w = 0, 1, m[i]
        else:
            j0, j1 = ptr[i], ptr[i + 1]
            w = m[i] / (j1 - j0)
        for j in range(j0, j1):
            k = 0 if single else cl[j]
            q0, q1, q2 = _qhat(g, hv, k, a0, a1, a2)
            d0 = tgt[p, 0] - x[i, 0]
            d1 = tgt[p, 1] - x[i, 1]
            d2 = tgt[p, 2] - x[i, 2]
            if quad:
                _acc_quad(part[0, k], w, d0, d1, d2, q0, q1, q2)
            else:
                _acc_lin(part[0, k], w, d0, d1, d2, q0, q1, q2)
        for j in range(3):
            v[i, j] = (tgt[p, j] - prev[p, j]) / h
            x[i, j] = tgt[p, j]


@njit(**JIT)
def inertia(x, m, com, out):
    """Inertia tensor about ``com``: sum m (|r|^2 I - r r^T)."""
    for i in range(3):
        for j in range(3):
            out[i, j] = 0.0
    for i in range(x.shape[0]):
        r0 = x[i, 0] - com[0]
        r1 = x[i, 1] - com[1]
        r2 = x[i, 2] - com[2]
        w = m[i]
        rr = r0 * r0 + r1 * r1 + r2 * r2
        out[0, 0] += w * (rr - r0 * r0)
        out[1, 1] += w * (rr - r1 * r1)
        out[2, 2] += w * (rr - r2 * r2)
        out[0, 1] -= w * r0 * r1
        out[0, 2] -= w * r0 * r2
        out[1, 2] -= w * r1 * r2
    out[1, 0] = out[0, 1]
    out[2, 0] = out[0, 2]
    out[2, 1] = out[1, 2]


@njit(**JIT)
def damp_rigid(x, v, m, ptr, cl, ref, k_damp, lin, w3, m3a, m3b, m3c, m3d):
    """Damp velocities towards each cluster's rigid motion (v_cm + w x r), never the motion.

    Per cluster: v_cm = sum w v / W, L = sum w r x v, I = sum w (|r|^2 - r r^T),
    omega = I^+ L; each particle moves a fraction ``k_damp`` towards the mean of its
    clusters' rigid velocities.  Linear and angular momentum of every cluster are kept.
    ``lin`` (K, 13) and ``w3`` (K, 3) are scratch buffers.

    r = x - ref is taken about the centre of mass d = sum w r / W that ``ref`` holds only
    up to rounding: L and I are corrected to d (L - W d x v_cm, parallel axes).  Without
    that, a body flying at 1e10 m/s far from the origin got ``(sum w r) x v`` of rounding
    noise as angular momentum, and the damping spun it apart.
    """
    nk = ref.shape[0]
    for k in range(nk):
        for j in range(13):
            lin[k, j] = 0.0
        for j in range(3):
            w3[k, j] = 0.0
    single = ptr.shape[0] == 0
    n = x.shape[0]
    for i in range(n):
        if single:
            j0, j1, w = 0, 1, m[i]
        else:
            j0, j1 = ptr[i], ptr[i + 1]
            w = m[i] / (j1 - j0)
        for j in range(j0, j1):
            k = 0 if single else cl[j]
            r0 = x[i, 0] - ref[k, 0]
            r1 = x[i, 1] - ref[k, 1]
            r2 = x[i, 2] - ref[k, 2]
            v0, v1, v2 = v[i, 0], v[i, 1], v[i, 2]
            rr = r0 * r0 + r1 * r1 + r2 * r2
            lin[k, 0] += w
            lin[k, 1] += w * v0
            lin[k, 2] += w * v1
            lin[k, 3] += w * v2
            w3[k, 0] += w * r0
            w3[k, 1] += w * r1
            w3[k, 2] += w * r2
            lin[k, 4] += w * (r1 * v2 - r2 * v1)
            lin[k, 5] += w * (r2 * v0 - r0 * v2)
            lin[k, 6] += w * (r0 * v1 - r1 * v0)
            lin[k, 7] += w * (rr - r0 * r0)
            lin[k, 8] += w * (rr - r1 * r1)
            lin[k, 9] += w * (rr - r2 * r2)
            lin[k, 10] -= w * r0 * r1
            lin[k, 11] -= w * r1 * r2
            lin[k, 12] -= w * r2 * r0
    for k in range(nk):
        wk = lin[k, 0]
        for j in range(1, 4):
            lin[k, j] /= wk
        u0, u1, u2 = lin[k, 1], lin[k, 2], lin[k, 3]
        d0, d1, d2 = w3[k, 0] / wk, w3[k, 1] / wk, w3[k, 2] / wk
        # about the centre of mass: L - W d x v_cm, I - W (|d|^2 - d d^T)
        l0 = lin[k, 4] - wk * (d1 * u2 - d2 * u1)
        l1 = lin[k, 5] - wk * (d2 * u0 - d0 * u2)
        l2 = lin[k, 6] - wk * (d0 * u1 - d1 * u0)
        dd = d0 * d0 + d1 * d1 + d2 * d2
        m3a[0, 0] = lin[k, 7] - wk * (dd - d0 * d0)
        m3a[1, 1] = lin[k, 8] - wk * (dd - d1 * d1)
        m3a[2, 2] = lin[k, 9] - wk * (dd - d2 * d2)
        m3a[0, 1] = m3a[1, 0] = lin[k, 10] + wk * d0 * d1
        m3a[1, 2] = m3a[2, 1] = lin[k, 11] + wk * d1 * d2
        m3a[2, 0] = m3a[0, 2] = lin[k, 12] + wk * d2 * d0
        pinv_sym(m3a, m3b, m3c, m3d, 1e-12)
        o0 = m3b[0, 0] * l0 + m3b[0, 1] * l1 + m3b[0, 2] * l2
        o1 = m3b[1, 0] * l0 + m3b[1, 1] * l1 + m3b[1, 2] * l2
        o2 = m3b[2, 0] * l0 + m3b[2, 1] * l1 + m3b[2, 2] * l2
        w3[k, 0] = o0
        w3[k, 1] = o1
        w3[k, 2] = o2
        # rigid field v_cm + omega x (r - d) = (v_cm - omega x d) + omega x r
        lin[k, 1] = u0 - (o1 * d2 - o2 * d1)
        lin[k, 2] = u1 - (o2 * d0 - o0 * d2)
        lin[k, 3] = u2 - (o0 * d1 - o1 * d0)
    for i in range(n):
        if single:
            j0, j1 = 0, 1
        else:
            j0, j1 = ptr[i], ptr[i + 1]
        t0 = 0.0
        t1 = 0.0
        t2 = 0.0
        for j in range(j0, j1):
            k = 0 if single else cl[j]
            r0 = x[i, 0] - ref[k, 0]
            r1 = x[i, 1] - ref[k, 1]
            r2 = x[i, 2] - ref[k, 2]
            t0 += lin[k, 1] + w3[k, 1] * r2 - w3[k, 2] * r1
            t1 += lin[k, 2] + w3[k, 2] * r0 - w3[k, 0] * r2
            t2 += lin[k, 3] + w3[k, 0] * r1 - w3[k, 1] * r0
        inv = 1.0 / (j1 - j0)
        v[i, 0] += k_damp * (t0 * inv - v[i, 0])
        v[i, 1] += k_damp * (t1 * inv - v[i, 1])
        v[i, 2] += k_damp * (t2 * inv - v[i, 2])


# ---------------------------------------------------------------------------------------
# Multi-cluster bodies in the set layout.  Particles that belong to the same clusters form
# a *set* (on the paper's cube grid, (k + 1)^3 sets for k^3 clusters).  Inside a set every
# cluster's goal is a polynomial of the particle's rest offset y = x0 - o_s (degree 1 for
# rigid/linear, degree 2 for quadratic), so the mean of its clusters' goals (Eq. 23,
# algorithm.md note) is one 3 x 4 (3 x 10) matrix M_s per set, and the sums each cluster
# needs (Eq. 7-9, 21) follow from per-set sums U_s = sum m (x - r_s) phi(y)^T with
# phi(y) = [1, y, y0^2, y1^2, y2^2, y0 y1, y1 y2, y2 y0].  A step then reads and writes each
# particle once and costs about as much per particle as a single-cluster body, whatever
# the number of clusters per particle; the per-cluster work moves to the few set-cluster
# pairs (``sets_reduce``, ``sets_maps``).  ``part`` is (chunks, sets, 3 * nphi).
# ---------------------------------------------------------------------------------------

@njit(**JIT)
def _feature_map(g, hv, k, o0, o1, o2, quad, pm):
    """Cluster k's features in set coordinates: q~ = P phi(y) with P into ``pm`` (9 x 10).

    q-hat = G_k (y + o) + h_k = G_k y + b; the quadratic rows expand q-hat_a q-hat_c.
    """
    for a in range(3):
        pm[a, 0] = g[k, a, 0] * o0 + g[k, a, 1] * o1 + g[k, a, 2] * o2 + hv[k, a]
        pm[a, 1] = g[k, a, 0]
        pm[a, 2] = g[k, a, 1]
        pm[a, 3] = g[k, a, 2]
    if not quad:
        return
    for a in range(3):
        for l in range(4, 10):
            pm[a, l] = 0.0
    for r in range(6):
        a = r if r < 3 else r - 3                  # features 3..8: q0^2, q1^2, q2^2,
        c = r if r < 3 else (r - 2) % 3            # q0 q1, q1 q2, q2 q0
        ba = pm[a, 0]
        bc = pm[c, 0]
        row = 3 + r
        pm[row, 0] = ba * bc
        for j in range(3):
            pm[row, 1 + j] = ba * g[k, c, j] + bc * g[k, a, j]
            pm[row, 4 + j] = g[k, a, j] * g[k, c, j]
        pm[row, 7] = g[k, a, 0] * g[k, c, 1] + g[k, a, 1] * g[k, c, 0]
        pm[row, 8] = g[k, a, 1] * g[k, c, 2] + g[k, a, 2] * g[k, c, 1]
        pm[row, 9] = g[k, a, 2] * g[k, c, 0] + g[k, a, 0] * g[k, c, 2]


@njit(**JIT)
def sets_reduce(part, sptr, scl, scnt, sphi, sref, sorg, g, hv, ref, quad, out, wk, pm):
    """Per-cluster accumulators ``out`` (1, clusters, 12 or 30) from the per-set sums.

    sum_{i in s} w (x - ref_k) phi^T = (U_s + (r_s - ref_k) Phi_s^T) / n_s (w = m / n_s),
    then mapped to cluster k's features by its P.  ``wk`` (2, 3, 10), ``pm`` (9, 10).
    """
    nch = part.shape[0]
    ns = part.shape[1]
    nphi = 10 if quad else 4
    nq = 9 if quad else 3
    for k in range(out.shape[1]):
        for a in range(out.shape[2]):
            out[0, k, a] = 0.0
    u = wk[0]
    vb = wk[1]
    for s in range(ns):
        for a in range(3):
            for l in range(nphi):
                acc = 0.0
                for c in range(nch):
                    acc += part[c, s, a * nphi + l]
                u[a, l] = acc
        inv_n = 1.0 / scnt[s]
        for j in range(sptr[s], sptr[s + 1]):
            k = scl[j]
            _feature_map(g, hv, k, sorg[s, 0], sorg[s, 1], sorg[s, 2], quad, pm)
            for a in range(3):
                dr = sref[s, a] - ref[k, a]
                for l in range(nphi):
                    vb[a, l] = inv_n * (u[a, l] + dr * sphi[s, l])
                out[0, k, a] += vb[a, 0]
                for jj in range(nq):
                    acc = 0.0
                    for l in range(nphi):
                        acc += vb[a, l] * pm[jj, l]
                    out[0, k, 3 + a * nq + jj] += acc


@njit(**JIT)
def sets_maps(sptr, scl, scnt, sorg, g, hv, t, lm, lb, ref, quad, gm, sref, pm):
    """Goal maps ``gm`` (sets, 3, 10): mean over the set's clusters of each goal polynomial.

    Also ``sref`` <- mean of the set's cluster centres (the reference point of the per-set
    sums of the next step).
    """
    ns = gm.shape[0]
    nphi = 10 if quad else 4
    for s in range(ns):
        for a in range(3):
            sref[s, a] = 0.0
            for l in range(nphi):
                gm[s, a, l] = 0.0
        o0, o1, o2 = sorg[s, 0], sorg[s, 1], sorg[s, 2]
        for j in range(sptr[s], sptr[s + 1]):
            k = scl[j]
            for a in range(3):
                sref[s, a] += ref[k, a]
            if quad:
                # goal_k = T_k q~ + lb_k = (T_k P) phi + lb_k
                _feature_map(g, hv, k, o0, o1, o2, True, pm)
                for a in range(3):
                    for l in range(10):
                        acc = 0.0
                        for jj in range(9):
                            acc += t[k, a, jj] * pm[jj, l]
                        gm[s, a, l] += acc
                    gm[s, a, 0] += lb[k, a]
            else:
                # goal_k = lm_k x0 + lb_k with x0 = y + o
                for a in range(3):
                    gm[s, a, 0] += (lm[k, a, 0] * o0 + lm[k, a, 1] * o1 + lm[k, a, 2] * o2
                                    + lb[k, a])
                    gm[s, a, 1] += lm[k, a, 0]
                    gm[s, a, 2] += lm[k, a, 1]
                    gm[s, a, 3] += lm[k, a, 2]
        inv_n = 1.0 / scnt[s]
        for a in range(3):
            sref[s, a] *= inv_n
            for l in range(nphi):
                gm[s, a, l] *= inv_n


@njit(**JIT)
def _sets_int_lin(start, end, x, v, y0, sid, gm, ah, h, ax, ay, az, w0, w1, w2):
    """Rigid/linear goals: each run of one set with its 3 x 4 map in registers.

    ``ax, ay, az`` is the uniform acceleration (acc - ang x com), ``w`` the angular one.
    """
    torque = w0 != 0.0 or w1 != 0.0 or w2 != 0.0
    e2 = 0.0
    i = start
    while i < end:
        s = sid[i]
        m00, m01, m02, m03 = gm[s, 0, 0], gm[s, 0, 1], gm[s, 0, 2], gm[s, 0, 3]
        m10, m11, m12, m13 = gm[s, 1, 0], gm[s, 1, 1], gm[s, 1, 2], gm[s, 1, 3]
        m20, m21, m22, m23 = gm[s, 2, 0], gm[s, 2, 1], gm[s, 2, 2], gm[s, 2, 3]
        j = i + 1
        while j < end and sid[j] == s:
            j += 1
        for k in range(i, j):
            y_0, y_1, y_2 = y0[k, 0], y0[k, 1], y0[k, 2]
            p0, p1, p2 = x[k, 0], x[k, 1], x[k, 2]
            e0 = m00 + m01 * y_0 + m02 * y_1 + m03 * y_2 - p0
            e1 = m10 + m11 * y_0 + m12 * y_1 + m13 * y_2 - p1
            ee = m20 + m21 * y_0 + m22 * y_1 + m23 * y_2 - p2
            e2 += e0 * e0 + e1 * e1 + ee * ee
            if torque:
                v0 = v[k, 0] + ah * e0 + h * (ax + w1 * p2 - w2 * p1)
                v1 = v[k, 1] + ah * e1 + h * (ay + w2 * p0 - w0 * p2)
                v2 = v[k, 2] + ah * ee + h * (az + w0 * p1 - w1 * p0)
            else:
                v0 = v[k, 0] + ah * e0 + h * ax
                v1 = v[k, 1] + ah * e1 + h * ay
                v2 = v[k, 2] + ah * ee + h * az
            x[k, 0] = p0 + h * v0
            x[k, 1] = p1 + h * v1
            x[k, 2] = p2 + h * v2
            v[k, 0] = v0
            v[k, 1] = v1
            v[k, 2] = v2
        i = j
    return e2


@njit(**JIT)
def _sets_int_quad(start, end, x, v, y0, sid, gm, ah, h, ax, ay, az, w0, w1, w2):
    """Quadratic goals: gm[s] (3 x 10) times phi(y)."""
    e2 = 0.0
    for i in range(start, end):
        s = sid[i]
        y_0, y_1, y_2 = y0[i, 0], y0[i, 1], y0[i, 2]
        f4 = y_0 * y_0
        f5 = y_1 * y_1
        f6 = y_2 * y_2
        f7 = y_0 * y_1
        f8 = y_1 * y_2
        f9 = y_2 * y_0
        g0 = (gm[s, 0, 0] + gm[s, 0, 1] * y_0 + gm[s, 0, 2] * y_1 + gm[s, 0, 3] * y_2
              + gm[s, 0, 4] * f4 + gm[s, 0, 5] * f5 + gm[s, 0, 6] * f6 + gm[s, 0, 7] * f7
              + gm[s, 0, 8] * f8 + gm[s, 0, 9] * f9)
        g1 = (gm[s, 1, 0] + gm[s, 1, 1] * y_0 + gm[s, 1, 2] * y_1 + gm[s, 1, 3] * y_2
              + gm[s, 1, 4] * f4 + gm[s, 1, 5] * f5 + gm[s, 1, 6] * f6 + gm[s, 1, 7] * f7
              + gm[s, 1, 8] * f8 + gm[s, 1, 9] * f9)
        g2 = (gm[s, 2, 0] + gm[s, 2, 1] * y_0 + gm[s, 2, 2] * y_1 + gm[s, 2, 3] * y_2
              + gm[s, 2, 4] * f4 + gm[s, 2, 5] * f5 + gm[s, 2, 6] * f6 + gm[s, 2, 7] * f7
              + gm[s, 2, 8] * f8 + gm[s, 2, 9] * f9)
        p0, p1, p2 = x[i, 0], x[i, 1], x[i, 2]
        e0 = g0 - p0
        e1 = g1 - p1
        ee = g2 - p2
        e2 += e0 * e0 + e1 * e1 + ee * ee
        v0 = v[i, 0] + ah * e0 + h * (ax + w1 * p2 - w2 * p1)
        v1 = v[i, 1] + ah * e1 + h * (ay + w2 * p0 - w0 * p2)
        v2 = v[i, 2] + ah * ee + h * (az + w0 * p1 - w1 * p0)
        x[i, 0] = p0 + h * v0
        x[i, 1] = p1 + h * v1
        x[i, 2] = p2 + h * v2
        v[i, 0] = v0
        v[i, 1] = v1
        v[i, 2] = v2
    return e2


@njit(**JIT)
def _sets_int_range(start, end, quad, x, v, y0, sid, gm, alpha, h, acc, ang, com):
    """Eq. 13-14 for particles start..end with the set goal maps; returns sum |g - x|^2."""
    w0, w1, w2 = ang[0], ang[1], ang[2]
    # acc + ang x (p - com) = (acc - ang x com) + ang x p
    ax = acc[0] - (w1 * com[2] - w2 * com[1])
    ay = acc[1] - (w2 * com[0] - w0 * com[2])
    az = acc[2] - (w0 * com[1] - w1 * com[0])
    if quad:
        return _sets_int_quad(start, end, x, v, y0, sid, gm, alpha / h, h, ax, ay, az,
                              w0, w1, w2)
    return _sets_int_lin(start, end, x, v, y0, sid, gm, alpha / h, h, ax, ay, az, w0, w1, w2)


@njit(**JIT)
def _sets_acc_lin(start, end, x, y0, m, sid, sref, pc):
    """U_s += m (x - r_s) [1, y]^T for particles start..end, runs of one set in registers."""
    i = start
    while i < end:
        s = sid[i]
        r0, r1, r2 = sref[s, 0], sref[s, 1], sref[s, 2]
        a00 = a01 = a02 = a03 = 0.0
        a10 = a11 = a12 = a13 = 0.0
        a20 = a21 = a22 = a23 = 0.0
        while i < end and sid[i] == s:
            w = m[i]
            d0 = w * (x[i, 0] - r0)
            d1 = w * (x[i, 1] - r1)
            d2 = w * (x[i, 2] - r2)
            y_0, y_1, y_2 = y0[i, 0], y0[i, 1], y0[i, 2]
            a00 += d0
            a01 += d0 * y_0
            a02 += d0 * y_1
            a03 += d0 * y_2
            a10 += d1
            a11 += d1 * y_0
            a12 += d1 * y_1
            a13 += d1 * y_2
            a20 += d2
            a21 += d2 * y_0
            a22 += d2 * y_1
            a23 += d2 * y_2
            i += 1
        pc[s, 0] += a00
        pc[s, 1] += a01
        pc[s, 2] += a02
        pc[s, 3] += a03
        pc[s, 4] += a10
        pc[s, 5] += a11
        pc[s, 6] += a12
        pc[s, 7] += a13
        pc[s, 8] += a20
        pc[s, 9] += a21
        pc[s, 10] += a22
        pc[s, 11] += a23


@njit(**JIT)
def _sets_acc_quad(start, end, x, y0, m, sid, sref, pc):
    """U_s += m (x - r_s) phi(y)^T (3 x 10) for particles start..end."""
    i = start
    while i < end:
        s = sid[i]
        r0, r1, r2 = sref[s, 0], sref[s, 1], sref[s, 2]
        a00 = a01 = a02 = a03 = a04 = a05 = a06 = a07 = a08 = a09 = 0.0
        a10 = a11 = a12 = a13 = a14 = a15 = a16 = a17 = a18 = a19 = 0.0
        a20 = a21 = a22 = a23 = a24 = a25 = a26 = a27 = a28 = a29 = 0.0
        while i < end and sid[i] == s:
            w = m[i]
            d0 = w * (x[i, 0] - r0)
            d1 = w * (x[i, 1] - r1)
            d2 = w * (x[i, 2] - r2)
            y_0, y_1, y_2 = y0[i, 0], y0[i, 1], y0[i, 2]
            f4 = y_0 * y_0
            f5 = y_1 * y_1
            f6 = y_2 * y_2
            f7 = y_0 * y_1
            f8 = y_1 * y_2
            f9 = y_2 * y_0
            a00 += d0
            a01 += d0 * y_0
            a02 += d0 * y_1
            a03 += d0 * y_2
            a04 += d0 * f4
            a05 += d0 * f5
            a06 += d0 * f6
            a07 += d0 * f7
            a08 += d0 * f8
            a09 += d0 * f9
            a10 += d1
            a11 += d1 * y_0
            a12 += d1 * y_1
            a13 += d1 * y_2
            a14 += d1 * f4
            a15 += d1 * f5
            a16 += d1 * f6
            a17 += d1 * f7
            a18 += d1 * f8
            a19 += d1 * f9
            a20 += d2
            a21 += d2 * y_0
            a22 += d2 * y_1
            a23 += d2 * y_2
            a24 += d2 * f4
            a25 += d2 * f5
            a26 += d2 * f6
            a27 += d2 * f7
            a28 += d2 * f8
            a29 += d2 * f9
            i += 1
        pc[s, 0] += a00
        pc[s, 1] += a01
        pc[s, 2] += a02
        pc[s, 3] += a03
        pc[s, 4] += a04
        pc[s, 5] += a05
        pc[s, 6] += a06
        pc[s, 7] += a07
        pc[s, 8] += a08
        pc[s, 9] += a09
        pc[s, 10] += a10
        pc[s, 11] += a11
        pc[s, 12] += a12
        pc[s, 13] += a13
        pc[s, 14] += a14
        pc[s, 15] += a15
        pc[s, 16] += a16
        pc[s, 17] += a17
        pc[s, 18] += a18
        pc[s, 19] += a19
        pc[s, 20] += a20
        pc[s, 21] += a21
        pc[s, 22] += a22
        pc[s, 23] += a23
        pc[s, 24] += a24
        pc[s, 25] += a25
        pc[s, 26] += a26
        pc[s, 27] += a27
        pc[s, 28] += a28
        pc[s, 29] += a29


@njit(**JIT)
def _sets_acc_range(start, end, quad, x, y0, m, sid, sref, pc):
    if quad:
        _sets_acc_quad(start, end, x, y0, m, sid, sref, pc)
    else:
        _sets_acc_lin(start, end, x, y0, m, sid, sref, pc)


@njit(**JIT)
def _sets_acc_chunk(c, nch, quad, x, y0, m, sid, sref, part):
    n = x.shape[0]
    pc = part[c]
    for s in range(pc.shape[0]):
        for j in range(pc.shape[1]):
            pc[s, j] = 0.0
    _sets_acc_range((c * n) // nch, ((c + 1) * n) // nch, quad, x, y0, m, sid, sref, pc)


@njit(**JIT)
def sets_accumulate_serial(quad, x, y0, m, sid, sref, part):
    """Per-set sums of the current state (when it was changed outside a step), one thread."""
    nch = part.shape[0]
    for c in range(nch):
        _sets_acc_chunk(c, nch, quad, x, y0, m, sid, sref, part)


@njit(parallel=True, **JIT)
def sets_accumulate_parallel(quad, x, y0, m, sid, sref, part):
    """Per-set sums of the current state, one chunk per thread."""
    nch = part.shape[0]
    for c in prange(nch):
        _sets_acc_chunk(c, nch, quad, x, y0, m, sid, sref, part)


@njit(**JIT)
def _sets_int_chunk(c, nch, quad, x, v, y0, m, sid, gm, sref, alpha, h, acc, ang, com, part,
                    err, has_col, ground, boxes, spheres, thresh):
    """Integrate, collide and accumulate a chunk block by block (one pass over memory)."""
    n = x.shape[0]
    start = (c * n) // nch
    end = ((c + 1) * n) // nch
    pc = part[c]
    for s in range(pc.shape[0]):
        for j in range(pc.shape[1]):
            pc[s, j] = 0.0
    e2 = 0.0
    for bs in range(start, end, BLOCK):
        be = min(bs + BLOCK, end)
        e2 += _sets_int_range(bs, be, quad, x, v, y0, sid, gm, alpha, h, acc, ang, com)
        if has_col:
            _collide_range(bs, be, x, v, ground, boxes, spheres, thresh)
        _sets_acc_range(bs, be, quad, x, y0, m, sid, sref, pc)
    err[c] = e2


@njit(**JIT)
def sets_integrate_serial(quad, x, v, y0, m, sid, gm, sref, alpha, h, acc, ang, com, part,
                          err, has_col, ground, boxes, spheres, thresh):
    """Fused step pass of a set-layout body, one thread."""
    nch = part.shape[0]
    for c in range(nch):
        _sets_int_chunk(c, nch, quad, x, v, y0, m, sid, gm, sref, alpha, h, acc, ang, com,
                        part, err, has_col, ground, boxes, spheres, thresh)


@njit(parallel=True, **JIT)
def sets_integrate_parallel(quad, x, v, y0, m, sid, gm, sref, alpha, h, acc, ang, com, part,
                            err, has_col, ground, boxes, spheres, thresh):
    """Fused step pass of a set-layout body, one chunk per thread."""
    nch = part.shape[0]
    for c in prange(nch):
        _sets_int_chunk(c, nch, quad, x, v, y0, m, sid, gm, sref, alpha, h, acc, ang, com,
                        part, err, has_col, ground, boxes, spheres, thresh)


@njit(**JIT)
def sets_kinematic(quad, x, v, y0, m, sid, sref, part, idx, tgt, prev, h):
    """Kinematic particles onto their targets; their per-set sums moved to the target."""
    pc = part[0]
    for p in range(idx.shape[0]):
        i = idx[p]
        s = sid[i]
        w = m[i]
        y_0, y_1, y_2 = y0[i, 0], y0[i, 1], y0[i, 2]
        nphi = 10 if quad else 4
        for a in range(3):
            d = w * (tgt[p, a] - x[i, a])
            pc[s, a * nphi] += d
            pc[s, a * nphi + 1] += d * y_0
            pc[s, a * nphi + 2] += d * y_1
            pc[s, a * nphi + 3] += d * y_2
            if quad:
                pc[s, a * nphi + 4] += d * y_0 * y_0
                pc[s, a * nphi + 5] += d * y_1 * y_1
                pc[s, a * nphi + 6] += d * y_2 * y_2
                pc[s, a * nphi + 7] += d * y_0 * y_1
                pc[s, a * nphi + 8] += d * y_1 * y_2
                pc[s, a * nphi + 9] += d * y_2 * y_0
        for a in range(3):
            v[i, a] = (tgt[p, a] - prev[p, a]) / h
            x[i, a] = tgt[p, a]
