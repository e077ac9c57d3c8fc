"""Compiled pieces of the contact pass that its two solves share
(``contact_kernels.solve_pairs``, ``contact_bodies.solve_bodies``): the pair normal, the
impulses on a particle and on a body carried as a whole, the compact rows of carried
pairs, the warm start of the carried bodies' pass and the collider pass over the
particles contact moved.  In the kernel package so that both modules' caches are stamped
with them (``jit.py``).
"""

import numpy as np
from numba import njit

from .colliders import Colliders, collide_point
from .jit import JIT


@njit(inline='always', **JIT)
def body_colliders(col, b):
    """The colliders of the contact pass (``col.radius``: one radius per body) as the
    particles of body ``b`` meet them: grown by its radius."""
    return Colliders(col.on, col.ground, col.boxes, col.spheres, col.thresh, col.radius[b])


@njit(inline='always', **JIT)
def _collide_moved(X, V, W, B, pi, pj, npairs, moved, col):
    """The static colliders of ``col`` (radius per body), once per particle the solve
    moved (``moved``, cleared), in pair order (deterministic); kinematic particles (W = 0)
    stay where they were put."""
    for k in range(npairs):
        for p in (pi[k], pj[k]):
            if moved[p]:
                moved[p] = 0
                if col.on and W[p] > 0.0:
                    X[0, p], X[1, p], X[2, p], V[0, p], V[1, p], V[2, p] = collide_point(
                        X[0, p], X[1, p], X[2, p], V[0, p], V[1, p], V[2, p],
                        body_colliders(col, B[p]))


@njit(inline='always', **JIT)
def _carried_velocity(vb, dv, b):
    """A carried body's own velocity: its velocity at the pass's start plus what the pass
    gave it so far (the law acts on it, not on the particle's)."""
    return vb[b, 0] + dv[b, 0], vb[b, 1] + dv[b, 1], vb[b, 2] + dv[b, 2]


@njit(inline='always', **JIT)
def _pair_normal(sx, sy, sz, dx, dy, dz, d2, rr):
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
def _own(X, V, i, c, h, px, py, pz, q0, q1, q2):
    """Particle i's own change, inverse mass c: velocity impulse p (it also moves by h
    times the velocity change), position impulse q (moves it only)."""
    X[0, i] += c * (h * px + q0)
    X[1, i] += c * (h * py + q1)
    X[2, i] += c * (h * pz + q2)
    V[0, i] += c * px
    V[1, i] += c * py
    V[2, i] += c * pz


@njit(inline='always', **JIT)
def _pair_impulse(acc, k, gn, qn, kn, rx, ry, rz, nx, ny, nz, vn0, mu, ih):
    """Pair k's impulses in ``solve_bodies``: its normal velocity change ``gn`` and
    position change ``qn`` over the inverse masses ``kn``, accumulated in ``acc[:, k]``
    (never negative: a later sweep may take back what an earlier one gave too much), and
    Coulomb friction on the relative velocity r (normal n, normal speed ``vn0``): at most
    ``mu`` times the normal change (the position impulse's too, over h: ``ih`` = 1 / h)
    and at most what stops the sliding.  Returns the velocity impulse p, the position
    impulse q (3 each) and the largest velocity change it makes (for the stop test)."""
    pn = gn / kn               # normal impulse (mass x velocity)
    qq = qn / kn               # position impulse (mass x length)
    a_new = max(acc[0, k] + pn, 0.0)
    pn = a_new - acc[0, k]
    acc[0, k] = a_new
    a_new = max(acc[1, k] + qq, 0.0)
    qq = a_new - acc[1, k]
    acc[1, k] = a_new
    tx = rx - vn0 * nx
    ty = ry - vn0 * ny
    tz = rz - vn0 * nz
    tl = np.sqrt(tx * tx + ty * ty + tz * tz)
    pt = 0.0
    if tl > 0.0:
        pt = min(mu * max(pn + qq * ih, 0.0), tl / kn) / tl
    ch = kn * max(abs(pn) + pt * tl, abs(qq) * ih)
    return (pn * nx - pt * tx, pn * ny - pt * ty, pn * nz - pt * tz, qq * nx, qq * ny,
            qq * nz, ch)


@njit(inline='always', **JIT)
def _body_move(dv, pend, b, c, px, py, pz, q0, q1, q2):
    """A carried body b takes the impulses p (velocity) and q (position) times ``c``
    (its inverse mass, negative on the pair's second side) as a translation, kept in
    ``dv[b]``; it is held by another body (no spin, ``dv[b, 6]``) and pending."""
    dv[b, 0] += c * px
    dv[b, 1] += c * py
    dv[b, 2] += c * pz
    dv[b, 3] += c * q0
    dv[b, 4] += c * q1
    dv[b, 5] += c * q2
    dv[b, 6] = 1.0
    pend[b] = 1


@njit(inline='always', **JIT)
def _compact_row(X, V, R, i, j, bi, bj, bw, vb, h, a, cij, cf):
    """Row a of ``solve_bodies``'s compact rows, for the pair (i, j) of the carried bodies
    bi, bj: ``cij[:, a]`` = (i, j, bi, bj, 1: the row is set; ``solve_bodies`` makes it 3
    while the pair holds impulses, 0 when the row takes the general path) and ``cf[:, a]`` =
    x_i - x_j (3), the start-of-step separation x_i - x_j - h (v_i - v_j) (3), r_i + r_j:
    what a visit of the later sweeps reads per pair, gathered in sweep order by the first
    sweep or, for the pairs it listed before it changed anything, before the second sweep
    (its particles' own x, v: their bodies' moves are added from dv at each visit).  What is
    the same for every pair of two bodies (their velocities ``vb``, inverse masses ``bw``)
    is read from the bodies' rows, which stay in cache (a row of 12 values cost
    ``paper_384``'s later sweeps about 15 % more: they stream the rows from memory)."""
    cij[0, a] = i
    cij[1, a] = j
    cij[2, a] = bi
    cij[3, a] = bj
    cij[4, a] = 1
    for c in range(3):
        d = X[c, i] - X[c, j]
        cf[c, a] = d
        cf[3 + c, a] = d - h * (V[c, i] - V[c, j])
    cf[6, a] = R[i] + R[j]


@njit(inline='always', **JIT)
def _carried(X, V, dv, pend, b, c, i, h):
    """Particle i's position and velocity with its body's moves so far (``c``: body b is
    carried as a whole) and the velocity the contact law sees (the body's when carried)."""
    x0, x1, x2 = X[0, i], X[1, i], X[2, i]
    v0, v1, v2 = V[0, i], V[1, i], V[2, i]
    if c and pend[b]:
        v0 += dv[b, 0]
        v1 += dv[b, 1]
        v2 += dv[b, 2]
        x0 += h * dv[b, 0] + dv[b, 3]
        x1 += h * dv[b, 1] + dv[b, 4]
        x2 += h * dv[b, 2] + dv[b, 5]
    return x0, x1, x2, v0, v1, v2


@njit(**JIT)
def _warm_start(X, V, W, B, R, pi, pj, npairs, mu, h, ground, off, bw, cpl, dv, pend, acc,
                vb, accg, warm, hasg):
    """Warm start of ``solve_bodies``: the velocity impulses its pairs of carried bodies and
    their ground contacts ended the last step with (``acc[0]``, ``accg[0]``) are applied
    again first, along the pairs' normals now, with Coulomb friction up to ``mu`` times
    them, when the pair list is the one of the last step (``warm``); the sweeps then only
    correct them (and may take them back).  A resting heap so carries its load from the
    first sweep: without it, the sweeps of one step (``STACK_SWEEPS``) do not carry the
    load of a heap ten bodies high to the ground, and its bodies keep a downward velocity
    that the position impulses then cancel every step (about 2 g h at the top of
    ``paper_384``).  Every other accumulated impulse is cleared."""
    for k in range(npairs):
        p = warm * acc[0, k]
        acc[0, k] = 0.0
        acc[1, k] = 0.0
        if not p > 0.0:
            continue
        i = pi[k]
        j = pj[k]
        wi = W[i]
        wj = W[j]
        bi = B[i]
        bj = B[j]
        ci = bi != bj and cpl[bi] and bw[bi] > 0.0 and wi > 0.0
        cj = bi != bj and cpl[bj] and bw[bj] > 0.0 and wj > 0.0
        if not (ci or cj) or wi + wj <= 0.0:
            continue
        xi0, xi1, xi2, vi0, vi1, vi2 = _carried(X, V, dv, pend, bi, ci, i, h)
        xj0, xj1, xj2, vj0, vj1, vj2 = _carried(X, V, dv, pend, bj, cj, j, h)
        dx = xi0 - xj0
        dy = xi1 - xj1
        dz = xi2 - xj2
        d2 = dx * dx + dy * dy + dz * dz
        if not d2 == d2:
            continue
        nx, ny, nz = _pair_normal(dx - h * (vi0 - vj0), dy - h * (vi1 - vj1),
                                  dz - h * (vi2 - vj2), dx, dy, dz, d2, R[i] + R[j])
        if ci:
            vi0, vi1, vi2 = _carried_velocity(vb, dv, bi)
        if cj:
            vj0, vj1, vj2 = _carried_velocity(vb, dv, bj)
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
            pt = min(mu * p, tl / kn) / tl
        px = p * nx - pt * tx
        py = p * ny - pt * ty
        pz = p * nz - pt * tz
        acc[0, k] = p
        if ci:
            dv[bi, 0] += ki * px
            dv[bi, 1] += ki * py
            dv[bi, 2] += ki * pz
            pend[bi] = 1
        elif wi > 0.0:
            _own(X, V, i, wi, h, px, py, pz, 0.0, 0.0, 0.0)
        if cj:
            dv[bj, 0] -= kj * px
            dv[bj, 1] -= kj * py
            dv[bj, 2] -= kj * pz
            pend[bj] = 1
        elif wj > 0.0:
            _own(X, V, j, -wj, h, px, py, pz, 0.0, 0.0, 0.0)
    for b in range(pend.shape[0]):
        p = warm * accg[0, b]
        accg[0, b] = 0.0
        accg[1, b] = 0.0
        if not (hasg and p > 0.0 and cpl[b] and bw[b] > 0.0):
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
        pend[b] = 1
