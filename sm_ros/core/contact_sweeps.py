"""Compiled sweeps of the contact solve over its rows (``contact_solve.py`` makes them;
the model is there and in ``doc/contact.md``).

Per step: the rows start from the last step's impulses (``_warm_apply``); the velocity
sweeps solve each group of rows (two bodies, or a body and a collider) as a block for the
linear part of its normal speeds (``block_pass``), then every row's normal impulse,
Jacobi within the group (``jacobi_pass``), and its friction; ``energy_guard`` takes back
what restitution over many points added to the stiff bodies' kinetic energy; the position
sweeps do the same on pseudo-velocities that move the particles and never enter the
velocities (split impulse).
"""

import numpy as np
from numba import njit

from .kernels.contact_rows import (LAW_GUARD, LAW_H, LAW_POS, LAW_VEL, ROW_ACCN, ROW_ACCP,
                                   ROW_ACCT, ROW_DEPTH, ROW_KN, ROW_KT, ROW_MU, ROW_T1,
                                   ROW_SQUEEZE, ROW_T2, ROW_TARGET, ROW_TOUCH, ROW_VN0, _apply,
                                   _cross,
                                   _rel_velocity, _side_mass)
from .kernels.jit import JIT

#: Velocity and position sweeps per step, and the share of the last step's impulses a
#: row starts from.
VEL_SWEEPS = 8
POS_SWEEPS = 4
WARM = 1.0
#: The first this many sweeps of each kind start with ``block_pass``.
BLOCK_SWEEPS = 8
#: Rows of two rigid motions averaged (Jacobi) rather than swept one by one.
JACOBI = False
#: ``block_pass`` leaves out a tilt of a patch whose rows spread less than this (m)
#: along it (an edge or a point of contact).
THIN = 1e-3
#: Share of the overlap left after the velocity solve that a step's pseudo-velocities
#: remove (1: all of it).
POS_BETA = 0.8


@njit(inline='always', **JIT)
def _friction_step(pt, bd, rf, ri, h):
    """One visit of a row's friction: the accumulated tangential impulse towards no
    sliding, clamped to the Coulomb disc mu times the accumulated normal impulse."""
    u0, u1, u2 = _rel_velocity(bd, pt.V, rf, ri, 0)
    t1, t2 = rf[ROW_T1:ROW_T1 + 3], rf[ROW_T2:ROW_T2 + 3]
    a1 = rf[ROW_ACCT] - (u0 * t1[0] + u1 * t1[1] + u2 * t1[2]) / rf[ROW_KT]
    a2 = rf[ROW_ACCT + 1] - (u0 * t2[0] + u1 * t2[1] + u2 * t2[2]) / rf[ROW_KT + 1]
    lim = rf[ROW_MU] * (rf[ROW_ACCN] + rf[ROW_SQUEEZE])
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
        lim = rf[ROW_MU] * (pn + rf[ROW_SQUEEZE])
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
def _patch_basis(rows, order, lo, hi, phi):
    """phi (cnt, 3) = (1, s, t) of the touching rows lo..hi of a group, s and t their
    points' coordinates in the patch's tangent plane over its spread along them (left
    out, 0, where the patch is thinner than ``THIN``: an edge, a point).  Returns cnt, 0
    for none or normals that cancel (then the rows alone)."""
    cnt = 0
    p0 = p1 = p2 = m0 = m1 = m2 = 0.0
    for a in range(lo, hi):
        rf = rows.f[order[a]]
        if rf[ROW_DEPTH] < rf[ROW_TOUCH]:
            continue
        cnt += 1
        m0, m1, m2 = m0 + rf[0], m1 + rf[1], m2 + rf[2]
        p0, p1, p2 = p0 + rf[3], p1 + rf[4], p2 + rf[5]
    ml = np.sqrt(m0 * m0 + m1 * m1 + m2 * m2)
    if cnt == 0 or not ml > 1e-9 * cnt:
        return 0
    p0, p1, p2 = p0 / cnt, p1 / cnt, p2 / cnt
    m0, m1, m2 = m0 / ml, m1 / ml, m2 / ml
    e0, e1, e2 = (0.0, m2, -m1) if abs(m0) < 0.6 else (-m2, 0.0, m0)
    el = np.sqrt(e0 * e0 + e1 * e1 + e2 * e2)
    e0, e1, e2 = e0 / el, e1 / el, e2 / el
    f0, f1, f2 = _cross(m0, m1, m2, e0, e1, e2)
    q = 0
    for a in range(lo, hi):
        rf = rows.f[order[a]]
        if rf[ROW_DEPTH] < rf[ROW_TOUCH]:
            continue
        d0, d1, d2 = rf[3] - p0, rf[4] - p1, rf[5] - p2
        phi[q, 0] = 1.0
        phi[q, 1] = d0 * e0 + d1 * e1 + d2 * e2
        phi[q, 2] = d0 * f0 + d1 * f1 + d2 * f2
        q += 1
    for k in (1, 2):
        sq = 0.0
        for q in range(cnt):
            sq += phi[q, k] * phi[q, k]
        spread = np.sqrt(sq / cnt)
        w = 1.0 / spread if spread > THIN else 0.0
        for q in range(cnt):
            phi[q, k] *= w
    return cnt


@njit(inline='always', **JIT)
def _solve3(a, b, out):
    """out = a^-1 b for a 3x3 a (Cramer's rule; a is regularised by the caller)."""
    c00 = a[1, 1] * a[2, 2] - a[1, 2] * a[2, 1]
    c01 = a[1, 2] * a[2, 0] - a[1, 0] * a[2, 2]
    c02 = a[1, 0] * a[2, 1] - a[1, 1] * a[2, 0]
    det = a[0, 0] * c00 + a[0, 1] * c01 + a[0, 2] * c02
    idet = 1.0 / det
    out[0] = (b[0] * c00 + b[1] * (a[0, 2] * a[2, 1] - a[0, 1] * a[2, 2])
              + b[2] * (a[0, 1] * a[1, 2] - a[0, 2] * a[1, 1])) * idet
    out[1] = (b[0] * c01 + b[1] * (a[0, 0] * a[2, 2] - a[0, 2] * a[2, 0])
              + b[2] * (a[0, 2] * a[1, 0] - a[0, 0] * a[1, 2])) * idet
    out[2] = (b[0] * c02 + b[1] * (a[0, 1] * a[2, 0] - a[0, 0] * a[2, 1])
              + b[2] * (a[0, 0] * a[1, 1] - a[0, 1] * a[1, 0])) * idet


@njit(inline='always', **JIT)
def _patch_system(pt, bd, rows, order, lo, hi, phi, vel, work):
    """The 3x3 system of a group (``work`` = (mat, rhs, buf)): mat = Phi^T K Phi, rhs =
    Phi^T (target - v_n); ``vel`` = (col, Vt, h)."""
    col, Vt, _ = vel
    mat, rhs, buf = work
    mat[:, :] = 0.0
    rhs[:] = 0.0
    q = 0
    for a in range(lo, hi):
        rf = rows.f[order[a]]
        if rf[ROW_DEPTH] < rf[ROW_TOUCH]:
            continue
        ri = rows.i[order[a]]
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


@njit(inline='always', **JIT)
def _patch_apply(pt, bd, rows, order, lo, hi, phi, coef, vel):
    """Apply lambda_r = phi_r . coef to the touching rows lo..hi, unless a row would have
    to pull (a clamped solution can push far more than the patch needs: then nothing,
    and the rows' sweeps do it alone).  Returns the largest speed change."""
    col, Vt, h = vel
    acc = ROW_ACCN if col == 0 else ROW_ACCP
    q = 0
    for a in range(lo, hi):
        rf = rows.f[order[a]]
        if rf[ROW_DEPTH] < rf[ROW_TOUCH]:
            continue
        if phi[q, 0] * coef[0] + phi[q, 1] * coef[1] + phi[q, 2] * coef[2] < -rf[acc]:
            return 0.0
        q += 1
    big = 0.0
    q = 0
    for a in range(lo, hi):
        rf = rows.f[order[a]]
        if rf[ROW_DEPTH] < rf[ROW_TOUCH]:
            continue
        lam = phi[q, 0] * coef[0] + phi[q, 1] * coef[1] + phi[q, 2] * coef[2]
        q += 1
        rf[acc] += lam
        if lam != 0.0:
            big = max(big, abs(lam) * rf[ROW_KN])
            _apply(bd, pt.X, Vt, pt.W, rf, rows.i[order[a]], lam * rf[0], lam * rf[1],
                   lam * rf[2], col, h)
    return big


@njit(**JIT)
def block_pass(pt, bd, rows, grp, col, Vt, backward):
    """Each group of rows of two rigid motions (``_rigid_group``: two stiff bodies, or
    one and a collider) solved at once for the linear part of its normal speeds over the
    contact patch: impulses lambda_r = phi_r . c, phi_r = (1, s_r, t_r) the row's point
    in the patch's tangent plane, c from the 3x3 Galerkin system Phi^T K Phi c = Phi^T
    (target - v_n).  A box landing flat or resting under a stack so gets the push and the
    torques of its whole face at once, without the spin a row-by-row sweep starts with;
    the sweeps that follow correct each row (and the clamp: accumulated impulses are
    never negative).  ``col``, ``Vt``: velocities (0, V) or pseudo-velocities (6, PV);
    ``grp`` = (order, start, groups, h); the groups in reverse order when ``backward``
    (symmetric Gauss-Seidel over the groups).  Returns the largest speed change."""
    order, start, ng, h = grp
    vel = (col, Vt, h)
    work = (np.zeros((3, 3)), np.zeros(3), np.zeros((6, 3)))
    coef = np.zeros(3)
    phi = np.zeros((max(start[ng] - start[0], 1), 3))
    big = 0.0
    for gg in range(ng):
        g = ng - 1 - gg if backward else gg
        lo, hi = start[g], start[g + 1]
        if not _rigid_group(bd, rows.i[order[lo]]) or _patch_basis(rows, order, lo, hi,
                                                                    phi) == 0:
            continue
        _patch_system(pt, bd, rows, order, lo, hi, phi, vel, work)
        mat = work[0]
        tr = mat[0, 0] + mat[1, 1] + mat[2, 2]
        if not tr > 0.0:
            continue
        for k in range(3):
            mat[k, k] += 1e-6 * tr
        _solve3(mat, work[1], coef)
        big = max(big, _patch_apply(pt, bd, rows, order, lo, hi, phi, coef, vel))
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


@njit(inline='always', **JIT)
def _row_push(pt, bd, rows, a, lam, vel):
    """Row a's accumulated normal (or position) impulse changed by ``lam``, never below
    zero, and applied; returns the speed change.  ``vel`` = (col, Vt, h)."""
    col, Vt, h = vel
    acc = ROW_ACCN if col == 0 else ROW_ACCP
    rf = rows.f[a]
    new = max(rf[acc] + lam, 0.0)
    dl = new - rf[acc]
    rf[acc] = new
    if dl == 0.0:
        return 0.0
    _apply(bd, pt.X, Vt, pt.W, rf, rows.i[a], dl * rf[0], dl * rf[1], dl * rf[2], col, h)
    return abs(dl) * rf[ROW_KN]


@njit(inline='always', **JIT)
def _rigid_group(bd, ri):
    """Whether a group (its first row's ints ``ri``) is two stiff bodies or a stiff body
    and a collider: redundant rows on the same two rigid motions."""
    return bd.share[ri[2]] > 0.0 and (ri[3] < 0 or bd.share[ri[3]] > 0.0)


@njit(**JIT)
def jacobi_pass(pt, bd, rows, grp, col, Vt):
    """Each row's normal impulse towards its target.  The rows of a group of two rigid
    motions (``_rigid_group``) all from the same state and each 1 / (rows of the group)
    of it (Jacobi, as FleX averages constraints): what ``block_pass`` leaves (rows of a
    curved patch, clamped rows, gaps closing), without favouring the rows swept first.
    The rows of a stiff body and soft particles one after the other in full
    (Gauss-Seidel): each is a particle of its own.  Returns the largest speed change."""
    order, start, ng, h = grp
    vel = (col, Vt, h)
    big = 0.0
    lam = np.zeros(max(start[ng] - start[0], 1))
    for g in range(ng):
        lo, hi = start[g], start[g + 1]
        ri = rows.i[order[lo]]
        stiff = JACOBI and _rigid_group(bd, ri)
        for a in range(lo, hi):
            rf = rows.f[order[a]]
            lam[a - lo] = 0.0
            if not rf[ROW_KN] > 0.0:
                continue
            u0, u1, u2 = _rel_velocity(bd, Vt, rf, rows.i[order[a]], col)
            target = rf[ROW_TARGET] if col == 0 else rf[ROW_VN0]
            lam[a - lo] = (target - (u0 * rf[0] + u1 * rf[1] + u2 * rf[2])) / rf[ROW_KN]
            if not stiff:
                big = max(big, _row_push(pt, bd, rows, order[a], lam[a - lo], vel))
        if not stiff:
            continue
        for a in range(lo, hi):
            big = max(big, _row_push(pt, bd, rows, order[a], lam[a - lo] / (hi - lo), vel))
    return big


@njit(**JIT)
def left_out_pass(pt, bd, rows, order, lo, hi, h):
    """One Gauss-Seidel visit of the rows contact reduction left out (``order[lo:hi]``):
    a normal impulse, never negative, where the sweeps left a pair approaching faster than
    its gap closes within the step (or at all, once it touches).  Impulses, not position
    corrections, so the points the kept rows do not cover do not sink in and both momenta
    stay exact; no restitution, so it takes energy and never adds it."""
    for q in range(lo, hi):
        a = order[q]
        rf = rows.f[a]
        ri = rows.i[a]
        n0, n1, n2 = rf[0], rf[1], rf[2]
        kn = (_side_mass(bd, pt.W, ri[2], ri[0], rf[3], rf[4], rf[5], n0, n1, n2)
              + _side_mass(bd, pt.W, ri[3], ri[1], rf[6], rf[7], rf[8], n0, n1, n2))
        if not kn > 0.0:
            continue
        u0, u1, u2 = _rel_velocity(bd, pt.V, rf, ri, 0)
        lam = (min(rf[ROW_DEPTH], 0.0) / h - (u0 * n0 + u1 * n1 + u2 * n2)) / kn
        if lam > 0.0:
            rf[ROW_ACCN] = lam
            _apply(bd, pt.X, pt.V, pt.W, rf, ri, lam * n0, lam * n1, lam * n2, 0, h)


@njit(**JIT)
def solve_rows(pt, bd, rows, m, law, tol, order, start, ng):
    """The velocity sweeps (each a pass over the groups, ``block_pass``, then normal and
    friction row by row, symmetric Gauss-Seidel, until no speed changes by more than
    ``tol``), then the position sweeps on pseudo-velocities towards removing
    ``POS_BETA`` of the overlap the velocities leave.  The rows contact reduction left
    out (``order[start[ng]:m]``) get one visit between the two."""
    h = law[LAW_H]
    _warm_apply(pt, bd, rows, m, h)
    grp = (order, start, ng, h)
    nvel = int(law[LAW_VEL])
    for it in range(nvel):
        big = 0.0
        if it < BLOCK_SWEEPS:
            big = block_pass(pt, bd, rows, grp, 0, pt.V, it % 2 == 1)
        big = max(big, jacobi_pass(pt, bd, rows, grp, 0, pt.V))
        mk = start[ng]
        for kk in range(mk):
            a = order[kk if it % 2 == 0 else mk - 1 - kk]
            rf = rows.f[a]
            if not rf[ROW_KN] > 0.0:
                continue
            ri = rows.i[a]
            if rf[ROW_MU] > 0.0:
                big = max(big, _friction_step(pt, bd, rf, ri, h))
        if big <= tol:
            break
    left_out_pass(pt, bd, rows, order, start[ng], m, h)
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
        if it < BLOCK_SWEEPS:
            block_pass(pt, bd, rows, grp, 6, PV, it % 2 == 1)
        jacobi_pass(pt, bd, rows, grp, 6, PV)
