"""The linear mode's goal matrix (Eq. 18): the unit-determinant minimiser B of a cluster's
matching energy and the safeguards around it.

``unit_det_match`` finds B = C M^-1 with C the closest matrix of determinant det M to
F = A_pq M^-1 (A_qq = M^2; ``unit_det_frames`` precomputes M per cluster): the same
singular vectors as F, each singular value moved to the root of x (x - s) = mu
(``nearest_unit_det``, warm started from the last step's vectors).  A B whose singular
values leave [1/limit, limit] is blended towards R (``_stretch_ok``);
``volume_preserving`` is the paper's A / cbrt(det A) with the same safeguards.
"""

import numpy as np
from numba import njit

from .jit import JIT_NO_REFCOUNT, finite
from .linalg import det3, jacobi3, jacobi3_warm, matmul


@njit(**JIT_NO_REFCOUNT)
def _logprod(s0, s1, s2, lam):
    """log prod_i (s_i + sqrt(s_i^2 + 4 lam)) / 2."""
    return (np.log(0.5 * (s0 + np.sqrt(max(s0 * s0 + 4.0 * lam, 0.0))))
            + np.log(0.5 * (s1 + np.sqrt(max(s1 * s1 + 4.0 * lam, 0.0))))
            + np.log(0.5 * (s2 + np.sqrt(max(s2 * s2 + 4.0 * lam, 0.0)))))


@njit(**JIT_NO_REFCOUNT)
def _plus_roots(s0, s1, s2, lo, hi, ftol, xtol):
    """x_i = (s_i + sqrt(s_i^2 + 4 mu)) / 2 at the root mu in [lo, hi] of sum_i log x_i.

    The sum increases with mu; safeguarded Newton (a step leaving the bracket bisects),
    stopping at |sum| < ``ftol`` or a bracket narrower than ``xtol`` (1 + |mu|).  It
    starts from the first-order root mu = -sum log s_i / sum s_i^-2 (x_i ~ s_i + mu / s_i)
    where that lies inside the bracket: near det 1, two steps instead of about six from
    the bracket's middle.  Shared by ``volume_preserving`` and ``nearest_unit_det``.
    """
    mu = -np.log(s0 * s1 * s2) / (1.0 / (s0 * s0) + 1.0 / (s1 * s1) + 1.0 / (s2 * s2))
    if not (lo < mu < hi):
        mu = 0.5 * (lo + hi)
    x0 = x1 = x2 = 1.0
    for _ in range(100):
        r0 = np.sqrt(max(s0 * s0 + 4.0 * mu, 0.0))
        r1 = np.sqrt(max(s1 * s1 + 4.0 * mu, 0.0))
        r2 = np.sqrt(max(s2 * s2 + 4.0 * mu, 0.0))
        x0 = 0.5 * (s0 + r0)
        x1 = 0.5 * (s1 + r1)
        x2 = 0.5 * (s2 + r2)
        fv = np.log(x0 * x1 * x2)          # one log a step (the product stays in range)
        if abs(fv) < ftol or hi - lo < xtol * (1.0 + abs(mu)):
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
    return x0, x1, x2


@njit(**JIT_NO_REFCOUNT)
def _times_v_diag_vt(a, wv, d0, d1, d2, out):
    """out = a V diag(d) V^T (3x3; V the columns of ``wv``)."""
    for i in range(3):
        for j in range(3):
            s = 0.0
            for u in range(3):
                vv = (wv[u, 0] * d0 * wv[j, 0] + wv[u, 1] * d1 * wv[j, 1]
                      + wv[u, 2] * d2 * wv[j, 2])
                s += a[i, u] * vv
            out[i, j] = s


#: Largest stretch (and 1 / smallest) of the volume-preserving linear transform A'.
STRETCH_LIMIT = 2.0


@njit(**JIT_NO_REFCOUNT)
def volume_preserving(a, out, wa, wv, limit):
    """A' = the det-1 matrix closest to ``a`` (3x3) with its singular vectors, into ``out``.

    Eq. 18 divides A by cbrt(det A).  That uniform rescaling is not the minimiser of any
    energy: a body flattened on impact (det A -> 0) gets goals far outside it, and the
    goal forces pump energy into a bouncing linear body until it flies apart.  Instead
    the singular values s_i of A are replaced by the closest x_i (least squares) with
    prod x_i = 1, i.e. x_i = (s_i + sqrt(s_i^2 + 4 lam)) / 2 with lam found by Newton's
    method (safeguarded by bisection), and then limited to [1 / limit, limit] so no goal
    shape is stretched without bound. ``out[:, :3]`` receives A V diag(x / s) V^T. Returns
    False (no volume-preserving transform exists) for det A <= 0 or a flat A: the caller
    falls back to R.
    """
    for i in range(3):
        for j in range(3):
            s = 0.0
            for u in range(3):
                s += a[u, i] * a[u, j]
            wa[i, j] = s
    det = det3(a)
    if not (det > 1e-9) or not finite(det):
        return False
    jacobi3(wa, wv, 50)
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
    x0 = x1 = x2 = 1.0
    if ok:
        x0, x1, x2 = _plus_roots(s0=s0, s1=s1, s2=s2, lo=lo, hi=hi, ftol=1e-14, xtol=1e-15)
    else:                       # no root in reach: the uniform rescaling of Eq. 18
        c = 1.0 / np.cbrt(s0 * s1 * s2)
        x0, x1, x2 = s0 * c, s1 * c, s2 * c
    _times_v_diag_vt(a=a, wv=wv, d0=min(max(x0, 1.0 / limit), limit) / s0,
                     d1=min(max(x1, 1.0 / limit), limit) / s1,
                     d2=min(max(x2, 1.0 / limit), limit) / s2, out=out)
    return True


@njit(**JIT_NO_REFCOUNT)
def _plus_prod(s0, s1, s2, mu):
    """prod_i (s_i + sqrt(s_i^2 + 4 mu)) / 2: compared with 1 it gives the sign of
    ``_unit_det_sum`` on the plus roots without three logarithms."""
    return (0.5 * (s0 + np.sqrt(max(s0 * s0 + 4.0 * mu, 0.0)))
            * (0.5 * (s1 + np.sqrt(max(s1 * s1 + 4.0 * mu, 0.0))))
            * (0.5 * (s2 + np.sqrt(max(s2 * s2 + 4.0 * mu, 0.0)))))


@njit(**JIT_NO_REFCOUNT)
def _logx(sv, root, minus):
    """log of x = (s + r) / 2, or of the minus root (s - r) / 2 = -mu / ((s + r) / 2)."""
    return np.log(0.5 * (sv - root)) if minus else np.log(0.5 * (sv + root))


@njit(**JIT_NO_REFCOUNT)
def _unit_det_sum(s0, s1, s2, mu, kmin):
    """sum_i log x_i(mu) with the minus root for index ``kmin`` (-1: plus roots only)."""
    r0 = np.sqrt(max(s0 * s0 + 4.0 * mu, 0.0))
    r1 = np.sqrt(max(s1 * s1 + 4.0 * mu, 0.0))
    r2 = np.sqrt(max(s2 * s2 + 4.0 * mu, 0.0))
    return _logx(s0, r0, kmin == 0) + _logx(s1, r1, kmin == 1) + _logx(s2, r2, kmin == 2)


@njit(**JIT_NO_REFCOUNT)
def nearest_unit_det(f, out, wa, wv):
    """``nearest_unit_det_warm`` from a cold start (``jacobi3`` from the identity)."""
    return nearest_unit_det_warm(f=f, out=out, wa=wa, wv=wv, vw=wv, warm=np.bool_(False))


@njit(**JIT_NO_REFCOUNT)
def nearest_unit_det_warm(f, out, wa, wv, vw, warm):
    """C = argmin ||C - f||_F over det C = 1 (3x3), into ``out``; False if det f <= 0.

    C shares f's singular vectors; its singular values x_i solve x_i^2 - s_i x_i = mu with
    prod x_i = 1.  On the plus roots x_i = (s_i + sqrt(s_i^2 + 4 mu)) / 2 the product grows
    with mu from mu = -s_min^2 / 4 (safeguarded Newton); when it is above 1 already there,
    the root is on the minus root of the smallest s (a strongly flattened f; bisection).
    ``out`` = f V diag(x / s) V^T, so f out^T is symmetric to rounding whatever the
    accuracy of V.  With ``warm`` the eigenvectors V of f^T f start from ``vw`` (in/out,
    orthonormal 3x3: the last step's V of the same cluster; ``linalg.jacobi3_warm``, whose
    scratch is ``out``): f^T f is invariant under rotations of the cluster and changes
    only with its deformation, so a step needs one or two sweeps of small rotations
    instead of three or four.  NumPy twin: ``reference.nearest_unit_det``.
    """
    for i in range(3):
        for j in range(3):
            s = 0.0
            for u in range(3):
                s += f[u, i] * f[u, j]
            wa[i, j] = s
    d = det3(f)
    if not (d > 0.0) or not finite(d):
        return False
    if warm:
        jacobi3_warm(wa, wv, vw, out)
    else:
        jacobi3(wa, wv, 50)
    s0 = np.sqrt(max(wa[0, 0], 0.0))
    s1 = np.sqrt(max(wa[1, 1], 0.0))
    s2 = np.sqrt(max(wa[2, 2], 0.0))
    smin = min(s0, min(s1, s2))
    if not (smin > 0.0):
        return False
    kmin = 0 if smin == s0 else (1 if smin == s1 else 2)
    lo = -0.25 * smin * smin
    x0 = x1 = x2 = 1.0
    if _plus_prod(s0=s0, s1=s1, s2=s2, mu=lo) <= 1.0:     # sum of logs <= 0
        hi = 0.0
        if _plus_prod(s0=s0, s1=s1, s2=s2, mu=0.0) < 1.0:
            lo, hi = 0.0, 1.0            # at mu = 1 every x_i >= 1
        x0, x1, x2 = _plus_roots(s0=s0, s1=s1, s2=s2, lo=lo, hi=hi, ftol=1e-15, xtol=1e-16)
    else:
        hi = 0.0                         # minus root of the smallest: sum falls to -inf
        for _ in range(200):
            mu = 0.5 * (lo + hi)
            if not (lo < mu < hi):
                break
            if _unit_det_sum(s0=s0, s1=s1, s2=s2, mu=mu, kmin=kmin) > 0.0:
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
    _times_v_diag_vt(a=f, wv=wv, d0=x0 / s0, d1=x1 / s1, d2=x2 / s2, out=out)
    return True


@njit(**JIT_NO_REFCOUNT)
def _stretch_ok(b, rot, blend, work, wa, wv, limit):
    """Whether R + t (B - R) has every singular value in [1 / limit, limit].

    Decided without an eigen-solve when the bounds sigma_max <= ||W||_F and sigma_min >=
    det W / ||adj W||_F (W = R + t (B - R)) already show it; else from the eigenvalues
    of W^T W.
    """
    for i in range(3):
        for j in range(3):
            work[i, j] = rot[i, j] + blend * (b[i, j] - rot[i, j])
    fro = 0.0
    for i in range(3):
        for j in range(3):
            fro += work[i, j] * work[i, j]
    det = det3(work)
    lim2 = limit * limit
    if fro <= lim2 and det > 0.0:
        adj = 0.0                   # ||adj W||_F^2: the 2x2 minors
        for i in range(3):
            i1, i2 = (i + 1) % 3, (i + 2) % 3
            for j in range(3):
                j1, j2 = (j + 1) % 3, (j + 2) % 3
                c = work[i1, j1] * work[i2, j2] - work[i1, j2] * work[i2, j1]
                adj += c * c
        if adj <= lim2 * det * det:
            return True
    for i in range(3):
        for j in range(3):
            s = 0.0
            for u in range(3):
                s += work[u, i] * work[u, j]
            wa[i, j] = s
    jacobi3(wa, wv, 50)
    lo2 = 1.0 / (limit * limit)
    hi2 = limit * limit
    for i in range(3):
        if not (lo2 <= wa[i, i] <= hi2):
            return False
    return True


@njit(**JIT_NO_REFCOUNT)
def unit_det_match(apq, nmat, c_s, rot, out, work, limit):
    """``unit_det_match_warm`` from a cold start."""
    return unit_det_match_warm(apq=apq, nmat=nmat, c_s=c_s, rot=rot, out=out, work=work,
                               limit=limit, vw=work[3], warm=np.bool_(False))


@njit(**JIT_NO_REFCOUNT)
def unit_det_match_warm(apq, nmat, c_s, rot, out, work, limit, vw, warm):
    """The linear mode's B = argmin sum w ||p - B q||^2 over det B = 1, into ``out``.

    ``apq`` = A_pq-hat (q in units of the cluster scale s), ``nmat`` = det(M)^(1/3) M^-1
    with M^2 = A_qq-hat (unit determinant, ``unit_det_frames``), ``c_s`` = s det(A_qq-hat)^(1/3).
    With C = B M the energy is ||C - A_pq M^-1||^2 + const and det C = det M: C is the
    nearest unit-determinant matrix to F = A_pq-hat N / c_s, scaled back, and B = C N.
    Stationarity makes A_pq B^T symmetric: no torque, and the goals derive from an energy.
    Stretches beyond [1 / limit, limit] are pulled back to R + t (B - R), which keeps
    A_pq B^T symmetric.  Returns False (use R) if det F <= 0.  ``vw``, ``warm``: the warm
    start of ``nearest_unit_det_warm``; ``work``: four 3 x 3 scratch matrices (the first
    two may be views).  Twin: ``reference.unit_det_match``.
    """
    w1, w2, wa, wv = work
    inv = 1.0 / c_s
    for i in range(3):
        for j in range(3):
            w1[i, j] = (apq[i, 0] * nmat[0, j] + apq[i, 1] * nmat[1, j]
                        + apq[i, 2] * nmat[2, j]) * inv
    if not nearest_unit_det_warm(f=w1, out=w2, wa=wa, wv=wv, vw=vw, warm=warm):
        return False
    matmul(w2, nmat, out)
    if _stretch_ok(b=out, rot=rot, blend=1.0, work=w1, wa=wa, wv=wv, limit=limit):
        return True
    lo = 0.0
    hi = 1.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if _stretch_ok(b=out, rot=rot, blend=mid, work=w1, wa=wa, wv=wv, limit=limit):
            lo = mid
        else:
            hi = mid
    for i in range(3):
        for j in range(3):
            out[i, j] = rot[i, j] + lo * (out[i, j] - rot[i, j])
    return True


@njit(**JIT_NO_REFCOUNT)
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
        jacobi3(wa, wv, 50)
        l0, l1, l2 = wa[0, 0], wa[1, 1], wa[2, 2]
        lmax = max(l0, max(l1, l2))
        if not (min(l0, min(l1, l2)) > rcond * lmax) or not (lmax > 0.0):
            cdet[k] = 0.0
            for i in range(3):
                for j in range(3):
                    nmat[k, i, j] = 0.0
            continue
        cbrt_det = np.cbrt(l0 * l1 * l2)
        cdet[k] = cbrt_det
        e0 = np.sqrt(cbrt_det / l0)
        e1 = np.sqrt(cbrt_det / l1)
        e2 = np.sqrt(cbrt_det / l2)
        for i in range(3):
            for j in range(3):
                nmat[k, i, j] = (wv[i, 0] * e0 * wv[j, 0] + wv[i, 1] * e1 * wv[j, 1]
                                 + wv[i, 2] * e2 * wv[j, 2])
