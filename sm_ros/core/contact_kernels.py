"""Compiled kernels of body-body contact: the per-particle pair solve and the carried
bodies' frames.

The model, the parameters and the Python-side pass (``Contact``) are in ``contact.py``;
the pair list (a Verlet list on a cell grid, sorted by lower index) is built by
``contact_build.py``; this file and ``contact_bodies.py`` (the carried bodies' solve, with
the pieces both share in ``kernels/pair_contact.py``) hold what runs per step on that
list.  Serial; nothing allocates (``solve_bodies`` takes the buffers of its compact rows
from ``Contact``).  A
world with one colliding body and no self-collision does not run the pass at all.

Everything here is serial and the pair order is fixed by the build, so the result does not
depend on thread scheduling (bit-identical between runs).

Tunnelling: a pair is seen only where it overlaps at the end of a step, so particles
approaching faster than about ``r / h`` (r = contact radius, h = step) may cross a layer
one particle thick between two steps; ``Contact.fast_particles`` counts the particles
moving faster than that.
"""

import numpy as np
from numba import njit

from .kernels.jit import JIT, JIT_NO_REFCOUNT, U
from .kernels.linalg import ZERO16, add_damping
from .kernels.pair_contact import collide_moved, is_carried, pair_normal, report_touch
from .kernels.spread import moved_box, spread_of


@njit(**JIT_NO_REFCOUNT)
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


@njit(**JIT_NO_REFCOUNT)
def solve_pairs(parts, pairs, law, report, col):
    """Project the overlapping pairs apart and apply the contact law (Gauss-Seidel,
    ``law.sweeps`` sweeps over the pair list in build order).

    Pair (i, j) overlaps when |x_i - x_j| < r_i + r_j.  Its normal n is the direction of
    x_i - x_j at the start of the step, x - h v (exact for the bodies' symplectic Euler
    step), so a pair that crossed within the step is pushed back to the side it came
    from.  The pair moves apart along n by the least lam that restores the distance,
    split by inverse mass, and the velocities by lam / h; the approaching normal speed
    left is removed (reversed times the restitution above ``law.thresh``) and the
    relative tangential speed reduced by at most the friction times the whole normal
    change (the law of ``kernels.colliders.contact_velocity`` on the relative velocity,
    its normal change counting lam / h too).  Every velocity change also moves the
    particle by h times it, so x - h v stays the start of the step for the later pairs
    and, without friction, angular momentum is kept.  Every particle moved is then put
    out of the static colliders ``col`` once (``collide_moved``), so contact never leaves
    a particle inside one.  Returns the overlapping pairs of the first sweep; ``report``
    gets each body's contacts and deepest penetration of that sweep.
    """
    found = 0
    for it in range(law.sweeps):
        for k in range(pairs.count):
            if _push_pair(parts, law, pairs.first[k], pairs.second[k], report, it == 0):
                found += 1
    collide_moved(parts, pairs, col)
    return found


@njit(inline='always', **JIT)
def _push_pair(parts, law, i, j, report, first):
    """One visit of pair (i, j) in ``solve_pairs``; whether it overlapped."""
    X, V, W, R, h = parts.x, parts.v, parts.inv_mass, parts.radius, law.h
    wi = W[i]
    wj = W[j]
    ws = wi + wj
    if ws <= 0.0:
        return False
    dx = X[0, i] - X[0, j]
    dy = X[1, i] - X[1, j]
    dz = X[2, i] - X[2, j]
    d2 = dx * dx + dy * dy + dz * dz
    rr = R[i] + R[j]
    if not d2 < rr * rr:       # apart, or NaN (a body that blew up: left alone)
        return False
    ih = 1.0 / h
    rx = V[0, i] - V[0, j]
    ry = V[1, i] - V[1, j]
    rz = V[2, i] - V[2, j]
    nx, ny, nz = pair_normal(dx - h * rx, dy - h * ry, dz - h * rz, dx, dy, dz, d2, rr)
    dn = dx * nx + dy * ny + dz * nz
    lam = -dn + np.sqrt(dn * dn - d2 + rr * rr)
    ai = wi / ws
    aj = wj / ws
    # normal speed before, the target after (restitution above the threshold)
    vn0 = rx * nx + ry * ny + rz * nz
    target = -law.restitution * vn0 if -vn0 > law.thresh else 0.0
    vn = vn0 + lam * ih
    dvn = target - vn if vn < target else 0.0
    # tangential: Coulomb, budget friction * (whole normal change)
    tx = rx - vn0 * nx
    ty = ry - vn0 * ny
    tz = rz - vn0 * nz
    tl = np.sqrt(tx * tx + ty * ty + tz * tz)
    f = 0.0
    if tl > 0.0:
        f = law.friction * (lam * ih + dvn) / tl
        if f > 1.0:
            f = 1.0
    gn = lam * ih + dvn        # relative velocity change: gn n - f t
    q = (gn * nx - f * tx, gn * ny - f * ty, gn * nz - f * tz)
    for c in range(3):
        X[c, i] += ai * h * q[c]
        X[c, j] -= aj * h * q[c]
        V[c, i] += ai * q[c]
        V[c, j] -= aj * q[c]
    parts.moved[i] = 1
    parts.moved[j] = 1
    if first:
        report_touch(report, parts.body[i], parts.body[j], rr - np.sqrt(d2))
    return True


@njit(**JIT_NO_REFCOUNT)
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


@njit(**JIT_NO_REFCOUNT)
def inverse_sym3(a, out):
    """out (9,) = the inverse of the symmetric 3x3 matrix a (9,), row-major, by its
    adjugate; zero when a is singular to round-off (a body of collinear particles)."""
    c00 = a[4] * a[8] - a[5] * a[7]
    c01 = a[5] * a[6] - a[3] * a[8]
    c02 = a[3] * a[7] - a[4] * a[6]
    det = a[0] * c00 + a[1] * c01 + a[2] * c02
    tr = a[0] + a[4] + a[8]
    if not abs(det) > 1e-12 * tr * tr * tr:
        out[:] = 0.0
        return
    idet = 1.0 / det
    out[0] = c00 * idet
    out[1] = (a[2] * a[7] - a[1] * a[8]) * idet
    out[2] = (a[1] * a[5] - a[2] * a[4]) * idet
    out[3] = c01 * idet
    out[4] = (a[0] * a[8] - a[2] * a[6]) * idet
    out[5] = (a[2] * a[3] - a[0] * a[5]) * idet
    out[6] = c02 * idet
    out[7] = (a[1] * a[6] - a[0] * a[7]) * idet
    out[8] = (a[0] * a[4] - a[1] * a[3]) * idet


@njit(**JIT)
def body_velocities(X, V, M, bodies, Xref, act, dbox):
    """The frames of the carried bodies (``is_carried``) at the pass's start, from the
    particles' masses ``M`` (a carried body has no pinned or grabbed particle): the
    velocity of the centre of mass, the lowest particle's height and vertical velocity,
    the centre, the inverse inertia about it and the spin (``CarriedBodies``).  Returns
    what ``contact_build.moved_spread2`` returns for the colliding bodies (``act``) and
    ``Xref``, and writes the displacements' bounding box to ``dbox`` (6,) (lo x y z, hi
    x y z; for ``wall_candidates``): body by body, so the pass reads the positions from
    memory once for both."""
    dlo = np.full(3, np.inf)
    dhi = np.full(3, -np.inf)
    nan = _body_frames(X, V, M, bodies, (Xref, act), (dlo, dhi), np.zeros(9))
    for r in range(3):
        dbox[r] = dlo[r] if dlo[0] <= dhi[0] else 0.0    # empty: nothing colliding
        dbox[3 + r] = dhi[r] if dlo[0] <= dhi[0] else 0.0
    return spread_of(dlo, dhi, nan)


@njit(**JIT_NO_REFCOUNT)
def _body_frames(X, V, M, bodies, moved_since, box, a):
    """``body_velocities``' loop over the bodies (it allocates nothing, so it runs without
    reference counting); ``moved_since`` (Xref, act), ``box`` (dlo, dhi) the
    displacements' bounds, ``a`` (9,) scratch.  Returns ``moved_box``'s non-finite count."""
    Xref, act = moved_since
    dlo, dhi = box
    nan = 0.0
    off = bodies.offsets
    for b in range(off.shape[0] - 1):
        for c in range(3):
            bodies.velocity[b, c] = 0.0
            bodies.spin[b, c] = 0.0
        if act[b]:
            nan += moved_box(X, Xref, off[b], off[b + 1], dlo, dhi)
        if is_carried(bodies, b):
            _body_frame(X, V, M, bodies, b, a)
    return nan


@njit(inline='always', **JIT)
def _moments(X, V, M, start, end):
    """Momentum, first moment, angular momentum and second moments (xx yy zz xy yz zx)
    of particles start..end about the first one (for round-off), and their lowest
    height."""
    q0, q1, q2 = X[0, start], X[1, start], X[2, start]
    sums = ZERO16
    lo = np.inf
    for k in range(U(start), U(end)):
        lo = min(lo, X[2, k])
        sums = add_damping(sums, M[k], X[0, k] - q0, X[1, k] - q1, X[2, k] - q2,
                           V[0, k], V[1, k], V[2, k])
    return sums[3:6], sums[:3], sums[6:9], sums[9:15], lo


@njit(inline='always', **JIT)
def _body_frame(X, V, M, bodies, b, a):
    """Body b's frame (``body_velocities``); ``a`` (9,) scratch for its inertia."""
    o = bodies.offsets[b]
    end = bodies.offsets[b + 1]
    (p0, p1, p2), (s0, s1, s2), (l0, l1, l2), sec, lo = _moments(X, V, M, o, end)
    xx, yy, zz, xy, yz, zx = sec
    klo = o                    # the first particle at the lowest height
    while klo < end - 1 and not X[2, klo] == lo:
        klo += 1
    iw = bodies.inv_mass[b]
    vb, bc, biv, bom = bodies.velocity, bodies.centre, bodies.inv_inertia, bodies.spin
    vb[b, 0] = p0 * iw
    vb[b, 1] = p1 * iw
    vb[b, 2] = p2 * iw
    bodies.lowest[0, b] = lo
    bodies.lowest[1, b] = V[2, klo]
    g0 = s0 * iw               # centre of mass, relative to the first particle
    g1 = s1 * iw
    g2 = s2 * iw
    bc[b, 0] = X[0, o] + g0
    bc[b, 1] = X[1, o] + g1
    bc[b, 2] = X[2, o] + g2
    # moments about the centre: shift by the total mass 1 / iw
    mm = 1.0 / iw
    xx -= mm * g0 * g0
    yy -= mm * g1 * g1
    zz -= mm * g2 * g2
    xy -= mm * g0 * g1
    yz -= mm * g1 * g2
    zx -= mm * g2 * g0
    l0 -= g1 * p2 - g2 * p1
    l1 -= g2 * p0 - g0 * p2
    l2 -= g0 * p1 - g1 * p0
    a[0] = yy + zz
    a[4] = zz + xx
    a[8] = xx + yy
    a[1] = a[3] = -xy
    a[5] = a[7] = -yz
    a[2] = a[6] = -zx
    inverse_sym3(a, biv[b])
    bom[b, 0] = biv[b, 0] * l0 + biv[b, 1] * l1 + biv[b, 2] * l2
    bom[b, 1] = biv[b, 3] * l0 + biv[b, 4] * l1 + biv[b, 5] * l2
    bom[b, 2] = biv[b, 6] * l0 + biv[b, 7] * l1 + biv[b, 8] * l2


@njit(**JIT_NO_REFCOUNT)
def wall_candidates(X, bodies, col, reach, walls, act, bbox, dbox):
    """The particles of the carried bodies (``is_carried``) within ``reach`` of a box or a
    sphere of ``col``, body by body: ``walls.particles[walls.start[b]:walls.start[b +
    1]]``; returns their number (more than the buffer holds: call again with a larger
    one).  A body's bounding box is tested first, so a body far from them costs nothing
    more: for a colliding body (``act``) its box at the last pair-list build
    (``bbox[b]``, ``body_overlaps``) widened by the bounding box of every colliding
    particle's displacement since then (``dbox``, ``body_velocities``); for another, a
    pass over its particles."""
    off, cand, cptr, margin = bodies.offsets, walls.particles, walls.start, reach
    boxes, spheres = col.boxes, col.spheres
    m = 0
    for b in range(off.shape[0] - 1):
        cptr[b] = m
        if not is_carried(bodies, b):
            continue
        if act[b]:
            lo0, lo1, lo2 = bbox[b, 0] + dbox[0], bbox[b, 1] + dbox[1], bbox[b, 2] + dbox[2]
            hi0, hi1, hi2 = bbox[b, 3] + dbox[3], bbox[b, 4] + dbox[4], bbox[b, 5] + dbox[5]
        else:
            lo0 = lo1 = lo2 = np.inf
            hi0 = hi1 = hi2 = -np.inf
            for p in range(off[b], off[b + 1]):
                lo0 = min(lo0, X[0, p])
                lo1 = min(lo1, X[1, p])
                lo2 = min(lo2, X[2, p])
                hi0 = max(hi0, X[0, p])
                hi1 = max(hi1, X[1, p])
                hi2 = max(hi2, X[2, p])
        for k in range(boxes.shape[0]):
            if not (lo0 - margin < boxes[k, 3] and hi0 + margin > boxes[k, 0]
                    and lo1 - margin < boxes[k, 4] and hi1 + margin > boxes[k, 1]
                    and lo2 - margin < boxes[k, 5] and hi2 + margin > boxes[k, 2]):
                continue
            for p in range(off[b], off[b + 1]):
                if (X[0, p] > boxes[k, 0] - margin and X[0, p] < boxes[k, 3] + margin
                        and X[1, p] > boxes[k, 1] - margin and X[1, p] < boxes[k, 4] + margin
                        and X[2, p] > boxes[k, 2] - margin
                        and X[2, p] < boxes[k, 5] + margin):
                    if m < cand.shape[0]:
                        cand[m] = p
                    m += 1
        for k in range(spheres.shape[0]):
            rr = spheres[k, 3] + margin
            for p in range(off[b], off[b + 1]):
                d0 = X[0, p] - spheres[k, 0]
                d1 = X[1, p] - spheres[k, 1]
                d2 = X[2, p] - spheres[k, 2]
                if d0 * d0 + d1 * d1 + d2 * d2 < rr * rr:
                    if m < cand.shape[0]:
                        cand[m] = p
                    m += 1
    cptr[off.shape[0] - 1] = m
    return m
