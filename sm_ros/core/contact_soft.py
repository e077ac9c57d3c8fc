"""Compiled pass over the pairs of two soft sides (``contact_solve``: rigid share 0 on
both), before the rows of the stiff bodies are made.

Such a pair is two particles, each dented on its own, so it needs no rows, warm start or
sweeps of the rigid-body solve: Gauss-Seidel over the pair list, each overlapping pair
pushed apart along its normal at the start of the step (x - h v) by inverse mass, and its
relative velocity given the contact law (restitution above the resting threshold,
Coulomb friction with the projection's speed in its budget).  Every velocity change also
moves the particles by h times it, so x - h v stays the start of the step for the pairs
that follow; impulses are equal and opposite (both momenta kept without friction).
"""

import numpy as np
from numba import njit

from .kernels.colliders import collide_point
from .kernels.contact_rows import LAW_E, LAW_H, LAW_MU, LAW_THRESH, _pair_normal
from .kernels.jit import JIT


@njit(inline='always', **JIT)
def _soft_impulse(pt, i, j, d2, rr, law):
    """The relative velocity change (3) of overlapping pair (i, j), distance squared d2,
    contact distance rr: its projection over h plus the contact law on what is left."""
    X, V = pt.X, pt.V
    h = law[LAW_H]
    dx, dy, dz = X[0, i] - X[0, j], X[1, i] - X[1, j], X[2, i] - X[2, j]
    rx, ry, rz = V[0, i] - V[0, j], V[1, i] - V[1, j], V[2, i] - V[2, j]
    nx, ny, nz = _pair_normal(dx - h * rx, dy - h * ry, dz - h * rz, dx, dy, dz, d2, rr)
    dn = dx * nx + dy * ny + dz * nz
    push = (-dn + np.sqrt(dn * dn - d2 + rr * rr)) / h
    vn0 = rx * nx + ry * ny + rz * nz
    target = -law[LAW_E] * vn0 if -vn0 > law[LAW_THRESH] else 0.0
    gn = push + max(target - vn0 - push, 0.0)
    tx, ty, tz = rx - vn0 * nx, ry - vn0 * ny, rz - vn0 * nz
    tl = np.sqrt(tx * tx + ty * ty + tz * tz)
    f = min(law[LAW_MU] * gn / tl, 1.0) if tl > 0.0 else 0.0
    return gn * nx - f * tx, gn * ny - f * ty, gn * nz - f * tz


@njit(**JIT)
def soft_pairs(pt, share, pl, law, sweeps, stats):
    """``sweeps`` Gauss-Seidel sweeps over the pairs of the list whose two bodies have no
    rigid share; ``stats`` = (touched, count, deepest) of the first sweep; ``moved`` (N,)
    flags the particles it moved.  Returns the overlapping pairs met in the first sweep."""
    X, V, W, R, B = pt.X, pt.V, pt.W, pt.R, pt.B
    touched, count, deepest, moved = stats
    h = law[LAW_H]
    found = 0
    for sweep in range(sweeps):
        for k in range(pl.n):
            i, j = pl.pi[k], pl.pj[k]
            bi, bj = B[i], B[j]
            ws = W[i] + W[j]
            if ws <= 0.0 or share[bi] > 0.0 or share[bj] > 0.0:
                continue
            d2 = ((X[0, i] - X[0, j]) ** 2 + (X[1, i] - X[1, j]) ** 2
                  + (X[2, i] - X[2, j]) ** 2)
            rr = R[i] + R[j]
            if not d2 < rr * rr:       # apart, or NaN (a body that blew up: left alone)
                continue
            q0, q1, q2 = _soft_impulse(pt, i, j, d2, rr, law)
            for p, c in ((i, W[i] / ws), (j, -W[j] / ws)):
                moved[p] = 1
                V[0, p] += c * q0
                V[1, p] += c * q1
                V[2, p] += c * q2
                X[0, p] += c * h * q0
                X[1, p] += c * h * q1
                X[2, p] += c * h * q2
            if sweep == 0:
                found += 1
                pen = rr - np.sqrt(d2)
                for b in (bi, bj):
                    touched[b] = 1
                    count[b] += 1
                    deepest[b] = max(deepest[b], pen)
    return found


@njit(**JIT)
def collide_moved(pt, moved, st, thresh):
    """The static colliders' per-particle law again for the particles ``soft_pairs``
    moved (flags cleared), so none ends the step inside a collider (the next step's pass
    would push it out with speed)."""
    X, V = pt.X, pt.V
    for p in range(moved.shape[0]):
        if not moved[p]:
            continue
        moved[p] = 0
        X[0, p], X[1, p], X[2, p], V[0, p], V[1, p], V[2, p] = collide_point(
            X[0, p], X[1, p], X[2, p], V[0, p], V[1, p], V[2, p], st.ground, st.boxes,
            st.spheres, thresh)
