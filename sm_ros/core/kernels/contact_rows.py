"""The contact rows of the contact solve (``sm_ros/core/contact_solve.py``,
``contact_sweeps.py``): their columns, the named structures the compiled passes take, and
the velocity of a row's two sides and the impulse on them.

Here, in the kernel package, because every ``sm_ros/core`` module that runs the solve
uses them: the cache stamp of such a module includes this package (``jit.py``), so an
edit here recompiles them all.  A side of a row is a particle i of body b with the body's
rigid share s (``Bodies.share``): its velocity is u = s (V_b + W_b x r) + (1 - s) v_i, and
an impulse P at it changes the body's velocity by s P / M_b, its spin by s I_b^-1 (r x P)
and the particle's own velocity by (1 - s) w_i P (which also moves it by h times that).
A collider side (body < 0) has infinite mass and its surface velocity in the row.
"""

from collections import namedtuple

import numpy as np
from numba import njit

from .jit import JIT

#: Columns of a contact row: normal n (from j to i), contact offsets from the centres of
#: mass of the two bodies, depth, target normal speed, inverse normal mass, accumulated
#: normal / pseudo / two tangential impulses, tangent basis, friction, the normal speed
#: at creation and the two tangential inverse masses.
ROW_N, ROW_RI, ROW_RJ, ROW_DEPTH, ROW_TARGET, ROW_KN = 0, 3, 6, 9, 10, 11
ROW_ACCN, ROW_ACCP, ROW_ACCT = 12, 13, 14
ROW_T1, ROW_T2, ROW_MU, ROW_VN0, ROW_KT, ROW_TOUCH, ROW_SQUEEZE = 16, 19, 22, 23, 24, 26, 27
ROW_WIDTH = 28
#: Columns of the warm-start stores (per pair, per particle): normal impulse, tangential
#: impulse (3), the step's number, position impulse.
WARM_STAMP, WARM_POS, WARM_WIDTH = 4, 5, 6
#: The per-body state of the solve (arrays over bodies): inverse mass, centre, inverse
#: inertia (9,), linear velocity, spin, rigid share, the changes of the step ``dvel``
#: (nb, 12): velocity, spin, pseudo-velocity, pseudo-spin; rotation from the rest shape
#: (9,) and rest centre.
Bodies = namedtuple('Bodies', 'bw bc biv vb bom share dvel rot c0')
#: The colliders as rows (``kernels.colliders.collide_point``): ground (4,), boxes (K, 8),
#: spheres (K, 6), and the restitution threshold (m/s).
Statics = namedtuple('Statics', 'ground boxes spheres')
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


@njit(inline='always', **JIT)
def _pair_normal(sx, sy, sz, dx, dy, dz, d2, rr):
    """Unit normal of a pair of particles along s (their separation at the start of
    the step), else d (now, squared length d2), else z; ``rr`` their contact distance
    sets what counts as zero."""
    sl = np.sqrt(sx * sx + sy * sy + sz * sz)
    if sl > 1e-9 * rr:
        return sx / sl, sy / sl, sz / sl
    d = np.sqrt(d2)
    if d > 1e-9 * rr:
        return dx / d, dy / d, dz / d
    return 0.0, 0.0, 1.0
