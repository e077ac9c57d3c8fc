"""The compiled pass of the bodies that carry their contacts as a whole
(``contact.py``, doc/contact.md): ``solve_bodies``.  Its pieces shared with the
per-particle solve are in ``kernels/pair_contact.py``; its arguments are the named tuples
of ``contact_state.py``.
"""

import numpy as np
from numba import njit

from .kernels.colliders import Colliders, collide_point, ground_height
from .kernels.jit import JIT_NO_REFCOUNT
from .kernels.pair_contact import (body_colliders, carried_velocity, collide_moved,
                                   compact_row, is_carried, move_body, move_particle,
                                   pair_impulse, pair_normal, report_touch, separation,
                                   warm_start, with_body_moves)

#: A pair of a carried body closer than 1.25 times its contact distance at its first
#: visit is visited again by the later sweeps (``PairSweep.active``); the square of it.
_NEAR_SQUARED = 1.5625
#: The marks of the listed pairs (``PairSweep.row_index[4]``): the general path, a
#: compact row, a compact row whose pair holds impulses.
_GENERAL, _ROW, _ROW_HOLDING = 0, 1, 3
#: A pair's law in ``PairSweep.target`` is the carried one (position impulse for the
#: overlap, velocity law on the bodies) when it holds its target plus this.
_SPLIT = 2.0
#: The ground row of colliders without a ground (the walls of ``_wall_sweep``).
_NO_GROUND = np.zeros(4)


@njit(**JIT_NO_REFCOUNT)
def solve_bodies(parts, pairs, sweep, bodies, law, col, walls, report):
    """Body-body contact under gravity, the stiff bodies carrying their contacts as a
    whole (doc/contact.md; ``Contact.run`` calls ``solve_pairs`` without gravity or
    without such bodies).

    A carried body (``is_carried``) takes every impulse on one of its particles as a
    translation of the whole body: its inverse mass is the body's, its changes so far are
    kept in ``bodies.change``, seen by the later pairs and applied to every particle at
    the end, so the load on it reaches all its particles within the step.  The law acts
    on such a body's own velocity; a pair with one is pushed apart by a position impulse
    (overlap does not turn into bounce) and its normal velocity goes to the law's target,
    fixed at the pair's first visit (``sweep.target``), with accumulated impulses over at
    most ``law.sweeps`` symmetric Gauss-Seidel sweeps (a one-way sweep drifts a stack
    towards its end), stopping once a sweep changes no velocity by more than ``law.tol``
    (or the first one changes nothing at all).  Other pairs get the law of
    ``solve_pairs`` in the first sweep.  Friction: Coulomb, at most ``law.friction`` times
    the normal change.  Impulses are equal and opposite: linear momentum is kept to
    round-off.  A carried body rests on the ground as a whole (``_floor_sweep``; a
    stiff body lying on another on that one too) and is
    pushed out of boxes and spheres as a whole (``_wall_sweep``); each step starts from
    the last step's impulses (``warm_start``).  ``change``, ``pending`` and
    ``parts.moved`` are zero on entry and on return.  Returns the overlapping pairs of
    the first sweep (``report`` as in ``solve_pairs``).
    """
    found = 0
    listed = 0                 # pairs in sweep.active
    lazy = 0                   # how many of them wait for their compact rows
    self_rows = False          # a pair of one carried body (self-collision) was met
    warm_start(parts, pairs, sweep, bodies, law, col)
    for it in range(law.sweeps):
        first = it == 0
        if it == 1:
            _prepare_rows(parts, pairs, sweep, bodies, law.h, lazy, listed)
        todo = pairs.count if first else listed
        big = 0.0
        for step in range(todo):
            a = step if it % 2 == 0 else todo - 1 - step     # forward, then backward
            if not first and sweep.row_index[4, a] != _GENERAL and not (
                    self_rows and _row_moved(parts, sweep, a)):
                ch = _visit_row(sweep, bodies, law, a)
            else:
                k = a if first else sweep.active[a]
                ch, near, touching, self_row = _visit_pair(parts, pairs, sweep, bodies, law,
                                                           report, k, first)
                self_rows = self_rows or self_row
                found += touching
                if near:
                    # listed for the later sweeps; a pair of two carried bodies gets its
                    # compact row once the sweep has changed something (a first sweep
                    # that changes nothing ends the pass: a resting bin pays nothing)
                    sweep.active[listed] = k
                    if big > 0.0:
                        sweep.row_index[4, listed] = _GENERAL
                        if near == 2:
                            compact_row(parts, sweep, law.h, pairs.first[k],
                                        pairs.second[k], listed)
                    else:
                        lazy = listed + 1
                    listed += 1
            if ch > big:
                big = ch
        ch = _floor_sweep(bodies, law, col.ground if col.on else _NO_GROUND)
        if ch > big:
            big = ch
        if col.on and walls.particles.shape[0] > 0:
            ch = _wall_sweep(parts, bodies, law, col, walls)
            if ch > big:
                big = ch
        if big <= law.tol and (not first or big == 0.0):
            break
    _apply_moves(parts, bodies, law.h, col, walls)
    collide_moved(parts, pairs, col)
    return found


@njit(inline='always', **JIT_NO_REFCOUNT)
def _row_moved(parts, sweep, a):
    """Whether a pair of one carried body moved a particle of compact row a."""
    return parts.moved[sweep.row_index[0, a]] or parts.moved[sweep.row_index[1, a]]


@njit(**JIT_NO_REFCOUNT)
def _prepare_rows(parts, pairs, sweep, bodies, h, lazy, listed):
    """Before the second sweep: the compact rows the first sweep left out (those of the
    pairs it listed before it changed anything), then each listed pair's mark: the
    general path for a pair whose law is not the carried one, else whether it holds
    impulses (a visit of a row apart and holding nothing then reads its row only)."""
    W, B, marks = parts.inv_mass, parts.body, sweep.row_index[4]
    for a in range(lazy):
        k = sweep.active[a]
        i = pairs.first[k]
        j = pairs.second[k]
        marks[a] = _GENERAL
        if (B[i] != B[j] and is_carried(bodies, B[i]) and W[i] > 0.0
                and is_carried(bodies, B[j]) and W[j] > 0.0):
            compact_row(parts, sweep, h, i, j, a)
    for a in range(listed):
        if marks[a] != _GENERAL:
            k = sweep.active[a]
            if not sweep.target[k] >= 1.0:
                marks[a] = _GENERAL
            elif sweep.impulse[0, k] > 0.0 or sweep.impulse[1, k] > 0.0:
                marks[a] = _ROW_HOLDING


@njit(inline='always', **JIT_NO_REFCOUNT)
def _visit_row(sweep, bodies, law, a):
    """A later sweep's visit of compact row a (a pair of two carried bodies): the law of
    ``_visit_pair`` on the row and its bodies' moves so far.  Returns the largest
    velocity change it made."""
    cf, dv, vb, bw = sweep.rows, bodies.change, bodies.velocity, bodies.inv_mass
    h = law.h
    bi = sweep.row_index[2, a]
    bj = sweep.row_index[3, a]
    u0 = dv[bi, 0] - dv[bj, 0]
    u1 = dv[bi, 1] - dv[bj, 1]
    u2 = dv[bi, 2] - dv[bj, 2]
    e0 = dv[bi, 3] - dv[bj, 3]
    e1 = dv[bi, 4] - dv[bj, 4]
    e2 = dv[bi, 5] - dv[bj, 5]
    dx = cf[0, a] + h * u0 + e0
    dy = cf[1, a] + h * u1 + e1
    dz = cf[2, a] + h * u2 + e2
    d2 = dx * dx + dy * dy + dz * dz
    if not d2 == d2:
        return 0.0             # NaN (a body that blew up): left alone
    rr = cf[6, a]
    if not (d2 < rr * rr or sweep.row_index[4, a] == _ROW_HOLDING):
        return 0.0             # apart and holding nothing
    k = sweep.active[a]
    rx = (vb[bi, 0] - vb[bj, 0]) + u0
    ry = (vb[bi, 1] - vb[bj, 1]) + u1
    rz = (vb[bi, 2] - vb[bj, 2]) + u2
    nx, ny, nz = pair_normal(cf[3, a] + e0, cf[4, a] + e1, cf[5, a] + e2, dx, dy, dz, d2,
                             rr)
    dn = dx * nx + dy * ny + dz * nz
    arg = dn * dn - d2 + rr * rr
    lam = -dn + np.sqrt(arg) if arg >= 0.0 else rr - np.sqrt(d2)
    vn0 = rx * nx + ry * ny + rz * nz
    ki = bw[bi]
    kj = bw[bj]
    push, shift, ch = pair_impulse(sweep.impulse, k, sweep.target[k] - _SPLIT - vn0, lam,
                                   ki + kj, (rx, ry, rz), (nx, ny, nz), vn0, law.friction,
                                   1.0 / h)
    holds = sweep.impulse[0, k] > 0.0 or sweep.impulse[1, k] > 0.0
    sweep.row_index[4, a] = _ROW_HOLDING if holds else _ROW
    move_body(bodies, bi, ki, push, shift)
    move_body(bodies, bj, -kj, push, shift)
    return ch


@njit(inline='always', **JIT_NO_REFCOUNT)
def _visit_pair(parts, pairs, sweep, bodies, law, report, k, first):
    """A visit of pair k by the general path.  Returns the largest velocity change it
    made; whether the first sweep lists it for the later ones (1, or 2: a pair of two
    carried bodies, with a compact row); whether it touched in the first sweep (1, and
    ``report`` counts it); whether it is a pair of one carried body."""
    h = law.h
    W, B, R = parts.inv_mass, parts.body, parts.radius
    i = pairs.first[k]
    j = pairs.second[k]
    wi = W[i]
    wj = W[j]
    if wi + wj <= 0.0:
        return 0.0, 0, 0, False
    bi = B[i]
    bj = B[j]
    ci = bi != bj and is_carried(bodies, bi) and wi > 0.0
    cj = bi != bj and is_carried(bodies, bj) and wj > 0.0
    self_row = bi == bj and is_carried(bodies, bi)
    own_i = with_body_moves(parts, bodies, bi, ci, i, h)
    own_j = with_body_moves(parts, bodies, bj, cj, j, h)
    # separation now and at the start of the step (the particles' own velocities)
    dx, dy, dz, d2, sx, sy, sz = separation(own_i, own_j, h)
    rr = R[i] + R[j]
    # the law acts on a carried body's own velocity
    vi0, vi1, vi2 = carried_velocity(bodies, bi) if ci else own_i[3:]
    vj0, vj1, vj2 = carried_velocity(bodies, bj) if cj else own_j[3:]
    if not d2 == d2:
        return 0.0, 0, 0, self_row        # NaN (a body that blew up): left alone
    over = d2 < rr * rr
    near = 0
    if first and (ci or cj) and (over or d2 < _NEAR_SQUARED * rr * rr):
        near = 2 if ci and cj else 1
    if not over and not (sweep.impulse[0, k] > 0.0 or sweep.impulse[1, k] > 0.0):
        if first and (ci or cj):
            # apart at its first visit: the carried law with target 0, should a later
            # sweep push it together (its overlap then never becomes a velocity)
            sweep.target[k] = _SPLIT
        return 0.0, near, 0, self_row
    rx = vi0 - vj0
    ry = vi1 - vj1
    rz = vi2 - vj2
    nx, ny, nz = pair_normal(sx, sy, sz, dx, dy, dz, d2, rr)
    dn = dx * nx + dy * ny + dz * nz
    arg = dn * dn - d2 + rr * rr
    lam = -dn + np.sqrt(arg) if arg >= 0.0 else rr - np.sqrt(d2)
    vn0 = rx * nx + ry * ny + rz * nz
    gn, qn, acts = _pair_law(sweep, law, k, first, ci or cj, over, vn0, lam)
    if not acts:
        return 0.0, near, 0, self_row
    ki = bodies.inv_mass[bi] if ci else wi
    kj = bodies.inv_mass[bj] if cj else wj
    push, shift, ch = pair_impulse(sweep.impulse, k, gn, qn, ki + kj, (rx, ry, rz),
                                   (nx, ny, nz), vn0, law.friction, 1.0 / h)
    _take(parts, bodies, i, ci, ki, h, push, shift)
    _take(parts, bodies, j, cj, -kj, h, push, shift)
    if first and over:
        report_touch(report, bi, bj, rr - np.sqrt(d2))
        return ch, near, 1, self_row
    return ch, near, 0, self_row


@njit(inline='always', **JIT_NO_REFCOUNT)
def _pair_law(sweep, law, k, first, carried, over, vn0, lam):
    """Pair k's normal velocity change and position change, and whether it acts: its law
    fixed at its first visit (``sweep.target``: restitution times the approach above
    ``law.thresh``, else 0; plus ``_SPLIT`` with a carried side: then the overlap ``lam``
    goes by a position impulse and the velocity to the target, and may be taken back),
    else the overlap pushed apart at ``lam`` / h and the approach removed."""
    tg = sweep.target
    if first:
        tg[k] = -law.restitution * vn0 if -vn0 > law.thresh else 0.0
        if carried:
            tg[k] += _SPLIT
    if tg[k] >= 1.0:
        return tg[k] - _SPLIT - vn0, lam, True
    if not over:
        return 0.0, 0.0, False
    ih = 1.0 / law.h
    vn = vn0 + lam * ih
    return lam * ih + (tg[k] - vn if vn < tg[k] else 0.0), 0.0, True


@njit(inline='always', **JIT_NO_REFCOUNT)
def _take(parts, bodies, i, carried, inv_mass, h, push, shift):
    """Particle i's side of a pair's impulses, ``inv_mass`` signed by the side: its body
    as a whole when ``carried``, else the particle itself unless it is pinned."""
    if carried:
        move_body(bodies, parts.body[i], inv_mass, push, shift)
    elif inv_mass != 0.0:
        move_particle(parts, i, inv_mass, h, push, shift)
        parts.moved[i] = 1


@njit(**JIT_NO_REFCOUNT)
def _floor_sweep(bodies, law, ground):
    """The floors in a sweep (the ground, or the higher ``bodies.floor``: the body a
    stiff one lies on): a carried body rests on its floor as a whole (its lowest particle,
    ``bodies.lowest``), with accumulated impulses like a pair's and the floor's friction,
    so the load of the bodies above goes into the floor instead of squashing the body
    against it.  Returns the largest velocity change it made."""
    h = law.h
    ih = 1.0 / h
    big = 0.0
    zlo, dv, bw, accg = bodies.lowest, bodies.change, bodies.inv_mass, bodies.ground_impulse
    vb = bodies.velocity
    ground_h, ground_mu = (ground[1], ground[2]) if ground[0] > 0.5 else (-np.inf, 0.0)
    for b in range(bodies.pending.shape[0]):
        gh, mu = ground_h, ground_mu
        if bodies.floor[0, b] > gh:
            gh, mu = bodies.floor[0, b], bodies.floor[1, b]
        if not is_carried(bodies, b) or gh == -np.inf:
            continue
        z = zlo[0, b] + h * dv[b, 2] + dv[b, 5]
        if not (z <= gh + 1e-9 or accg[0, b] > 0.0 or accg[1, b] > 0.0):
            continue
        # pressed down by other bodies: the law acts on the body's own velocity; else on
        # the lowest particle's, which the bodies' step has already stopped at the ground
        # (acting on the body's velocity there would lift resting blocks every step)
        m = 1.0 / bw[b]
        down = dv[b, 2] - bw[b] * accg[0, b] < -0.25 * law.thresh   # > g h / 2
        vz = (vb[b, 2] if down else zlo[1, b]) + dv[b, 2]
        a_new = max(accg[1, b] + m * (gh - z), 0.0)
        qq = a_new - accg[1, b]
        accg[1, b] = a_new
        a_new = max(accg[0, b] - m * vz, 0.0)
        pn = a_new - accg[0, b]
        accg[0, b] = a_new
        tx = vb[b, 0] + dv[b, 0]
        ty = vb[b, 1] + dv[b, 1]
        tl = np.sqrt(tx * tx + ty * ty)
        pt = 0.0
        if tl > 0.0:
            pt = min(mu * max(pn + qq * ih, 0.0), tl * m) / tl
        if pn == 0.0 and qq == 0.0 and pt == 0.0:
            continue           # resting on it, nothing to change: not pending
        dv[b, 0] -= bw[b] * pt * tx
        dv[b, 1] -= bw[b] * pt * ty
        dv[b, 2] += bw[b] * pn
        dv[b, 5] += bw[b] * qq
        bodies.pending[b] = 1
        ch = bw[b] * max(abs(pn) + pt * tl, abs(qq) * ih)
        if ch > big:
            big = ch
    return big


@njit(**JIT_NO_REFCOUNT)
def _wall_sweep(parts, bodies, law, col, walls):
    """Boxes and spheres in a sweep: a carried body is pushed out of them as a whole
    (its particles near them, ``walls``), so a jam is not dented into them.  Returns the
    largest velocity change it made."""
    X, dv = parts.x, bodies.change
    h = law.h
    ih = 1.0 / h
    big = 0.0
    for b in range(bodies.pending.shape[0]):
        if not bodies.pending[b]:
            continue
        own = Colliders(True, _NO_GROUND, col.boxes, col.spheres, law.thresh, col.radius[b], 0.0)
        for t in range(walls.start[b], walls.start[b + 1]):
            p = walls.particles[t]
            x0 = X[0, p] + h * dv[b, 0] + dv[b, 3]
            x1 = X[1, p] + h * dv[b, 1] + dv[b, 4]
            x2 = X[2, p] + h * dv[b, 2] + dv[b, 5]
            y0, y1, y2, _, _, _ = collide_point(x0, x1, x2, 0.0, 0.0, 0.0, own)
            if y0 != x0 or y1 != x1 or y2 != x2:
                dv[b, 3] += y0 - x0
                dv[b, 4] += y1 - x1
                dv[b, 5] += y2 - x2
                ch = np.sqrt((y0 - x0) ** 2 + (y1 - x1) ** 2 + (y2 - x2) ** 2) * ih
                if ch > big:
                    big = ch
    return big


@njit(**JIT_NO_REFCOUNT)
def _apply_moves(parts, bodies, h, col, walls):
    """The carried bodies' moves onto their particles (a body held by another also
    loses its spin about its centre: contacts translate carried bodies and never turn
    them, so nothing else would stop a spin picked up from the ground's friction), then
    the static colliders, only where a particle can be inside one: below the ground,
    moved by a pair, of a body near a box or sphere (``walls``), or moved by
    ``walls.margin`` or more."""
    dv = bodies.change
    for b in range(bodies.pending.shape[0]):
        if not bodies.pending[b]:
            continue
        bodies.pending[b] = 0
        bodies.ground_impulse[1, b] = 0.0
        move = (dv[b, 0], dv[b, 1], dv[b, 2], dv[b, 3], dv[b, 4], dv[b, 5])
        spin = (0.0, 0.0, 0.0)
        if dv[b, 6] > 0.0:             # held by another body: its spin is stopped
            spin = (-bodies.spin[b, 0], -bodies.spin[b, 1], -bodies.spin[b, 2])
        dv[b, :] = 0.0
        if (move[0] == 0.0 and move[1] == 0.0 and move[2] == 0.0 and move[3] == 0.0
                and move[4] == 0.0 and move[5] == 0.0 and spin[0] == 0.0 and spin[1] == 0.0
                and spin[2] == 0.0):
            continue                   # nothing moved it (a warm start taken back, say)
        near = walls.start[b + 1] > walls.start[b] if walls.particles.shape[0] > 0 else False
        _move_body_particles(parts, bodies, b, h, move, spin, near, col, walls.margin)


@njit(inline='always', **JIT_NO_REFCOUNT)
def _move_body_particles(parts, bodies, b, h, move, spin, near, col, margin):
    """Body b's particles take its ``move`` (velocity change, position change) and the
    ``spin`` change about its centre; then the static colliders, where one can be inside
    (``near`` a box or sphere: every particle)."""
    X, V, moved = parts.x, parts.v, parts.moved
    u0, u1, u2, e0, e1, e2 = move
    w0, w1, w2 = spin
    c0, c1, c2 = bodies.centre[b, 0], bodies.centre[b, 1], bodies.centre[b, 2]
    own = body_colliders(col, b)
    gh = ground_height(own)
    m2 = margin * margin
    for p in range(bodies.offsets[b], bodies.offsets[b + 1]):
        r0 = X[0, p] - c0
        r1 = X[1, p] - c1
        r2 = X[2, p] - c2
        g0 = u0 + w1 * r2 - w2 * r1
        g1 = u1 + w2 * r0 - w0 * r2
        g2 = u2 + w0 * r1 - w1 * r0
        d0 = h * g0 + e0
        d1 = h * g1 + e1
        d2 = h * g2 + e2
        X[0, p] += d0
        X[1, p] += d1
        X[2, p] += d2
        V[0, p] += g0
        V[1, p] += g1
        V[2, p] += g2
        mp = moved[p]
        moved[p] = 0
        if col.on and (near or mp or X[2, p] < gh or not d0 * d0 + d1 * d1 + d2 * d2 < m2):
            X[0, p], X[1, p], X[2, p], V[0, p], V[1, p], V[2, p] = collide_point(
                X[0, p], X[1, p], X[2, p], V[0, p], V[1, p], V[2, p], own)
