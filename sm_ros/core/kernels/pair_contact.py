"""Compiled pieces of the contact pass that its two solves share
(``contact_kernels.solve_pairs``, ``contact_bodies.solve_bodies``): the pair normal, the
impulses on a particle and on a body carried as a whole, the compact rows of carried
pairs, the warm start of the carried bodies' pass and the collider pass over the
particles contact moved.  Their arguments are the named tuples of
``contact_state.py``.  In the kernel package so that both modules' caches are stamped
with them (``jit.py``).
"""

import numpy as np
from numba import njit

from .colliders import Colliders, collide_point
from .jit import JIT, JIT_NO_REFCOUNT


@njit(inline='always', **JIT)
def body_colliders(col, b):
    """The colliders of the contact pass (``col.radius``: one radius per body) as the
    particles of body ``b`` meet them: grown by its radius."""
    return Colliders(col.on, col.ground, col.boxes, col.spheres, col.thresh, col.radius[b],
                     col.h)


@njit(inline='always', **JIT)
def collide_moved(parts, pairs, col):
    """The static colliders of ``col`` (radius per body), once per particle the solve
    moved (``parts.moved``, cleared), in pair order (deterministic); kinematic particles
    (inverse mass 0) stay where they were put."""
    X, V, moved = parts.x, parts.v, parts.moved
    for k in range(pairs.count):
        for p in (pairs.first[k], pairs.second[k]):
            if moved[p]:
                moved[p] = 0
                if col.on and parts.inv_mass[p] > 0.0:
                    X[0, p], X[1, p], X[2, p], V[0, p], V[1, p], V[2, p] = collide_point(
                        X[0, p], X[1, p], X[2, p], V[0, p], V[1, p], V[2, p],
                        body_colliders(col, parts.body[p]))


@njit(inline='always', **JIT)
def report_touch(report, bi, bj, pen):
    """Count a touching pair of bodies bi, bj overlapping by ``pen`` in ``report``."""
    report.touched[bi] = 1
    report.touched[bj] = 1
    report.count[bi] += 1
    report.count[bj] += 1
    if pen > report.deepest[bi]:
        report.deepest[bi] = pen
    if pen > report.deepest[bj]:
        report.deepest[bj] = pen


@njit(inline='always', **JIT)
def is_carried(bodies, b):
    """Whether body b carries its contacts as a whole (marked, finite mass)."""
    return bodies.carried[b] and bodies.inv_mass[b] > 0.0


@njit(inline='always', **JIT)
def carried_velocity(bodies, b):
    """A carried body's own velocity: its velocity at the pass's start plus what the pass
    gave it so far (the law acts on it, not on the particle's)."""
    vb, dv = bodies.velocity, bodies.change
    return vb[b, 0] + dv[b, 0], vb[b, 1] + dv[b, 1], vb[b, 2] + dv[b, 2]


@njit(inline='always', **JIT)
def pair_normal(sx, sy, sz, dx, dy, dz, d2, rr):
    """The unit normal of a pair: along its separation at the start of the step (s), else
    along its separation now (d, squared length d2), else along z when the two coincide
    (deterministic); ``rr`` the contact distance sets what counts as zero."""
    sl = np.sqrt(sx * sx + sy * sy + sz * sz)
    if sl > 1e-9 * rr:
        return sx / sl, sy / sl, sz / sl
    d = np.sqrt(d2)
    if d > 1e-9 * rr:
        return dx / d, dy / d, dz / d
    return 0.0, 0.0, 1.0


@njit(inline='always', **JIT)
def move_particle(parts, i, c, h, push, shift):
    """Particle i's own change, inverse mass c: velocity impulse ``push`` (it also moves
    by h times the velocity change), position impulse ``shift`` (moves it only)."""
    X, V = parts.x, parts.v
    X[0, i] += c * (h * push[0] + shift[0])
    X[1, i] += c * (h * push[1] + shift[1])
    X[2, i] += c * (h * push[2] + shift[2])
    V[0, i] += c * push[0]
    V[1, i] += c * push[1]
    V[2, i] += c * push[2]


@njit(inline='always', **JIT)
def pair_impulse(impulse, k, gn, qn, kn, rel, normal, vn0, friction, ih):
    """Pair k's impulses in ``solve_bodies``: its normal velocity change ``gn`` and
    position change ``qn`` over the inverse masses ``kn``, accumulated in
    ``impulse[:, k]`` (never negative: a later sweep may take back what an earlier one
    gave too much), and Coulomb friction on the relative velocity ``rel`` (``normal``,
    normal speed ``vn0``): at most ``friction`` times the normal change (the position
    impulse's too, over h: ``ih`` = 1 / h) and at most what stops the sliding.  Returns
    the velocity impulse, the position impulse (3 each) and the largest velocity change
    it makes (for the stop test)."""
    rx, ry, rz = rel
    nx, ny, nz = normal
    pn = gn / kn               # normal impulse (mass x velocity)
    qq = qn / kn               # position impulse (mass x length)
    a_new = max(impulse[0, k] + pn, 0.0)
    pn = a_new - impulse[0, k]
    impulse[0, k] = a_new
    a_new = max(impulse[1, k] + qq, 0.0)
    qq = a_new - impulse[1, k]
    impulse[1, k] = a_new
    tx = rx - vn0 * nx
    ty = ry - vn0 * ny
    tz = rz - vn0 * nz
    tl = np.sqrt(tx * tx + ty * ty + tz * tz)
    pt = 0.0
    if tl > 0.0:
        pt = min(friction * max(pn + qq * ih, 0.0), tl / kn) / tl
    ch = kn * max(abs(pn) + pt * tl, abs(qq) * ih)
    return ((pn * nx - pt * tx, pn * ny - pt * ty, pn * nz - pt * tz),
            (qq * nx, qq * ny, qq * nz), ch)


@njit(inline='always', **JIT)
def move_body(bodies, b, c, push, shift):
    """A carried body b takes the impulses ``push`` (velocity) and ``shift`` (position)
    times ``c`` (its inverse mass, negative on the pair's second side) as a translation,
    kept in its ``change``; it is held by another body (no spin) and pending."""
    dv = bodies.change
    dv[b, 0] += c * push[0]
    dv[b, 1] += c * push[1]
    dv[b, 2] += c * push[2]
    dv[b, 3] += c * shift[0]
    dv[b, 4] += c * shift[1]
    dv[b, 5] += c * shift[2]
    dv[b, 6] = 1.0
    bodies.pending[b] = 1


@njit(inline='always', **JIT)
def compact_row(parts, sweep, h, i, j, a):
    """Row a of ``solve_bodies``'s compact rows, for the pair (i, j) of two carried
    bodies: ``row_index[:, a]`` = (i, j, their bodies, 1: the row is set;
    ``solve_bodies`` makes it 3 while the pair holds impulses, 0 when the row takes the
    general path) and ``rows[:, a]`` = x_i - x_j (3), the start-of-step separation
    x_i - x_j - h (v_i - v_j) (3), r_i + r_j: what a visit of the later sweeps reads per
    pair (their bodies' moves are added from ``change`` at each visit).  What every pair
    of two bodies shares (their velocities, inverse masses) is read from the bodies'
    rows, which stay in cache."""
    X, V = parts.x, parts.v
    cij, cf = sweep.row_index, sweep.rows
    cij[0, a] = i
    cij[1, a] = j
    cij[2, a] = parts.body[i]
    cij[3, a] = parts.body[j]
    cij[4, a] = 1
    for c in range(3):
        d = X[c, i] - X[c, j]
        cf[c, a] = d
        cf[3 + c, a] = d - h * (V[c, i] - V[c, j])
    cf[6, a] = parts.radius[i] + parts.radius[j]


@njit(inline='always', **JIT)
def with_body_moves(parts, bodies, b, c, i, h):
    """Particle i's position and velocity with its body's moves so far (``c``: body b is
    carried as a whole)."""
    X, V, dv = parts.x, parts.v, bodies.change
    x0, x1, x2 = X[0, i], X[1, i], X[2, i]
    v0, v1, v2 = V[0, i], V[1, i], V[2, i]
    if c and bodies.pending[b]:
        v0 += dv[b, 0]
        v1 += dv[b, 1]
        v2 += dv[b, 2]
        x0 += h * dv[b, 0] + dv[b, 3]
        x1 += h * dv[b, 1] + dv[b, 4]
        x2 += h * dv[b, 2] + dv[b, 5]
    return x0, x1, x2, v0, v1, v2


@njit(inline='always', **JIT)
def separation(own_i, own_j, h):
    """A pair's separation x_i - x_j (3), its square, and its separation at the start of
    the step x_i - x_j - h (v_i - v_j) (3), from each side's (x, v) (``with_body_moves``)."""
    xi0, xi1, xi2, vi0, vi1, vi2 = own_i
    xj0, xj1, xj2, vj0, vj1, vj2 = own_j
    dx = xi0 - xj0
    dy = xi1 - xj1
    dz = xi2 - xj2
    return (dx, dy, dz, dx * dx + dy * dy + dz * dz, dx - h * (vi0 - vj0),
            dy - h * (vi1 - vj1), dz - h * (vi2 - vj2))


@njit(**JIT_NO_REFCOUNT)
def warm_start(parts, pairs, sweep, bodies, law, col):
    """Warm start of ``solve_bodies``: the velocity impulses its pairs of carried bodies
    and their ground contacts ended the last step with (``impulse[0]``,
    ``ground_impulse[0]``) are applied again first, times ``law.warm`` (0: none), along
    the pairs' normals now, with Coulomb friction up to ``law.friction`` times them; the
    sweeps then only correct them (and may take them back).  A resting heap so carries
    its load from the first sweep (without it, the sweeps of one step do not carry the
    load of a heap ten bodies high to the ground).  Every other accumulated impulse is
    cleared."""
    for k in range(pairs.count):
        p = law.warm * sweep.impulse[0, k]
        sweep.impulse[0, k] = 0.0
        sweep.impulse[1, k] = 0.0
        if p > 0.0:
            _warm_pair(parts, pairs, sweep, bodies, law, k, p)
    ground = col.ground
    hasg = col.on and ground[0] > 0.5
    bw, dv, vb, accg = bodies.inv_mass, bodies.change, bodies.velocity, bodies.ground_impulse
    for b in range(bodies.pending.shape[0]):
        p = law.warm * accg[0, b]
        accg[0, b] = 0.0
        accg[1, b] = 0.0
        if not (hasg and p > 0.0 and is_carried(bodies, b)):
            continue
        tx = vb[b, 0] + dv[b, 0]
        ty = vb[b, 1] + dv[b, 1]
        tl = np.sqrt(tx * tx + ty * ty)
        pt = 0.0
        if tl > 0.0:
            pt = min(ground[2] * p, tl / bw[b]) / tl
        dv[b, 0] -= bw[b] * pt * tx
        dv[b, 1] -= bw[b] * pt * ty
        dv[b, 2] += bw[b] * p
        accg[0, b] = p
        bodies.pending[b] = 1


@njit(inline='always', **JIT)
def _warm_pair(parts, pairs, sweep, bodies, law, k, p):
    """Pair k's share of ``warm_start``: the normal impulse p again, with friction, when
    a side is carried as a whole."""
    h = law.h
    W, B, bw, dv = parts.inv_mass, parts.body, bodies.inv_mass, bodies.change
    i = pairs.first[k]
    j = pairs.second[k]
    wi = W[i]
    wj = W[j]
    bi = B[i]
    bj = B[j]
    ci = bi != bj and is_carried(bodies, bi) and wi > 0.0
    cj = bi != bj and is_carried(bodies, bj) and wj > 0.0
    if not (ci or cj) or wi + wj <= 0.0:
        return
    own_i = with_body_moves(parts, bodies, bi, ci, i, h)
    own_j = with_body_moves(parts, bodies, bj, cj, j, h)
    dx, dy, dz, d2, sx, sy, sz = separation(own_i, own_j, h)
    if not d2 == d2:
        return
    nx, ny, nz = pair_normal(sx, sy, sz, dx, dy, dz, d2, parts.radius[i] + parts.radius[j])
    vi0, vi1, vi2 = carried_velocity(bodies, bi) if ci else own_i[3:]
    vj0, vj1, vj2 = carried_velocity(bodies, bj) if cj else own_j[3:]
    rx = vi0 - vj0
    ry = vi1 - vj1
    rz = vi2 - vj2
    vn = rx * nx + ry * ny + rz * nz
    ki = bw[bi] if ci else wi
    kj = bw[bj] if cj else wj
    kn = ki + kj
    tx = rx - vn * nx
    ty = ry - vn * ny
    tz = rz - vn * nz
    tl = np.sqrt(tx * tx + ty * ty + tz * tz)
    pt = 0.0
    if tl > 0.0:
        pt = min(law.friction * p, tl / kn) / tl
    push = (p * nx - pt * tx, p * ny - pt * ty, p * nz - pt * tz)
    sweep.impulse[0, k] = p
    if ci:
        dv[bi, 0] += ki * push[0]
        dv[bi, 1] += ki * push[1]
        dv[bi, 2] += ki * push[2]
        bodies.pending[bi] = 1
    elif wi > 0.0:
        move_particle(parts, i, wi, h, push, (0.0, 0.0, 0.0))
    if cj:
        dv[bj, 0] -= kj * push[0]
        dv[bj, 1] -= kj * push[1]
        dv[bj, 2] -= kj * push[2]
        bodies.pending[bj] = 1
    elif wj > 0.0:
        move_particle(parts, j, -wj, h, push, (0.0, 0.0, 0.0))
