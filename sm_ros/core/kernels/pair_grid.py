"""Pieces the pair-list builders share (``contact_build.py``, ``contact_cells.py``): the
dense grid over the colliding particles, the counting sort by cell and the test that
keeps a pair.  Here, in the
kernel package, so that an edit recompiles both builders (``jit.py``: the package's cache
stamp)."""

import math

import numpy as np
from numba import njit

from .jit import JIT


@njit(**JIT)
def grid_box(X, B, act, hb, inv, tsize):
    """The dense grid of cells of side 1 / ``inv`` over the colliding particles (body
    ``act``, finite): its corner and cells per axis (lo0, lo1, lo2, nx, ny, nz); nx is 0
    when no particle collides and -1 when the box holds more than ``tsize`` cells.
    ``hb[i]`` is set to 0 for a colliding particle, -1 for any other."""
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
        return 0.0, 0.0, 0.0, np.int64(0), np.int64(0), np.int64(0)
    f0 = math.floor((hi0 - lo0) * inv) + 1.0
    f1 = math.floor((hi1 - lo1) * inv) + 1.0
    f2 = math.floor((hi2 - lo2) * inv) + 1.0
    if f0 * f1 * f2 > tsize:
        return 0.0, 0.0, 0.0, np.int64(-1), np.int64(0), np.int64(0)
    return lo0, lo1, lo2, np.int64(f0), np.int64(f1), np.int64(f2)


@njit(inline='always', **JIT)
def kept_pair(sco, a, t, selfc, X0, srt, skin, self_fac):
    """Whether the particles at sorted places a and t (``sco`` (5, N): x, y, z, radius,
    body) make a pair of the list: closer than their contact distance plus ``skin``, of
    two bodies, or of one self-colliding body (``selfc``) farther apart at rest than
    ``self_fac`` times their contact distance (``X0``; ``srt`` the particles)."""
    bi = np.int64(sco[4, a])
    same = np.int64(sco[4, t]) == bi
    if same and not selfc[bi]:
        return False                   # one body without self-collision
    cut = sco[3, a] + sco[3, t]
    dx = sco[0, t] - sco[0, a]
    dy = sco[1, t] - sco[1, a]
    dz = sco[2, t] - sco[2, a]
    lim = cut + skin
    if dx * dx + dy * dy + dz * dz >= lim * lim:
        return False
    if same:
        i, j = srt[a], srt[t]
        ex = X0[0, j] - X0[0, i]
        ey = X0[1, j] - X0[1, i]
        ez = X0[2, j] - X0[2, i]
        rest = self_fac * cut
        return ex * ex + ey * ey + ez * ez > rest * rest
    return True


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
