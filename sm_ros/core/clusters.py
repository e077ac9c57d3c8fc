"""Overlapping cube clusters over the rest shape (algorithm.md §4.4).

The bounding box of the rest positions is cut into ``k`` cubes per axis; each cube is
enlarged by ``margin`` cube widths on every side so that neighbours overlap (the paper's
layout, and the one the pypbd peer benchmark builds).  Axes along which the body is flat
get a single cell.  Empty cubes are dropped; every particle lies in its own cube, so none
is left without a cluster.

Neighbouring cubes must share particles, or the body falls apart into pieces that no
cluster holds together: a 4 x 4 x 4 lattice cut into 4 cubes per axis has no particle in
the overlap of the two middle cubes, and spun at 3 rad/s it flew apart to 16 times its
size.  So along an axis where an overlap holds no particle, the number of cubes is lowered
until every overlap holds one; and if the cubes still do not hold the body in one piece
(cubes linked through face neighbours that share at least ``tuning.MIN_SHARED``
particles, three: a joint that does not hinge; every particle in a cube of the largest
linked piece), fewer cubes are used on every axis until they do.
"""

import numpy as np

from . import tuning


def build_memberships(x0: np.ndarray, k: int, margin: float = tuning.DEFAULT_MARGIN):
    """Cluster memberships of the rest positions ``x0`` (N, 3).

    Returns ``(ptr, cluster_ids, n_clusters)``: particle i belongs to clusters
    ``cluster_ids[ptr[i]:ptr[i + 1]]`` (particle-major CSR, cluster ids 0 .. n_clusters - 1).
    """
    x0 = np.asarray(x0, dtype=float)
    n = len(x0)
    lo = x0.min(axis=0)
    ext = x0.max(axis=0) - lo
    big = max(float(ext.max()), 1e-300)
    while True:
        kk = np.where(ext > 1e-9 * big, k, 1)
        for a in range(3):
            kk[a] = _connected_cells(x0[:, a] - lo[a], ext[a], int(kk[a]), margin)
        both, cid, first, last = _candidates(x0, lo, ext, kk, margin)
        rows, cols = np.nonzero(both)                                   # particle-major
        raw = cid[rows, cols]
        if k <= 1 or kk.max() <= 1 or _one_piece(first, last, rows, raw, kk):
            break
        k = int(kk.max()) - 1
    used, cluster_ids = np.unique(raw, return_inverse=True)
    counts = np.bincount(rows, minlength=n)
    if np.any(counts == 0):  # cannot happen by construction; keep the invariant explicit
        raise RuntimeError('cluster construction left a particle without a cluster')
    ptr = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(counts, out=ptr[1:])
    return ptr, cluster_ids.astype(np.int32), len(used)


def _candidates(x0, lo, ext, kk, margin):
    """Membership mask and cell ids of the 4 x 4 x 4 candidate cubes of every particle."""
    n = len(x0)
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
    # each particle's cubes along an axis are a run first .. last of candidates
    first = cand[:, :, 0] + np.argmax(ok, axis=2)
    last = first + ok.sum(axis=2) - 1
    return both.reshape(n, 64), cid.reshape(n, 64), first, last


def _one_piece(first, last, rows, raw, kk) -> bool:
    """Whether the cubes hold the body in one piece (see the module docstring)."""
    n = len(first)
    ncell = int(np.prod(kk))
    stride = np.array([kk[1] * kk[2], kk[2], 1])
    shared = np.zeros((ncell, 3), dtype=np.int64)
    for axis in range(3):
        shared[:, axis] = _pair_counts(first, last, kk, axis).ravel()
    shared = shared.ravel()
    link = np.nonzero(shared >= tuning.MIN_SHARED)[0]
    a = link // 3
    b = a + stride[link % 3]
    label = np.arange(ncell)
    while True:                           # connected components by label propagation
        low = np.minimum(label[a], label[b])
        new = label.copy()
        np.minimum.at(new, a, low)
        np.minimum.at(new, b, low)
        new = new[new]
        if np.array_equal(new, label):
            break
        label = new
    # every particle must lie in a cube of the largest linked piece; a sparse cube at a
    # corner whose few particles all lie in well-linked cubes as well is harmless
    lab = label[raw]
    main = np.bincount(lab).argmax()
    covered = np.zeros(n, dtype=bool)
    covered[rows[lab == main]] = True
    return bool(covered.all())


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


def _pair_counts(first, last, kk, axis):
    """Particles shared by cube c and its neighbour c + 1 along ``axis``, per cube c.

    A particle lies in the box of cubes first .. last; it is shared by the pairs
    (c, c + 1) with first[axis] <= c < last[axis] and any cube of its box on the other
    axes.  The boxes are summed with a difference array (8 corners each) and prefix sums.
    """
    lo = first.copy()
    hi = last.copy()
    hi[:, axis] -= 1                      # pairs, identified by their lower cube
    keep = hi[:, axis] >= lo[:, axis]
    lo, hi = lo[keep], hi[keep] + 1       # half-open
    shape = np.asarray(kk) + 1
    diff = np.zeros(int(np.prod(shape)), dtype=np.int64)
    for cx in (0, 1):
        for cy in (0, 1):
            for cz in (0, 1):
                ix = hi[:, 0] if cx else lo[:, 0]
                iy = hi[:, 1] if cy else lo[:, 1]
                iz = hi[:, 2] if cz else lo[:, 2]
                sign = -1 if (cx + cy + cz) % 2 else 1
                diff += sign * np.bincount((ix * shape[1] + iy) * shape[2] + iz,
                                           minlength=len(diff))
    d = diff.reshape(shape)
    d = d.cumsum(axis=0).cumsum(axis=1).cumsum(axis=2)
    return d[:kk[0], :kk[1], :kk[2]]
