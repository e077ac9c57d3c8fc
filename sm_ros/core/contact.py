"""Contact between bodies, and self-collision, on the world's flat state (``flat.py``).

Model (README "Contact between bodies"): every particle of a colliding body is a sphere of
its body's contact radius ``r``; two particles of different bodies (or of one
self-colliding body whose rest distance exceeds ``SELF_REST_FACTOR`` times their contact
distance) must stay at least ``r_i + r_j`` apart.  After the bodies' own step (each
substep) every overlapping pair is pushed apart along the line of its start-of-step
positions (x - h v), weighted by inverse mass (pinned and grabbed particles have infinite
mass), equal and opposite, so linear momentum is kept to round-off; its relative velocity
then gets the ground's contact law (``solve_pairs``).  Every velocity change also moves the
particles by h times it, so without friction angular momentum is kept to round-off too.
Particles that contact moved are then projected out of the static colliders again.

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

from dataclasses import dataclass, fields, replace
import math
from typing import Optional

import numpy as np
from numba import njit

from .kernels.colliders import collide_point, contact_velocity
from .kernels.jit import JIT
from .params import _finite

#: Same-body pairs self-collide only when their rest distance exceeds this many times
#: their contact distance ``r_i + r_j`` (lattice neighbours up to two spacings apart
#: never do: they are held by the shape match).
SELF_REST_FACTOR = 2.0
#: Verlet skin as a fraction of the largest contact radius.
SKIN_FACTOR = 0.5
_NO_GROUND = np.zeros(4)
_NO_ROWS8 = np.zeros((0, 8))
_NO_ROWS6 = np.zeros((0, 6))


# ---------------------------------------------------------------------------------------
# Kernels (serial; nothing allocates)
# ---------------------------------------------------------------------------------------

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


# ---------------------------------------------------------------------------------------
# Parameters
# ---------------------------------------------------------------------------------------

def _flag(name, value):
    if not isinstance(value, (bool, np.bool_)):
        raise ValueError(f'{name} must be true or false, got {value!r}')
    return bool(value)


@dataclass(frozen=True)
class ContactParams:
    """Scene-wide contact settings (README "Contact").

    ``enabled`` turns body-body contact on; ``friction`` (Coulomb mu) and ``restitution``
    act like the ground's; ``radius_scale`` multiplies every body's default contact
    radius (half its median nearest-neighbour distance; a body's own ``contact_radius``
    is used as given); ``iterations`` Gauss-Seidel sweeps over the pairs per step.
    """

    enabled: bool = True
    friction: float = 0.5
    restitution: float = 0.0
    radius_scale: float = 1.0
    iterations: int = 1

    def validate(self) -> 'ContactParams':
        """Return a normalised copy; raise ValueError naming the bad field."""
        it = self.iterations
        if isinstance(it, bool) or not isinstance(it, (int, np.integer)) or not 1 <= it <= 16:
            raise ValueError(f'contact.iterations must be an integer in [1, 16], got {it!r}')
        return replace(
            self,
            enabled=_flag('contact.enabled', self.enabled),
            friction=_finite('contact.friction', self.friction, 0.0, 10.0),
            restitution=_finite('contact.restitution', self.restitution, 0.0, 1.0),
            radius_scale=_finite('contact.radius_scale', self.radius_scale, 0.0, 10.0,
                                 lo_open=True),
            iterations=int(it),
        )

    @staticmethod
    def field_names():
        """Names of all fields."""
        return tuple(f.name for f in fields(ContactParams))


@dataclass(frozen=True)
class BodyContact:
    """Per-body contact settings: ``collide`` with other bodies, ``radius`` (m; None =
    the default rule), ``self_collision`` (opt-in)."""

    collide: bool = True
    radius: Optional[float] = None
    self_collision: bool = False

    def validate(self) -> 'BodyContact':
        """Return a normalised copy; raise ValueError naming the bad field."""
        r = self.radius
        if r is not None:
            r = _finite('contact_radius', r, 0.0, lo_open=True)
        return replace(self, collide=_flag('collide', self.collide), radius=r,
                       self_collision=_flag('self_collision', self.self_collision))


def default_radius(points) -> float:
    """Half the median nearest-neighbour distance of a point set (N, 3); 0 for N < 2.

    For a lattice body that is half its spacing.  Measured on at most ~512 evenly strided
    points against all of them (exact for N <= 512).
    """
    x = np.ascontiguousarray(points, dtype=np.float64)
    if len(x) < 2:
        return 0.0
    step = max(1, len(x) // 512)
    d = float(median_nn_distance(x, step))
    return 0.5 * d if math.isfinite(d) else 0.0


# ---------------------------------------------------------------------------------------
# The pass
# ---------------------------------------------------------------------------------------

class Contact:
    """Body-body contact over a ``FlatState``: Verlet pair list and the response.

    Made by ``World``; ``run(flat, h, thresh)`` is called after the bodies' step.  Per
    body after each step: ``count`` contacts, ``deepest`` penetration (m) found before the
    projection (``fast_particles`` counts those moving faster than their radius per
    step, on demand).  ``builds``
    counts list rebuilds, ``pairs`` the pairs in the list, ``found`` the touching ones.
    """

    def __init__(self, flat, params: ContactParams, body_contacts, radii):
        self.flat = flat
        self.params = params
        nb = len(flat.bodies)
        self.act = np.array([c.collide for c in body_contacts], dtype=np.bool_)
        self.selfc = np.array([c.collide and c.self_collision for c in body_contacts],
                              dtype=np.bool_)
        if nb == 0:
            self.act = np.zeros(1, dtype=np.bool_)
            self.selfc = np.zeros(1, dtype=np.bool_)
        self.radii = np.asarray(radii, dtype=np.float64)
        for k in range(nb):
            flat.R[flat.off[k]:flat.off[k + 1]] = self.radii[k]
        n = flat.n
        rmax = float(self.radii[self.act[:nb]].max()) if nb and self.act[:nb].any() else 0.0
        self.skin = SKIN_FACTOR * rmax
        self.cell = max(2.0 * rmax + self.skin, 1e-12)
        self.needed = nb > 0 and rmax > 0.0 and (int(self.act[:nb].sum()) >= 2
                                                  or bool(self.selfc[:nb].any()))
        tsize = 1 << max(4, int(math.ceil(math.log2(max(4 * n, 2)))))
        self._hb = np.zeros(n, dtype=np.int64)
        self._cnt = np.zeros(tsize + 1, dtype=np.int64)
        self._srt = np.zeros(n, dtype=np.int64)
        self._skey = np.zeros(n, dtype=np.int64)
        self._sco = np.zeros((5, n))
        cap = max(1024, 2 * n)
        self._pi = np.zeros(cap, dtype=np.int32)
        self._pj = np.zeros(cap, dtype=np.int32)
        self._ti = np.zeros(cap, dtype=np.int32)
        self._tj = np.zeros(cap, dtype=np.int32)
        self._pcnt = np.zeros(n + 1, dtype=np.int64)
        self._xref = np.zeros((3, n))
        self._moved = np.zeros(n, dtype=np.uint8)
        self.npairs = 0
        self.valid = False
        self.builds = 0
        self.found = 0
        self.count = np.zeros(max(nb, 1), dtype=np.int64)
        self.deepest = np.zeros(max(nb, 1))
        self.fast = np.zeros(max(nb, 1), dtype=np.int64)

    def invalidate(self):
        """Force a rebuild of the pair list at the next step."""
        self.valid = False

    def _build(self):
        f = self.flat
        while True:
            m = build_pairs_grid(f.X, f.R, f.B, self.act, self.selfc, f.X0, self.cell,
                                 self.skin, SELF_REST_FACTOR, self._hb, self._cnt, self._srt,
                                 self._sco, self._pi, self._pj)
            if m < 0:                           # sparse world: hashed cells
                m = build_pairs(f.X, f.R, f.B, self.act, self.selfc, f.X0, self.cell,
                                self.skin, SELF_REST_FACTOR, self._hb, self._cnt, self._srt,
                                self._skey, self._sco, self._pi, self._pj)
            if m <= len(self._pi):
                break
            cap = int(m * 1.5) + 1024           # grows rarely (a rebuild, not a step)
            self._pi = np.zeros(cap, dtype=np.int32)
            self._pj = np.zeros(cap, dtype=np.int32)
            self._ti = np.zeros(cap, dtype=np.int32)
            self._tj = np.zeros(cap, dtype=np.int32)
        sort_pairs(self._pi, self._pj, m, f.n, self._pcnt, self._ti, self._tj)
        self.npairs = m
        self._xref[:] = f.X
        self.valid = True
        self.builds += 1

    def run(self, h, thresh, has_col=False, ground=_NO_GROUND, boxes=_NO_ROWS8,
            spheres=_NO_ROWS6):
        """Detect and resolve contacts on ``flat.X``/``flat.V`` (already gathered).

        ``has_col``, ``ground``, ``boxes``, ``spheres``: the World's static colliders (rows
        as in ``kernels.colliders.collide_point``), re-applied to every particle contact
        moved.
        """
        f = self.flat
        half = 0.5 * self.skin
        if not self.valid or max_moved2(f.X, self._xref, f.B, self.act) > half * half:
            self._build()
        self.count[:] = 0
        self.deepest[:] = 0.0
        p = self.params
        self.found = solve_pairs(f.X, f.V, f.W, f.R, f.B, self._pi, self._pj, self.npairs,
                                 p.friction, p.restitution, thresh, float(h), p.iterations,
                                 f.touched, self.count, self.deepest, bool(has_col), ground,
                                 boxes, spheres, self._moved)

    def fast_particles(self, h):
        """Per body, the particles that moved more than their contact radius in the last
        step of ``h`` seconds (those can tunnel through a thin layer; see the module)."""
        f = self.flat
        count_fast(f.V, f.R, f.B, self.act, float(h), self.fast)
        return self.fast[:len(f.bodies)].copy()


__all__ = ['ContactParams', 'BodyContact', 'Contact', 'default_radius', 'SELF_REST_FACTOR',
           'contact_velocity']
