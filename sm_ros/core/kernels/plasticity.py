"""Plasticity (Eq. 24-27, with the erratum of Eq. 26).

From this step's A = A_pq A_qq: its symmetric factor S (polar decomposition, Eq. 24-25);
if ||S - I||_2 > c_yield the plastic state creeps, S^P <- (I + h c_creep (S - I)) S^P,
normalised to det S^P = 1 and capped at ||S^P - I||_2 <= c_max (Eq. 27, tested on S^P).
A cluster whose S^P changed gets its rest shape and A_qq refreshed (``refresh_rest``).
"""

from collections import namedtuple

import numpy as np
from numba import njit

from .goals import invert_moments, moments
from .jit import JIT_NO_REFCOUNT, finite
from .linalg import det3, jacobi_eigh, matmul, norm2
from .rotation import extract_rotation
from .unit_det import unit_det_frames

#: Below this fraction of the largest eigenvalue a rest moment counts as zero (its
#: pseudo-inverse drops the direction).
RCOND = 1e-10

#: A body's rest shape as ``refresh_rest`` rebuilds it: the rest positions as their (3, N)
#: block ``x0t`` and the masses, the memberships (ptr, cluster_ids), the plastic state S^P
#: and each cluster's scale, the rest moments kept from the build (centres ``cm0``, sum w d,
#: sum w d d^T, weights), and what the refresh writes: the rest map (rest_lin, rest_off),
#: sum w q, the moments and their pseudo-inverses, the linear mode's unit-determinant frames.
RestShape = namedtuple('RestShape', (
    'x0t mass ptr cluster_ids s_plastic scale cm0 dsum0 cov0 wsum rest_lin rest_off sum_q '
    'mom3 mom9 aqq3 aqq9 nmat cdet').split())

#: The plastic flow's buffers: the clusters whose S^P changed this step, and scratch (a
#: 9-vector and two 9 x 9 for ``refresh_rest``, a quaternion for ``plastic_update``).
PlasticWork = namedtuple('PlasticWork', 'changed features9 m9a m9b quat')


@njit(**JIT_NO_REFCOUNT)
def _cap_plastic(s_plastic, c_max, m3, wa, wv):
    """Sp <- Sp / cbrt(det Sp), then pulled towards I until ||Sp - I||_2 <= c_max (Eq. 27).

    The write-up's cap ``I + c_max (Sp - I)/||Sp - I||`` followed by the volume
    normalisation can land slightly above c_max again; bisecting on the blend
    t in [0, 1] of ``normalise(I + t (Sp - I))`` keeps both det Sp = 1 and the cap exact.
    """
    for i in range(3):
        for j in range(3):
            m3[i, j] = s_plastic[i, j] - (1.0 if i == j else 0.0)
    if norm2(m3, wa, wv) <= c_max:
        return
    lo = 0.0
    hi = 1.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        for i in range(3):
            for j in range(3):
                wa[i, j] = ((1.0 if i == j else 0.0)
                            + mid * (s_plastic[i, j] - (1.0 if i == j else 0.0)))
        det = det3(wa)
        ok = False
        if det > 0.0:
            inv_cbrt = 1.0 / np.cbrt(det)
            for i in range(3):
                for j in range(3):
                    m3[i, j] = wa[i, j] * inv_cbrt - (1.0 if i == j else 0.0)
            ok = norm2(m3, wa, wv) <= c_max
        if ok:
            lo = mid
        else:
            hi = mid
    for i in range(3):
        for j in range(3):
            wa[i, j] = (1.0 if i == j else 0.0) + lo * (s_plastic[i, j] - (1.0 if i == j else 0.0))
    inv_cbrt = 1.0 / np.cbrt(det3(wa))
    for i in range(3):
        for j in range(3):
            s_plastic[i, j] = wa[i, j] * inv_cbrt


@njit(**JIT_NO_REFCOUNT)
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


@njit(**JIT_NO_REFCOUNT)
def plastic_update(apq, clusters, s_plastic, law, changed, scratch):
    """Plasticity (Eq. 24-27) of every cluster from this step's A_pq-hat (``apq``);
    ``clusters`` = (A_qq (``aqq3``), scale, rotation quaternion), ``law`` = (yield, creep,
    max, h), ``scratch`` = (a 4-vector, three 3 x 3, two 4 x 4, two C-contiguous 3 x 3).

    Updates the plastic state ``s_plastic``; ``changed`` marks the clusters whose rest
    shape must be refreshed.  Returns the number of changed clusters.
    """
    aqq3, scale, quat = clusters
    c_yield, c_creep, c_max, h = law
    q4, m3a, m3b, m3c, n4, v4, wa, wv = scratch
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
        extract_rotation(mat=m3c, quat=q4, rot=m3b, n4=n4, v4=v4)
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
        _add_null_projector(aqq3[k], m3a, wa, wv)
        for i in range(3):
            for j in range(3):
                m3b[i, j] = m3a[i, j]
        nrm = norm2(m3b, wa, wv)
        if nrm > c_yield and c_creep > 0.0 and finite(nrm):
            tc = h * c_creep
            if tc > 1.0:
                tc = 1.0
            # Sp <- (I + h c_creep (S - I)) Sp
            for i in range(3):
                for j in range(3):
                    s = 0.0
                    for u in range(3):
                        s += ((1.0 if i == u else 0.0) + tc * m3a[i, u]) * s_plastic[k, u, j]
                    m3c[i, j] = s
            det = det3(m3c)
            if det > 1e-12 and finite(det):
                inv_cbrt = 1.0 / np.cbrt(det)
                for i in range(3):
                    for j in range(3):
                        m3c[i, j] *= inv_cbrt
                _cap_plastic(s_plastic=m3c, c_max=c_max, m3=m3a, wa=wa, wv=wv)
                for i in range(3):
                    for j in range(3):
                        s_plastic[k, i, j] = m3c[i, j]
                changed[k] = True
                nchanged += 1
    return nchanged


@njit(inline='always', **JIT_NO_REFCOUNT)
def refresh_rest(which, rest, needs, linear, work):
    """Plastic rest shape q = S^P (x0 - cm0) / s of the clusters marked in ``which``, and
    A_qq (``rest``: a ``RestShape``; ``needs`` = (need3, need9): which moments; ``linear``:
    the linear mode's frames too; ``work`` = (9-vector, two 3 x 3, two 9 x 9)): the rest
    maps (``rest_maps``), the quadratic moments, their pseudo-inverses and the frames.
    ``body_build.refresh_rest`` calls the same kernels one by one (a body's build)."""
    need3, need9 = needs
    f9, w3a, w3b, w9a, w9b = work
    rest_maps(which, rest, need3 and not need9)
    if need9:
        moments(rest.x0t.T, rest.mass, (rest.ptr, rest.cluster_ids),
                (rest.rest_lin, rest.rest_off), rest.wsum, which, needs,
                (rest.sum_q, rest.mom3, rest.mom9), f9)
    invert_moments(which, needs, (rest.mom3, rest.mom9), (rest.aqq3, rest.aqq9),
                   (w3a, w3b, w9a, w9b), RCOND)
    if linear:
        unit_det_frames(which, rest.mom3, rest.nmat, rest.cdet, w3a, w3b, RCOND)


@njit(**JIT_NO_REFCOUNT)
def rest_maps(which, rest, mom3):
    """The rest maps of the clusters marked in ``which``: G = S^P / s, q = G (x0 - cm0),
    so sum w q = G sum w d, and with ``mom3`` the centred moments G (sum w d d^T) G^T -
    (sum w q)(sum w q)^T / W, from the rest moments kept since the build: a cost per
    changed cluster.  Quadratic features need moments up to degree 4 (``goals.moments``:
    a pass over the particles)."""
    for k in range(which.shape[0]):
        if which[k]:
            _rest_map(k, rest, mom3)


@njit(inline='always', **JIT_NO_REFCOUNT)
def _rest_map(k, rest, mom3):
    """Cluster k's rest map G = S^P / s, offset -G cm0, sum w q = G sum w d and, with
    ``mom3``, its centred moment from the build's sum w d d^T."""
    g, cm0, dsum0 = rest.rest_lin[k], rest.cm0[k], rest.dsum0[k]
    inv_scale = 1.0 / rest.scale[k]
    for i in range(3):
        for j in range(3):
            g[i, j] = rest.s_plastic[k, i, j] * inv_scale
    for i in range(3):
        rest.rest_off[k, i] = -(g[i, 0] * cm0[0] + g[i, 1] * cm0[1] + g[i, 2] * cm0[2])
    for j in range(9):
        rest.sum_q[k, j] = 0.0
    for i in range(3):
        rest.sum_q[k, i] = g[i, 0] * dsum0[0] + g[i, 1] * dsum0[1] + g[i, 2] * dsum0[2]
    if not mom3:
        return
    cov, sq, inv_w = rest.cov0[k], rest.sum_q[k], 1.0 / rest.wsum[k]
    for i in range(3):
        for j in range(i, 3):
            s = 0.0
            for a in range(3):
                for b in range(3):
                    s += g[i, a] * cov[a, b] * g[j, b]
            s -= sq[i] * sq[j] * inv_w
            rest.mom3[k, i, j] = s
            rest.mom3[k, j, i] = s
