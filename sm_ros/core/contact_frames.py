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
                                   ROW_KN, ROW_T1, ROW_T2, WARM_POS, WARM_STAMP, _cross,
                                   _imul)
from .kernels.jit import JIT

#: Contact reduction (``group_rows``): a group of two stiff bodies (or a stiff body and a
#: collider) is split into at most ``PATCHES`` flat patches (normals within
#: acos(``FLAT_COS``) of the patch's first), each keeping at most ``KEEP`` rows.
KEEP = 17
FLAT_COS = 0.995
PATCHES = 4
#: A row deeper than this share of its contact distance is always kept: reduction only
#: leaves out rows its kept ones cover, never a point that has sunk in.
DEEP = 0.25


#: Entries of ``_body_sums``' accumulator: mass, momentum (3), first moment (3), angular
#: momentum (3), second moments xx yy zz xy yz zx (6), sum m y (x0 - c0)^T (9), bounding
#: box (6).
S_M, S_P, S_S, S_L, S_MOM, S_APQ, S_BOX, S_WIDTH = 0, 1, 4, 7, 10, 16, 25, 31


@njit(inline='always', **JIT)
def _body_sums(pt, X0, c0, o, e, h, q, acc):
    """The sums over particles o..e of a body about q (its first particle at the step's
    start, for round-off), into ``acc`` (``S_*``)."""
    X, V, M = pt.X, pt.V, pt.M
    acc[:S_BOX] = 0.0
    acc[S_BOX:S_BOX + 3] = np.inf
    acc[S_BOX + 3:S_WIDTH] = -np.inf
    for k in range(o, e):
        for c in range(3):
            acc[S_BOX + c] = min(acc[S_BOX + c], X[c, k])
            acc[S_BOX + 3 + c] = max(acc[S_BOX + 3 + c], X[c, k])
        m = M[k]
        y0 = X[0, k] - h * V[0, k] - q[0]
        y1 = X[1, k] - h * V[1, k] - q[1]
        y2 = X[2, k] - h * V[2, k] - q[2]
        u0, u1, u2 = m * V[0, k], m * V[1, k], m * V[2, k]
        acc[S_M] += m
        w0, w1, w2 = _cross(y0, y1, y2, u0, u1, u2)
        acc[S_P] += u0
        acc[S_P + 1] += u1
        acc[S_P + 2] += u2
        acc[S_S] += m * y0
        acc[S_S + 1] += m * y1
        acc[S_S + 2] += m * y2
        acc[S_L] += w0
        acc[S_L + 1] += w1
        acc[S_L + 2] += w2
        for d in range(3):
            r = m * (X0[d, k] - c0[d])
            acc[S_APQ + d] += y0 * r
            acc[S_APQ + 3 + d] += y1 * r
            acc[S_APQ + 6 + d] += y2 * r
        acc[S_MOM] += m * y0 * y0
        acc[S_MOM + 1] += m * y1 * y1
        acc[S_MOM + 2] += m * y2 * y2
        acc[S_MOM + 3] += m * y0 * y1
        acc[S_MOM + 4] += m * y1 * y2
        acc[S_MOM + 5] += m * y2 * y0


@njit(**JIT)
def body_frames(pt, off, cpl, bd, h, box, X0):
    """Per body: rigid share (1 for a stiff body, ``cpl``, with no pinned or grabbed
    particle), and for those the inverse mass, centre, inverse inertia, velocity and spin
    at the start of the step (x - h v: the solve's impulses act there, so their moments
    about the centre are those the particles get), its rotation from the rest shape
    ``X0`` (3, N) (rest centres ``bd.c0``), the bounding box now ``box`` (nb, 6); the
    step's changes cleared."""
    X, V, W = pt.X, pt.V, pt.W
    a = np.zeros(9)
    acc = np.zeros(S_WIDTH)
    q = np.zeros(3)
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
        for c in range(3):
            q[c] = X[c, o] - h * V[c, o]
        _body_sums(pt, X0, bd.c0[b], o, off[b + 1], h, q, acc)
        mt = acc[S_M]
        if not (mt > 0.0 and np.isfinite(np.sum(acc))):
            bd.share[b] = 0.0              # massless or non-finite (reset after the step)
            continue
        iw = 1.0 / mt
        bd.bw[b] = iw
        g = acc[S_S:S_S + 3] * iw
        p = acc[S_P:S_P + 3]
        for c in range(3):
            bd.bc[b, c] = q[c] + g[c]
            bd.vb[b, c] = p[c] * iw
        box[b, :] = acc[S_BOX:S_WIDTH]
        mom = acc[S_MOM:S_MOM + 6]
        xx = mom[0] - mt * g[0] * g[0]
        yy = mom[1] - mt * g[1] * g[1]
        zz = mom[2] - mt * g[2] * g[2]
        xy = mom[3] - mt * g[0] * g[1]
        yz = mom[4] - mt * g[1] * g[2]
        zx = mom[5] - mt * g[2] * g[0]
        c0, c1, c2 = _cross(g[0], g[1], g[2], p[0], p[1], p[2])
        l0, l1, l2 = acc[S_L] - c0, acc[S_L + 1] - c1, acc[S_L + 2] - c2
        a[0] = yy + zz
        a[4] = zz + xx
        a[8] = xx + yy
        a[1] = a[3] = -xy
        a[5] = a[7] = -yz
        a[2] = a[6] = -zx
        _inverse_sym3(a, bd.biv[b])
        w0, w1, w2 = _imul(bd.biv, b, l0, l1, l2)
        bd.bom[b, 0], bd.bom[b, 1], bd.bom[b, 2] = w0, w1, w2
        _rotation(acc[S_APQ:S_APQ + 9], bd.rot[b])


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
    regulariser.  A single particle (no inertia) takes no spin: zero."""
    tr = a[0] + a[4] + a[8]
    eps = 1e-9 * tr
    a0, a4, a8 = a[0] + eps, a[4] + eps, a[8] + eps
    c00 = a4 * a8 - a[5] * a[7]
    c01 = a[5] * a[6] - a[3] * a8
    c02 = a[3] * a[7] - a4 * a[6]
    det = a0 * c00 + a[1] * c01 + a[2] * c02
    if not det > 0.0:
        out[:] = 0.0
        return
    idet = 1.0 / det
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
def group_rows(rows, m, share, order, start, radii):
    """Sort the rows by their pair of bodies (``order``) and return the number of groups,
    ``start[g]:start[g + 1]`` the positions in ``order`` of group g.  Contact reduction,
    as Bullet's manifold keeps four points: a group of two stiff bodies, or of a stiff
    body and a collider, keeps at most ``KEEP`` rows (``_reduce``); in a group of a stiff
    and a soft body each soft particle keeps its deepest row.  The others follow the kept
    ones in ``order`` (``order[start[ng]:m]``): they leave the sweeps and get one
    clean-up visit (``contact_sweeps.left_out_pass``)."""
    nb = share.shape[0]
    npt = 1
    for a in range(m):
        npt = max(npt, rows.i[a, 0] + 1, rows.i[a, 1] + 1)
    keys = np.empty(m, dtype=np.int64)
    for a in range(m):
        keys[a] = (rows.i[a, 2] * (nb + 1) + rows.i[a, 3] + 1) * (npt + 1) + _soft_particle(
            rows.i[a], share) + 1
    srt = np.argsort(keys, kind='mergesort')
    ng = 0
    for a in range(m):
        order[a] = srt[a]
        if a == 0 or keys[srt[a]] // (npt + 1) != keys[srt[a - 1]] // (npt + 1):
            start[ng] = a
            ng += 1
    start[ng] = m
    kept = np.zeros(m, dtype=np.bool_)
    label = np.empty(m, dtype=np.int64)
    seeds = np.empty((PATCHES, 3))
    left_out = np.empty(m, dtype=np.int64)
    nout = 0
    w = 0
    for g in range(ng):
        lo, hi = start[g], start[g + 1]
        start[g] = w
        ri = rows.i[order[lo]]
        rigid = share[ri[2]] > 0.0 and (ri[3] < 0 or share[ri[3]] > 0.0)
        if rigid and hi - lo > KEEP:
            _reduce(rows, order, lo, hi, kept, label, seeds)
            _keep_deep(rows, order, lo, hi, radii, kept)
        elif not rigid:
            _deepest_per_particle(rows, order, lo, hi, keys, npt, kept)
        for a in range(lo, hi):
            r = order[a]
            if (rigid and hi - lo <= KEEP) or kept[r]:
                order[w] = r
                w += 1
            else:
                f = rows.f[r]
                f[ROW_KN] = f[ROW_ACCN] = f[ROW_ACCP] = f[ROW_ACCT] = f[ROW_ACCT + 1] = 0.0
                left_out[nout] = r
                nout += 1
    start[ng] = w
    order[w:w + nout] = left_out[:nout]
    return ng


@njit(inline='always', **JIT)
def _keep_deep(rows, order, lo, hi, radii, kept):
    """Mark in ``kept`` the rows lo..hi deeper than ``DEEP`` of their contact distance
    (a collider's: twice the particle's radius)."""
    for a in range(lo, hi):
        r = order[a]
        i, j = rows.i[r, 0], rows.i[r, 1]
        reach = radii[i] + (radii[j] if j >= 0 else radii[i])
        if rows.f[r, ROW_DEPTH] > DEEP * reach:
            kept[r] = True


@njit(inline='always', **JIT)
def _soft_particle(ri, share):
    """The particle of a row's soft side when its other side is a stiff body, else -1."""
    if ri[3] < 0:
        return -1
    si, sj = share[ri[2]] > 0.0, share[ri[3]] > 0.0
    if si and not sj:
        return ri[1]
    if sj and not si:
        return ri[0]
    return -1


@njit(inline='always', **JIT)
def _deepest_per_particle(rows, order, lo, hi, keys, npt, kept):
    """Mark in ``kept`` the deepest row of each run of rows lo..hi with the same key (one
    soft particle against a stiff body); rows whose key names no soft particle all stay."""
    a = lo
    while a < hi:
        e = a + 1
        while e < hi and keys[order[e]] == keys[order[a]]:
            e += 1
        deep = order[a]
        for q in range(a, e):
            r = order[q]
            if keys[r] % (npt + 1) == 0:
                kept[r] = True
            elif rows.f[r, ROW_DEPTH] > rows.f[deep, ROW_DEPTH]:
                deep = r
        kept[deep] = True
        a = e


@njit(inline='always', **JIT)
def _reduce(rows, order, lo, hi, kept, label, seeds):
    """Mark in ``kept`` what a group of rows lo..hi keeps: its rows split into flat
    patches (normals within acos(``FLAT_COS``) of the patch's first row, at most
    ``PATCHES`` of them; rows of none are left out), each patch of more than ``KEEP``
    rows its deepest row and its extremes in 16 directions of its tangent plane, a
    smaller patch every row.  ``label`` (rows) and ``seeds`` (``PATCHES``, 3) are scratch."""
    npatch = 0
    for a in range(lo, hi):
        f = rows.f[order[a]]
        label[a - lo] = -1
        for s in range(npatch):
            if f[0] * seeds[s, 0] + f[1] * seeds[s, 1] + f[2] * seeds[s, 2] >= FLAT_COS:
                label[a - lo] = s
                break
        if label[a - lo] < 0 and npatch < PATCHES:
            seeds[npatch, 0], seeds[npatch, 1], seeds[npatch, 2] = f[0], f[1], f[2]
            label[a - lo] = npatch
            npatch += 1
    for s in range(npatch):
        cnt = 0
        for a in range(lo, hi):
            if label[a - lo] == s:
                cnt += 1
        if cnt <= KEEP:
            for a in range(lo, hi):
                if label[a - lo] == s:
                    kept[order[a]] = True
        else:
            _keep_extremes(rows, order, lo, hi, label, s, kept)


@njit(inline='always', **JIT)
def _keep_extremes(rows, order, lo, hi, label, s, kept):
    """Mark in ``kept`` the deepest row of patch s of a group and its extremes in 16
    directions of the patch's tangent plane (offsets from body i's centre)."""
    m0 = m1 = m2 = 0.0
    deep = -1
    for a in range(lo, hi):
        if label[a - lo] != s:
            continue
        f = rows.f[order[a]]
        m0, m1, m2 = m0 + f[0], m1 + f[1], m2 + f[2]
        if deep < 0 or f[ROW_DEPTH] > rows.f[deep, ROW_DEPTH]:
            deep = order[a]
    kept[deep] = True
    ml = np.sqrt(m0 * m0 + m1 * m1 + m2 * m2) + 1e-300
    m0, m1, m2 = m0 / ml, m1 / ml, m2 / ml
    e0, e1, e2 = (0.0, m2, -m1) if abs(m0) < 0.6 else (-m2, 0.0, m0)
    el = np.sqrt(e0 * e0 + e1 * e1 + e2 * e2)
    e0, e1, e2 = e0 / el, e1 / el, e2 / el
    f0, f1, f2 = _cross(m0, m1, m2, e0, e1, e2)
    for k in range(16):
        ca = np.cos(0.125 * np.pi * k)
        sa = np.sin(0.125 * np.pi * k)
        best = -np.inf
        arg = deep
        for a in range(lo, hi):
            if label[a - lo] != s:
                continue
            f = rows.f[order[a]]
            d = (ca * (f[3] * e0 + f[4] * e1 + f[5] * e2)
                 + sa * (f[3] * f0 + f[4] * f1 + f[5] * f2))
            if d > best + 1e-12:
                best = d
                arg = order[a]
        kept[arg] = True


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
def carry_warm(old, new, m):
    """The warm-start impulses of the pairs of a rebuilt pair list (``new`` = (pi, pj,
    store), its first m pairs) from the old list's (``old`` = (pi, pj, ends, store), its
    pairs sorted by lower index, ``ends[i]`` the end of particle i's run): a pair of both
    lists keeps its impulses, a new one starts cold.  So a heap whose list is rebuilt
    every step, because something in it moves, still starts each step from the last."""
    opi, opj, ends, ostore = old
    npi, npj, nstore = new
    for k in range(m):
        i, j = npi[k], npj[k]
        nstore[k, WARM_STAMP] = -np.inf
        lo = ends[i - 1] if i > 0 else 0
        for q in range(lo, ends[i]):
            if opi[q] == i and opj[q] == j:
                nstore[k, :] = ostore[q, :]
                break


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
