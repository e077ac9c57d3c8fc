"""Compiled sequential-impulse contact solve: contact turns the bodies it touches.

Every contact (a pair of overlapping particles of two bodies, or a particle inside a static
collider) is a row of ``rows`` (``ROW_*`` columns) and ``rint`` (i, j, body of i, body of
j, warm-start key; j = -1 for a collider, which has infinite mass).  A side of a contact
is a particle i of body b with its body's rigid share s (``Bodies.share``: 1 for a stiff
body, alpha at the step at least ``contact.COUPLE_ALPHA`` and no pinned or grabbed
particle; 0 for a soft one): the velocity the contact law acts on is

    u_i = s (V_b + W_b x r_i) + (1 - s) v_i,   r_i = x_i - c_b,

and an impulse P at it changes the body's linear and angular velocity by s P / M_b and
s I_b^-1 (r_i x P) and the particle's own by (1 - s) w_i P (Box2D, Bullet: rigid-body
sequential impulses, with the mass, centre and inertia tensor of each stiff body from its
particles).  Off-centre loads so tip, roll and yaw stiff bodies while soft ones are dented
per particle.  Per step:

* the velocity sweeps: accumulated normal impulses (never negative) drive the normal
  speed to the law's target, restitution e times the approach speed at the row's creation
  when it exceeds the resting threshold, else 0 (no bounce from resting contact); friction
  accumulates a tangential impulse clamped to the Coulomb disc mu times the accumulated
  normal impulse (static friction holds a body while the disc allows);
* the position sweeps (split impulse): pseudo-velocities, separate from the velocities,
  remove what overlap the velocity change leaves; they move the particles and never enter
  the velocities, so position correction adds no energy;
* warm start: a row starts from ``WARM`` times the impulses its pair (or particle and
  collider) ended the last step with, while the pair list is unchanged.

Every velocity change also moves the particle by h times it (the bodies' step put
x = x_start + h v), so the solve acts as if before the position update.  Impulses are
equal and opposite: linear momentum is kept to round-off, and angular momentum too (an
impulse's moment about the body's centre goes to its spin through the inertia tensor of
the same particles).
"""

import numpy as np
from numba import njit

from .kernels.contact_rows import (LAW_G, LAW_H, LAW_MU, LAW_E, LAW_STAMP, LAW_WARM,
                                   ROW_ACCN, ROW_ACCP, ROW_ACCT, ROW_DEPTH, ROW_KN, ROW_KT,
                                   ROW_MU, ROW_SQUEEZE, ROW_T1, ROW_T2, ROW_TARGET, ROW_TOUCH,
                                   ROW_VN0, WARM_POS, WARM_STAMP,
                                   _cross, _pair_normal, _rel_velocity, _side_mass)
from .kernels.jit import JIT

#: Pairs closer than (1 + this) times their contact distance are rows (speculative: a
#: gap only limits the speed that closes it), so that a body stopped in the sweeps stops
#: the one resting on it within the same step.
SPECULATIVE = 0.2
#: Two particles' outward normals face each other (``_surface_normal``) when their
#: cosine is below minus this.
FACE_COS = 0.9
#: A row within this gap (m) counts as touching in ``contact_sweeps.block_pass``.
TOUCH = 1e-7


@njit(**JIT)
def fill_row(pt, bd, rf, ri, n, depth, mu, e, law, warm):
    """Finish row (rf, ri) whose ints (i, j, bi, bj, key) and offsets are set: normal n
    (3-tuple), depth, friction ``mu``, restitution ``e``; ``law`` = (h, thresh); ``warm``
    (5,) the impulses to start from (normal, tangential vector, last position impulse)."""
    rf[0], rf[1], rf[2] = n
    rf[ROW_DEPTH] = depth
    # what counts as touching for ``block_pass``: a lattice resting exactly on another
    # has gaps of either sign at round-off (a subset of its rows would tilt it)
    rf[ROW_TOUCH] = -TOUCH
    rf[ROW_MU] = mu
    u0, u1, u2 = _rel_velocity(bd, pt.V, rf, ri, 0)
    vn = u0 * n[0] + u1 * n[1] + u2 * n[2]
    rf[ROW_VN0] = vn
    # the approach speed before the step: a collider does not fall with the body
    va = vn
    if ri[1] < 0:
        va -= law[LAW_H] * (law[LAW_G] * n[0] + law[LAW_G + 1] * n[1] + law[LAW_G + 2] * n[2])
    rf[ROW_TARGET] = -e * va if -va > law[1] else 0.0
    if depth < 0.0:
        # speculative (a gap): any speed that does not close the gap by the step's end
        rf[ROW_TARGET] = vn + depth / law[LAW_H]
    # tangent basis: along the sliding, else the warm friction, else any
    t0, t1, t2 = u0 - vn * n[0], u1 - vn * n[1], u2 - vn * n[2]
    tl = np.sqrt(t0 * t0 + t1 * t1 + t2 * t2)
    if not tl > 1e-12:
        t0 = warm[1] - 0.0
        t1 = warm[2] - 0.0
        t2 = warm[3] - 0.0
        wn = t0 * n[0] + t1 * n[1] + t2 * n[2]
        t0, t1, t2 = t0 - wn * n[0], t1 - wn * n[1], t2 - wn * n[2]
        tl = np.sqrt(t0 * t0 + t1 * t1 + t2 * t2)
    if not tl > 1e-12:
        if abs(n[0]) < 0.6:
            t0, t1, t2 = 0.0, n[2], -n[1]
        else:
            t0, t1, t2 = -n[2], 0.0, n[0]
        tl = np.sqrt(t0 * t0 + t1 * t1 + t2 * t2)
    t0, t1, t2 = t0 / tl, t1 / tl, t2 / tl
    s0, s1, s2 = _cross(n[0], n[1], n[2], t0, t1, t2)
    rf[ROW_T1], rf[ROW_T1 + 1], rf[ROW_T1 + 2] = t0, t1, t2
    rf[ROW_T2], rf[ROW_T2 + 1], rf[ROW_T2 + 2] = s0, s1, s2
    W = pt.W
    rf[ROW_KN] = (_side_mass(bd, W, ri[2], ri[0], rf[3], rf[4], rf[5], n[0], n[1], n[2])
                  + _side_mass(bd, W, ri[3], ri[1], rf[6], rf[7], rf[8], n[0], n[1], n[2]))
    rf[ROW_KT] = (_side_mass(bd, W, ri[2], ri[0], rf[3], rf[4], rf[5], t0, t1, t2)
                  + _side_mass(bd, W, ri[3], ri[1], rf[6], rf[7], rf[8], t0, t1, t2))
    rf[ROW_KT + 1] = (_side_mass(bd, W, ri[2], ri[0], rf[3], rf[4], rf[5], s0, s1, s2)
                      + _side_mass(bd, W, ri[3], ri[1], rf[6], rf[7], rf[8], s0, s1, s2))
    rf[ROW_ACCN] = warm[0]
    rf[ROW_ACCP] = 0.0
    # a squeeze (a collider or body pressing in, its overlap removed by position impulses
    # every step) presses as much as a normal impulse: friction counts it (a grasp holds)
    rf[ROW_SQUEEZE] = warm[4]
    rf[ROW_ACCT] = warm[1] * t0 + warm[2] * t1 + warm[3] * t2
    rf[ROW_ACCT + 1] = warm[1] * s0 + warm[2] * s1 + warm[3] * s2


@njit(inline='always', **JIT)
def _warm(store, key, law):
    """The impulses (normal, tangential vector) a row starts from: ``store[key]`` when
    stamped by the last step, times the warm-start share; and the position impulse it
    ended the last step with."""
    if store[key, WARM_STAMP] == law[LAW_STAMP] - 1.0:
        c = law[LAW_WARM]
        return (c * store[key, 0], c * store[key, 1], c * store[key, 2], c * store[key, 3],
                store[key, WARM_POS])
    return (0.0, 0.0, 0.0, 0.0, 0.0)


@njit(inline='always', **JIT)
def _offset(rf, col, bd, b, x0, x1, x2):
    """Row offset of point x from body b's centre (zero for a particle-only side)."""
    if b >= 0 and bd.share[b] > 0.0:
        rf[col] = x0 - bd.bc[b, 0]
        rf[col + 1] = x1 - bd.bc[b, 1]
        rf[col + 2] = x2 - bd.bc[b, 2]
    else:
        rf[col] = rf[col + 1] = rf[col + 2] = 0.0


@njit(**JIT)
def collider_offsets(pt, bd, rows, lo, hi, h):
    """Offsets of rows lo..hi, particles inside colliders as ``contact_statics`` and
    ``kinematic.contact_rows`` left them (particle, body, normal, depth, friction;
    restitution in the target's place, the collider's surface velocity in the second
    offset's): the particle's position at the step's start from its body's centre."""
    X, V = pt.X, pt.V
    for a in range(lo, hi):
        k = rows.i[a, 0]
        _offset(rows.f[a], 3, bd, rows.i[a, 2], X[0, k] - h * V[0, k], X[1, k] - h * V[1, k],
                X[2, k] - h * V[2, k])


@njit(**JIT)
def fill_rows(pt, bd, rows, order, kept, law, wp, wc):
    """Finish the rows ``order[:kept]`` that contact reduction kept (``group_rows``):
    their law, tangents, inverse masses and warm start (``wp`` by pair, ``wc`` by
    particle for a collider).  Their geometry, friction and restitution (in the target's
    place) are set."""
    for q in range(kept):
        a = order[q]
        rf = rows.f[a]
        ri = rows.i[a]
        warm = _warm(wp, ri[4], law) if ri[1] >= 0 else _warm(wc, ri[0], law)
        fill_row(pt, bd, rf, ri, (rf[0], rf[1], rf[2]), rf[ROW_DEPTH], rf[ROW_MU],
                 rf[ROW_TARGET], law, warm)


@njit(**JIT)
def pair_rows(pt, bd, pl, rows, law):
    """The geometry of the rows (``fill_rows`` finishes those that contact reduction
    keeps) of the overlapping pairs of the pair list (a stiff body's pairs with itself
    are left out: its shape holds them).  The normal is along the pair's separation at
    the start of the step (x - h v), the contact point the middle of the overlap there
    (the particle's own position when one side is a particle alone, so that the two
    impulses' moments cancel).  Returns the number of rows."""
    X, V, R, B = pt.X, pt.V, pt.R, pt.B
    h = law[LAW_H]
    m = 0
    for k in range(pl.n):
        i = pl.pi[k]
        j = pl.pj[k]
        if pt.W[i] + pt.W[j] <= 0.0:
            continue
        bi, bj = B[i], B[j]
        if bi == bj and bd.share[bi] > 0.0:
            continue
        if not (bd.share[bi] > 0.0 or bd.share[bj] > 0.0):
            continue                   # two soft sides: ``contact_soft.soft_pairs``
        dx, dy, dz = X[0, i] - X[0, j], X[1, i] - X[1, j], X[2, i] - X[2, j]
        d2 = dx * dx + dy * dy + dz * dz
        rr = R[i] + R[j]
        reach = (1.0 + SPECULATIVE) * rr
        if not d2 < reach * reach:
            continue
        xi0, xi1, xi2 = X[0, i] - h * V[0, i], X[1, i] - h * V[1, i], X[2, i] - h * V[2, i]
        xj0, xj1, xj2 = X[0, j] - h * V[0, j], X[1, j] - h * V[1, j], X[2, j] - h * V[2, j]
        n = _pair_normal(xi0 - xj0, xi1 - xj1, xi2 - xj2, dx, dy, dz, d2, rr)
        n = _surface_normal(pt, bd, i, j, bi, bj, n)
        if bd.share[bi] == 0.0:
            c0, c1, c2 = xi0, xi1, xi2
        elif bd.share[bj] == 0.0:
            c0, c1, c2 = xj0, xj1, xj2
        else:
            c = 0.5 * (R[j] - R[i])
            c0 = 0.5 * (xi0 + xj0) + c * n[0]
            c1 = 0.5 * (xi1 + xj1) + c * n[1]
            c2 = 0.5 * (xi2 + xj2) + c * n[2]
        rf = rows.f[m]
        ri = rows.i[m]
        ri[0], ri[1], ri[2], ri[3], ri[4] = i, j, bi, bj, k
        _offset(rf, 3, bd, bi, c0, c1, c2)
        _offset(rf, 6, bd, bj, c0, c1, c2)
        rf[0], rf[1], rf[2] = n
        rf[ROW_DEPTH] = rr - np.sqrt(d2)
        rf[ROW_MU] = law[LAW_MU]
        rf[ROW_TARGET] = law[LAW_E]
        m += 1
    return m


@njit(inline='always', **JIT)
def _outward(pt, bd, b, k):
    """Particle k's outward surface normal now (its rest normal turned with body b), or
    zero for a particle of a body with no rigid share or inside its body."""
    if not bd.share[b] > 0.0:
        return 0.0, 0.0, 0.0
    r = bd.rot[b]
    a0, a1, a2 = pt.NS[0, k], pt.NS[1, k], pt.NS[2, k]
    return (r[0] * a0 + r[1] * a1 + r[2] * a2, r[3] * a0 + r[4] * a1 + r[5] * a2,
            r[6] * a0 + r[7] * a1 + r[8] * a2)


@njit(inline='always', **JIT)
def _surface_normal(pt, bd, i, j, bi, bj, n):
    """The normal of a pair of particles on two faces of stiff bodies that face each
    other (outward normals within ``FACE_COS`` of opposite): the mean of j's outward
    normal and minus i's (two flat faces of particles touch along their normal, not along
    the line between two particle centres, which tilts as the lattices slide over each
    other like the bumps of an egg crate); else, or when it disagrees with the pair's
    normal ``n`` by more than 60 degrees, ``n``."""
    a0, a1, a2 = _outward(pt, bd, bj, j)
    c0, c1, c2 = _outward(pt, bd, bi, i)
    if a0 * c0 + a1 * c1 + a2 * c2 > -FACE_COS:
        return n                       # not two faces: an edge or a corner meets
    s0, s1, s2 = a0 - c0, a1 - c1, a2 - c2
    sl = np.sqrt(s0 * s0 + s1 * s1 + s2 * s2)
    if not sl > 1e-6:
        return n
    s0, s1, s2 = s0 / sl, s1 / sl, s2 / sl
    if s0 * n[0] + s1 * n[1] + s2 * n[2] < 0.5:
        return n
    return s0, s1, s2
