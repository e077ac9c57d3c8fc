"""Per-cluster shape matching: sums -> x_cm, A_pq, A and the goal transform (Eq. 7-12, 18-22).

``solve_clusters_warm`` reduces the per-cluster sums that the particle passes accumulated
(Eq. 7-9: x_cm and A_pq = sum m (x - x_cm) q^T, taken about the previous centre of mass so
large coordinates do not cancel) and builds each cluster's goal transform: rigid R
(Eq. 12), linear beta A' + (1 - beta) R with the volume-preserving A' (Eq. 18, see
``unit_det.py``), quadratic beta A~ + (1 - beta) R~ on the centred features q~
(Eq. 19-22, errata of Eq. 21 and 22).  ``moments``/``invert_moments`` give the rest-shape
moments A_qq = (sum m q q^T)^+ (Eq. 10) and A~_qq (Eq. 21) at build time and whenever the
plastic state changes; ``_qhat`` is a particle's plastic, scaled rest offset q-hat.
"""

from collections import namedtuple

from numba import njit

from .jit import JIT, JIT_NO_REFCOUNT, finite
from .limits import _span
from .linalg import det3, matmul, pinv_sym
from .rotation import extract_rotation
from .unit_det import STRETCH_LIMIT, unit_det_match_warm

#: Each cluster's constants of its rest shape: its mass (``wsum``), sum m q~ (``sum_q``),
#: A_qq (``aqq3``; ``aqq9`` quadratic), its volume scale and the frames of the
#: unit-determinant match (``nmat``, ``cdet``; ``unit_det.unit_det_frames``).
ClusterShape = namedtuple('ClusterShape', 'wsum sum_q aqq3 aqq9 scale nmat cdet')
#: What the match writes per cluster: its rotation (``quat``), goal transform (``trans``,
#: 3 x 9: the linear modes use the 3 x 3 block) and affine goal map (``goal_lin``,
#: ``goal_off``), A_pq-hat (``apq``, for ``plastic_update``) and the linear mode's
#: eigenvectors (``udv``, the warm start of its next match).
ClusterMatch = namedtuple('ClusterMatch', 'quat trans goal_lin goal_off apq udv')
#: The match's scratch: a cluster's reduced sums (``sums``), three 3 x 3, a 3 x 9 and two
#: 4 x 4 matrices, and two more 3 x 3 (``work``, 2 x 3 x 3) for the linear mode.
MatchScratch = namedtuple('MatchScratch', 'sums m3a m3b m3c m39 n4 v4 work')


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


@njit(**JIT_NO_REFCOUNT)
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


@njit(**JIT_NO_REFCOUNT)
def solve_clusters_warm(part, rest, shape, match, scratch, mode, beta, warm):
    """Reduce the per-chunk sums ``part`` and build every cluster's goal transform.

    ``mode``: 0 rigid, 1 linear, 2 quadratic.  ``rest`` (``integrate.ClusterRest``): its
    ``ref`` becomes each cluster's centre of mass x_cm; ``match`` (``ClusterMatch``) gets
    the rotation of A_pq, the transform and, for the rigid/linear modes, the affine goal
    map ``goal_lin x0 + goal_off``.  Plasticity is a kernel of its own, so a scene without
    it neither runs nor compiles it.  With ``warm`` each linear cluster's match starts
    from the eigenvectors of its last (``match.udv``; ``nearest_unit_det_warm``).
    """
    m39 = scratch.m39
    # the linear mode's 3x3 scratch (the last two C-contiguous like the packed step's, so
    # both callers share one compiled eigen solver)
    work = (m39[:, 3:6], m39[:, 6:9], scratch.work[0], scratch.work[1])
    _match_clusters(part, rest, shape, match, scratch, mode, beta, warm, work)


@njit(**JIT_NO_REFCOUNT)
def _match_clusters(part, rest, shape, match, scratch, mode, beta, warm, work):
    """``solve_clusters_warm``'s loop over the clusters (it allocates nothing, and reads
    its tuples' arrays in the loop: no reference counting)."""
    nq = 9 if mode == 2 else 3
    for k in range(part.shape[1]):
        inv_w = _reduce_cluster(part, k, rest.ref, shape, match.apq, scratch, nq)
        extract_rotation(mat=scratch.m3a, quat=match.quat[k], rot=scratch.m3b, n4=scratch.n4,
                         v4=scratch.v4)                     # m3b = R
        if mode == 2:
            _quadratic_goal(k, rest.ref, shape, match, scratch, beta, inv_w)
        else:
            _linear_transform(k, shape, match, scratch, mode == 1, beta, work, warm)
            _affine_goal(k, rest, match)


@njit(inline='always', **JIT)
def _reduce_cluster(part, k, ref, shape, apq, scratch, nq):
    """Cluster k's sums over the chunks: moves ``ref[k]`` to its centre of mass, writes
    A_pq-hat (3 x nq) = sum w (x - cm) q^T to ``scratch.m39``, its 3 x 3 block to
    ``scratch.m3a`` and ``apq[k]``; returns 1 / its mass."""
    acc, m39, m3a = scratch.sums, scratch.m39, scratch.m3a
    for a in range(part.shape[2]):
        s = 0.0
        for chunk in range(part.shape[0]):
            s += part[chunk, k, a]
        acc[a] = s
    inv_w = 1.0 / shape.wsum[k]
    d0 = acc[0] * inv_w
    d1 = acc[1] * inv_w
    d2 = acc[2] * inv_w
    for i in range(3):
        di = d0 if i == 0 else (d1 if i == 1 else d2)
        for j in range(nq):
            m39[i, j] = acc[3 + i * nq + j] - di * shape.sum_q[k, j]
    ref[k, 0] += d0
    ref[k, 1] += d1
    ref[k, 2] += d2
    for i in range(3):
        for j in range(3):
            m3a[i, j] = m39[i, j]
            apq[k, i, j] = m39[i, j]
    return inv_w


@njit(inline='always', **JIT)
def _quadratic_goal(k, ref, shape, match, scratch, beta, inv_w):
    """Cluster k's quadratic transform beta A~ + (1 - beta) R~ (Eq. 22) and its offset on
    the centred features: goal = T (q~ - mean q~) + cm."""
    m39, m3b, aqq9, trans = scratch.m39, scratch.m3b, shape.aqq9, match.trans
    s_k = shape.scale[k]
    for i in range(3):
        for j in range(9):
            s = 0.0
            for u in range(9):
                s += m39[i, u] * aqq9[k, u, j]
            rt = s_k * m3b[i, j] if j < 3 else 0.0
            trans[k, i, j] = beta * s + (1.0 - beta) * rt
    for i in range(3):
        s = ref[k, i]
        for j in range(9):
            s -= trans[k, i, j] * shape.sum_q[k, j] * inv_w
        match.goal_off[k, i] = s


@njit(inline='always', **JIT)
def _linear_transform(k, shape, match, scratch, linear, beta, work, warm):
    """Cluster k's rigid transform s R (Eq. 12), or linear s (beta B + (1 - beta) R) with
    B the unit-determinant minimiser (Eq. 18, see ``unit_det_match``); R when A is
    inverted, flat or line-like (det A <= 0).  ``work``: the match's 3 x 3 scratch."""
    m3a, m3b, m3c, trans = scratch.m3a, scratch.m3b, scratch.m3c, match.trans
    s_k = shape.scale[k]
    if linear:
        matmul(m3a, shape.aqq3[k], m3c)             # A * s = A_pq-hat A_qq-hat
        det = det3(m3c) / (s_k * s_k * s_k)
        if (det > 1e-9 and finite(det) and shape.cdet[k] > 0.0
                and unit_det_match_warm(apq=m3a, nmat=shape.nmat[k], c_s=s_k * shape.cdet[k],
                                        rot=m3b, out=m3c, work=work, limit=STRETCH_LIMIT,
                                        vw=match.udv[k if warm else 0], warm=warm)):
            for i in range(3):
                for j in range(3):
                    trans[k, i, j] = s_k * (beta * m3c[i, j] + (1.0 - beta) * m3b[i, j])
            return
    for i in range(3):
        for j in range(3):
            trans[k, i, j] = s_k * m3b[i, j]


@njit(inline='always', **JIT)
def _affine_goal(k, rest, match):
    """Cluster k's affine goal map in rest coordinates: goal = T (G x0 + h) + cm."""
    trans, rest_lin, rest_off, ref = match.trans, rest.rest_lin, rest.rest_off, rest.ref
    for i in range(3):
        for j in range(3):
            match.goal_lin[k, i, j] = (trans[k, i, 0] * rest_lin[k, 0, j]
                                       + trans[k, i, 1] * rest_lin[k, 1, j]
                                       + trans[k, i, 2] * rest_lin[k, 2, j])
        match.goal_off[k, i] = (trans[k, i, 0] * rest_off[k, 0] + trans[k, i, 1] * rest_off[k, 1]
                                + trans[k, i, 2] * rest_off[k, 2] + ref[k, i])


@njit(**JIT_NO_REFCOUNT)
def moments(x0, mass, members, rest_map, wsum, which, needs, out, f9):
    """sum w q~ and the centred moments sum w (q - mean)(q - mean)^T of the clusters marked
    in ``which`` (``members`` = (ptr, cluster_ids), the clusters of each particle, empty for one;
    ``rest_map`` = (rest_lin, rest_off); ``needs`` = (need3, need9): which moments; ``out``
    = (sum_q, mom3, mom9); ``f9`` scratch).

    The quadratic features q~ are centred per cluster (their squares have a non-zero
    mean): the goals then share the cluster's centre of mass, which keeps linear momentum,
    and an exactly quadratic deformation is reproduced.
    """
    ptr, cluster_ids = members
    rest_lin, rest_off = rest_map
    need3, need9 = needs
    sum_q, mom3, mom9 = out
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
        j0, j1, w = _span(i, single, ptr, mass)
        for j in range(j0, j1):
            k = 0 if single else cluster_ids[j]
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


@njit(**JIT_NO_REFCOUNT)
def invert_moments(which, needs, moments, inverses, work, rcond):
    """A_qq = (sum w q q^T)^+ and A~_qq = (sum w q~ q~^T)^+ (robust pseudo-inverses) of
    the clusters marked in ``which``: ``needs`` = (need3, need9), ``moments`` = (mom3,
    mom9), ``inverses`` = (aqq3, aqq9), ``work`` two 3 x 3 and two 9 x 9 scratch."""
    need3, need9 = needs
    mom3, mom9 = moments
    aqq3, aqq9 = inverses
    w3a, w3b, w9a, w9b = work
    for k in range(which.shape[0]):
        if which[k]:
            if need3:
                pinv_sym(mat=mom3[k], out=aqq3[k], wa=w3a, wv=w3b, rcond=rcond)
            if need9:
                pinv_sym(mat=mom9[k], out=aqq9[k], wa=w9a, wv=w9b, rcond=rcond)
