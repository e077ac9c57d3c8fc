"""The cell grid of the pair-list builder (``contact_build.build_pairs_grid``): the box of
the colliding particles, the grid's cells per axis (wrapped around where the box holds
more cells than the table) and the counting sort by cell.  Here, in the kernel package,
so that an edit recompiles the builder (``jit.py``: the package's cache stamp)."""

import math

import numpy as np
from numba import njit

from .jit import JIT


@njit(**JIT)
def grid_box(X, B, act, hb, inv):
    """The box of the colliding particles (body ``act``, finite) in cells of side 1 /
    ``inv``: its corner and cells per axis (lo0, lo1, lo2, f0, f1, f2); f0 is 0 when no
    particle collides.  ``hb[i]`` is set to 0 for a colliding particle, -1 for any other."""
    lo0 = lo1 = lo2 = np.inf
    hi0 = hi1 = hi2 = -np.inf
    for i in range(X.shape[1]):
        hb[i] = -1
        if not act[B[i]]:
            continue
        x, y, z = X[0, i], X[1, i], X[2, i]
        if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z)):
            continue
        hb[i] = 0
        lo0 = min(lo0, x)
        lo1 = min(lo1, y)
        lo2 = min(lo2, z)
        hi0 = max(hi0, x)
        hi1 = max(hi1, y)
        hi2 = max(hi2, z)
    if not lo0 <= hi0:
        return 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    # np.floor stays a float: math.floor is an int64 in Numba, undefined (CPU-dependent)
    # for a box of more cells than an int64 counts
    return (lo0, lo1, lo2, np.floor((hi0 - lo0) * inv) + 1.0,
            np.floor((hi1 - lo1) * inv) + 1.0, np.floor((hi2 - lo2) * inv) + 1.0)


@njit(**JIT)
def wrapped_dims(extent, tsize, dims):
    """The grid's cells per axis for a box of ``extent`` (f0, f1, f2) cells and a table of
    ``tsize`` (at least 27) cells, into ``dims``: (nx, ny, nz, then 1 for an axis that wraps
    around).  A box that fits keeps its cells; one that does not wraps its longer axes
    around to at least 3 cells each (cell k at k mod n: particles far apart may share a
    cell, which the distance test sorts out, and neighbours stay neighbours)."""
    budget = float(tsize)
    if extent[0] * extent[1] * extent[2] <= budget:
        for k in range(3):
            dims[k], dims[3 + k] = np.int64(extent[k]), 0
        return
    order = np.argsort(np.array(extent))            # the shortest axes keep their cells
    for r in range(3):
        k = order[r]
        left = 3 - r
        cap = max(np.int64(budget ** (1.0 / left)), 3)
        while float(cap + 1) ** left <= budget:     # the root rounded down exactly
            cap += 1
        while cap > 3 and float(cap) ** left > budget:
            cap -= 1
        n = cap if extent[k] > cap else np.int64(extent[k])    # compared as floats: any size
        dims[k], dims[3 + k] = n, np.int64(n < extent[k])
        budget = budget / n


@njit(**JIT)
def counting_sort(hb, cnt, srt, ncell):
    """The particles into ``srt`` ordered by their cell ``hb[i]`` (-1: left out), from
    each cell's count in ``cnt[c + 1]``; leaves ``cnt[c]`` the start of cell c in that
    order (``cnt[ncell]`` their number, returned)."""
    for c in range(ncell):
        cnt[c + 1] += cnt[c]
    for i in range(hb.shape[0]):
        c = hb[i]
        if c >= 0:
            a = cnt[c]
            srt[a] = i
            cnt[c] = a + 1
    for c in range(ncell, 0, -1):
        cnt[c] = cnt[c - 1]
    cnt[0] = 0
    return cnt[ncell]
