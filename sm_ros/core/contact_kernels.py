"""Compiled kernels of body-body contact: the pair search and the pair solve.

The model, the parameters and the Python-side pass (``Contact``) are in ``contact.py``;
this file holds what runs per step.  Serial; nothing allocates.

Neighbour search: a Verlet list.  Every candidate pair closer than ``r_i + r_j + skin`` is
found on a dense cell grid over the colliding particles (``build_pairs_grid``; a hashed grid,
``build_pairs``, when the bounding box is too large), counting sort by cell, the forward
half-stencil of 13 cells plus the own cell, so each pair is met once; pairs are then sorted
by their lower index (``sort_pairs``).  The list stays valid while no particle has moved
more than ``skin / 2`` since it was built, which one pass over the positions checks each
step.  Pairs of one body are skipped in the build by one integer compare (unless the body
self-collides).  A world with one colliding body and no self-collision does not run the
pass at all.

Everything here is serial and the pair order is fixed by the build, so the result does not
depend on thread scheduling (bit-identical between runs).

Tunnelling: a pair is seen only where it overlaps at the end of a step, so particles
approaching faster than about ``r / h`` (r = contact radius, h = step) may cross a layer
one particle thick between two steps; ``Contact.fast_particles`` counts the particles
moving faster than that.
"""

import math

import numpy as np
from numba import njit

from .kernels.colliders import collide_point
from .kernels.jit import JIT


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


# build_pairs and build_pairs_grid share their inner pair test (distance with skin, same
# body only with self-collision and beyond the rest distance).  It is written out in
# both on purpose: as a shared helper (also with inline='always') the rebuild of the
# 384-block bin took 14-39 ms against 6 ms (one thread, side by side).


@njit(**JIT)
def build_pairs(X, R, B, act, selfc, X0, cell, skin, self_fac, hb, cnt, srt, skey, sco,
                pi, pj):
    """Candidate pairs closer than r_i + r_j + skin into pi, pj; returns their number.

    ``act[b]`` says body b collides, ``selfc[b]`` that it self-collides.  Scratch: ``hb``
    (N,) int64, ``cnt`` (T + 1,) int64 with T a power of two, ``srt`` (N,) int64 (the
    particles sorted by hash slot), ``skey`` (N,) int64 and ``sco`` (5, N) float64 (their
    cell keys and x, y, z, r, body copied in slot order, so the neighbour loops read
    contiguous memory).  When more pairs exist than ``pi`` holds, the count is still
    returned (the caller grows the arrays and calls again).
    """
    n = X.shape[1]
    tsize = cnt.shape[0] - 1
    mask = tsize - 1
    inv = 1.0 / cell
    cnt[:] = 0
    # 1. hashed cell of every colliding particle; counting sort by slot
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
    for s in range(tsize):
        cnt[s + 1] += cnt[s]
    for i in range(n):
        s = hb[i]
        if s >= 0:
            a = cnt[s]
            srt[a] = i
            cnt[s] = a + 1
    for s in range(tsize, 0, -1):
        cnt[s] = cnt[s - 1]
    cnt[0] = 0
    nact = cnt[tsize]
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
    # 2. pairs, cell by cell (a run of equal keys in slot order; a slot may also hold
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
                xi, yi, zi, ri = sco[0, a], sco[1, a], sco[2, a], sco[3, a]
                bi = np.int64(sco[4, a])
                si = selfc[bi]
                t0 = a + 1 if q == 0 else cnt[s]
                for t in range(t0, t1):
                    if skey[t] != k:
                        continue
                    bj = np.int64(sco[4, t])
                    same = bj == bi
                    if same and not si:
                        continue              # one body without self-collision: skip
                    cut = ri + sco[3, t]
                    dx = sco[0, t] - xi
                    dy = sco[1, t] - yi
                    dz = sco[2, t] - zi
                    d2 = dx * dx + dy * dy + dz * dz
                    lim = cut + skin
                    if d2 >= lim * lim:
                        continue
                    i = srt[a]
                    j = srt[t]
                    if same:
                        ex = X0[0, j] - X0[0, i]
                        ey = X0[1, j] - X0[1, i]
                        ez = X0[2, j] - X0[2, i]
                        rest = self_fac * cut
                        if ex * ex + ey * ey + ez * ez <= rest * rest:
                            continue
                    if m < cap:
                        pi[m] = i
                        pj[m] = j
                    m += 1
        a0 = a1
    return m


@njit(**JIT)
def build_pairs_grid(X, R, B, act, selfc, X0, cell, skin, self_fac, hb, cnt, srt, sco,
                     pi, pj):
    """``build_pairs`` on a dense cell grid over the colliding particles' bounding box.

    Cells are numbered x fastest, so particles sorted by cell are sorted in space and the
    half-stencil reads five nearby rows of the sorted arrays (the hashed grid jumps at
    random: ~4x slower at 55k particles).  Returns -1, doing nothing else, when the box
    holds more cells than ``cnt`` has slots (far-apart bodies: use ``build_pairs``).
    """
    n = X.shape[1]
    tsize = cnt.shape[0] - 1
    inv = 1.0 / cell
    lo0 = lo1 = lo2 = np.inf
    hi0 = hi1 = hi2 = -np.inf
    for i in range(n):
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
        return 0
    f0 = math.floor((hi0 - lo0) * inv) + 1.0
    f1 = math.floor((hi1 - lo1) * inv) + 1.0
    f2 = math.floor((hi2 - lo2) * inv) + 1.0
    if f0 * f1 * f2 > tsize:
        return -1
    nx = np.int64(f0)
    ny = np.int64(f1)
    nz = np.int64(f2)
    nxy = nx * ny
    cnt[:] = 0
    for i in range(n):
        if hb[i] < 0:
            continue
        cx = min(np.int64((X[0, i] - lo0) * inv), nx - 1)
        cy = min(np.int64((X[1, i] - lo1) * inv), ny - 1)
        cz = min(np.int64((X[2, i] - lo2) * inv), nz - 1)
        c = cx + nx * cy + nxy * cz
        hb[i] = c
        cnt[c + 1] += 1
    for c in range(tsize):
        cnt[c + 1] += cnt[c]
    for i in range(n):
        c = hb[i]
        if c >= 0:
            a = cnt[c]
            srt[a] = i
            cnt[c] = a + 1
    for c in range(tsize, 0, -1):
        cnt[c] = cnt[c - 1]
    cnt[0] = 0
    nact = cnt[tsize]
    for a in range(nact):
        i = srt[a]
        sco[0, a] = X[0, i]
        sco[1, a] = X[1, i]
        sco[2, a] = X[2, i]
        sco[3, a] = R[i]
        sco[4, a] = B[i]
    cap = pi.shape[0]
    m = 0
    a0 = 0
    while a0 < nact:
        c = hb[srt[a0]]
        a1 = cnt[c + 1]
        cz = c // nxy
        cy = (c - cz * nxy) // nx
        cx = c - cz * nxy - cy * nx
        for q in range(14):
            r = q + 13                     # q = 0: own cell; then the forward half-stencil
            ox = r // 9 - 1
            oy = (r // 3) % 3 - 1
            oz = r % 3 - 1
            # offsets ordered (z, y, x) like the cell numbers: (oz, oy, ox) > (0, 0, 0)
            qx, qy, qz = cx + oz, cy + oy, cz + ox
            if qx < 0 or qx >= nx or qy < 0 or qy >= ny or qz >= nz:
                continue
            c2 = qx + nx * qy + nxy * qz
            t1 = cnt[c2 + 1]
            for a in range(a0, a1):
                xi, yi, zi, ri = sco[0, a], sco[1, a], sco[2, a], sco[3, a]
                bi = np.int64(sco[4, a])
                si = selfc[bi]
                t0 = a + 1 if q == 0 else cnt[c2]
                for t in range(t0, t1):
                    bj = np.int64(sco[4, t])
                    same = bj == bi
                    if same and not si:
                        continue              # one body without self-collision: skip
                    cut = ri + sco[3, t]
                    dx = sco[0, t] - xi
                    dy = sco[1, t] - yi
                    dz = sco[2, t] - zi
                    d2 = dx * dx + dy * dy + dz * dz
                    lim = cut + skin
                    if d2 >= lim * lim:
                        continue
                    i = srt[a]
                    j = srt[t]
                    if same:
                        ex = X0[0, j] - X0[0, i]
                        ey = X0[1, j] - X0[1, i]
                        ez = X0[2, j] - X0[2, i]
                        rest = self_fac * cut
                        if ex * ex + ey * ey + ez * ez <= rest * rest:
                            continue
                    if m < cap:
                        pi[m] = i
                        pj[m] = j
                    m += 1
        a0 = a1
    return m


@njit(**JIT)
def sort_pairs(pi, pj, m, n, cnt, ti, tj):
    """Order the first m pairs by their lower index (counting sort; ``cnt`` (n + 1,) int64,
    ``ti``/``tj`` scratch like ``pi``/``pj``): the per-step sweep then reads X, V in
    increasing order for one particle of each pair (3.9 -> 1.2 ms a step at 55k particles
    in the bench's bin: the (3, N) rows are read by prefetched streams, not at random)."""
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


@njit(**JIT)
def max_moved2(X, Xref, B, act):
    """Largest squared displacement of a colliding particle since ``Xref`` (NaN -> inf)."""
    best = 0.0
    for i in range(X.shape[1]):
        if not act[B[i]]:
            continue
        dx = X[0, i] - Xref[0, i]
        dy = X[1, i] - Xref[1, i]
        dz = X[2, i] - Xref[2, i]
        d2 = dx * dx + dy * dy + dz * dz
        if not d2 <= best:             # also catches NaN
            best = d2 if d2 == d2 else np.inf
    return best


@njit(**JIT)
def body_inverse_masses(W, off, bw):
    """bw[b] = 1 / (mass of body b), or 0 when b has a pinned or grabbed particle."""
    for b in range(off.shape[0] - 1):
        m = 0.0
        for k in range(off[b], off[b + 1]):
            if W[k] <= 0.0:
                m = -1.0
                break
            m += 1.0 / W[k]
        bw[b] = 1.0 / m if m > 0.0 else 0.0


@njit(**JIT)
def solve_pairs(X, V, W, R, B, pi, pj, npairs, mu, e, thresh, h, iters, touched, count,
                deepest, has_col, ground, boxes, spheres, moved):
    """Project the overlapping pairs apart and apply the contact law (Gauss-Seidel).

    Pair (i, j) overlaps when |x_i - x_j| < r_i + r_j.  Its normal n is the direction of
    x_i - x_j at the start of the step, x - h v (exact for the bodies' symplectic Euler
    step), so a pair that crossed within the step is pushed back to the side it came from,
    and the impulses, all along n or across it at the two particles, keep angular
    momentum when there is no friction.  The pair moves apart along n by the least lam
    that restores the distance, split by inverse mass, and the velocities by lam / h;
    the approaching normal speed left is removed (reversed times ``e`` above ``thresh``)
    and the relative tangential speed reduced by at most ``mu`` times the whole normal
    change: the law of ``kernels.colliders.contact_velocity`` applied to the relative
    velocity, written out here because its normal change also counts the projection's
    lam / h in the friction budget.  Every velocity change also moves the particle by h
    times it, so x - h v stays the start of the step for the pairs that follow.
    With ``has_col``, every particle moved (flagged in ``moved`` (N,) uint8, zero on entry
    and on return) is then projected out of the static colliders, once, after the sweeps
    (``kernels.colliders.collide_point``: ground, boxes, spheres), so contact never leaves
    a particle inside one (a body pressed into the ground by another would otherwise be
    pushed back out by the next step's collider pass, and the two would pump energy).
    Returns the overlapping pairs met in the first sweep; ``count[b]``, ``deepest[b]`` get
    each body's contacts and deepest penetration (m) of that sweep.
    """
    # one sweep over the pair list in build order (spatially sorted): per pair ~20 loads,
    # two square roots and a few dozen multiply-adds; a pair apart costs one distance
    found = 0
    ih = 1.0 / h
    for it in range(iters):
        for k in range(npairs):
            i = pi[k]
            j = pj[k]
            wi = W[i]
            wj = W[j]
            ws = wi + wj
            if ws <= 0.0:
                continue
            dx = X[0, i] - X[0, j]
            dy = X[1, i] - X[1, j]
            dz = X[2, i] - X[2, j]
            d2 = dx * dx + dy * dy + dz * dz
            rr = R[i] + R[j]
            if not d2 < rr * rr:       # apart, or NaN (a body that blew up: left alone)
                continue
            rx = V[0, i] - V[0, j]
            ry = V[1, i] - V[1, j]
            rz = V[2, i] - V[2, j]
            sx = dx - h * rx           # separation at the start of the step
            sy = dy - h * ry
            sz = dz - h * rz
            sl = np.sqrt(sx * sx + sy * sy + sz * sz)
            if sl > 1e-9 * rr:
                nx, ny, nz = sx / sl, sy / sl, sz / sl
            else:
                d = np.sqrt(d2)
                if d > 1e-9 * rr:
                    nx, ny, nz = dx / d, dy / d, dz / d
                else:                  # coincident: apart along z (deterministic)
                    nx, ny, nz = 0.0, 0.0, 1.0
            dn = dx * nx + dy * ny + dz * nz
            lam = -dn + np.sqrt(dn * dn - d2 + rr * rr)
            ai = wi / ws
            aj = wj / ws
            # normal speed before, the target after (restitution above the threshold)
            vn0 = rx * nx + ry * ny + rz * nz
            target = -e * vn0 if -vn0 > thresh else 0.0
            vn = vn0 + lam * ih
            dvn = target - vn if vn < target else 0.0
            # tangential: Coulomb, budget mu * (whole normal change)
            tx = rx - vn0 * nx
            ty = ry - vn0 * ny
            tz = rz - vn0 * nz
            tl = np.sqrt(tx * tx + ty * ty + tz * tz)
            f = 0.0
            if tl > 0.0:
                f = mu * (lam * ih + dvn) / tl
                if f > 1.0:
                    f = 1.0
            gn = lam * ih + dvn        # relative velocity change: gn n - f t
            qx = gn * nx - f * tx
            qy = gn * ny - f * ty
            qz = gn * nz - f * tz
            # every velocity change moves the particles by h times it, so x - h v stays
            # the start of the step for the later pairs (and angular momentum exact)
            X[0, i] += ai * h * qx
            X[1, i] += ai * h * qy
            X[2, i] += ai * h * qz
            X[0, j] -= aj * h * qx
            X[1, j] -= aj * h * qy
            X[2, j] -= aj * h * qz
            V[0, i] += ai * qx
            V[1, i] += ai * qy
            V[2, i] += ai * qz
            V[0, j] -= aj * qx
            V[1, j] -= aj * qy
            V[2, j] -= aj * qz
            moved[i] = 1
            moved[j] = 1
            if it == 0:
                found += 1
                bi = B[i]
                bj = B[j]
                touched[bi] = 1
                touched[bj] = 1
                count[bi] += 1
                count[bj] += 1
                pen = rr - np.sqrt(d2)
                if pen > deepest[bi]:
                    deepest[bi] = pen
                if pen > deepest[bj]:
                    deepest[bj] = pen
    # the static colliders, once per moved particle, in pair order (deterministic)
    for k in range(npairs):
        for p in (pi[k], pj[k]):
            if moved[p]:
                moved[p] = 0
                if has_col and W[p] > 0.0:
                    X[0, p], X[1, p], X[2, p], V[0, p], V[1, p], V[2, p] = collide_point(
                        X[0, p], X[1, p], X[2, p], V[0, p], V[1, p], V[2, p], ground, boxes,
                        spheres, thresh)
    return found


@njit(**JIT)
def solve_contacts(X, V, W, R, B, pi, pj, npairs, mu, e, thresh, h, iters, touched, count,
                   deepest, has_col, ground, boxes, spheres, moved, off, up, shock, bw, dv,
                   pend):
    """``solve_pairs`` with stacking (``ContactParams.stacking``; a separate kernel so that
    the default pays nothing for it: ~25 % of the per-step sweep when merged).

    Project the overlapping pairs apart and apply the contact law (Gauss-Seidel).

    Pair (i, j) overlaps when |x_i - x_j| < r_i + r_j.  Its normal n is the direction of
    x_i - x_j at the start of the step, x - h v (exact for the bodies' symplectic Euler
    step), so a pair that crossed within the step is pushed back to the side it came from,
    and the impulses, all along n or across it at the two particles, keep angular
    momentum when there is no friction.  The pair moves apart along n by the least lam
    that restores the distance, split by inverse mass, and the velocities by lam / h;
    the approaching normal speed left is removed (reversed times ``e`` above ``thresh``)
    and the relative tangential speed reduced by at most ``mu`` times the whole normal
    change: the law of ``kernels.colliders.contact_velocity`` applied to the relative
    velocity, written out here because its normal change also counts the projection's
    lam / h in the friction budget.  Every velocity change also moves the particle by h
    times it, so x - h v stays the start of the step for the pairs that follow.
    With ``has_col``, every particle moved (flagged in ``moved`` (N,) uint8, zero on entry
    and on return) is then projected out of the static colliders, once, after the sweeps
    (``kernels.colliders.collide_point``: ground, boxes, spheres), so contact never leaves
    a particle inside one (a body pressed into the ground by another would otherwise be
    pushed back out by the next step's collider pass, and the two would pump energy).
    Returns the overlapping pairs met in the first sweep; ``count[b]``, ``deepest[b]`` get
    each body's contacts and deepest penetration (m) of that sweep.

    Load (``up``, the unit vector against gravity, nonzero): a pair of two different bodies
    that both have an inverse mass ``bw[b]`` (no pinned or grabbed particle; ``off`` (nb + 1,)
    their particle ranges) moves the two bodies as a whole instead of the two particles:
    the same velocity change is split by the bodies' inverse masses into ``dv`` (nb, 3), a
    translation of every particle of the body (``pend[b]`` set; later pairs see it), so the
    whole body, not its touching layer, carries the load and the shape match is not
    compressed by it (README "Contact between bodies").  Shock propagation: when such a
    pair is resting (approach speed at most ``thresh``) and its normal is within 60 degrees
    of ``up``, the lower body counts ``1 / shock`` times heavier, so a stack is solved from
    the bottom up in one sweep (linear momentum is then not exchanged exactly; it is in
    every other pair, and without gravity nothing here changes).  ``dv`` and ``pend`` are
    zero on entry and on return.
    """
    # one sweep over the pair list in build order (spatially sorted): per pair ~20 loads,
    # two square roots and a few dozen multiply-adds; a pair apart costs one distance
    found = 0
    ih = 1.0 / h
    load = up[0] != 0.0 or up[1] != 0.0 or up[2] != 0.0
    for it in range(iters):
        for k in range(npairs):
            i = pi[k]
            j = pj[k]
            wi = W[i]
            wj = W[j]
            ws = wi + wj
            if ws <= 0.0:
                continue
            bi = B[i]
            bj = B[j]
            xi0, xi1, xi2 = X[0, i], X[1, i], X[2, i]
            vi0, vi1, vi2 = V[0, i], V[1, i], V[2, i]
            xj0, xj1, xj2 = X[0, j], X[1, j], X[2, j]
            vj0, vj1, vj2 = V[0, j], V[1, j], V[2, j]
            if pend[bi]:               # the body's translation so far in this sweep
                xi0 += h * dv[bi, 0] + dv[bi, 3]
                xi1 += h * dv[bi, 1] + dv[bi, 4]
                xi2 += h * dv[bi, 2] + dv[bi, 5]
                vi0 += dv[bi, 0]
                vi1 += dv[bi, 1]
                vi2 += dv[bi, 2]
            if pend[bj]:
                xj0 += h * dv[bj, 0] + dv[bj, 3]
                xj1 += h * dv[bj, 1] + dv[bj, 4]
                xj2 += h * dv[bj, 2] + dv[bj, 5]
                vj0 += dv[bj, 0]
                vj1 += dv[bj, 1]
                vj2 += dv[bj, 2]
            dx = xi0 - xj0
            dy = xi1 - xj1
            dz = xi2 - xj2
            d2 = dx * dx + dy * dy + dz * dz
            rr = R[i] + R[j]
            if not d2 < rr * rr:       # apart, or NaN (a body that blew up: left alone)
                continue
            rx = vi0 - vj0
            ry = vi1 - vj1
            rz = vi2 - vj2
            sx = dx - h * rx           # separation at the start of the step
            sy = dy - h * ry
            sz = dz - h * rz
            sl = np.sqrt(sx * sx + sy * sy + sz * sz)
            if sl > 1e-9 * rr:
                nx, ny, nz = sx / sl, sy / sl, sz / sl
            else:
                d = np.sqrt(d2)
                if d > 1e-9 * rr:
                    nx, ny, nz = dx / d, dy / d, dz / d
                else:                  # coincident: apart along z (deterministic)
                    nx, ny, nz = 0.0, 0.0, 1.0
            dn = dx * nx + dy * ny + dz * nz
            lam = -dn + np.sqrt(dn * dn - d2 + rr * rr)
            # normal speed before, the target after (restitution above the threshold)
            vn0 = rx * nx + ry * ny + rz * nz
            target = -e * vn0 if -vn0 > thresh else 0.0
            vn = vn0 + lam * ih
            dvn = target - vn if vn < target else 0.0
            # tangential: Coulomb, budget mu * (whole normal change)
            tx = rx - vn0 * nx
            ty = ry - vn0 * ny
            tz = rz - vn0 * nz
            tl = np.sqrt(tx * tx + ty * ty + tz * tz)
            f = 0.0
            if tl > 0.0:
                f = mu * (lam * ih + dvn) / tl
                if f > 1.0:
                    f = 1.0
            gn = lam * ih + dvn        # relative velocity change: gn n - f t
            qx = gn * nx - f * tx
            qy = gn * ny - f * ty
            qz = gn * nz - f * tz
            if load and bi != bj and bw[bi] > 0.0 and bw[bj] > 0.0:
                # the two bodies as a whole (translation); resting and stacked: the lower
                # body counts 1 / shock times heavier
                wbi = bw[bi]
                wbj = bw[bj]
                if -vn0 <= thresh:
                    a = nx * up[0] + ny * up[1] + nz * up[2]
                    if a > 0.5:
                        wbj *= shock
                    elif a < -0.5:
                        wbi *= shock
                c = 1.0 / (wbi + wbj)
                ci = c * wbi
                cj = c * wbj
                # the overlap is removed by moving the bodies, but they leave it at most at
                # a tenth of the resting threshold (a body's velocity carries every particle, so
                # lam / h of a deep overlap would launch it); the rest of lam moves them
                # without velocity.  Friction budget: mu times the velocity change.
                va = vn0 + lam * ih
                vcap = 0.1 * thresh if vn0 < 0.1 * thresh else vn0
                if va > vcap:
                    va = vcap
                if va < target:
                    va = target
                dvn = va - vn0
                f = 0.0
                if tl > 0.0:
                    f = mu * dvn / tl
                    if f > 1.0:
                        f = 1.0
                qx = dvn * nx - f * tx
                qy = dvn * ny - f * ty
                qz = dvn * nz - f * tz
                lam -= h * dvn                 # the part the velocity change moves
                dv[bi, 0] += ci * qx
                dv[bi, 1] += ci * qy
                dv[bi, 2] += ci * qz
                dv[bj, 0] -= cj * qx
                dv[bj, 1] -= cj * qy
                dv[bj, 2] -= cj * qz
                dv[bi, 3] += ci * lam * nx
                dv[bi, 4] += ci * lam * ny
                dv[bi, 5] += ci * lam * nz
                dv[bj, 3] -= cj * lam * nx
                dv[bj, 4] -= cj * lam * ny
                dv[bj, 5] -= cj * lam * nz
                pend[bi] = 1
                pend[bj] = 1
                moved[i] = 1
                moved[j] = 1
                if it == 0:
                    found += 1
                    touched[bi] = 1
                    touched[bj] = 1
                    count[bi] += 1
                    count[bj] += 1
                    pen = rr - np.sqrt(d2)
                    if pen > deepest[bi]:
                        deepest[bi] = pen
                    if pen > deepest[bj]:
                        deepest[bj] = pen
                continue
            ai = wi / ws
            aj = wj / ws
            # every velocity change moves the particles by h times it, so x - h v stays
            # the start of the step for the later pairs (and angular momentum exact)
            X[0, i] += ai * h * qx
            X[1, i] += ai * h * qy
            X[2, i] += ai * h * qz
            X[0, j] -= aj * h * qx
            X[1, j] -= aj * h * qy
            X[2, j] -= aj * h * qz
            V[0, i] += ai * qx
            V[1, i] += ai * qy
            V[2, i] += ai * qz
            V[0, j] -= aj * qx
            V[1, j] -= aj * qy
            V[2, j] -= aj * qz
            moved[i] = 1
            moved[j] = 1
            if it == 0:
                found += 1
                touched[bi] = 1
                touched[bj] = 1
                count[bi] += 1
                count[bj] += 1
                pen = rr - np.sqrt(d2)
                if pen > deepest[bi]:
                    deepest[bi] = pen
                if pen > deepest[bj]:
                    deepest[bj] = pen
    # the bodies moved as a whole: every particle, then the static colliders
    for b in range(pend.shape[0]):
        if not pend[b]:
            continue
        pend[b] = 0
        d0, d1, d2_ = dv[b, 0], dv[b, 1], dv[b, 2]
        e0 = h * d0 + dv[b, 3]
        e1 = h * d1 + dv[b, 4]
        e2 = h * d2_ + dv[b, 5]
        dv[b, :] = 0.0
        for p in range(off[b], off[b + 1]):
            X[0, p] += e0
            X[1, p] += e1
            X[2, p] += e2
            V[0, p] += d0
            V[1, p] += d1
            V[2, p] += d2_
            moved[p] = 0
            if has_col:
                X[0, p], X[1, p], X[2, p], V[0, p], V[1, p], V[2, p] = collide_point(
                    X[0, p], X[1, p], X[2, p], V[0, p], V[1, p], V[2, p], ground, boxes,
                    spheres, thresh)
    # the static colliders, once per moved particle, in pair order (deterministic)
    for k in range(npairs):
        for p in (pi[k], pj[k]):
            if moved[p]:
                moved[p] = 0
                if has_col and W[p] > 0.0:
                    X[0, p], X[1, p], X[2, p], V[0, p], V[1, p], V[2, p] = collide_point(
                        X[0, p], X[1, p], X[2, p], V[0, p], V[1, p], V[2, p], ground, boxes,
                        spheres, thresh)
    return found


@njit(**JIT)
def count_fast(V, R, B, act, h, fast):
    """fast[b] = particles of colliding body b moving more than their radius per step."""
    fast[:] = 0
    for i in range(V.shape[1]):
        b = B[i]
        if not act[b]:
            continue
        s2 = V[0, i] * V[0, i] + V[1, i] * V[1, i] + V[2, i] * V[2, i]
        lim = R[i] / h
        if s2 > lim * lim:
            fast[b] += 1


@njit(**JIT)
def median_nn_distance(x, step):
    """Median nearest-neighbour distance of the points x[::step] among all of x (N, 3)."""
    n = x.shape[0]
    ns = (n + step - 1) // step
    best = np.empty(ns)
    for a in range(ns):
        i = a * step
        b2 = np.inf
        for j in range(n):
            if j == i:
                continue
            dx = x[j, 0] - x[i, 0]
            dy = x[j, 1] - x[i, 1]
            dz = x[j, 2] - x[i, 2]
            d2 = dx * dx + dy * dy + dz * dz
            if d2 > 0.0 and d2 < b2:
                b2 = d2
        best[a] = b2
    best.sort()
    return np.sqrt(best[ns // 2])
