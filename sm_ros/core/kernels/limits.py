"""Speed and turn limits: what one step can represent (not an equation of the paper).

A step moves a particle by h v along a straight line and a cluster's goals by the rotation
extracted from A_pq.  A spin of more than about a radian per step cannot be represented
(the extracted rotation aliases) and a body spun that fast is smeared for ever: angular
momentum is conserved, correctly.  Physics engines bound what a step may do (FleX
``maxSpeed``, PhysX ``maxAngularVelocity``, ``maxDepenetrationVelocity``); so does sm_ros,
with two per-body limits, both off when 0 and, by default, far above anything the bundled
scenes do (they run bit-for-bit as without them):

* ``limit_speed``: every particle's speed is capped at ``v_max`` (m/s); the part of this
  step's displacement made with the excess is taken back (x -= h (v - v_capped));
* ``limit_turn``: a cluster whose angular velocity omega (from its particles' velocities,
  omega = I^+ L about its centre of mass) exceeds ``w_max`` (rad/s; the node gives the
  turn per step, w_max = turn / h) loses the excess: each particle's velocity changes by
  the mean over its clusters of -(omega - omega_capped) x r.  Only clusters flagged by the
  caller (their extracted rotation turned more than the limit in the last step) are
  measured, so a scene that never spins that fast pays one comparison per cluster.

Both return how many particles / clusters they capped (counted in /diagnostics).
"""

from numba import njit
import numpy as np

from .jit import JIT, JIT_NO_REFCOUNT, U, finite
from .linalg import add_moments, sym3_solve

@njit(**JIT_NO_REFCOUNT)
def limit_speed(x, v, h, v_max):
    """Cap |v_i| at ``v_max`` (and the displacement made with the excess); return the count.

    Reads every velocity; writes only the capped particles (``limit_speed_range`` over
    all of them).
    """
    return limit_speed_range(np.int64(0), v.shape[0], x, v, h, v_max)   # int64: one copy


@njit(**JIT_NO_REFCOUNT)
def limit_speed_range(start, end, x, v, h, v_max):
    """``limit_speed`` for particles start..end (the packed step caps block by block).

    A first loop only counts the speeds above the cap: compares and a masked count over
    the unit-stride columns of v with an unsigned index (``jit.U``), which vectorises; the
    capping loop, whose conditional stores do not vectorise, runs only when that count is
    not zero (almost never: the cap is a guard).  NaN speeds are counted by neither loop
    (left to the non-finite recovery).
    """
    lim2 = v_max * v_max
    over = 0
    for i in range(U(start), U(end)):
        v0, v1, v2 = v[i, 0], v[i, 1], v[i, 2]
        over += (v0 * v0 + v1 * v1 + v2 * v2) > lim2
    if over == 0:
        return 0
    count = 0
    for i in range(start, end):
        v0, v1, v2 = v[i, 0], v[i, 1], v[i, 2]
        s2 = v0 * v0 + v1 * v1 + v2 * v2
        if s2 > lim2:
            if not finite(s2):
                continue                       # left to the non-finite recovery
            f = v_max / np.sqrt(s2)
            d = h * (1.0 - f)
            x[i, 0] -= d * v0
            x[i, 1] -= d * v1
            x[i, 2] -= d * v2
            v[i, 0] = v0 * f
            v[i, 1] = v1 * f
            v[i, 2] = v2 * f
            count += 1
    return count


@njit(**JIT_NO_REFCOUNT)
def limit_turn(x, v, mass, members, flagged, w_max, scratch):
    """Take from every flagged cluster the angular velocity above ``w_max``; return the count.

    Per flagged cluster k: W, v_cm, d (centre), L and I about d from its members
    (``members`` = (ptr, cluster_ids), the clusters of each particle, empty for one; weights
    m_i / clusters of i, like the goals), omega = I^+ L; if |omega| > w_max the excess
    e_k = omega (1 - w_max / |omega|) is removed from each member's velocity as the mean
    over its clusters of e_k x (x_i - c_k).  ``scratch`` = (lin (K, 13), w3 (K, 6), four
    3 x 3).
    """
    ptr, cluster_ids = members
    lin, w3, m3a, m3b, m3c, m3d = scratch
    lin[:, :] = 0.0
    w3[:, :] = 0.0
    _turn_centres(x, v, mass, ptr, cluster_ids, flagged, lin, w3)
    _turn_moments(x, v, mass, ptr, cluster_ids, flagged, lin, w3)
    count = 0
    for k in range(flagged.shape[0]):
        if flagged[k] and lin[k, 0] > 0.0:
            count += _turn_excess(k, w_max, lin, w3, m3a, m3b, m3c, m3d)
    if count > 0:
        _remove_excess(x, v, ptr, cluster_ids, flagged, w3)
    return count


@njit(inline='always', **JIT)
def _span(i, single, ptr, mass):
    """Particle i's memberships j0..j1 (one cluster: 0..1) and its weight in each."""
    if single:
        return 0, 1, mass[i]
    j0, j1 = ptr[i], ptr[i + 1]
    return j0, j1, mass[i] / (j1 - j0)


@njit(inline='always', **JIT)
def _turn_centres(x, v, mass, ptr, cluster_ids, flagged, lin, w3):
    """Each flagged cluster's weight W (``lin[k, 0]``), centre (``w3[k, 3:6]``) and mean
    velocity (``lin[k, 1:4]``), the particles' own."""
    single = ptr.shape[0] == 0
    for i in range(x.shape[0]):
        j0, j1, w = _span(i, single, ptr, mass)
        for j in range(j0, j1):
            k = 0 if single else cluster_ids[j]
            if not flagged[k]:
                continue
            lin[k, 0] += w
            w3[k, 3] += w * x[i, 0]
            w3[k, 4] += w * x[i, 1]
            w3[k, 5] += w * x[i, 2]
            lin[k, 1] += w * v[i, 0]
            lin[k, 2] += w * v[i, 1]
            lin[k, 3] += w * v[i, 2]
    for k in range(flagged.shape[0]):
        if flagged[k] and lin[k, 0] > 0.0:
            for j in range(1, 4):
                lin[k, j] /= lin[k, 0]
            for j in range(3, 6):
                w3[k, j] /= lin[k, 0]


@njit(inline='always', **JIT)
def _turn_moments(x, v, mass, ptr, cluster_ids, flagged, lin, w3):
    """Each flagged cluster's angular momentum L (``lin[k, 4:7]``) and inertia I
    (``lin[k, 7:13]``: xx, yy, zz, xy, yz, zx) about its centre."""
    single = ptr.shape[0] == 0
    for i in range(x.shape[0]):
        j0, j1, w = _span(i, single, ptr, mass)
        for j in range(j0, j1):
            k = 0 if single else cluster_ids[j]
            if not flagged[k]:
                continue
            r0 = x[i, 0] - w3[k, 3]
            r1 = x[i, 1] - w3[k, 4]
            r2 = x[i, 2] - w3[k, 5]
            add_moments(lin, k, w, (r0, r1, r2),
                        (v[i, 0] - lin[k, 1], v[i, 1] - lin[k, 2], v[i, 2] - lin[k, 3]))


@njit(inline='always', **JIT)
def _turn_excess(k, w_max, lin, w3, m3a, m3b, m3c, m3d):
    """Cluster k's omega = I^+ L; its excess over ``w_max`` into ``w3[k, 0:3]``; returns 1
    if it had one, else 0."""
    m3a[0, 0] = lin[k, 7]
    m3a[1, 1] = lin[k, 8]
    m3a[2, 2] = lin[k, 9]
    m3a[0, 1] = m3a[1, 0] = lin[k, 10]
    m3a[1, 2] = m3a[2, 1] = lin[k, 11]
    m3a[2, 0] = m3a[0, 2] = lin[k, 12]
    o0, o1, o2 = sym3_solve(mat=m3a, b0=lin[k, 4], b1=lin[k, 5], b2=lin[k, 6],
                            rcond=1e-12, wout=m3b, wa=m3c, wv=m3d)
    om = np.sqrt(o0 * o0 + o1 * o1 + o2 * o2)
    if not (om > w_max and finite(om)):
        return 0
    f = 1.0 - w_max / om
    w3[k, 0] = f * o0
    w3[k, 1] = f * o1
    w3[k, 2] = f * o2
    return 1


@njit(inline='always', **JIT)
def _remove_excess(x, v, ptr, cluster_ids, flagged, w3):
    """Take from each particle the mean over its clusters of e_k x (x_i - c_k)."""
    single = ptr.shape[0] == 0
    for i in range(x.shape[0]):
        j0, j1 = (0, 1) if single else (ptr[i], ptr[i + 1])
        t0 = 0.0
        t1 = 0.0
        t2 = 0.0
        for j in range(j0, j1):
            k = 0 if single else cluster_ids[j]
            if not flagged[k]:
                continue
            r0 = x[i, 0] - w3[k, 3]
            r1 = x[i, 1] - w3[k, 4]
            r2 = x[i, 2] - w3[k, 5]
            t0 += w3[k, 1] * r2 - w3[k, 2] * r1
            t1 += w3[k, 2] * r0 - w3[k, 0] * r2
            t2 += w3[k, 0] * r1 - w3[k, 1] * r0
        inv = 1.0 / (j1 - j0)
        v[i, 0] -= t0 * inv
        v[i, 1] -= t1 * inv
        v[i, 2] -= t2 * inv
