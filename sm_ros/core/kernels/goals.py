"""Per-cluster shape matching: sums -> x_cm, A_pq, A and the goal transform (Eq. 7-12, 18-22).

``solve_clusters`` reduces the per-cluster sums that the particle passes accumulated
(Eq. 7-9: x_cm and A_pq = sum m (x - x_cm) q^T, taken about the previous centre of mass so
large coordinates do not cancel) and builds each cluster's goal transform: rigid R
(Eq. 12), linear beta A' + (1 - beta) R with the volume-preserving A' (Eq. 18, see
``volume_preserving``), quadratic beta A~ + (1 - beta) R~ on the centred features q~
(Eq. 19-22, errata of Eq. 21 and 22).  ``moments``/``invert_moments`` give the rest-shape
moments A_qq = (sum m q q^T)^+ (Eq. 10) and A~_qq (Eq. 21) at build time and whenever the
plastic state changes; ``_qhat`` is a particle's plastic, scaled rest offset q-hat.
"""

import numpy as np
from numba import njit

from .jit import JIT, finite
from .linalg import det3, jacobi3, jacobi3_warm, matmul, pinv_sym
from .rotation import extract_rotation


@njit(**JIT)
def _logprod(s0, s1, s2, lam):
    """log prod_i (s_i + sqrt(s_i^2 + 4 lam)) / 2."""
    return (np.log(0.5 * (s0 + np.sqrt(max(s0 * s0 + 4.0 * lam, 0.0))))
            + np.log(0.5 * (s1 + np.sqrt(max(s1 * s1 + 4.0 * lam, 0.0))))
            + np.log(0.5 * (s2 + np.sqrt(max(s2 * s2 + 4.0 * lam, 0.0)))))


@njit(**JIT)
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


@njit(**JIT)
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


@njit(**JIT)
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


@njit(**JIT)
def _plus_prod(s0, s1, s2, mu):
    """prod_i (s_i + sqrt(s_i^2 + 4 mu)) / 2: compared with 1 it gives the sign of
    ``_unit_det_sum`` on the plus roots without three logarithms."""
    return (0.5 * (s0 + np.sqrt(max(s0 * s0 + 4.0 * mu, 0.0)))
            * (0.5 * (s1 + np.sqrt(max(s1 * s1 + 4.0 * mu, 0.0))))
            * (0.5 * (s2 + np.sqrt(max(s2 * s2 + 4.0 * mu, 0.0)))))


@njit(**JIT)
def _logx(sv, root, minus):
    """log of x = (s + r) / 2, or of the minus root (s - r) / 2 = -mu / ((s + r) / 2)."""
    return np.log(0.5 * (sv - root)) if minus else np.log(0.5 * (sv + root))


@njit(**JIT)
def _unit_det_sum(s0, s1, s2, mu, kmin):
    """sum_i log x_i(mu) with the minus root for index ``kmin`` (-1: plus roots only)."""
    r0 = np.sqrt(max(s0 * s0 + 4.0 * mu, 0.0))
    r1 = np.sqrt(max(s1 * s1 + 4.0 * mu, 0.0))
    r2 = np.sqrt(max(s2 * s2 + 4.0 * mu, 0.0))
    return _logx(s0, r0, kmin == 0) + _logx(s1, r1, kmin == 1) + _logx(s2, r2, kmin == 2)


@njit(**JIT)
def nearest_unit_det(f, out, wa, wv):
    """``nearest_unit_det_warm`` from a cold start (``jacobi3`` from the identity)."""
    return nearest_unit_det_warm(f=f, out=out, wa=wa, wv=wv, vw=wv, warm=False)


@njit(**JIT)
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


@njit(**JIT)
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


@njit(**JIT)
def unit_det_match(apq, nmat, c_s, rot, out, w1, w2, wa, wv, limit):
    """``unit_det_match_warm`` from a cold start."""
    return unit_det_match_warm(apq=apq, nmat=nmat, c_s=c_s, rot=rot, out=out, w1=w1, w2=w2,
                               wa=wa, wv=wv, limit=limit, vw=wv, warm=False)


@njit(**JIT)
def unit_det_match_warm(apq, nmat, c_s, rot, out, w1, w2, wa, wv, limit, vw, warm):
    """The linear mode's B = argmin sum w ||p - B q||^2 over det B = 1, into ``out``.

    ``apq`` = A_pq-hat (q in units of the cluster scale s), ``nmat`` = det(M)^(1/3) M^-1
    with M^2 = A_qq-hat (unit determinant, ``unit_det_frames``), ``c_s`` = s det(A_qq-hat)^(1/3).
    With C = B M the energy is ||C - A_pq M^-1||^2 + const and det C = det M: C is the
    nearest unit-determinant matrix to F = A_pq-hat N / c_s, scaled back, and B = C N.
    Stationarity makes A_pq B^T symmetric: no torque, and the goals derive from an energy.
    Stretches beyond [1 / limit, limit] are pulled back to R + t (B - R), which keeps
    A_pq B^T symmetric.  Returns False (use R) if det F <= 0.  ``vw``, ``warm``: the warm
    start of ``nearest_unit_det_warm``.  Twin: ``reference.unit_det_match``.
    """
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


@njit(inline='always', **JIT)
def _qhat(rest_lin, rest_off, k, a0, a1, a2):
    """q-hat = G_k x0 + h_k: the (plastic, scaled) rest offset of rest position ``a`` in
    cluster k (G_k = ``rest_lin[k]``, h_k = ``rest_off[k]``)."""
    return (rest_lin[k, 0, 0] * a0 + rest_lin[k, 0, 1] * a1 + rest_lin[k, 0, 2] * a2
            + rest_off[k, 0],
            rest_lin[k, 1, 0] * a0 + rest_lin[k, 1, 1] * a1 + rest_lin[k, 1, 2] * a2
            + rest_off[k, 1],
            rest_lin[k, 2, 0] * a0 + rest_lin[k, 2, 1] * a1 + rest_lin[k, 2, 2] * a2
            + rest_off[k, 2])


@njit(**JIT)
def quad_features(q0, q1, q2, feat):
    """q~ = [qx, qy, qz, qx^2, qy^2, qz^2, qx qy, qy qz, qz qx] (Eq. 19) into ``f``."""
    feat[0] = q0
    feat[1] = q1
    feat[2] = q2
    feat[3] = q0 * q0
    feat[4] = q1 * q1
    feat[5] = q2 * q2
    feat[6] = q0 * q1
    feat[7] = q1 * q2
    feat[8] = q2 * q0


@njit(inline='always', **JIT)
def _goal_quad(trans, k, q0, q1, q2):
    """T_c q~ (3x9 times the quadratic features of q-hat); the caller adds the centre."""
    f3 = q0 * q0
    f4 = q1 * q1
    f5 = q2 * q2
    f6 = q0 * q1
    f7 = q1 * q2
    f8 = q2 * q0
    out0 = (trans[k, 0, 0] * q0 + trans[k, 0, 1] * q1 + trans[k, 0, 2] * q2 + trans[k, 0, 3] * f3
            + trans[k, 0, 4] * f4 + trans[k, 0, 5] * f5 + trans[k, 0, 6] * f6 + trans[k, 0, 7] * f7
            + trans[k, 0, 8] * f8)
    out1 = (trans[k, 1, 0] * q0 + trans[k, 1, 1] * q1 + trans[k, 1, 2] * q2 + trans[k, 1, 3] * f3
            + trans[k, 1, 4] * f4 + trans[k, 1, 5] * f5 + trans[k, 1, 6] * f6 + trans[k, 1, 7] * f7
            + trans[k, 1, 8] * f8)
    out2 = (trans[k, 2, 0] * q0 + trans[k, 2, 1] * q1 + trans[k, 2, 2] * q2 + trans[k, 2, 3] * f3
            + trans[k, 2, 4] * f4 + trans[k, 2, 5] * f5 + trans[k, 2, 6] * f6 + trans[k, 2, 7] * f7
            + trans[k, 2, 8] * f8)
    return out0, out1, out2


@njit(**JIT)
def solve_clusters(part, wsum, sum_q, ref, quat, aqq3, aqq9, rest_lin, rest_off, scale, trans,
                   goal_lin, goal_off, mode, beta, apq, acc, m3a, m3b, m3c, m39, n4, v4, nmat,
                   cdet):
    """``solve_clusters_warm`` with the linear mode's eigen-solves started cold."""
    solve_clusters_warm(part=part, wsum=wsum, sum_q=sum_q, ref=ref, quat=quat, aqq3=aqq3,
                        aqq9=aqq9, rest_lin=rest_lin, rest_off=rest_off, scale=scale,
                        trans=trans, goal_lin=goal_lin, goal_off=goal_off, mode=mode,
                        beta=beta, apq=apq, acc=acc, m3a=m3a, m3b=m3b, m3c=m3c, m39=m39,
                        n4=n4, v4=v4, nmat=nmat, cdet=cdet, udv=nmat, warm=False)


@njit(**JIT)
def solve_clusters_warm(part, wsum, sum_q, ref, quat, aqq3, aqq9, rest_lin, rest_off, scale,
                        trans, goal_lin, goal_off, mode, beta, apq, acc, m3a, m3b, m3c, m39, n4,
                        v4, nmat, cdet, udv, warm):
    """Reduce the accumulators and build every cluster's goal transform.

    ``mode``: 0 rigid, 1 linear, 2 quadratic.  Outputs: ``ref`` <- centre of mass x_cm,
    ``quat`` <- rotation of A_pq, ``t`` (3x9; linear modes use the 3x3 block) and, for the
    rigid/linear modes, the affine goal map ``lm x0 + lb``; ``apq`` (clusters, 3, 3)
    <- A_pq-hat for ``plastic_update``; ``nmat``/``cdet``: ``unit_det_frames`` (linear).
    Plasticity is a kernel of its own, so a scene without it neither runs nor compiles it.
    ``udv`` (clusters, 3, 3), with ``warm``: each linear cluster's eigenvectors of its last
    unit-determinant match, the warm start of the next (``nearest_unit_det_warm``).
    """
    nchunks = part.shape[0]
    nk = part.shape[1]
    na = part.shape[2]
    nq = 9 if mode == 2 else 3
    # the linear mode's 3x3 scratch views, made once (not once a cluster)
    w1, w2, wa, wv = m39[:, 3:6], m39[:, 6:9], n4[:3, :3], v4[:3, :3]
    for k in range(nk):
        for a in range(na):
            s = 0.0
            for chunk in range(nchunks):
                s += part[chunk, k, a]
            acc[a] = s
        inv_w = 1.0 / wsum[k]
        d0 = acc[0] * inv_w
        d1 = acc[1] * inv_w
        d2 = acc[2] * inv_w
        # A_pq-hat (3 x nq) = sum w (x - cm) q^T, stored in m39
        for i in range(3):
            di = d0 if i == 0 else (d1 if i == 1 else d2)
            for j in range(nq):
                m39[i, j] = acc[3 + i * nq + j] - di * sum_q[k, j]
        ref[k, 0] += d0
        ref[k, 1] += d1
        ref[k, 2] += d2
        for i in range(3):
            for j in range(3):
                m3a[i, j] = m39[i, j]
                apq[k, i, j] = m39[i, j]
        extract_rotation(mat=m3a, quat=quat[k], rot=m3b, n4=n4, v4=v4)   # m3b = R
        s_k = scale[k]
        if mode == 2:
            for i in range(3):
                for j in range(9):
                    s = 0.0
                    for u in range(9):
                        s += m39[i, u] * aqq9[k, u, j]
                    rt = s_k * m3b[i, j] if j < 3 else 0.0
                    trans[k, i, j] = beta * s + (1.0 - beta) * rt
            # centred features: goal = T (q~ - mean q~) + cm, so lb = cm - T mean q~
            for i in range(3):
                s = ref[k, i]
                for j in range(9):
                    s -= trans[k, i, j] * sum_q[k, j] * inv_w
                goal_off[k, i] = s
        else:
            if mode == 1:
                matmul(m3a, aqq3[k], m3c)             # A * s = A_pq-hat A_qq-hat
                det = det3(m3c) / (s_k * s_k * s_k)
                # B = the unit-determinant minimiser (Eq. 18, see unit_det_match), written
                # into t's 3x3 block; inverted, flat or line-like (det A <= 0): R
                if (det > 1e-9 and finite(det) and cdet[k] > 0.0
                        and unit_det_match_warm(apq=m3a, nmat=nmat[k], c_s=s_k * cdet[k],
                                                rot=m3b, out=m3c, w1=w1, w2=w2, wa=wa,
                                                wv=wv, limit=STRETCH_LIMIT,
                                                vw=udv[k if warm else 0], warm=warm)):
                    for i in range(3):
                        for j in range(3):
                            trans[k, i, j] = s_k * (beta * m3c[i, j] + (1.0 - beta) * m3b[i, j])
                else:
                    for i in range(3):
                        for j in range(3):
                            trans[k, i, j] = s_k * m3b[i, j]
            else:
                for i in range(3):
                    for j in range(3):
                        trans[k, i, j] = s_k * m3b[i, j]
            # affine goal map in rest coordinates: goal = T (G x0 + h) + cm
            for i in range(3):
                for j in range(3):
                    goal_lin[k, i, j] = (trans[k, i, 0] * rest_lin[k, 0, j]
                                         + trans[k, i, 1] * rest_lin[k, 1, j]
                                         + trans[k, i, 2] * rest_lin[k, 2, j])
                goal_off[k, i] = (trans[k, i, 0] * rest_off[k, 0] + trans[k, i, 1] * rest_off[k, 1]
                            + trans[k, i, 2] * rest_off[k, 2] + ref[k, i])


@njit(**JIT)
def moments(x0, mass, ptr, cl, rest_lin, rest_off, wsum, which, need3, need9, sum_q, mom3, mom9,
            f9):
    """sum w q~ and the centred moments sum w (q - mean)(q - mean)^T for ``which``.

    The quadratic features q~ are centred per cluster (their squares have a non-zero
    mean): the goals then share the cluster's centre of mass, which keeps linear momentum,
    and an exactly quadratic deformation is reproduced.
    """
    nk = rest_lin.shape[0]
    for k in range(nk):
        if which[k]:
            for i in range(9):
                sum_q[k, i] = 0.0
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
            j0, j1, w = 0, 1, mass[i]
        else:
            j0, j1 = ptr[i], ptr[i + 1]
            w = mass[i] / (j1 - j0)
        for j in range(j0, j1):
            k = 0 if single else cl[j]
            if not which[k]:
                continue
            q0, q1, q2 = _qhat(rest_lin=rest_lin, rest_off=rest_off, k=k, a0=a0, a1=a1, a2=a2)
            if need9:
                quad_features(q0, q1, q2, f9)
            else:                           # rigid/linear: no quadratic terms at all
                f9[0], f9[1], f9[2] = q0, q1, q2
            for u in range(9 if need9 else 3):
                sum_q[k, u] += w * f9[u]
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
                        mom9[k, u, z] -= sum_q[k, u] * sum_q[k, z] * inv_w
                    for z in range(u):
                        mom9[k, u, z] = mom9[k, z, u]
            if need3:
                for u in range(3):
                    for z in range(3):
                        mom3[k, u, z] -= sum_q[k, u] * sum_q[k, z] * inv_w


@njit(**JIT)
def invert_moments(which, need3, need9, mom3, mom9, aqq3, aqq9, w3a, w3b, w9a, w9b, rcond):
    """A_qq = (sum w q q^T)^+ and A~_qq = (sum w q~ q~^T)^+ (robust pseudo-inverses)."""
    for k in range(which.shape[0]):
        if which[k]:
            if need3:
                pinv_sym(mat=mom3[k], out=aqq3[k], wa=w3a, wv=w3b, rcond=rcond)
            if need9:
                pinv_sym(mat=mom9[k], out=aqq9[k], wa=w9a, wv=w9b, rcond=rcond)
