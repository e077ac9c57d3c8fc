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

from collections import namedtuple

import numpy as np
from numba import njit

from .kernels.jit import JIT

#: Columns of a contact row: normal n (from j to i), contact offsets from the centres of
#: mass of the two bodies, depth, target normal speed, inverse normal mass, accumulated
#: normal / pseudo / two tangential impulses, tangent basis, friction, the normal speed
#: at creation and the two tangential inverse masses.
ROW_N, ROW_RI, ROW_RJ, ROW_DEPTH, ROW_TARGET, ROW_KN = 0, 3, 6, 9, 10, 11
ROW_ACCN, ROW_ACCP, ROW_ACCT = 12, 13, 14
ROW_T1, ROW_T2, ROW_MU, ROW_VN0, ROW_KT, ROW_TOUCH = 16, 19, 22, 23, 24, 26
ROW_WIDTH = 27
#: (``contact_frames.py`` repeats the numbers of the columns it reads.)
#: Velocity and position sweeps per step, and the share of the last step's impulses a
#: row starts from.
VEL_SWEEPS = 8
POS_SWEEPS = 4
#: The last this many velocity sweeps also visit each row's normal alone (the others
#: only the groups, ``block_pass``, which keeps a symmetric load symmetric).
ROW_SWEEPS = 0
WARM = 1.0
#: Pairs closer than (1 + this) times their contact distance are rows (speculative: a
#: gap only limits the speed that closes it), so that a body stopped in the sweeps stops
#: the one resting on it within the same step.
SPECULATIVE = 0.2
#: ``block_pass`` leaves out a tilt of a patch whose rows spread less than this (m)
#: along it (an edge or a point of contact).
THIN = 1.0
#: Two particles' outward normals face each other (``_surface_normal``) when their
#: cosine is below minus this.
FACE_COS = 0.9
#: A row within this gap (m) counts as touching in ``block_pass``.
TOUCH = 1e-7
#: Share of the overlap left after the velocity solve that a step's pseudo-velocities
#: remove (1: all of it).
POS_BETA = 0.8

#: The per-body state of the solve (arrays over bodies): inverse mass, centre, inverse
#: inertia (9,), linear velocity, spin, rigid share, the changes of the step ``dvel``
#: (nb, 12): velocity, spin, pseudo-velocity, pseudo-spin; rotation from the rest shape
#: (9,) and rest centre.
Bodies = namedtuple('Bodies', 'bw bc biv vb bom share dvel rot c0')
#: The colliders as rows (``kernels.colliders.collide_point``): ground (4,), boxes (K, 8),
#: spheres (K, 6), and the restitution threshold (m/s).
Statics = namedtuple('Statics', 'ground boxes spheres')


@njit(inline='always', **JIT)
def _cross(a0, a1, a2, b0, b1, b2):
    return a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0


@njit(inline='always', **JIT)
def _imul(biv, b, a0, a1, a2):
    """biv[b] (a 3x3 row-major inverse inertia) times a."""
    m = biv[b]
    return (m[0] * a0 + m[1] * a1 + m[2] * a2, m[3] * a0 + m[4] * a1 + m[5] * a2,
            m[6] * a0 + m[7] * a1 + m[8] * a2)


@njit(inline='always', **JIT)
def _side_mass(bd, W, b, i, r0, r1, r2, d0, d1, d2):
    """Inverse mass of side (body b, particle i, offset r) along the unit direction d."""
    if b < 0:
        return 0.0
    s = bd.share[b]
    k = (1.0 - s) * (1.0 - s) * W[i]
    if s > 0.0:
        c0, c1, c2 = _cross(r0, r1, r2, d0, d1, d2)
        a0, a1, a2 = _imul(bd.biv, b, c0, c1, c2)
        k += s * s * (bd.bw[b] + c0 * a0 + c1 * a1 + c2 * a2)
    return k


@njit(inline='always', **JIT)
def _side_velocity(bd, Vt, b, i, r0, r1, r2, col):
    """u of a side: s (V_b + W_b x r) + (1 - s) v_i with the step's changes so far
    (``col`` 0: velocities, ``Vt`` = V; 6: pseudo-velocities, ``Vt`` = their particle
    part)."""
    if b < 0:                          # a collider: its surface velocity (in the offset)
        if col == 0:
            return r0, r1, r2
        return 0.0, 0.0, 0.0
    s = bd.share[b]
    u0 = (1.0 - s) * Vt[0, i]
    u1 = (1.0 - s) * Vt[1, i]
    u2 = (1.0 - s) * Vt[2, i]
    if s > 0.0:
        dv = bd.dvel[b]
        l0, l1, l2 = dv[col], dv[col + 1], dv[col + 2]
        w0, w1, w2 = dv[col + 3], dv[col + 4], dv[col + 5]
        if col == 0:
            l0 += bd.vb[b, 0]
            l1 += bd.vb[b, 1]
            l2 += bd.vb[b, 2]
            w0 += bd.bom[b, 0]
            w1 += bd.bom[b, 1]
            w2 += bd.bom[b, 2]
        c0, c1, c2 = _cross(w0, w1, w2, r0, r1, r2)
        u0 += s * (l0 + c0)
        u1 += s * (l1 + c1)
        u2 += s * (l2 + c2)
    return u0, u1, u2


@njit(inline='always', **JIT)
def _push(bd, X, Vt, W, b, i, r, p0, p1, p2, col, h):
    """Impulse p on a side (offset r = (r0, r1, r2)): its body's share to ``dvel[b, col:col
    + 6]``, the particle's own to ``Vt`` (V or the pseudo-velocities), which also moves it
    by h times the change."""
    if b < 0:
        return
    s = bd.share[b]
    c = (1.0 - s) * W[i]
    if c > 0.0:
        Vt[0, i] += c * p0
        Vt[1, i] += c * p1
        Vt[2, i] += c * p2
        X[0, i] += h * c * p0
        X[1, i] += h * c * p1
        X[2, i] += h * c * p2
    if s > 0.0:
        dv = bd.dvel[b]
        m = s * bd.bw[b]
        dv[col] += m * p0
        dv[col + 1] += m * p1
        dv[col + 2] += m * p2
        c0, c1, c2 = _cross(r[0], r[1], r[2], p0, p1, p2)
        a0, a1, a2 = _imul(bd.biv, b, c0, c1, c2)
        dv[col + 3] += s * a0
        dv[col + 4] += s * a1
        dv[col + 5] += s * a2


@njit(inline='always', **JIT)
def _rel_velocity(bd, Vt, rf, ri, col):
    """Relative velocity u_i - u_j of row ``rf`` (floats) / ``ri`` (ints)."""
    a0, a1, a2 = _side_velocity(bd, Vt, ri[2], ri[0], rf[3], rf[4], rf[5], col)
    b0, b1, b2 = _side_velocity(bd, Vt, ri[3], ri[1], rf[6], rf[7], rf[8], col)
    return a0 - b0, a1 - b1, a2 - b2


@njit(inline='always', **JIT)
def _apply(bd, X, Vt, W, rf, ri, p0, p1, p2, col, h):
    """Impulse p on side i of a row and -p on side j."""
    _push(bd, X, Vt, W, ri[2], ri[0], rf[3:6], p0, p1, p2, col, h)
    _push(bd, X, Vt, W, ri[3], ri[1], rf[6:9], -p0, -p1, -p2, col, h)


@njit(**JIT)
def fill_row(pt, bd, rf, ri, n, depth, mu, e, law, warm):
    """Finish row (rf, ri) whose ints (i, j, bi, bj, key) and offsets are set: normal n
    (3-tuple), depth, friction ``mu``, restitution ``e``; ``law`` = (h, thresh); ``warm``
    (4,) the impulses to start from (normal, tangential vector)."""
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
    rf[ROW_ACCT] = warm[1] * t0 + warm[2] * t1 + warm[3] * t2
    rf[ROW_ACCT + 1] = warm[1] * s0 + warm[2] * s1 + warm[3] * s2


#: The particles (flat state): positions, velocities, inverse masses, radii, bodies,
#: masses, the particles' pseudo-velocities (3, N) of the position sweeps and their
#: outward surface normals in the rest shape (3, N; zero inside a body).
Particles = namedtuple('Particles', 'X V W R B M PV NS')
#: Contact rows: floats (M, ROW_WIDTH) and ints (M, 5); the pair list (pi, pj, count).
Rows = namedtuple('Rows', 'f i')
PairList = namedtuple('PairList', 'pi pj n')
#: ``law`` entries: step, restitution threshold, body-body friction and restitution, the
#: step's number (warm-start stamps), the warm-start share, velocity and position sweeps,
#: gravity (3), whether ``energy_guard`` applies (1: every row of a stiff body against a
#: stiff body or a static collider).
LAW_H, LAW_THRESH, LAW_MU, LAW_E, LAW_STAMP, LAW_WARM, LAW_VEL, LAW_POS = 0, 1, 2, 3, 4, 5, 6, 7
LAW_G = 8
LAW_GUARD = 11


@njit(inline='always', **JIT)
def _warm(store, key, law):
    """The impulses (normal, tangential vector) a row starts from: ``store[key]`` when
    stamped by the last step, times the warm-start share."""
    if store[key, 4] == law[LAW_STAMP] - 1.0:
        c = law[LAW_WARM]
        return (c * store[key, 0], c * store[key, 1], c * store[key, 2], c * store[key, 3])
    return (0.0, 0.0, 0.0, 0.0)


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
def fill_collider_rows(pt, bd, rows, lo, hi, law, wc):
    """Finish rows lo..hi, particles inside colliders as ``contact_statics`` and
    ``kinematic.contact_rows`` left them (particle, body, normal, depth, friction;
    restitution in the target's place, the collider's surface velocity in the second
    offset's): the offset from the body's centre is the particle's position at the
    step's start."""
    h = law[LAW_H]
    X, V = pt.X, pt.V
    for a in range(lo, hi):
        rf = rows.f[a]
        ri = rows.i[a]
        k = ri[0]
        _offset(rf, 3, bd, ri[2], X[0, k] - h * V[0, k], X[1, k] - h * V[1, k],
                X[2, k] - h * V[2, k])
        fill_row(pt, bd, rf, ri, (rf[0], rf[1], rf[2]), rf[ROW_DEPTH], rf[ROW_MU],
                 rf[ROW_TARGET], law, _warm(wc, k, law))


@njit(**JIT)
def pair_rows(pt, bd, pl, rows, law, wp):
    """Rows of the overlapping pairs of the pair list (a stiff body's pairs with itself
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
        fill_row(pt, bd, rf, ri, n, rr - np.sqrt(d2), law[LAW_MU], law[LAW_E], law,
                 _warm(wp, k, law))
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


@njit(inline='always', **JIT)
def _pair_normal(sx, sy, sz, dx, dy, dz, d2, rr):
    """Unit normal along s (the start-of-step separation), else d, else z."""
    sl = np.sqrt(sx * sx + sy * sy + sz * sz)
    if sl > 1e-9 * rr:
        return sx / sl, sy / sl, sz / sl
    d = np.sqrt(d2)
    if d > 1e-9 * rr:
        return dx / d, dy / d, dz / d
    return 0.0, 0.0, 1.0


@njit(inline='always', **JIT)
def _normal_step(pt, bd, rf, ri, h, col, Vt, target, acc):
    """One visit of a row's normal constraint (velocity, col 0, or pseudo-velocity, col
    6): the accumulated impulse ``rf[acc]`` (never negative) towards the normal speed
    ``target``; returns the speed change."""
    u0, u1, u2 = _rel_velocity(bd, Vt, rf, ri, col)
    vn = u0 * rf[0] + u1 * rf[1] + u2 * rf[2]
    lam = (target - vn) / rf[ROW_KN]
    new = max(rf[acc] + lam, 0.0)
    lam = new - rf[acc]
    rf[acc] = new
    if lam != 0.0:
        _apply(bd, pt.X, Vt, pt.W, rf, ri, lam * rf[0], lam * rf[1], lam * rf[2], col, h)
    return abs(lam) * rf[ROW_KN]


@njit(inline='always', **JIT)
def _friction_step(pt, bd, rf, ri, h):
    """One visit of a row's friction: the accumulated tangential impulse towards no
    sliding, clamped to the Coulomb disc mu times the accumulated normal impulse."""
    u0, u1, u2 = _rel_velocity(bd, pt.V, rf, ri, 0)
    t1, t2 = rf[ROW_T1:ROW_T1 + 3], rf[ROW_T2:ROW_T2 + 3]
    a1 = rf[ROW_ACCT] - (u0 * t1[0] + u1 * t1[1] + u2 * t1[2]) / rf[ROW_KT]
    a2 = rf[ROW_ACCT + 1] - (u0 * t2[0] + u1 * t2[1] + u2 * t2[2]) / rf[ROW_KT + 1]
    lim = rf[ROW_MU] * rf[ROW_ACCN]
    nrm = np.sqrt(a1 * a1 + a2 * a2)
    if nrm > lim:
        c = lim / nrm
        a1 *= c
        a2 *= c
    d1 = a1 - rf[ROW_ACCT]
    d2 = a2 - rf[ROW_ACCT + 1]
    rf[ROW_ACCT] = a1
    rf[ROW_ACCT + 1] = a2
    if d1 != 0.0 or d2 != 0.0:
        _apply(bd, pt.X, pt.V, pt.W, rf, ri, d1 * t1[0] + d2 * t2[0], d1 * t1[1] + d2 * t2[1],
               d1 * t1[2] + d2 * t2[2], 0, h)
    return abs(d1) * rf[ROW_KT] + abs(d2) * rf[ROW_KT + 1]


@njit(**JIT)
def _warm_apply(pt, bd, rows, m, h):
    """Apply the impulses the rows start from (their warm start, clamped to the disc)."""
    for a in range(m):
        rf = rows.f[a]
        pn = rf[ROW_ACCN]
        if not (pn > 0.0 and rf[ROW_KN] > 0.0):
            rf[ROW_ACCN] = rf[ROW_ACCT] = rf[ROW_ACCT + 1] = 0.0
            continue
        a1, a2 = rf[ROW_ACCT], rf[ROW_ACCT + 1]
        nrm = np.sqrt(a1 * a1 + a2 * a2)
        lim = rf[ROW_MU] * pn
        if nrm > lim:
            a1 *= lim / nrm
            a2 *= lim / nrm
        rf[ROW_ACCT], rf[ROW_ACCT + 1] = a1, a2
        p0 = pn * rf[0] + a1 * rf[ROW_T1] + a2 * rf[ROW_T2]
        p1 = pn * rf[1] + a1 * rf[ROW_T1 + 1] + a2 * rf[ROW_T2 + 1]
        p2 = pn * rf[2] + a1 * rf[ROW_T1 + 2] + a2 * rf[ROW_T2 + 2]
        _apply(bd, pt.X, pt.V, pt.W, rf, rows.i[a], p0, p1, p2, 0, h)


@njit(inline='always', **JIT)
def _side_block(bd, b, rows, order, lo, hi, side, phi, mat, buf):
    """Add to ``mat`` (3, 3) one side's part of a group's block matrix: s^2 (M^-1 N^T N +
    A^T I^-1 A), N and A (3, 3) the sums over the rows of n phi^T and (r x n) phi^T
    (``phi`` (cnt, 3) the rows' basis values)."""
    if b < 0 or not bd.share[b] > 0.0:
        return
    buf[:, :] = 0.0                    # rows 0-2: N, rows 3-5: A
    q = 0
    for a in range(lo, hi):
        rf = rows.f[order[a]]
        if rf[ROW_DEPTH] < rf[ROW_TOUCH]:
            continue
        o = 3 + 3 * side
        c0, c1, c2 = _cross(rf[o], rf[o + 1], rf[o + 2], rf[0], rf[1], rf[2])
        for k in range(3):
            f = phi[q, k]
            buf[0, k] += rf[0] * f
            buf[1, k] += rf[1] * f
            buf[2, k] += rf[2] * f
            buf[3, k] += c0 * f
            buf[4, k] += c1 * f
            buf[5, k] += c2 * f
        q += 1
    s2 = bd.share[b] * bd.share[b]
    iv = bd.biv[b]
    for k in range(3):
        i0, i1, i2 = (iv[0] * buf[3, k] + iv[1] * buf[4, k] + iv[2] * buf[5, k],
                      iv[3] * buf[3, k] + iv[4] * buf[4, k] + iv[5] * buf[5, k],
                      iv[6] * buf[3, k] + iv[7] * buf[4, k] + iv[8] * buf[5, k])
        for c in range(3):
            mat[c, k] += s2 * (bd.bw[b] * (buf[0, c] * buf[0, k] + buf[1, c] * buf[1, k]
                                           + buf[2, c] * buf[2, k])
                               + buf[3, c] * i0 + buf[4, c] * i1 + buf[5, c] * i2)


@njit(inline='always', **JIT)
def _row_reach(rows, order, lo):
    """A length of a group's scale: its first row's depth plus contact gap (the mean
    normal speeds need no basis along a spread far below it)."""
    return 1e-3


@njit(**JIT)
def block_pass(pt, bd, rows, grp, col, Vt, backward):
    """Each group of rows in contact (two bodies, or a body and a collider) solved at
    once for the linear part of its normal speeds over the contact patch: impulses
    lambda_r = phi_r . c, phi_r = (1, s_r, t_r) the row's point in the patch's tangent
    plane, with c from the 3x3 Galerkin system Phi^T K Phi c = Phi^T (target - v_n).  A
    box landing flat or resting under a stack so gets the push and the torques of its
    whole face at once, without the spin a row-by-row sweep starts with; the sweeps that
    follow correct each row (and the clamp, accumulated impulses never negative).
    ``col``, ``Vt``: velocities (0, V) or pseudo-velocities (6, PV); ``grp`` = (order,
    start, groups, h); the groups in reverse order when ``backward`` (symmetric
    Gauss-Seidel over the groups).  Returns the largest speed change."""
    order, start, ng, h = grp
    acc = ROW_ACCN if col == 0 else ROW_ACCP
    big = 0.0
    mat = np.zeros((3, 3))
    rhs = np.zeros(3)
    buf = np.zeros((6, 3))
    phi = np.zeros((max(start[ng] - start[0], 1), 3))
    for gg in range(ng):
        g = ng - 1 - gg if backward else gg
        lo, hi = start[g], start[g + 1]
        cnt = 0
        p0 = p1 = p2 = m0 = m1 = m2 = 0.0
        for a in range(lo, hi):
            rf = rows.f[order[a]]
            if rf[ROW_DEPTH] < rf[ROW_TOUCH]:
                continue
            cnt += 1
            m0 += rf[0]
            m1 += rf[1]
            m2 += rf[2]
            p0 += rf[3]
            p1 += rf[4]
            p2 += rf[5]
        if cnt == 0:
            continue
        p0, p1, p2 = p0 / cnt, p1 / cnt, p2 / cnt
        ml = np.sqrt(m0 * m0 + m1 * m1 + m2 * m2)
        m0, m1, m2 = m0 / ml, m1 / ml, m2 / ml
        if abs(m0) < 0.6:
            e0, e1, e2 = 0.0, m2, -m1
        else:
            e0, e1, e2 = -m2, 0.0, m0
        el = np.sqrt(e0 * e0 + e1 * e1 + e2 * e2)
        e0, e1, e2 = e0 / el, e1 / el, e2 / el
        f0, f1, f2 = _cross(m0, m1, m2, e0, e1, e2)
        # the patch's spread along e and f: a basis function of a patch too thin along
        # its direction (an edge, a point) is left out
        s1 = s2 = 0.0
        for a in range(lo, hi):
            rf = rows.f[order[a]]
            if rf[ROW_DEPTH] < rf[ROW_TOUCH]:
                continue
            d0, d1, d2 = rf[3] - p0, rf[4] - p1, rf[5] - p2
            s1 += (d0 * e0 + d1 * e1 + d2 * e2) ** 2
            s2 += (d0 * f0 + d1 * f1 + d2 * f2) ** 2
        s1 = np.sqrt(s1 / cnt)
        s2 = np.sqrt(s2 / cnt)
        w1 = 1.0 / s1 if s1 > THIN * _row_reach(rows, order, lo) else 0.0
        w2 = 1.0 / s2 if s2 > THIN * _row_reach(rows, order, lo) else 0.0
        mat[:, :] = 0.0
        rhs[:] = 0.0
        q = 0
        for a in range(lo, hi):
            rf = rows.f[order[a]]
            if rf[ROW_DEPTH] < rf[ROW_TOUCH]:
                continue
            ri = rows.i[order[a]]
            d0, d1, d2 = rf[3] - p0, rf[4] - p1, rf[5] - p2
            phi[q, 0] = 1.0
            phi[q, 1] = (d0 * e0 + d1 * e1 + d2 * e2) * w1
            phi[q, 2] = (d0 * f0 + d1 * f1 + d2 * f2) * w2
            u0, u1, u2 = _rel_velocity(bd, Vt, rf, ri, col)
            gap = (rf[ROW_TARGET] if col == 0 else rf[ROW_VN0]) - (
                u0 * rf[0] + u1 * rf[1] + u2 * rf[2])
            loc = 0.0
            for c in range(2):
                b = ri[2 + c]
                if b >= 0:
                    loc += (1.0 - bd.share[b]) ** 2 * pt.W[ri[c]]
            for k in range(3):
                rhs[k] += phi[q, k] * gap
                for c in range(3):
                    mat[k, c] += loc * phi[q, k] * phi[q, c]
            q += 1
        _side_block(bd, rows.i[order[lo], 2], rows, order, lo, hi, 0, phi, mat, buf)
        _side_block(bd, rows.i[order[lo], 3], rows, order, lo, hi, 1, phi, mat, buf)
        tr = mat[0, 0] + mat[1, 1] + mat[2, 2]
        if not tr > 0.0:
            continue
        for k in range(3):
            mat[k, k] += 1e-6 * tr
        c = np.linalg.solve(mat, rhs)
        # only a solution no row would have to pull for is taken (a clamped one can push
        # far more than the patch needs); else the rows' sweeps do it alone
        q = 0
        pulls = False
        for a in range(lo, hi):
            rf = rows.f[order[a]]
            if rf[ROW_DEPTH] < rf[ROW_TOUCH]:
                continue
            if phi[q, 0] * c[0] + phi[q, 1] * c[1] + phi[q, 2] * c[2] < -rf[acc]:
                pulls = True
            q += 1
        if pulls:
            continue
        q = 0
        for a in range(lo, hi):
            rf = rows.f[order[a]]
            if rf[ROW_DEPTH] < rf[ROW_TOUCH]:
                continue
            lam = phi[q, 0] * c[0] + phi[q, 1] * c[1] + phi[q, 2] * c[2]
            q += 1
            rf[acc] += lam
            if lam != 0.0:
                big = max(big, abs(lam) * rf[ROW_KN])
                _apply(bd, pt.X, Vt, pt.W, rf, rows.i[order[a]], lam * rf[0], lam * rf[1],
                       lam * rf[2], col, h)
    return big


@njit(**JIT)
def energy_guard(bd):
    """Scale the velocity changes of the step's stiff bodies by one common factor when
    they raised the bodies' kinetic energy (restitution over many contact points can:
    Newton's law per point is not energy-consistent): K(s) = K0 + s A + s^2 B back to
    K0.  A common factor scales every impulse alike, so both momenta stay exact."""
    lin = quad = 0.0
    for b in range(bd.share.shape[0]):
        if not bd.share[b] > 0.0:
            continue
        dv = bd.dvel[b]
        if dv[0] == 0.0 and dv[1] == 0.0 and dv[2] == 0.0 and dv[3] == 0.0 and (
                dv[4] == 0.0 and dv[5] == 0.0):
            continue
        inertia = np.linalg.inv(bd.biv[b].reshape(3, 3))
        mass = 1.0 / bd.bw[b]
        for k in range(3):
            lin += mass * bd.vb[b, k] * dv[k]
            quad += 0.5 * mass * dv[k] * dv[k]
            for c in range(3):
                lin += bd.bom[b, k] * inertia[k, c] * dv[3 + c]
                quad += 0.5 * dv[3 + k] * inertia[k, c] * dv[3 + c]
    if lin + quad > 0.0 and quad > 0.0 and lin < 0.0:
        f = -lin / quad
        for b in range(bd.share.shape[0]):
            for k in range(6):
                bd.dvel[b, k] *= f


@njit(**JIT)
def jacobi_pass(pt, bd, rows, grp, col, Vt):
    """Each row's normal impulse towards its target, all rows of a group from the same
    state and each 1 / (rows of the group) of it (Jacobi, as FleX averages constraints):
    what ``block_pass`` leaves (rows of a curved patch, clamped rows, gaps closing),
    without favouring the rows swept first.  Returns the largest speed change."""
    order, start, ng, h = grp
    acc = ROW_ACCN if col == 0 else ROW_ACCP
    big = 0.0
    lam = np.zeros(max(start[ng] - start[0], 1))
    for g in range(ng):
        lo, hi = start[g], start[g + 1]
        for a in range(lo, hi):
            rf = rows.f[order[a]]
            lam[a - lo] = 0.0
            if not rf[ROW_KN] > 0.0:
                continue
            u0, u1, u2 = _rel_velocity(bd, Vt, rf, rows.i[order[a]], col)
            target = rf[ROW_TARGET] if col == 0 else rf[ROW_VN0]
            lam[a - lo] = (target - (u0 * rf[0] + u1 * rf[1] + u2 * rf[2])) / rf[ROW_KN]
        for a in range(lo, hi):
            rf = rows.f[order[a]]
            new = max(rf[acc] + lam[a - lo] / (hi - lo), 0.0)
            dl = new - rf[acc]
            rf[acc] = new
            if dl != 0.0:
                big = max(big, abs(dl) * rf[ROW_KN])
                _apply(bd, pt.X, Vt, pt.W, rf, rows.i[order[a]], dl * rf[0], dl * rf[1],
                       dl * rf[2], col, h)
    return big


@njit(**JIT)
def solve_rows(pt, bd, rows, m, law, tol, order, start, ng):
    """The velocity sweeps (each a pass over the groups, ``block_pass``, then normal and
    friction row by row, symmetric Gauss-Seidel, until no speed changes by more than
    ``tol``), then the position sweeps on pseudo-velocities towards removing
    ``POS_BETA`` of the overlap the velocities leave."""
    h = law[LAW_H]
    _warm_apply(pt, bd, rows, m, h)
    grp = (order, start, ng, h)
    nvel = int(law[LAW_VEL])
    for it in range(nvel):
        big = block_pass(pt, bd, rows, grp, 0, pt.V, it % 2 == 1)
        big = max(big, jacobi_pass(pt, bd, rows, grp, 0, pt.V))
        for kk in range(m):
            a = order[kk if it % 2 == 0 else m - 1 - kk]
            rf = rows.f[a]
            if not rf[ROW_KN] > 0.0:
                continue
            ri = rows.i[a]
            if rf[ROW_MU] > 0.0:
                big = max(big, _friction_step(pt, bd, rf, ri, h))
        if big <= tol:
            break
    if law[LAW_GUARD] > 0.0:
        energy_guard(bd)
    PV = pt.PV
    for a in range(m):
        rf = rows.f[a]
        ri = rows.i[a]
        u0, u1, u2 = _rel_velocity(bd, pt.V, rf, ri, 0)
        vn = u0 * rf[0] + u1 * rf[1] + u2 * rf[2]
        left = rf[ROW_DEPTH] - h * (vn - rf[ROW_VN0])
        rf[ROW_VN0] = POS_BETA * max(left, 0.0) / h
        rf[ROW_ACCP] = 0.0
        for c in range(2):
            p = ri[c]
            if p >= 0:
                PV[0, p] = PV[1, p] = PV[2, p] = 0.0
    for it in range(int(law[LAW_POS])):
        block_pass(pt, bd, rows, grp, 6, PV, it % 2 == 1)
        jacobi_pass(pt, bd, rows, grp, 6, PV)
