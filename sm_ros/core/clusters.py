"""Overlapping cube clusters over the rest shape (algorithm.md §4.4).

The bounding box of the rest positions is cut into ``k`` cubes per axis; each cube is
enlarged by ``margin`` cube widths on every side so that neighbours overlap (the paper's
layout, and the one the pypbd peer benchmark builds).  Axes along which the body is flat
get a single cell.  Empty cubes are dropped; every particle lies in its own cube, so none
is left without a cluster.

Neighbouring cubes must share particles, or the body falls apart into pieces that no
cluster holds together: a 4 x 4 x 4 lattice cut into 4 cubes per axis has no particle in
the overlap of the two middle cubes, and spun at 3 rad/s it flew apart to 16 times its
size.  Along an axis where an overlap holds no particle, the number of cubes is lowered
until every overlap holds one.
"""

import numpy as np

#: Enlargement of each cube on every side, in cube widths (0.5: "by half a cell").
DEFAULT_MARGIN = 0.5


def build_memberships(x0: np.ndarray, k: int, margin: float = DEFAULT_MARGIN):
    """Cluster memberships of the rest positions ``x0`` (N, 3).

    Returns ``(ptr, cl, n_clusters)``: particle i belongs to clusters
    ``cl[ptr[i]:ptr[i + 1]]`` (particle-major CSR, cluster ids 0 .. n_clusters - 1).
    """
    x0 = np.asarray(x0, dtype=float)
    n = len(x0)
    lo = x0.min(axis=0)
    ext = x0.max(axis=0) - lo
    big = max(float(ext.max()), 1e-300)
    kk = np.where(ext > 1e-9 * big, k, 1)
    for a in range(3):
        kk[a] = _connected_cells(x0[:, a] - lo[a], ext[a], int(kk[a]), margin)
    cw = np.where(kk > 1, ext / kk, 1.0)
    u = (x0 - lo) / cw
    eps = 1e-9 * kk
    base = np.floor(u).astype(np.int64)
    cand = base[:, :, None] + np.arange(-2, 2)[None, None, :]          # (N, 3, 4)
    ok = ((cand >= 0) & (cand < kk[None, :, None])
          & (cand - margin - eps[None, :, None] <= u[:, :, None])
          & (u[:, :, None] <= cand + 1 + margin + eps[None, :, None]))
    # combine the per-axis candidates: (N, 4, 4, 4)
    both = ok[:, 0, :, None, None] & ok[:, 1, None, :, None] & ok[:, 2, None, None, :]
    cid = ((cand[:, 0, :, None, None] * kk[1] + cand[:, 1, None, :, None]) * kk[2]
           + cand[:, 2, None, None, :])
    both = both.reshape(n, 64)
    cid = cid.reshape(n, 64)
    rows, cols = np.nonzero(both)                                       # particle-major
    raw = cid[rows, cols]
    used, cl = np.unique(raw, return_inverse=True)
    counts = np.bincount(rows, minlength=n)
    if np.any(counts == 0):  # cannot happen by construction; keep the invariant explicit
        raise RuntimeError('cluster construction left a particle without a cluster')
    ptr = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(counts, out=ptr[1:])
    return ptr, cl.astype(np.int32), len(used)


def _connected_cells(t: np.ndarray, ext: float, k: int, margin: float) -> int:
    """The largest cube count <= ``k`` along one axis whose every overlap holds a particle.

    ``t`` are the particles' coordinates along the axis from the lowest one, ``ext`` their
    range.  Cube c spans [c - margin, c + 1 + margin] cube widths, so cubes c and c + 1
    overlap in [c + 1 - margin, c + 1 + margin].
    """
    while k > 1:
        u = np.sort(t) * (k / ext)
        eps = 1e-9 * k
        edges = np.arange(1, k, dtype=float)
        first = np.searchsorted(u, edges - margin - eps, side='left')
        last = np.searchsorted(u, edges + margin + eps, side='right')
        if np.all(last > first):
            return k
        k -= 1
    return 1
