"""Compiled per-body and bookkeeping passes of the contact solve (``contact_solve.py``).

``body_frames`` gives each stiff body its mass, centre, inertia, velocity and spin at the
start of the step; ``group_rows`` sorts the contact rows by pair of bodies;
``finish_rows`` keeps the impulses for the next step's warm start and moves the stiff
bodies' particles by what the solve gave their bodies.  Like every module of the solve,
it calls no jitted function of another ``sm_ros/core`` module, only of the kernel package
(``kernels/contact_rows.py``: a module's cache is stamped with its own source and that
package's, ``kernels/jit.py``).
"""

import numpy as np
from numba import njit

from .kernels.contact_rows import (LAW_H, LAW_STAMP, ROW_ACCN, ROW_ACCP, ROW_ACCT, ROW_DEPTH,
                                   ROW_T1, ROW_T2, WARM_POS, WARM_STAMP, _cross, _imul)
from .kernels.jit import JIT


@njit(**JIT)
def body_frames(pt, off, cpl, bd, h, box, X0):
    """Per body: rigid share (1 for a stiff body, ``cpl``, with no pinned or grabbed
    particle), and for those the inverse mass, centre, inverse inertia, velocity and spin
    at the start of the step (x - h v: the solve's impulses act there, so their moments
    about the centre are those the particles get), its rotation from the rest shape
    ``X0`` (3, N) (rest centres ``bd.c0``), the bounding box now ``box`` (nb, 6); the
    step's changes cleared."""
    X, V, W, M = pt.X, pt.V, pt.W, pt.M
    a = np.zeros(9)
    for b in range(off.shape[0] - 1):
        bd.dvel[b, :] = 0.0
        s = 1.0 if cpl[b] else 0.0
        for k in range(off[b], off[b + 1]):
            if not W[k] > 0.0:
                s = 0.0
                break
        bd.share[b] = s
        if s == 0.0:
            continue
        o = off[b]
        q0, q1, q2 = X[0, o] - h * V[0, o], X[1, o] - h * V[1, o], X[2, o] - h * V[2, o]
        mt = p0 = p1 = p2 = s0 = s1 = s2 = l0 = l1 = l2 = 0.0
        xx = yy = zz = xy = yz = zx = 0.0
        apq = np.zeros(9)              # sum m (x - q) (x0 - c0)^T: the body's rotation
        lo0 = lo1 = lo2 = np.inf
        hi0 = hi1 = hi2 = -np.inf
        for k in range(o, off[b + 1]):
            lo0, lo1, lo2 = min(lo0, X[0, k]), min(lo1, X[1, k]), min(lo2, X[2, k])
            hi0, hi1, hi2 = max(hi0, X[0, k]), max(hi1, X[1, k]), max(hi2, X[2, k])
            m = M[k]
            y0 = X[0, k] - h * V[0, k] - q0
            y1 = X[1, k] - h * V[1, k] - q1
            y2 = X[2, k] - h * V[2, k] - q2
            u0, u1, u2 = m * V[0, k], m * V[1, k], m * V[2, k]
            mt += m
            p0 += u0
            p1 += u1
            p2 += u2
            s0 += m * y0
            s1 += m * y1
            s2 += m * y2
            c0, c1, c2 = _cross(y0, y1, y2, u0, u1, u2)
            l0 += c0
            l1 += c1
            l2 += c2
            e0 = X0[0, k] - bd.c0[b, 0]
            e1 = X0[1, k] - bd.c0[b, 1]
            e2 = X0[2, k] - bd.c0[b, 2]
            apq[0] += m * y0 * e0
            apq[1] += m * y0 * e1
            apq[2] += m * y0 * e2
            apq[3] += m * y1 * e0
            apq[4] += m * y1 * e1
            apq[5] += m * y1 * e2
            apq[6] += m * y2 * e0
            apq[7] += m * y2 * e1
            apq[8] += m * y2 * e2
            xx += m * y0 * y0
            yy += m * y1 * y1
            zz += m * y2 * y2
            xy += m * y0 * y1
            yz += m * y1 * y2
            zx += m * y2 * y0
        iw = 1.0 / mt
        g0, g1, g2 = s0 * iw, s1 * iw, s2 * iw
        bd.bw[b] = iw
        bd.bc[b, 0], bd.bc[b, 1], bd.bc[b, 2] = q0 + g0, q1 + g1, q2 + g2
        bd.vb[b, 0], bd.vb[b, 1], bd.vb[b, 2] = p0 * iw, p1 * iw, p2 * iw
        box[b, 0], box[b, 1], box[b, 2], box[b, 3], box[b, 4], box[b, 5] = (
            lo0, lo1, lo2, hi0, hi1, hi2)
        xx -= mt * g0 * g0
        yy -= mt * g1 * g1
        zz -= mt * g2 * g2
        xy -= mt * g0 * g1
        yz -= mt * g1 * g2
        zx -= mt * g2 * g0
        c0, c1, c2 = _cross(g0, g1, g2, p0, p1, p2)
        l0 -= c0
        l1 -= c1
        l2 -= c2
        a[0] = yy + zz
        a[4] = zz + xx
        a[8] = xx + yy
        a[1] = a[3] = -xy
        a[5] = a[7] = -yz
        a[2] = a[6] = -zx
        _inverse_sym3(a, bd.biv[b])
        w0, w1, w2 = _imul(bd.biv, b, l0, l1, l2)
        bd.bom[b, 0], bd.bom[b, 1], bd.bom[b, 2] = w0, w1, w2
        _rotation(apq, bd.rot[b])


@njit(inline='always', **JIT)
def _rotation(apq, out):
    """out (9,) = the rotation of the polar decomposition of apq (9,), row-major (the
    best-fit rotation of a body from its rest shape; the first-moment terms about the
    first particle vanish with the rest centre: sum m (x0 - c0) = 0)."""
    u, _, vt = np.linalg.svd(apq.reshape(3, 3))
    r = u @ vt
    if np.linalg.det(r) < 0.0:
        for i in range(3):
            u[i, 2] = -u[i, 2]
        r = u @ vt
    for i in range(3):
        for j in range(3):
            out[3 * i + j] = r[i, j]


@njit(inline='always', **JIT)
def _inverse_sym3(a, out):
    """out (9,) = the inverse of the symmetric 3x3 a (9,) by its adjugate; for a body of
    collinear particles (singular) the inverse on the plane across the line is not
    needed by any contact along it: the pseudo-inverse is approximated by a tiny
    regulariser."""
    tr = a[0] + a[4] + a[8]
    eps = 1e-9 * tr + 1e-300
    a0, a4, a8 = a[0] + eps, a[4] + eps, a[8] + eps
    c00 = a4 * a8 - a[5] * a[7]
    c01 = a[5] * a[6] - a[3] * a8
    c02 = a[3] * a[7] - a4 * a[6]
    idet = 1.0 / (a0 * c00 + a[1] * c01 + a[2] * c02)
    out[0] = c00 * idet
    out[1] = (a[2] * a[7] - a[1] * a8) * idet
    out[2] = (a[1] * a[5] - a[2] * a4) * idet
    out[3] = c01 * idet
    out[4] = (a0 * a8 - a[2] * a[6]) * idet
    out[5] = (a[2] * a[3] - a0 * a[5]) * idet
    out[6] = c02 * idet
    out[7] = (a[1] * a[6] - a0 * a[7]) * idet
    out[8] = (a0 * a4 - a[1] * a[3]) * idet


@njit(**JIT)
def group_rows(rows, m, nb, order, start):
    """Sort the rows by their pair of bodies (``order``) and return the number of groups,
    ``start[g]:start[g + 1]`` the positions in ``order`` of group g."""
    keys = np.empty(m, dtype=np.int64)
    for a in range(m):
        keys[a] = rows.i[a, 2] * (nb + 1) + rows.i[a, 3] + 1
    srt = np.argsort(keys, kind='mergesort')
    ng = 0
    for a in range(m):
        order[a] = srt[a]
        if a == 0 or keys[srt[a]] != keys[srt[a - 1]]:
            start[ng] = a
            ng += 1
    start[ng] = m
    return ng


@njit(**JIT)
def finish_rows(pt, bd, off, rows, m, law, wp, wc, stats):
    """Keep each row's impulses for the next step's warm start (``wp`` by pair, ``wc`` by
    particle), count the pairs per body (``stats``: touched, count, deepest), and move
    every particle of a stiff body the solve changed by its body's velocity and
    pseudo-velocity changes (dV + dW x r, r from the centre at the start of the step).
    Returns the number of pair rows."""
    touched, count, deepest = stats
    h = law[LAW_H]
    found = 0
    for a in range(m):
        rf = rows.f[a]
        ri = rows.i[a]
        store = wp if ri[1] >= 0 else wc
        k = ri[4]
        store[k, 0] = rf[ROW_ACCN]
        for c in range(3):
            store[k, 1 + c] = rf[ROW_ACCT] * rf[ROW_T1 + c] + rf[ROW_ACCT + 1] * rf[ROW_T2 + c]
        store[k, WARM_STAMP] = law[LAW_STAMP]
        store[k, WARM_POS] = rf[ROW_ACCP]
        touched[ri[2]] = 1
        if ri[1] >= 0:
            found += 1
            for b in (ri[2], ri[3]):
                touched[b] = 1
                count[b] += 1
                deepest[b] = max(deepest[b], rf[ROW_DEPTH])
    X, V = pt.X, pt.V
    for b in range(off.shape[0] - 1):
        dv = bd.dvel[b]
        if not bd.share[b] > 0.0 or not np.any(dv != 0.0):
            continue
        touched[b] = 1
        c0, c1, c2 = bd.bc[b, 0], bd.bc[b, 1], bd.bc[b, 2]
        for p in range(off[b], off[b + 1]):
            r0 = X[0, p] - h * V[0, p] - c0
            r1 = X[1, p] - h * V[1, p] - c1
            r2 = X[2, p] - h * V[2, p] - c2
            g0, g1, g2 = _cross(dv[3], dv[4], dv[5], r0, r1, r2)
            q0, q1, q2 = _cross(dv[9], dv[10], dv[11], r0, r1, r2)
            g0 += dv[0]
            g1 += dv[1]
            g2 += dv[2]
            X[0, p] += h * (g0 + dv[6] + q0)
            X[1, p] += h * (g1 + dv[7] + q1)
            X[2, p] += h * (g2 + dv[8] + q2)
            V[0, p] += g0
            V[1, p] += g1
            V[2, p] += g2
    return found


@njit(**JIT)
def guarded(rows, m, share):
    """Whether every row of ``m`` is between two stiff bodies or a stiff body and a static
    collider (then the kinetic energy of the stiff bodies alone must not rise in the
    solve: ``contact_solve.energy_guard``)."""
    for a in range(m):
        ri = rows.i[a]
        if ri[3] < -1 or not share[ri[2]] > 0.0 or (ri[3] >= 0 and not share[ri[3]] > 0.0):
            return False
    return True
