"""Eq. 13-14 for one particle (``advance``), the named tuples the passes read, and the
helpers the set layout's passes (``sets.py``, ``sets_sums.py``) share.

``advance`` is the whole integration of the method, written once and inlined into every
particle loop.  ``_rest_sums`` takes the 12 one-set sums of a run in rest coordinates
with its accumulators in registers (vectorised across particles: unit-stride columns of x
and y, an unsigned loop index ``jit.U``).
"""

from collections import namedtuple

from numba import njit

from .jit import JIT, U
from .linalg import ZERO12, add_outer

#: A body's particles as the passes read them: positions, velocities and rest positions
#: (N, 3; the transposes of its (3, N) blocks, typed F) and masses (N,).
BodyParticles = namedtuple('BodyParticles', 'x v x0 mass')
#: Its clusters: the membership (``ptr`` (N + 1,) into ``cluster_ids``, the clusters of each
#: particle; empty for one cluster), each cluster's rest map (``rest_lin``, ``rest_off``)
#: and the point its sums are taken about (``ref``, the last centre of mass).
ClusterRest = namedtuple('ClusterRest', 'ptr cluster_ids rest_lin rest_off ref')
#: Damping fused into the pass: whether it is on, its rate, its field (``dmp``: a row
#: per set) and the per-chunk damping sums.
FusedDamping = namedtuple('FusedDamping', 'on rate field part')

#: Particles per block of the fused pass: integrated, then accumulated while in cache
#: (1024: 72 KiB of x, v, x0, in L2; smaller blocks pay the call per block more often).
BLOCK = 1024


@njit(inline='always', **JIT)
def _rest_sums(start, end, x, x0, mass, r0, r1, r2):
    """The 12 one-cluster sums of particles start..end in rest coordinates, about the point
    r: (sum w d, sum w d x0^T row by row), d = x - r.  12 accumulators in registers;
    vectorises across particles (unit-stride columns of x, x0, unsigned index: one lane a
    particle, 12 vector accumulators).  Inlined by Numba into its callers
    (``sets._sets_fused_lin``, ``sets_sums``, with x0 the set offsets y)."""
    sums = ZERO12
    for i in range(U(start), U(end)):
        w = mass[i]
        sums = add_outer(sums, w * (x[i, 0] - r0), w * (x[i, 1] - r1), w * (x[i, 2] - r2),
                         x0[i, 0], x0[i, 1], x0[i, 2])
    return sums


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


@njit(inline='always', **JIT)
def _zero_chunk(part, chunk):
    """Clear chunk ``chunk``'s slot of the per-chunk sums ``part``; returns it."""
    sums = part[chunk]
    for k in range(sums.shape[0]):
        for j in range(sums.shape[1]):
            sums[k, j] = 0.0
    return sums
