"""Compiled kernels of the contact pair list: the Verlet-list builders and their helpers.

``contact.py`` holds the pass (``Contact``) that calls them; ``contact_kernels.py`` the
per-step solve.  Nothing here allocates (scratch comes from ``Contact``).

Every candidate pair closer than ``r_i + r_j + skin`` is listed.  The list stays valid while
no pair's distance can have shrunk by ``skin`` since it was built: while the particles'
displacements since then fit in a ball of radius ``skin / 2``, which one pass over the
positions checks each step (``moved_spread2``; a common motion, such as bodies falling
together, does not count).  Pairs of one body are skipped (unless the body
self-collides, and then only pairs farther apart than the rest-distance rule).

``build_pairs_grid``, the one builder: a dense cell grid of side ``r_i + r_j + skin`` (largest)
over the colliding particles' bounding box; counting sort by cell (x fastest), the
particles' x, y, z, r copied in cell order into one (N, 4) array so that a cell's particles
are one run of memory; the forward half-stencil of 13 cells plus the own cell, so each pair
is met once, walked as five runs of the sorted particles (three cells side by side in x are
adjacent).  Each cell also records its body when it holds only one (``cb``); a run whose
cells hold only the body of a one-body cell (without self-collision) is skipped without
touching its particles: in a heap of small bodies most of the stencil lies within one
body, and a visit of a cell of about two particles costs more than its tests.

Where the bounding box holds more cells than the table (bodies far apart), the grid wraps
its longer axes around (``pair_grid.wrapped_dims``): cell k of an axis of n is k mod n, so
particles of far-apart places may share a cell (the distance test drops their pairs) and
neighbouring cells stay neighbours; a row of the stencil that crosses the end of x is two
runs.  ``sort_pairs`` orders the list by lower index (stable): the solve then reads X, V
in increasing order.  One thread builds the list, so the solve's result does not depend on
the thread count.
"""

from collections import namedtuple

import numpy as np
from numba import njit

from .kernels.jit import JIT, JIT_NO_REFCOUNT
from .kernels.pair_grid import counting_sort, grid_box, wrapped_dims
from .kernels.spread import moved_box, spread_of

#: ``cb`` of a cell without particles (``grid_sort``).
EMPTY = -2

#: What a pair-list build reads (``Contact._build``): positions (3, N), contact radii (N,),
#: the body of each particle (N,), per body whether it collides and whether it
#: self-collides, rest positions (3, N), the cell size, the skin, and the factor on the
#: contact distance beyond which two particles of one self-colliding body may pair at rest.
PairSource = namedtuple('PairSource', 'x radius body active self_collide rest cell skin '
                                      'self_factor')
#: A build's scratch: each particle's cell (N,) int64, each cell's start in the sorted
#: order (T + 1,) int64, the particle at each sorted place (N,) int64; the dense grid's
#: sorted x, y, z, r (N, 4), their bodies (N,) int32 and each cell's one body (T,) int32.
GridScratch = namedtuple('GridScratch', 'particle_cell cell_start order points point_body '
                                        'cell_body')


@njit(**JIT)
def body_overlaps(X, off, flags, grow, box, order, out):
    """The broad phase of a pair-list build: out[b] = 1 for a colliding body that
    self-collides or whose bounding box, grown by ``grow[b]`` on every side, overlaps
    another colliding body's grown box, unless both are rigid (the stiff pass takes their
    contact); 0 otherwise (none of its particles can come within a contact distance plus
    the skin of another body's that this pass solves: the builders may leave it out).
    ``flags``: per body whether it collides, self-collides and is rigid.

    ``box`` (bodies, 6) and ``order`` (bodies,) int64: scratch.  One pass over the
    colliding particles (min/max per row: vectorises over a body's particles), then a
    sweep over the boxes sorted by their low x (each box meets only those that start
    before it ends).  A body whose box is not finite is kept, with every other (out 1).
    """
    act, selfc, rigid = flags
    nb = off.shape[0] - 1
    m = 0
    for b in range(nb):
        out[b] = 0
        if not act[b]:
            continue
        g = grow[b]
        for r in range(3):
            lo = np.inf
            hi = -np.inf
            for k in range(off[b], off[b + 1]):
                v = X[r, k]
                lo = min(lo, v)
                hi = max(hi, v)
            box[b, r] = lo - g
            box[b, 3 + r] = hi + g
        ok = True
        for r in range(6):
            if not np.isfinite(box[b, r]):
                ok = False
        if selfc[b]:
            out[b] = 1                         # its own pairs are listed whatever the rest
        if not ok:
            out[b] = 1
            box[b, 0] = -np.inf                # meets every box in the sweep below
            box[b, 3] = np.inf
            box[b, 1] = box[b, 2] = -np.inf
            box[b, 4] = box[b, 5] = np.inf
        order[m] = b
        m += 1
    keys = np.empty(m)
    for a in range(m):
        keys[a] = box[order[a], 0]
    rank = np.argsort(keys)
    srt = np.empty(m, dtype=np.int64)
    for a in range(m):
        srt[a] = order[rank[a]]
    for a in range(m):
        b = srt[a]
        for c_ in range(a + 1, m):
            c = srt[c_]
            if box[c, 0] > box[b, 3]:
                break                          # sorted by low x: no later box meets b
            if rigid[b] and rigid[c]:
                continue
            if (box[c, 1] <= box[b, 4] and box[b, 1] <= box[c, 4]
                    and box[c, 2] <= box[b, 5] and box[b, 2] <= box[c, 5]):
                out[b] = 1
                out[c] = 1


@njit(**JIT)
def moved_spread2(X, Xref, off, act):
    """Squared radius of a ball that holds every colliding particle's displacement since
    ``Xref`` (NaN -> inf): the half diagonal of the displacements' bounding box.

    A pair's distance changes by at most the difference of its two displacements, at most
    twice this radius, whatever the common motion: bodies falling together, or a whole
    heap carried along, keep their list (the largest displacement itself, the test before,
    rebuilt it at every step of a fall).  Body by body (``off``; a body with ``act`` off
    is skipped whole, ``moved_box``).
    """
    dlo = np.full(3, np.inf)
    dhi = np.full(3, -np.inf)
    nan = 0.0
    for b in range(off.shape[0] - 1):
        if act[b]:
            nan += moved_box(X, Xref, off[b], off[b + 1], dlo, dhi)
    return spread_of(dlo, dhi, nan)


@njit(**JIT)
def grid_sort(src, grid, dims):
    """Counting sort of the colliding particles of ``src`` (``PairSource``) into a grid of
    cells of side ``src.cell``, in ``grid`` (``GridScratch``: hb, cnt, srt, P, sb, cb below).

    Returns the number of particles sorted (0: none collide).  Out: ``dims`` the grid's
    cells per axis and which axes wrap around (``pair_grid.wrapped_dims``; a table of T
    cells), ``hb[i]`` the cell of particle i (-1: not colliding or not finite), ``cnt[c]``
    the start of cell c in the sorted order (cells numbered x fastest; ``cnt[c + 1]`` its
    end), ``srt[a]`` the particle at sorted place a, ``P[a]`` its x, y, z, r, ``sb[a]`` its
    body; ``cb[c]`` (T,) the body of every particle of cell c, -1 when it holds several,
    ``EMPTY`` when none (every cell of the grid written).
    """
    if dims.shape[0] != 6:
        raise ValueError('grid_sort: dims must hold 6 values')
    X, R, B, act = src.x, src.radius, src.body, src.active
    hb, cnt, srt = grid.particle_cell, grid.cell_start, grid.order
    P, sb, cb = grid.points, grid.point_body, grid.cell_body
    n = X.shape[1]
    inv = 1.0 / src.cell
    lo0, lo1, lo2, f0, f1, f2 = grid_box(X, B, act, hb, inv)
    if f0 == 0.0:
        return 0
    wrapped_dims((f0, f1, f2), cnt.shape[0] - 1, dims)
    nx, ny, nz = dims[0], dims[1], dims[2]
    wraps = dims[3] + dims[4] + dims[5] > 0
    nxy = nx * ny
    ncell = nxy * nz
    cnt[:ncell + 1] = 0                 # only the cells of this grid (the table may be larger)
    for i in range(n):
        if hb[i] < 0:
            continue
        # cell coordinates as floats (a box of any size), wrapped before they become integers
        fx = min((X[0, i] - lo0) * inv, f0 - 1.0)
        fy = min((X[1, i] - lo1) * inv, f1 - 1.0)
        fz = min((X[2, i] - lo2) * inv, f2 - 1.0)
        if wraps:
            c = _wrap_cell(fx, nx) + nx * _wrap_cell(fy, ny) + nxy * _wrap_cell(fz, nz)
        else:
            c = np.int64(fx) + nx * np.int64(fy) + nxy * np.int64(fz)
        hb[i] = c
        cnt[c + 1] += 1
    nact = counting_sort(hb, cnt, srt, ncell)
    cb[:ncell] = EMPTY
    # copy in cell order, and each cell's one body (-1: several)
    a0 = 0
    while a0 < nact:
        c = hb[srt[a0]]
        a1 = cnt[c + 1]
        b = B[srt[a0]]
        for a in range(a0, a1):
            i = srt[a]
            P[a, 0] = X[0, i]
            P[a, 1] = X[1, i]
            P[a, 2] = X[2, i]
            P[a, 3] = R[i]
            bi = B[i]
            sb[a] = bi
            if bi != b:
                b = -1
        cb[c] = b
        a0 = a1
    return nact


@njit(inline='always', **JIT)
def _wrap_cell(f, n):
    """The cell of coordinate f >= 0 (a float, however large) on an axis of n cells that
    wraps around; beyond what floats hold (a box wider than 1e308 m), cell 0: the distance
    test decides."""
    if f < 4.0e18:                       # an integer holds it
        return np.int64(f) % n
    if f < np.inf:                       # a float this large is an integer: exact remainder
        return np.int64(np.fmod(f, n))
    return np.int64(0)


@njit(inline='always', **JIT)
def _only(cb, cell, b):
    """Whether grid cell ``cell`` holds body b only, or nothing (``grid_sort``'s ``cb``)."""
    e = cb[cell]
    return (e == b) | (e == EMPTY)


@njit(inline='always', **JIT)
def _beside(k, d, n, wrap):
    """Cell coordinate k + d on an axis of n cells (wrapped around with ``wrap``), or -1
    past the grid's edge."""
    k += d
    if wrap:
        return k % n
    return k if 0 <= k < n else -1


@njit(inline='always', **JIT)
def _around(k, n):
    """Cell coordinate k (-1 .. n) of a row of n cells that wraps around."""
    return k + n if k < 0 else (k - n if k >= n else k)


@njit(**JIT_NO_REFCOUNT)
def _cell_pairs(nact, dims, src, grid, pairs):
    """The pairs of the ``nact`` sorted particles (``grid_sort``), each with the later
    particles of its own cell and the 13 cells of the forward half-stencil: the own cell
    with the next in x, and the rows of three at (dy, dz) = (1, 0), (-1, 1), (0, 1), (1, 1)
    (cells being numbered x fastest, a row is one run of the sorted particles, two where it
    wraps around), written to ``pairs`` (pi, pj) while they have room; returns their
    number.  From a cell of one body (not self-colliding), cells of that body alone or
    empty are left out.
    """
    hb, cnt, srt, cb = grid.particle_cell, grid.cell_start, grid.order, grid.cell_body
    nx, ny, nz = dims[0], dims[1], dims[2]
    wrap_x, wrap_y, wrap_z = dims[3] > 0, dims[4] > 0, dims[5] > 0
    nxy = nx * ny
    m, a0 = 0, 0
    while a0 < nact:
        c = hb[srt[a0]]
        a1 = cnt[c + 1]
        cz = c // nxy
        cy = (c - cz * nxy) // nx
        cx = c - cz * nxy - cy * nx
        b = cb[c]
        one = b >= 0 and not src.self_collide[b]   # one body, not self-colliding
        edge = wrap_x and (cx == 0 or cx == nx - 1)  # rows that wrap around: two runs
        xl = -1 if cx > 0 else 0
        xh = 1 if cx < nx - 1 else 0
        for q in range(5):
            dy = 0 if q == 0 else (1 if q == 1 else q - 3)
            dz = 0 if q <= 1 else 1
            ry = _beside(cy, dy, ny, wrap_y)
            rz = _beside(cz, dz, nz, wrap_z)
            if ry < 0 or rz < 0:
                continue
            row = nx * ry + nxy * rz
            if edge:
                first = (1 if one else 0) if q == 0 else -1
                m = _test_row((a0, a1), (row, cx, first, 1), b if one else -1, dims, src,
                              grid, pairs, m)
                continue
            base = row + cx
            if q == 0:                      # own cell (later particles) and the next in x
                if one and (xh == 0 or _only(cb, c + 1, b)):
                    continue
                t0b = cnt[c + 1] if one else -1     # one body: nothing to test in its cell
                t1 = cnt[c + 1 + xh]
            else:                           # a row of up to three cells
                first, last = xl, xh
                if one:
                    k0 = _only(cb, base + xl, b)
                    k1 = _only(cb, base, b)
                    k2 = _only(cb, base + xh, b)
                    if k0 & k1 & k2:
                        continue            # the row holds this body only: nothing to test
                    # leave out end cells that hold this body only
                    if k0:
                        first = xh if k1 else 0
                    if k2:
                        last = xl if k1 else 0
                t0b = cnt[base + first]
                t1 = cnt[base + last + 1]
            m = _test_run((a0, a1), (t0b, t1), src, grid, pairs, m)
        a0 = a1
    return m


@njit(inline='always', **JIT)
def _test_row(places, span, b, dims, src, grid, pairs, m):
    """``_test_run`` of ``places`` [a0, a1) (cell cx) against the cells cx + first ..
    cx + last of the row starting at cell ``row`` (``span``) of a grid whose x wraps around
    (two runs where they cross its end; ``_cell_pairs`` walks the cells at the ends of x
    with it); first = 0 takes the own cell from the place after each particle's own.  For
    a cell of one body b (>= 0), end cells of b alone or empty are left out."""
    row, cx, first, last = span
    nx, cnt, cb = dims[0], grid.cell_start, grid.cell_body
    lo, hi = cx + first, cx + last
    while lo <= hi and b >= 0 and _only(cb, row + _around(lo, nx), b):
        lo += 1
    while hi >= lo and b >= 0 and _only(cb, row + _around(hi, nx), b):
        hi -= 1
    if lo > hi:
        return m
    if lo < 0:                                      # wrapped: the row's last cell first
        m = _test_run(places, (cnt[row + nx - 1], cnt[row + nx]), src, grid, pairs, m)
        lo = 0
    if hi >= nx:                                    # wrapped: then its first cell
        m = _test_run(places, (cnt[row], cnt[row + 1]), src, grid, pairs, m)
        hi = nx - 1
    if lo <= hi:
        start = -1 if first == 0 else cnt[row + lo]
        m = _test_run(places, (start, cnt[row + hi + 1]), src, grid, pairs, m)
    return m


@njit(inline='always', **JIT)
def _test_run(places, others, src, grid, pairs, m):
    """The pairs of the particles at sorted ``places`` [a0, a1) with those at ``others``
    [t0, t1) (t0 < 0: from the place after each one's own), written to ``pairs`` (pi, pj)
    from m while they have room; returns m plus their number."""
    a0, a1 = places
    t0b, t1 = others
    if t0b == t1:
        return m
    pi, pj = pairs
    cap = pi.shape[0]
    R, selfc, X0, skin, self_fac = (src.radius, src.self_collide, src.rest, src.skin,
                                    src.self_factor)
    srt, P, sb = grid.order, grid.points, grid.point_body
    for a in range(a0, a1):
        xi, yi, zi, ri = P[a, 0], P[a, 1], P[a, 2], P[a, 3]
        bi = sb[a]
        si = selfc[bi]
        t0 = a + 1 if t0b < 0 else t0b
        for t in range(t0, t1):
            dx = P[t, 0] - xi
            dy = P[t, 1] - yi
            dz = P[t, 2] - zi
            d2 = dx * dx + dy * dy + dz * dz
            lim = ri + P[t, 3] + skin
            # one rarely taken branch: in range, and two bodies or self-colliding
            if (d2 < lim * lim) & ((sb[t] != bi) | si):
                i, j = srt[a], srt[t]
                if sb[t] == bi:
                    ex = X0[0, j] - X0[0, i]
                    ey = X0[1, j] - X0[1, i]
                    ez = X0[2, j] - X0[2, i]
                    rest = self_fac * (R[i] + R[j])
                    if ex * ex + ey * ey + ez * ez <= rest * rest:
                        continue
                if m < cap:
                    pi[m] = i
                    pj[m] = j
                m += 1
    return m


@njit(**JIT)
def build_pairs_grid(src, grid, pi, pj):
    """Candidate pairs of ``src`` (``PairSource``) closer than r_i + r_j + skin into pi,
    pj (one thread; scratch ``grid``, a ``GridScratch``); returns their number.

    Pairs of one body are listed only when it self-collides, and only when farther apart
    at rest than ``self_factor`` times their contact distance.  When more pairs exist than
    ``pi`` holds, the count is still returned (the caller grows the arrays and calls
    again).
    """
    dims = np.zeros(6, dtype=np.int64)
    nact = grid_sort(src, grid, dims)
    if nact <= 0:
        return nact
    return _cell_pairs(nact, dims, src, grid, (pi, pj))


@njit(**JIT)
def drop_rigid_pairs(pi, pj, count, body, rigid, out_i, out_j):
    """The particle pairs of ``pi``, ``pj`` (first ``count``) but those between two
    bodies flagged ``rigid`` (their contact is the stiff pass's), into ``out_i``,
    ``out_j``; returns how many."""
    kept = 0
    for k in range(count):
        i, j = pi[k], pj[k]
        bi, bj = body[i], body[j]
        if rigid[bi] and rigid[bj] and bi != bj:
            continue
        out_i[kept], out_j[kept] = i, j
        kept += 1
    return kept


@njit(**JIT)
def sort_pairs(pi, pj, m, n, cnt, ti, tj):
    """Order the first m pairs by their lower index (counting sort, stable: a particle's
    partners stay in build order; ``cnt`` (n + 1,) int64, ``ti``/``tj`` scratch like
    ``pi``/``pj``): the per-step sweep then reads X, V in increasing order for one particle
    of each pair (the (3, N) rows are read by prefetched streams, not at random).
    Ordering each particle's partners too
    would make the list independent of the builder, but the Gauss-Seidel sweep's result
    depends on that order, and tests tuned on this one (the head-on bounce) change."""
    cnt[:] = 0
    for k in range(m):
        a, b = pi[k], pj[k]
        if b < a:
            pi[k], pj[k] = b, a
        cnt[pi[k] + 1] += 1
    for i in range(n):
        cnt[i + 1] += cnt[i]
    for k in range(m):
        a = pi[k]
        t = cnt[a]
        ti[t] = a
        tj[t] = pj[k]
        cnt[a] = t + 1
    for k in range(m):
        pi[k] = ti[k]
        pj[k] = tj[k]
