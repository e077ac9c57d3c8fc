"""Per-particle passes of the membership layout: Eq. 13-14 with goals averaged over clusters.

One step reads and writes every particle once: ``integrate_*`` computes each particle's
goal as the mean of its clusters' goals (Eq. 23 and the note on it: a mass-weighted
average, not a sum), applies Eq. 13-14 (``advance``), the colliders, and adds the particle
to the per-cluster sums of Eq. 7-9 for the next step, block by block while the block is in
L1.  ``accumulate_*`` recomputes those sums when the state was changed outside a step.
``part`` is (chunks, clusters, 12 or 30): every chunk owns its slot, reduced in
``goals.solve_clusters``; ref is the previous centre of mass, so large coordinates do not
cancel (A_pq = sum w (x - ref) q^T - (cm - ref)(sum w q)^T).  Single-cluster bodies take
fast paths that keep every cluster constant and accumulator in registers.

Vectorisation: a body stores x, v, x0 per component (``Body`` keeps (3, N) blocks and
hands the kernels their (N, 3) transposes, typed layout F), so ``x[i, j]`` is unit-stride
in i, and the one-cluster loops (``_int_single_lin``, ``_acc_single``) and
``damping.damp_acc_range`` run several particles a vector instruction.  What it takes
(each loop says so): an unsigned
loop index (``jit.U``: no negative-index wraparound), ``advance`` and the accumulators
inlined by Numba (an LLVM-level call stayed a call), every constant in a local (an array
read in the loop may alias x/v: LLVM gave up, "too many memory checks needed"), branches
outside the loops.  The membership loops (several clusters a particle, gathered by index)
stay scalar; multi-cluster bodies mostly take the set layout (``sets.py``).
"""

from collections import namedtuple

import numpy as np
from numba import njit

from .jit import JIT, JIT_NO_REFCOUNT, U, claim_next
from .colliders import _collide_range
from .damping import damp_acc_range, damp_towards
from .goals import _goal_quad, _qhat
from .linalg import ZERO12, add_outer

#: A body's particles as the passes read them: positions, velocities and rest positions
#: (N, 3; the transposes of its (3, N) blocks, typed F) and masses (N,).
BodyParticles = namedtuple('BodyParticles', 'x v x0 mass')
#: Its clusters: the membership (``ptr`` (N + 1,) into ``cluster_ids``, the clusters of each
#: particle; empty for one cluster), each cluster's rest map (``rest_lin``, ``rest_off``)
#: and the point its sums are taken about (``ref``, the last centre of mass).
ClusterRest = namedtuple('ClusterRest', 'ptr cluster_ids rest_lin rest_off ref')
#: The step's goals and forces: each cluster's goal map (``goal_lin``, ``goal_off``;
#: ``trans`` when quadratic), alpha, h, the acceleration ``acc`` and the angular one
#: ``ang`` about ``com``.
StepGoals = namedtuple('StepGoals', 'goal_lin goal_off trans alpha h acc ang com')
#: Damping fused into the pass: whether it is on, its rate, its field (``dmp``: a row
#: per set) and the per-chunk damping sums.
FusedDamping = namedtuple('FusedDamping', 'on rate field part')

@njit(inline='always', **JIT)
def _acc_weighted(row, w, d0, d1, d2):
    """row[0:3] += w d (d = x - ref); returns w d."""
    d0 *= w
    d1 *= w
    d2 *= w
    row[0] += d0
    row[1] += d1
    row[2] += d2
    return d0, d1, d2


@njit(inline='always', **JIT)
def _acc_lin(row, w, d0, d1, d2, q0, q1, q2):
    """Add one particle's w (x - ref) and w (x - ref) q^T to the accumulator row ``a``."""
    d0, d1, d2 = _acc_weighted(row, w, d0, d1, d2)
    row[3] += d0 * q0
    row[4] += d0 * q1
    row[5] += d0 * q2
    row[6] += d1 * q0
    row[7] += d1 * q1
    row[8] += d1 * q2
    row[9] += d2 * q0
    row[10] += d2 * q1
    row[11] += d2 * q2


@njit(inline='always', **JIT)
def _acc_quad(row, w, d0, d1, d2, q0, q1, q2):
    """Quadratic accumulator: w (x - ref) and w (x - ref) q~^T (3 + 27 entries)."""
    d0, d1, d2 = _acc_weighted(row, w, d0, d1, d2)
    f3 = q0 * q0
    f4 = q1 * q1
    f5 = q2 * q2
    f6 = q0 * q1
    f7 = q1 * q2
    f8 = q2 * q0
    row[3] += d0 * q0
    row[4] += d0 * q1
    row[5] += d0 * q2
    row[6] += d0 * f3
    row[7] += d0 * f4
    row[8] += d0 * f5
    row[9] += d0 * f6
    row[10] += d0 * f7
    row[11] += d0 * f8
    row[12] += d1 * q0
    row[13] += d1 * q1
    row[14] += d1 * q2
    row[15] += d1 * f3
    row[16] += d1 * f4
    row[17] += d1 * f5
    row[18] += d1 * f6
    row[19] += d1 * f7
    row[20] += d1 * f8
    row[21] += d2 * q0
    row[22] += d2 * q1
    row[23] += d2 * q2
    row[24] += d2 * f3
    row[25] += d2 * f4
    row[26] += d2 * f5
    row[27] += d2 * f6
    row[28] += d2 * f7
    row[29] += d2 * f8


@njit(**JIT_NO_REFCOUNT)
def _acc_single(start, end, quad, x, x0, mass, rest_lin, rest_off, ref, sums):
    g00, g01, g02 = rest_lin[0, 0, 0], rest_lin[0, 0, 1], rest_lin[0, 0, 2]
    g10, g11, g12 = rest_lin[0, 1, 0], rest_lin[0, 1, 1], rest_lin[0, 1, 2]
    g20, g21, g22 = rest_lin[0, 2, 0], rest_lin[0, 2, 1], rest_lin[0, 2, 2]
    h0, h1, h2 = rest_off[0, 0], rest_off[0, 1], rest_off[0, 2]
    r0, r1, r2 = ref[0, 0], ref[0, 1], ref[0, 2]
    if quad:
        for i in range(U(start), U(end)):
            a0, a1, a2 = x0[i, 0], x0[i, 1], x0[i, 2]
            _acc_quad(row=sums[0], w=mass[i], d0=x[i, 0] - r0, d1=x[i, 1] - r1, d2=x[i, 2] - r2,
                      q0=g00 * a0 + g01 * a1 + g02 * a2 + h0,
                      q1=g10 * a0 + g11 * a1 + g12 * a2 + h1,
                      q2=g20 * a0 + g21 * a1 + g22 * a2 + h2)
        return
    # sum w d q^T = (sum w d x0^T) G^T + (sum w d) h^T: accumulate in rest coordinates
    # (9 multiply-adds per particle less) and map once per block
    t = _rest_sums(start, end, x, x0, mass, r0, r1, r2)
    _add_rest_sums(rest_lin, rest_off, sums[0], t)


@njit(inline='always', **JIT)
def _rest_sums(start, end, x, x0, mass, r0, r1, r2):
    """The 12 one-cluster sums of particles start..end in rest coordinates, about the point
    r: (sum w d, sum w d x0^T row by row), d = x - r.  12 accumulators in registers;
    vectorises across particles (unit-stride columns of x, x0, unsigned index: one lane a
    particle, 12 vector accumulators).  Inlined by Numba into its callers (``_acc_single``;
    ``sets._sets_fused_lin`` with x0 the set offsets y)."""
    sums = ZERO12
    for i in range(U(start), U(end)):
        w = mass[i]
        sums = add_outer(sums, w * (x[i, 0] - r0), w * (x[i, 1] - r1), w * (x[i, 2] - r2),
                         x0[i, 0], x0[i, 1], x0[i, 2])
    return sums


@njit(inline='always', **JIT)
def _add_rest_sums(rest_lin, rest_off, row, rest_sums):
    """row += the 12 one-cluster sums from ``rest_sums`` = (sum w d (s, 3), sum w d x0^T
    (c, 9, row by row)) in rest coordinates: sum w d q^T = c G^T + s h^T (G, h: the rest
    map)."""
    s0, s1, s2, c00, c01, c02, c10, c11, c12, c20, c21, c22 = rest_sums
    g00, g01, g02 = rest_lin[0, 0, 0], rest_lin[0, 0, 1], rest_lin[0, 0, 2]
    g10, g11, g12 = rest_lin[0, 1, 0], rest_lin[0, 1, 1], rest_lin[0, 1, 2]
    g20, g21, g22 = rest_lin[0, 2, 0], rest_lin[0, 2, 1], rest_lin[0, 2, 2]
    h0, h1, h2 = rest_off[0, 0], rest_off[0, 1], rest_off[0, 2]
    row[0] += s0
    row[1] += s1
    row[2] += s2
    row[3] += g00 * c00 + g01 * c01 + g02 * c02 + h0 * s0
    row[4] += g10 * c00 + g11 * c01 + g12 * c02 + h1 * s0
    row[5] += g20 * c00 + g21 * c01 + g22 * c02 + h2 * s0
    row[6] += g00 * c10 + g01 * c11 + g02 * c12 + h0 * s1
    row[7] += g10 * c10 + g11 * c11 + g12 * c12 + h1 * s1
    row[8] += g20 * c10 + g21 * c11 + g22 * c12 + h2 * s1
    row[9] += g00 * c20 + g01 * c21 + g02 * c22 + h0 * s2
    row[10] += g10 * c20 + g11 * c21 + g12 * c22 + h1 * s2
    row[11] += g20 * c20 + g21 * c21 + g22 * c22 + h2 * s2


@njit(inline='always', **JIT)
def advance(x, v, i, p, g, alpha_h, h, dv):
    """Eq. 13-14 for particle ``i`` at ``p`` (= x[i]) towards its goal g; returns |g - p|^2
    (not finite when p or the new velocity is not; when both are, so is x = p + h v).

    v <- v + (alpha / h) (g - p) + dv, then x <- p + h v, where dv is h times the external
    acceleration.  Every integration loop calls this; it is inlined into them by Numba
    (``inline='always'``): left to LLVM the call stays a call, and a loop with a call
    does not vectorise.  The caller loads ``p`` where the loop needs it first, so that the
    fast-math reassociation sees the same expressions whatever the loop (the results stay
    bit-identical).
    """
    p0, p1, p2 = p
    g0, g1, g2 = g
    dv0, dv1, dv2 = dv
    e0 = g0 - p0
    e1 = g1 - p1
    e2 = g2 - p2
    err = e0 * e0 + e1 * e1 + e2 * e2
    v0 = v[i, 0] + alpha_h * e0 + dv0
    v1 = v[i, 1] + alpha_h * e1 + dv1
    v2 = v[i, 2] + alpha_h * e2 + dv2
    x[i, 0] = p0 + h * v0
    x[i, 1] = p1 + h * v1
    x[i, 2] = p2 + h * v2
    v[i, 0] = v0
    v[i, 1] = v1
    v[i, 2] = v2
    # + 0 (v0 + v1 + v2): exactly err while the new v is finite, NaN when it is not (0 * inf
    # = NaN; no ``nnan``/``ninf`` fast math folds it away; an infinite p makes err infinite),
    # so a body's shape-error sums flag a non-finite state without a pass of their own
    # (sm_ros/nonfinite.py)
    return err + 0.0 * (v0 + v1 + v2)


@njit(**JIT_NO_REFCOUNT)
def _int_single_lin(start, end, particles, rest, goals, damping):
    """Eq. 13-14 for a one-cluster rigid/linear body, its goal map held in registers; with
    ``damping.on`` the velocities are first damped towards its field about ``rest.ref``.

    Vectorises across particles (``inspect_asm``: 8 particles a ``zmm`` instruction on
    AVX-512, 4 a ``ymm`` on AVX2): unit-stride columns of the F-ordered x, v, x0, an
    unsigned index (``jit.U``), every constant (map, field, reference) in a local so that
    the loop reads only x, v, x0 (each array read in it may alias v and costs runtime
    overlap checks: LLVM gives up with "too many memory checks needed"), and the damping
    and torque branches hoisted out of the loops.
    """
    x, v, x0 = particles.x, particles.v, particles.x0
    goal_lin, goal_off, acc, ang, com = (goals.goal_lin, goals.goal_off, goals.acc, goals.ang,
                                         goals.com)
    alpha, h, ref = goals.alpha, goals.h, rest.ref
    damp, k_damp, dmp = damping.on, damping.rate, damping.field
    l00, l01, l02 = goal_lin[0, 0, 0], goal_lin[0, 0, 1], goal_lin[0, 0, 2]
    l10, l11, l12 = goal_lin[0, 1, 0], goal_lin[0, 1, 1], goal_lin[0, 1, 2]
    l20, l21, l22 = goal_lin[0, 2, 0], goal_lin[0, 2, 1], goal_lin[0, 2, 2]
    b0, b1, b2 = goal_off[0, 0], goal_off[0, 1], goal_off[0, 2]
    w0, w1, w2 = ang[0], ang[1], ang[2]
    # acc + ang x (p - com) = (acc - ang x com) + ang x p
    ax = acc[0] - (w1 * com[2] - w2 * com[1])
    ay = acc[1] - (w2 * com[0] - w0 * com[2])
    az = acc[2] - (w0 * com[1] - w1 * com[0])
    alpha_h = alpha / h
    r0c, r1c, r2c = ref[0, 0], ref[0, 1], ref[0, 2]
    c0, c1, c2 = dmp[0, 0], dmp[0, 1], dmp[0, 2]
    o0, o1, o2 = dmp[0, 3], dmp[0, 4], dmp[0, 5]
    field = (c0, c1, c2, o0, o1, o2)
    torque = not (w0 == 0.0 and w1 == 0.0 and w2 == 0.0)
    # no torque: a uniform acceleration (6 multiply-adds per particle less)
    hx, hy, hz = h * ax, h * ay, h * az
    err2 = 0.0
    if damp and not torque:
        for i in range(U(start), U(end)):
            a0, a1, a2 = x0[i, 0], x0[i, 1], x0[i, 2]
            p0, p1, p2 = x[i, 0], x[i, 1], x[i, 2]
            damp_towards(v=v, i=i, r=(p0 - r0c, p1 - r1c, p2 - r2c), field=field, k_damp=k_damp)
            err2 += advance(x=x, v=v, i=i, p=(p0, p1, p2),
                            g=(l00 * a0 + l01 * a1 + l02 * a2 + b0,
                               l10 * a0 + l11 * a1 + l12 * a2 + b1,
                               l20 * a0 + l21 * a1 + l22 * a2 + b2),
                            alpha_h=alpha_h, h=h, dv=(hx, hy, hz))
    elif not torque:
        for i in range(U(start), U(end)):
            a0, a1, a2 = x0[i, 0], x0[i, 1], x0[i, 2]
            p0, p1, p2 = x[i, 0], x[i, 1], x[i, 2]
            err2 += advance(x=x, v=v, i=i, p=(p0, p1, p2),
                            g=(l00 * a0 + l01 * a1 + l02 * a2 + b0,
                               l10 * a0 + l11 * a1 + l12 * a2 + b1,
                               l20 * a0 + l21 * a1 + l22 * a2 + b2),
                            alpha_h=alpha_h, h=h, dv=(hx, hy, hz))
    else:
        for i in range(U(start), U(end)):
            a0, a1, a2 = x0[i, 0], x0[i, 1], x0[i, 2]
            p0, p1, p2 = x[i, 0], x[i, 1], x[i, 2]
            if damp:
                damp_towards(v=v, i=i, r=(p0 - r0c, p1 - r1c, p2 - r2c),
                             field=field, k_damp=k_damp)
            err2 += advance(x=x, v=v, i=i, p=(p0, p1, p2),
                            g=(l00 * a0 + l01 * a1 + l02 * a2 + b0,
                               l10 * a0 + l11 * a1 + l12 * a2 + b1,
                               l20 * a0 + l21 * a1 + l22 * a2 + b2),
                            alpha_h=alpha_h, h=h,
                            dv=(h * (ax + w1 * p2 - w2 * p1),
                                h * (ay + w2 * p0 - w0 * p2),
                                h * (az + w0 * p1 - w1 * p0)))
    return err2


@njit(**JIT_NO_REFCOUNT)
def _acc_range(start, end, quad, particles, rest, sums):
    """Add particles start..end to the sums of their clusters (``sums``: clusters, 12 or
    30)."""
    x, x0, mass = particles.x, particles.x0, particles.mass
    ptr, cluster_ids, rest_lin = rest.ptr, rest.cluster_ids, rest.rest_lin
    rest_off, ref = rest.rest_off, rest.ref
    if ptr.shape[0] == 0:
        _acc_single(start=start, end=end, quad=quad, x=x, x0=x0, mass=mass, rest_lin=rest_lin,
                    rest_off=rest_off, ref=ref, sums=sums)
        return
    for i in range(start, end):
        a0, a1, a2 = x0[i, 0], x0[i, 1], x0[i, 2]
        j0, j1 = ptr[i], ptr[i + 1]
        w = mass[i] / (j1 - j0)
        for j in range(j0, j1):
            k = cluster_ids[j]
            q0, q1, q2 = _qhat(rest_lin=rest_lin, rest_off=rest_off, k=k, a0=a0, a1=a1, a2=a2)
            d0 = x[i, 0] - ref[k, 0]
            d1 = x[i, 1] - ref[k, 1]
            d2 = x[i, 2] - ref[k, 2]
            if quad:
                _acc_quad(row=sums[k], w=w, d0=d0, d1=d1, d2=d2, q0=q0, q1=q1, q2=q2)
            else:
                _acc_lin(row=sums[k], w=w, d0=d0, d1=d1, d2=d2, q0=q0, q1=q1, q2=q2)


@njit(inline='always', **JIT)
def _zero_chunk(part, chunk):
    """Clear chunk ``chunk``'s slot of the per-chunk sums ``part``; returns it."""
    sums = part[chunk]
    for k in range(sums.shape[0]):
        for j in range(sums.shape[1]):
            sums[k, j] = 0.0
    return sums


@njit(**JIT_NO_REFCOUNT)
def accumulate_chunks(claim, quad, particles, rest, part):
    """Accumulation pass over the chunks this call claims (``claim``, counted up
    atomically): called once it does every chunk; called on several threads with one
    ``claim`` (a body built for threads) each chunk once.  ``part`` (chunks, clusters,
    12 or 30): each chunk's sums."""
    nchunks = part.shape[0]
    n = particles.x.shape[0]
    while True:
        chunk = claim_next(claim)
        if chunk >= nchunks:
            return
        _acc_range(start=(chunk * n) // nchunks, end=((chunk + 1) * n) // nchunks, quad=quad,
                   particles=particles, rest=rest, sums=_zero_chunk(part, chunk))


#: Particles per block of the fused pass: integrated, then accumulated while in cache
#: (1024: 72 KiB of x, v, x0, in L2; smaller blocks pay the call per block more often).
BLOCK = 1024


@njit(**JIT_NO_REFCOUNT)
def _int_range(start, end, quad, particles, rest, goals, damping):
    """Eq. 13-14 for particles start..end; returns sum |g - x|^2.  Fused damping
    (``damping.on``) only on the one-cluster rigid/linear path (else
    ``damping.damp_rigid``)."""
    single = rest.ptr.shape[0] == 0
    if single and not quad:
        return _int_single_lin(start, end, particles, rest, goals, damping)
    x, v, x0 = particles.x, particles.v, particles.x0
    ptr, cluster_ids, rest_lin, rest_off = rest.ptr, rest.cluster_ids, rest.rest_lin, rest.rest_off
    trans, goal_lin, goal_off = goals.trans, goals.goal_lin, goals.goal_off
    acc, ang, com, h = goals.acc, goals.ang, goals.com, goals.h
    alpha_h = goals.alpha / h
    err2 = 0.0
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
            k = 0 if single else cluster_ids[j]
            if quad:
                q0, q1, q2 = _qhat(rest_lin=rest_lin, rest_off=rest_off, k=k, a0=a0, a1=a1, a2=a2)
                o0, o1, o2 = _goal_quad(trans=trans, k=k, q0=q0, q1=q1, q2=q2)
                g0 += o0 + goal_off[k, 0]
                g1 += o1 + goal_off[k, 1]
                g2 += o2 + goal_off[k, 2]
            else:
                g0 += (goal_lin[k, 0, 0] * a0 + goal_lin[k, 0, 1] * a1 + goal_lin[k, 0, 2] * a2
                       + goal_off[k, 0])
                g1 += (goal_lin[k, 1, 0] * a0 + goal_lin[k, 1, 1] * a1 + goal_lin[k, 1, 2] * a2
                       + goal_off[k, 1])
                g2 += (goal_lin[k, 2, 0] * a0 + goal_lin[k, 2, 1] * a1 + goal_lin[k, 2, 2] * a2
                       + goal_off[k, 2])
        if not single:
            inv = 1.0 / (j1 - j0)
            g0 *= inv
            g1 *= inv
            g2 *= inv
        p0, p1, p2 = x[i, 0], x[i, 1], x[i, 2]
        r0 = p0 - com[0]
        r1 = p1 - com[1]
        r2 = p2 - com[2]
        err2 += advance(x=x, v=v, i=i, p=(p0, p1, p2), g=(g0, g1, g2), alpha_h=alpha_h, h=h,
                        dv=(h * (acc[0] + ang[1] * r2 - ang[2] * r1),
                            h * (acc[1] + ang[2] * r0 - ang[0] * r2),
                            h * (acc[2] + ang[0] * r1 - ang[1] * r0)))
    return err2


#: The set ids of fused damping without the set layout: one cluster, every particle in
#: set 0, so none are stored (a constant: the pass allocates nothing).
_ONE_SET = np.zeros(0, dtype=np.int32)


@njit(inline='always', **JIT)
def _int_chunk(chunk, quad, particles, rest, goals, part, err, col, damping):
    """Integrate a chunk block by block; collide (``col``: ``colliders.Colliders``) and
    accumulate each block for the next step while it is still in L1 (one pass over
    memory, short loops without spills); with ``damping.on`` damp in the same pass and
    accumulate the damping sums into ``damping.part``."""
    nchunks = part.shape[0]
    x, v, mass = particles.x, particles.v, particles.mass
    n = x.shape[0]
    start = (chunk * n) // nchunks
    end = ((chunk + 1) * n) // nchunks
    sums = _zero_chunk(part, chunk)
    if damping.on:
        _zero_chunk(damping.part, chunk)
    err2 = 0.0
    for bs in range(start, end, BLOCK):
        be = min(bs + BLOCK, end)
        err2 += _int_range(bs, be, quad, particles, rest, goals, damping)
        if col.on:
            _collide_range(bs, be, x, v, col)
        _acc_range(start=bs, end=be, quad=quad, particles=particles, rest=rest, sums=sums)
        if damping.on:
            damp_acc_range(start=bs, end=be, x=x, v=v, mass=mass, sid=_ONE_SET,
                           dsums=damping.part[chunk])
    err[chunk] = err2


@njit(**JIT_NO_REFCOUNT)
def integrate_chunks(claim, quad, particles, rest, goals, part, err, col, damping):
    """Integration pass over the chunks this call claims (as ``accumulate_chunks``): Eq.
    13-14 towards ``goals``, the colliders ``col``, the sums of the new state into
    ``part`` and each chunk's shape error into ``err``."""
    nchunks = part.shape[0]
    while True:
        chunk = claim_next(claim)
        if chunk >= nchunks:
            return
        _int_chunk(chunk, quad, particles, rest, goals, part, err, col, damping)
