"""The pair-list builder for sparse worlds: a hashed cell grid (``build_pairs``: a world
whose box holds too many cells for the dense grid of ``contact_build.build_pairs_grid``).
The same pairs, by the rules of ``contact_build``'s docstring.
"""

import math

import numpy as np
from numba import njit

from .kernels.jit import JIT
from .kernels.pair_grid import counting_sort, kept_pair


@njit(**JIT)
def _cell_key(cx, cy, cz):
    """Pack three cell coordinates (21 bits each, wrapping) into one int64."""
    return (((cx + 1048576) & 2097151) << 42) | (((cy + 1048576) & 2097151) << 21) | \
        ((cz + 1048576) & 2097151)


@njit(**JIT)
def _bucket(key, mask):
    """Hash table slot of a packed cell key (multiplicative hash)."""
    h = np.uint64(key) * np.uint64(0x9E3779B97F4A7C15)
    return np.int64(h >> np.uint64(32)) & mask


@njit(**JIT)
def _hash_sort(src, grid, skey, sco):
    """``build_pairs``' sort: the hashed cell of every colliding particle, a counting sort
    by slot, and the sorted particles' keys and x, y, z, r, body copied in slot order.
    Returns how many were sorted."""
    X, R, B, act = src.x, src.radius, src.body, src.active
    hb, cnt, srt = grid.particle_cell, grid.cell_start, grid.order
    n = X.shape[1]
    tsize = cnt.shape[0] - 1
    mask = tsize - 1
    inv = 1.0 / src.cell
    cnt[:] = 0
    for i in range(n):
        hb[i] = -1
        if not act[B[i]]:
            continue
        x, y, z = X[0, i], X[1, i], X[2, i]
        if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z)):
            continue
        k = _cell_key(np.int64(math.floor(x * inv)), np.int64(math.floor(y * inv)),
                      np.int64(math.floor(z * inv)))
        s = _bucket(k, mask)
        hb[i] = s
        cnt[s + 1] += 1
    nact = counting_sort(hb, cnt, srt, tsize)
    for a in range(nact):
        i = srt[a]
        sco[0, a] = X[0, i]
        sco[1, a] = X[1, i]
        sco[2, a] = X[2, i]
        sco[3, a] = R[i]
        sco[4, a] = B[i]
        skey[a] = _cell_key(np.int64(math.floor(X[0, i] * inv)),
                            np.int64(math.floor(X[1, i] * inv)),
                            np.int64(math.floor(X[2, i] * inv)))
    return nact


# The builders share their inner pair test (distance with skin, same body only with
# self-collision and beyond the rest distance).  It is written out in each on purpose: as
# a shared helper (also with inline='always') the rebuild was several times slower.


@njit(**JIT)
def build_pairs(src, grid, skey, sco, pi, pj):
    """Candidate pairs of ``src`` (``contact_build.PairSource``) closer than r_i + r_j +
    skin into pi, pj; returns their number.

    Scratch: of ``grid`` (``contact_build.GridScratch``) ``particle_cell`` (hb, N),
    ``cell_start`` (cnt, T + 1 with T a power of two), ``order`` (srt, N: the particles
    sorted by hash slot); ``skey`` (N,) int64 and ``sco`` (5, N) float64 (their
    cell keys and x, y, z, r, body copied in slot order, so the neighbour loops read
    contiguous memory).  When more pairs exist than ``pi`` holds, the count is still
    returned (the caller grows the arrays and calls again).
    """
    selfc, X0 = src.self_collide, src.rest
    skin, self_fac = src.skin, src.self_factor
    cnt, srt = grid.cell_start, grid.order
    mask = cnt.shape[0] - 2
    inv = 1.0 / src.cell
    nact = _hash_sort(src, grid, skey, sco)
    # pairs, cell by cell (a run of equal keys in slot order; a slot may also hold
    # other cells, hash collisions, so exact keys are compared): a particle against the
    # later ones of its run, and the run against the 13 cells of the forward half-stencil,
    # so each pair is met once
    cap = pi.shape[0]
    m = 0
    a0 = 0
    while a0 < nact:
        key = skey[a0]
        a1 = a0 + 1
        while a1 < nact and skey[a1] == key:
            a1 += 1
        cx = np.int64(math.floor(sco[0, a0] * inv))
        cy = np.int64(math.floor(sco[1, a0] * inv))
        cz = np.int64(math.floor(sco[2, a0] * inv))
        for q in range(14):
            # q = 0: own cell; 1..13: (ox, oy, oz) lexicographically after (0, 0, 0)
            r = q + 13
            k = _cell_key(cx + r // 9 - 1, cy + (r // 3) % 3 - 1, cz + r % 3 - 1)
            s = _bucket(k, mask)
            t1 = cnt[s + 1]
            for a in range(a0, a1):
                t0 = a + 1 if q == 0 else cnt[s]
                for t in range(t0, t1):
                    if skey[t] != k:
                        continue
                    if not kept_pair(sco, a, t, selfc, X0, srt, skin, self_fac):
                        continue
                    if m < cap:
                        pi[m] = srt[a]
                        pj[m] = srt[t]
                    m += 1
        a0 = a1
    return m
