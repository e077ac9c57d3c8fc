"""Compiled static-collider contacts of the contact pass (``contact_solve``'s rows).

A stiff body's particles inside the ground, a box or a sphere become rows of the
sequential-impulse solve (the collider an infinite mass), so a body tipping over an edge or
rolling on the ground turns.  A soft body's particles get the per-particle law of
``kernels.colliders.collide_point`` (the same as in the bodies' own step, which leaves the
colliders to this pass whenever it runs).
"""

import numpy as np
from numba import njit

from .kernels.colliders import collide_point
from .kernels.contact_rows import ROW_DEPTH, ROW_MU, ROW_TARGET
from .kernels.jit import JIT


@njit(inline='always', **JIT)
def _box_face(x0, x1, x2, bx):
    """For a point strictly inside box row ``bx``: (depth, normal) of its nearest face;
    depth -1 outside."""
    if not (x0 > bx[0] and x0 < bx[3] and x1 > bx[1] and x1 < bx[4]
            and x2 > bx[2] and x2 < bx[5]):
        return -1.0, 0.0, 0.0, 0.0
    best, n0, n1, n2 = x0 - bx[0], -1.0, 0.0, 0.0
    d = bx[3] - x0
    if d < best:
        best, n0, n1, n2 = d, 1.0, 0.0, 0.0
    d = x1 - bx[1]
    if d < best:
        best, n0, n1, n2 = d, 0.0, -1.0, 0.0
    d = bx[4] - x1
    if d < best:
        best, n0, n1, n2 = d, 0.0, 1.0, 0.0
    d = x2 - bx[2]
    if d < best:
        best, n0, n1, n2 = d, 0.0, 0.0, -1.0
    d = bx[5] - x2
    if d < best:
        best, n0, n1, n2 = d, 0.0, 0.0, 1.0
    return best, n0, n1, n2


@njit(inline='always', **JIT)
def _sphere_face(x0, x1, x2, sp):
    """For a point inside sphere row ``sp``: (depth, outward normal); depth -1 outside."""
    d0, d1, d2 = x0 - sp[0], x1 - sp[1], x2 - sp[2]
    dd = d0 * d0 + d1 * d1 + d2 * d2
    if not dd < sp[3] * sp[3]:
        return -1.0, 0.0, 0.0, 0.0
    d = np.sqrt(dd)
    if d > 0.0:
        return sp[3] - d, d0 / d, d1 / d, d2 / d
    return sp[3], 0.0, 0.0, 1.0


@njit(inline='always', **JIT)
def _add_row(rows, m, k, b, n, depth, mu, e):
    """Row m (its particle, body, normal, depth, friction and restitution): particle k of
    stiff body b inside a collider; ``contact_solve.fill_rows`` finishes it."""
    rf = rows.f[m]
    ri = rows.i[m]
    ri[0], ri[1], ri[2], ri[3], ri[4] = k, -1, b, -1, k
    rf[0], rf[1], rf[2] = n
    rf[6] = rf[7] = rf[8] = 0.0             # a static collider's surface velocity
    rf[ROW_DEPTH] = depth
    rf[ROW_MU] = mu
    rf[ROW_TARGET] = e


@njit(**JIT)
def collider_rows(pt, bd, off, st, rows, m, box):
    """Append the (unfinished: ``contact_solve.fill_rows``) rows of the stiff
    bodies' particles inside the static colliders (``st``: ground, boxes, spheres) from
    row m; returns the new count.  A body whose
    bounding box (``box``, ``contact_solve.body_frames``) misses a collider skips it."""
    X = pt.X
    g = st.ground
    cap = rows.f.shape[0]
    for b in range(off.shape[0] - 1):
        if not bd.share[b] > 0.0:
            continue
        lo = box[b]
        if g[0] > 0.5 and lo[2] < g[1]:
            for k in range(off[b], off[b + 1]):
                if X[2, k] < g[1] and m < cap:
                    _add_row(rows, m, k, b, (0.0, 0.0, 1.0), g[1] - X[2, k], g[2], g[3])
                    m += 1
        for c in range(st.boxes.shape[0]):
            bx = st.boxes[c]
            if not (lo[0] < bx[3] and lo[3] > bx[0] and lo[1] < bx[4] and lo[4] > bx[1]
                    and lo[2] < bx[5] and lo[5] > bx[2]):
                continue
            for k in range(off[b], off[b + 1]):
                dep, n0, n1, n2 = _box_face(X[0, k], X[1, k], X[2, k], bx)
                if dep >= 0.0 and m < cap:
                    _add_row(rows, m, k, b, (n0, n1, n2), dep, bx[6], bx[7])
                    m += 1
        for c in range(st.spheres.shape[0]):
            sp = st.spheres[c]
            if not (lo[0] < sp[0] + sp[3] and lo[3] > sp[0] - sp[3]
                    and lo[1] < sp[1] + sp[3] and lo[4] > sp[1] - sp[3]
                    and lo[2] < sp[2] + sp[3] and lo[5] > sp[2] - sp[3]):
                continue
            for k in range(off[b], off[b + 1]):
                dep, n0, n1, n2 = _sphere_face(X[0, k], X[1, k], X[2, k], sp)
                if dep >= 0.0 and m < cap:
                    _add_row(rows, m, k, b, (n0, n1, n2), dep, sp[4], sp[5])
                    m += 1
    return m


@njit(**JIT)
def collide_soft(pt, off, bd, st, thresh, touched):
    """The per-particle law of the static colliders for every particle of a body with no
    rigid share (``bd.share`` 0) and a finite mass; a body moved is marked in
    ``touched``."""
    X, V = pt.X, pt.V
    for b in range(off.shape[0] - 1):
        if bd.share[b] > 0.0:
            continue
        for p in range(off[b], off[b + 1]):
            if pt.W[p] > 0.0:
                x0, x1, x2 = X[0, p], X[1, p], X[2, p]
                X[0, p], X[1, p], X[2, p], V[0, p], V[1, p], V[2, p] = collide_point(
                    x0, x1, x2, V[0, p], V[1, p], V[2, p], st.ground, st.boxes, st.spheres,
                    thresh)
                if X[0, p] != x0 or X[1, p] != x1 or X[2, p] != x2:
                    touched[b] = 1


@njit(**JIT)
def collide_rows_soft(pt, bd, rows, m, st, thresh):
    """The per-particle law of the static colliders again for the particles of bodies
    with no rigid share that the solve moved, so none ends the step inside a collider
    (the next step's pass would push it out with speed)."""
    X, V = pt.X, pt.V
    for a in range(m):
        for c in range(2):
            p = rows.i[a, c]
            if p < 0 or bd.share[rows.i[a, 2 + c]] > 0.0 or not pt.W[p] > 0.0:
                continue
            X[0, p], X[1, p], X[2, p], V[0, p], V[1, p], V[2, p] = collide_point(
                X[0, p], X[1, p], X[2, p], V[0, p], V[1, p], V[2, p], st.ground, st.boxes,
                st.spheres, thresh)


@njit(**JIT)
def project_moved(pt, off, bd, st):
    """Put the particles of the stiff bodies the solve moved that are left inside a
    static collider onto its surface, positions only (what the position sweeps did not
    remove, or a body pushed down by a load: no particle ends a step inside one; the shape
    match takes the small deviation back)."""
    X = pt.X
    for b in range(off.shape[0] - 1):
        if not bd.share[b] > 0.0:
            continue
        dv = bd.dvel[b]
        moved = False
        for k in range(12):
            if dv[k] != 0.0:
                moved = True
        if not moved:
            continue
        for p in range(off[b], off[b + 1]):
            X[0, p], X[1, p], X[2, p], _, _, _ = collide_point(
                X[0, p], X[1, p], X[2, p], 0.0, 0.0, 0.0, st.ground, st.boxes, st.spheres,
                1.0)
