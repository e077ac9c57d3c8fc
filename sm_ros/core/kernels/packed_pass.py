"""The packed step's particle pass (``sm_ros.core.packed``): a one-cluster rigid/linear
body's damping, Eq. 13-14, speed count and next step's sums in one loop over a block
(``fused._fused_range``), and its sums taken afresh."""

import numpy as np
from numba import njit

from .fused import _fused_range, damp_constants
from .integrate import _rest_sums
from .jit import JIT, JIT_NO_REFCOUNT


@njit(**JIT_NO_REFCOUNT)
def one_cluster_sums(start, end, x, x0, mass, rest_lin, rest_off, ref, sums):
    """Add the 12 sums of particles start..end of a one-cluster rigid/linear body about
    ``ref[0]`` to ``sums[0]``: taken in rest coordinates (``integrate._rest_sums``) and
    mapped once (``_add_rest_sums``)."""
    t = _rest_sums(start, end, x, x0, mass, ref[0, 0], ref[0, 1], ref[0, 2])
    _add_rest_sums(rest_lin, rest_off, sums[0], t)


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


@njit(**JIT_NO_REFCOUNT)
def _int_single_fused(start, end, particles, wuni, work, step, gz, boxed):
    """The one-cluster pass over ``particles`` = (x, v, x0) start..end in one loop (no
    torque), with ``work`` a packed body's rows (``packed.Work``) and ``step`` =
    (alpha, h, damp, k_damp, v_max): the damping towards ``work.dmp[0]`` about
    ``work.ref[0]`` (with ``damp``), Eq. 13-14, the count of speeds above ``v_max`` (0: no
    cap) and of new heights below ``gz`` (the ground's height; -inf without a ground),
    and the shape match's 12 sums of the new state about ``work.pnt[0]`` (``one_cluster_sums``)
    into ``work.part[0]`` (``_fused_range``, the loop), and with ``damp`` its 12 damping
    sums about the same point into ``work.dpart[0, 3:15]`` (``damp_acc_range``'s rows; W
    and sum w d are the caller's).

    Returns (sum of |g - p|^2 as ``advance``, speeds over the cap, heights below the
    ground).  The sums are added only when no speed is over the cap and no box or sphere is
    in the world (``boxed``): otherwise the caller projects the range onto the colliders,
    caps it and takes its sums again, so a moved particle is summed where it ends.  With
    heights below the ground (and neither), the caller projects them and adds what that
    changed in the sums (``colliders.ground_range_sums``).
    """
    x, v, x0 = particles
    alpha, h, damp, k_damp, v_max = step
    goal_lin, goal_off, dmp, ref, pnt = work.goal_lin, work.goal_off, work.dmp, work.ref, work.pnt
    acc, sums, dsums = work.acc, work.part, work.dpart
    gmap = (goal_lin[0, 0, 0], goal_lin[0, 0, 1], goal_lin[0, 0, 2], goal_lin[0, 1, 0],
            goal_lin[0, 1, 1], goal_lin[0, 1, 2], goal_lin[0, 2, 0], goal_lin[0, 2, 1],
            goal_lin[0, 2, 2], goal_off[0, 0], goal_off[0, 1], goal_off[0, 2])
    field = damp_constants(damp, k_damp,
                           (dmp[0, 0], dmp[0, 1], dmp[0, 2], dmp[0, 3], dmp[0, 4], dmp[0, 5]),
                           (ref[0, 0], ref[0, 1], ref[0, 2]))
    lim2 = v_max * v_max if v_max > 0.0 else np.inf
    out = _fused_range(start, end, (x, v, x0), wuni, gmap, damp, field,
                       (alpha / h, h, h * acc[0], h * acc[1], h * acc[2]),
                       (pnt[0, 0], pnt[0, 1], pnt[0, 2]), (lim2, gz))
    err2, over, low = out[0], out[1], out[14]
    if over == 0 and not boxed:
        _add_rest_sums(work.rest_lin, work.rest_off, sums[0], out[2:14])
        if damp:
            d = out[15:27]
            for j in range(12):
                dsums[0, 3 + j] += d[j]
    return err2, over, low
