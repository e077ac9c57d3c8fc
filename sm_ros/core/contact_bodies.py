"""The compiled pass of the bodies that carry their contacts as a whole
(``contact.py``, doc/contact.md): ``solve_bodies``; its pieces shared with the
per-particle solve are in ``kernels/pair_contact.py``.
"""

import numpy as np
from numba import njit

from .kernels.colliders import Colliders, collide_point, ground_height
from .kernels.jit import JIT
from .kernels.pair_contact import (_body_move, _carried_velocity, _collide_moved,
                                   _compact_row, _own, _pair_impulse, _pair_normal,
                                   _warm_start, body_colliders)


@njit(**JIT)
def solve_bodies(X, V, W, R, B, pi, pj, npairs, mu, e, thresh, h, iters, touched, count,
                 deepest, col, moved, off, bw, cpl, dv, pend,
                 active, acc, tg, tol, vb, noground, cand, cptr, zlo, accg, warm, bc, bom,
                 biv, margin=0.0, cbuf=None, ibuf=None):
    """Body-body contact under gravity, the stiff bodies carrying their contacts as a
    whole (doc/contact.md; ``Contact.run`` calls ``solve_pairs``
    without gravity or without such bodies).

    A body with ``cpl[b]`` and an inverse mass ``bw[b]`` (stiff, one cluster or many, no
    pinned or grabbed particle: ``Contact``) takes every impulse on one of its particles as a
    translation of the whole body: a pair's inverse mass on its side is ``bw[b]``, the
    body's changes so far are kept in ``dv[b]`` (velocity, then position; ``pend[b]``
    set), seen by the later pairs and applied to every particle at the end.  The load on
    it so reaches all its particles within the step instead of compressing its touching
    layer (through the shape match it reaches them a step later, the layer giving way by a
    load-dependent depth every step).  The contact law acts on such a body's own velocity
    (``vb[b]``, momentum / mass, plus its changes): the deviation of a particle from it is
    the shape match's.  A pair with such a body is pushed apart by a position impulse (no
    speed: overlap does not turn into bounce) and its normal velocity goes to the law's
    target (0, or restitution times the approach above ``thresh``, fixed at the first
    visit in ``tg``, + 2 for these pairs; 0 for a pair apart at its first visit), with
    accumulated impulses (``acc`` (2, P): velocity and position impulse of the pair so
    far, never negative, so a later sweep may take back what an earlier one gave too
    much) over at most ``iters`` symmetric
    Gauss-Seidel sweeps (forward, backward, ...: a one-way sweep drifts a stack towards
    its end), stopping once a sweep changes no velocity by more than ``tol`` (or the
    first one changes nothing at all); after the first sweep only these pairs closer
    than 1.25 (r_i + r_j) (``active``) are visited.
    Other pairs (two per-particle bodies, or one body) get the law of ``solve_pairs`` in
    the first sweep.  Friction: Coulomb, at most ``mu`` times the normal change (the
    position impulse's too, over h) and at most what stops the sliding.  Impulses are
    equal and opposite: linear momentum is kept to round-off.  Particles moved are put
    out of the static colliders at the end, as in ``solve_pairs``.  ``dv``, ``pend``,
    ``moved`` are zero on entry and on return.  Returns the overlapping pairs of the first
    sweep (``count``, ``deepest`` as in ``solve_pairs``).

    A carried body rests on the ground inside the sweeps, as a whole (its lowest particle,
    ``zlo``; accumulated impulses ``accg`` (2, bodies) like a pair's, the ground's
    friction): the load of the bodies above goes into the ground instead of squashing the
    body against it.  Each step starts from ``warm`` (0: none) times the velocity impulses
    of the last step (``_warm_start``; ``acc[0]``, ``accg[0]`` kept between calls while
    the pair list is the same).  A carried body that another body held in this pass
    (``dv[b, 6]`` set) loses its spin: ``bom[b]``, about its centre of mass ``bc[b]``
    (``body_velocities``), is removed from its particles at the end (contacts translate
    carried bodies and never turn them, so nothing else would stop a spin picked up from
    the ground's friction).  ``biv`` is the bodies' inverse inertia (unused here).

    At the end a carried body's particles are put out of the static colliders only where
    one can be inside: below the ground's plane, moved by a pair (``moved``), of a body
    with particles near a box or sphere (``cand``, found ``margin`` from them at the start
    of the pass), or moved by ``margin`` or more (every particle with ``margin`` 0, the
    default); elsewhere ``collide_point`` would return the particle unchanged.
    """
    found = 0
    ih = 1.0 / h
    nact = 0
    nlazy = 0
    selfp = False                      # a row of one carried body (self-collision)
    # the compact rows of the later sweeps: the caller's buffers (``cbuf`` (7, P) float64,
    # ``ibuf`` (5, P) int32; ``Contact``: sized to the pair list's capacity, so nothing is
    # allocated a step and no page faults are paid) or, without them, allocated here
    if cbuf is None:
        cf = np.empty((7, npairs))
    else:
        cf = cbuf
    if ibuf is None:
        cij = np.empty((5, npairs), dtype=np.int32)
    else:
        cij = ibuf
    if cf.shape[0] < 7 or cf.shape[1] < npairs or cij.shape[1] < npairs:
        cf = np.empty((7, npairs))
        cij = np.empty((5, npairs), dtype=np.int32)
    cm = cij[4]
    has_col, ground = col.on, col.ground
    _warm_start(X, V, W, B, R, pi, pj, npairs, mu, h, ground, off, bw, cpl, dv, pend, acc,
                vb, accg, warm, has_col and ground[0] > 0.5)
    for it in range(iters):
        first = it == 0
        todo = npairs if first else nact
        big = 0.0
        if it == 1:
            # the compact rows the first sweep left out: those of the pairs it listed
            # before it changed anything (below)
            for r in range(nlazy):
                k = active[r]
                i = pi[k]
                j = pj[k]
                bi = B[i]
                bj = B[j]
                cm[r] = 0
                if (bi != bj and cpl[bi] and bw[bi] > 0.0 and W[i] > 0.0 and cpl[bj]
                        and bw[bj] > 0.0 and W[j] > 0.0):
                    _compact_row(X, V, R, i, j, bi, bj, bw, vb, h, r, cij, cf)
            # a row's law is fixed from here on (``tg``): rows whose law is not the
            # carried one (not fixed in the first sweep) take the general path; the
            # others note whether they hold impulses (3), so that a visit of a row apart
            # and holding nothing reads its row only (not acc: about 5 % of the pass)
            for r in range(nact):
                if cm[r]:
                    k = active[r]
                    if not tg[k] >= 1.0:
                        cm[r] = 0
                    elif acc[0, k] > 0.0 or acc[1, k] > 0.0:
                        cm[r] = 3      # compact, holding impulses (kept up by its visits)
        for kk in range(todo):
            # symmetric Gauss-Seidel: forward, then backward
            a = kk if it % 2 == 0 else todo - 1 - kk
            cma = cm[a] if not first else 0
            if cma:
                # a pair of two carried bodies, from its compact row (the same law as
                # below with ci and cj; about a quarter faster a visit in paper_384's
                # heap): unless a same-body pair moved one of its particles (then the
                # general path; its law fixed in the first sweep: ``cm``)
                if not (selfp and (moved[cij[0, a]] or moved[cij[1, a]])):
                    bi = cij[2, a]
                    bj = cij[3, a]
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
                        continue       # NaN (a body that blew up): left alone
                    rr = cf[6, a]
                    if not (d2 < rr * rr or cma == 3):
                        continue       # apart and holding nothing
                    k = active[a]
                    rx = (vb[bi, 0] - vb[bj, 0]) + u0
                    ry = (vb[bi, 1] - vb[bj, 1]) + u1
                    rz = (vb[bi, 2] - vb[bj, 2]) + u2
                    nx, ny, nz = _pair_normal(cf[3, a] + e0, cf[4, a] + e1, cf[5, a] + e2,
                                              dx, dy, dz, d2, rr)
                    dn = dx * nx + dy * ny + dz * nz
                    arg = dn * dn - d2 + rr * rr
                    lam = -dn + np.sqrt(arg) if arg >= 0.0 else rr - np.sqrt(d2)
                    vn0 = rx * nx + ry * ny + rz * nz
                    ki = bw[bi]
                    kj = bw[bj]
                    px, py, pz, q0, q1, q2, ch = _pair_impulse(
                        acc, k, tg[k] - 2.0 - vn0, lam, ki + kj, rx, ry, rz, nx, ny, nz,
                        vn0, mu, ih)
                    if ch > big:
                        big = ch
                    cm[a] = 3 if acc[0, k] > 0.0 or acc[1, k] > 0.0 else 1
                    _body_move(dv, pend, bi, ki, px, py, pz, q0, q1, q2)
                    _body_move(dv, pend, bj, -kj, px, py, pz, q0, q1, q2)
                    continue
            k = a if first else active[a]
            i = pi[k]
            j = pj[k]
            wi = W[i]
            wj = W[j]
            if wi + wj <= 0.0:
                continue
            bi = B[i]
            bj = B[j]
            ci = bi != bj and cpl[bi] and bw[bi] > 0.0 and wi > 0.0
            cj = bi != bj and cpl[bj] and bw[bj] > 0.0 and wj > 0.0
            if bi == bj and cpl[bi] and bw[bi] > 0.0:
                selfp = True           # may move a carried body's particle (``moved``)
            xi0, xi1, xi2 = X[0, i], X[1, i], X[2, i]
            vi0, vi1, vi2 = V[0, i], V[1, i], V[2, i]
            xj0, xj1, xj2 = X[0, j], X[1, j], X[2, j]
            vj0, vj1, vj2 = V[0, j], V[1, j], V[2, j]
            if ci and pend[bi]:        # the body's moves so far in this pass
                vi0 += dv[bi, 0]
                vi1 += dv[bi, 1]
                vi2 += dv[bi, 2]
                xi0 += h * dv[bi, 0] + dv[bi, 3]
                xi1 += h * dv[bi, 1] + dv[bi, 4]
                xi2 += h * dv[bi, 2] + dv[bi, 5]
            if cj and pend[bj]:
                vj0 += dv[bj, 0]
                vj1 += dv[bj, 1]
                vj2 += dv[bj, 2]
                xj0 += h * dv[bj, 0] + dv[bj, 3]
                xj1 += h * dv[bj, 1] + dv[bj, 4]
                xj2 += h * dv[bj, 2] + dv[bj, 5]
            dx = xi0 - xj0
            dy = xi1 - xj1
            dz = xi2 - xj2
            d2 = dx * dx + dy * dy + dz * dz
            rr = R[i] + R[j]
            # separation at the start of the step (the particles' own velocities)
            sx = dx - h * (vi0 - vj0)
            sy = dy - h * (vi1 - vj1)
            sz = dz - h * (vi2 - vj2)
            # the law acts on a carried body's own velocity (its momentum over its mass):
            # the particle's deviation from it is the shape match's to restore
            if ci:
                vi0, vi1, vi2 = _carried_velocity(vb, dv, bi)
            if cj:
                vj0, vj1, vj2 = _carried_velocity(vb, dv, bj)
            if not d2 == d2:
                continue               # NaN (a body that blew up): left alone
            over = d2 < rr * rr
            held = acc[0, k] > 0.0 or acc[1, k] > 0.0
            if first and (ci or cj) and (over or d2 < 1.5625 * rr * rr):
                active[nact] = k       # visited again by the later sweeps
                # a pair of two carried bodies: its compact row for the later sweeps (its
                # particles do not move within the sweeps, its bodies' moves are kept in
                # dv), written here once the sweep has changed something; until then a
                # second sweep may not come (a first sweep that changed nothing ends the
                # pass, which keeps a resting bin cheap), so those are
                # written before the second sweep
                if big > 0.0:
                    cm[nact] = 0
                    if ci and cj:
                        _compact_row(X, V, R, i, j, bi, bj, bw, vb, h, nact, cij, cf)
                else:
                    nlazy = nact + 1
                nact += 1
            if not over and not held:
                if first and (ci or cj):
                    # a pair of a carried body not touching at its first visit: the
                    # carried law with target 0, should a later sweep push it together
                    # (without it the row kept the law of whichever pair had its index
                    # before: with the per-particle one, its overlap became a velocity,
                    # up to 2 g h for a body at rest that a later pair pushed into it)
                    tg[k] = 2.0
                continue
            rx = vi0 - vj0
            ry = vi1 - vj1
            rz = vi2 - vj2
            nx, ny, nz = _pair_normal(sx, sy, sz, dx, dy, dz, d2, rr)
            dn = dx * nx + dy * ny + dz * nz
            arg = dn * dn - d2 + rr * rr
            lam = -dn + np.sqrt(arg) if arg >= 0.0 else rr - np.sqrt(d2)
            vn0 = rx * nx + ry * ny + rz * nz
            if first:                  # the pair's law, fixed at its first visit
                tg[k] = -e * vn0 if -vn0 > thresh else 0.0
                if ci or cj:
                    tg[k] += 2.0       # split: position for the overlap, velocity law
            split = tg[k] >= 1.0
            target = tg[k] - 2.0 if split else tg[k]
            if split:
                gn = target - vn0      # may be negative: takes back, down to zero
                qn = lam
            elif over:
                vn = vn0 + lam * ih
                gn = lam * ih + (target - vn if vn < target else 0.0)
                qn = 0.0
            else:
                continue
            ki = bw[bi] if ci else wi
            kj = bw[bj] if cj else wj
            kn = ki + kj
            px, py, pz, q0, q1, q2, ch = _pair_impulse(acc, k, gn, qn, kn, rx, ry, rz, nx,
                                                       ny, nz, vn0, mu, ih)
            if ch > big:
                big = ch
            if ci:
                _body_move(dv, pend, bi, ki, px, py, pz, q0, q1, q2)
            elif wi > 0.0:
                _own(X, V, i, wi, h, px, py, pz, q0, q1, q2)
                moved[i] = 1
            if cj:
                _body_move(dv, pend, bj, -kj, px, py, pz, q0, q1, q2)
            elif wj > 0.0:
                _own(X, V, j, -wj, h, px, py, pz, q0, q1, q2)
                moved[j] = 1
            if first and over:
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
        if has_col and ground[0] > 0.5:
            # the ground: a body carried as a whole rests on it as a whole (its lowest
            # particle, ``zlo[:, b]``: height, vertical velocity), with accumulated
            # impulses like a pair's
            gh = ground[1]
            for b in range(pend.shape[0]):
                if not (cpl[b] and bw[b] > 0.0):
                    continue
                z = zlo[0, b] + h * dv[b, 2] + dv[b, 5]
                if not (z <= gh + 1e-9 or accg[0, b] > 0.0 or accg[1, b] > 0.0):
                    continue
                # pressed down by other bodies: the law acts on the body's own velocity
                # (their load goes into the ground, not into squashing it); else on the
                # lowest particle's, which the bodies' step has already stopped at the
                # ground, so only what contact adds is taken back, not the body's own
                # sagging under its weight (acting on the body's velocity there lifted
                # resting blocks off the ground every step)
                m = 1.0 / bw[b]
                down = dv[b, 2] - bw[b] * accg[0, b] < -0.25 * thresh   # > g h / 2
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
                    pt = min(ground[2] * max(pn + qq * ih, 0.0), tl * m) / tl
                if pn == 0.0 and qq == 0.0 and pt == 0.0:
                    continue           # resting on it, nothing to change: not pended
                dv[b, 0] -= bw[b] * pt * tx
                dv[b, 1] -= bw[b] * pt * ty
                dv[b, 2] += bw[b] * pn
                dv[b, 5] += bw[b] * qq
                pend[b] = 1
                ch = bw[b] * max(abs(pn) + pt * tl, abs(qq) * ih)
                if ch > big:
                    big = ch
        if has_col and cand.shape[0] > 0:
            # walls: a body carried as a whole is pushed out of boxes and spheres as a
            # whole (its particles near them, ``cand``), so a jam is not dented into them
            for b in range(pend.shape[0]):
                if not pend[b]:
                    continue
                walls = Colliders(True, noground, col.boxes, col.spheres, thresh,
                                  col.radius[b])
                for t in range(cptr[b], cptr[b + 1]):
                    p = cand[t]
                    x0 = X[0, p] + h * dv[b, 0] + dv[b, 3]
                    x1 = X[1, p] + h * dv[b, 1] + dv[b, 4]
                    x2 = X[2, p] + h * dv[b, 2] + dv[b, 5]
                    y0, y1, y2, _, _, _ = collide_point(x0, x1, x2, 0.0, 0.0, 0.0, walls)
                    if y0 != x0 or y1 != x1 or y2 != x2:
                        dv[b, 3] += y0 - x0
                        dv[b, 4] += y1 - x1
                        dv[b, 5] += y2 - x2
                        ch = np.sqrt((y0 - x0) ** 2 + (y1 - x1) ** 2 + (y2 - x2) ** 2) * ih
                        if ch > big:
                            big = ch
        if big <= tol and (not first or big == 0.0):
            # converged; or the first sweep changed nothing at all (no pair, ground or
            # wall acted: a resting world), then a second one would see the same state
            # and change nothing either (the resting bench bin: 1 sweep instead of 2)
            break
    # the bodies' moves: every particle, then the static colliders
    for b in range(pend.shape[0]):
        if not pend[b]:
            continue
        pend[b] = 0
        accg[1, b] = 0.0
        u0, u1, u2 = dv[b, 0], dv[b, 1], dv[b, 2]
        e0 = dv[b, 3]
        e1 = dv[b, 4]
        e2 = dv[b, 5]
        w0 = w1 = w2 = 0.0
        if dv[b, 6] > 0.0:             # held by another body: its spin is stopped
            w0, w1, w2 = -bom[b, 0], -bom[b, 1], -bom[b, 2]
        c0, c1, c2 = bc[b, 0], bc[b, 1], bc[b, 2]
        dv[b, :] = 0.0
        if (u0 == 0.0 and u1 == 0.0 and u2 == 0.0 and e0 == 0.0 and e1 == 0.0 and e2 == 0.0
                and w0 == 0.0 and w1 == 0.0 and w2 == 0.0):
            continue                   # nothing moved it (a warm start taken back, say)
        # every particle of a body near a box or sphere goes through them; the others
        # only below the ground, moved by a pair, or moved by margin or more (a particle
        # not in ``cand`` was at least margin out of every box and sphere)
        near = cptr[b + 1] > cptr[b] if cand.shape[0] > 0 else False
        own = body_colliders(col, b)
        gh = ground_height(own)
        m2 = margin * margin
        for p in range(off[b], off[b + 1]):
            # the translation, and the spin stopped: dw x (x - centre)
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
            if has_col and (near or mp or X[2, p] < gh
                            or not d0 * d0 + d1 * d1 + d2 * d2 < m2):
                X[0, p], X[1, p], X[2, p], V[0, p], V[1, p], V[2, p] = collide_point(
                    X[0, p], X[1, p], X[2, p], V[0, p], V[1, p], V[2, p], own)
    _collide_moved(X, V, W, B, pi, pj, npairs, moved, col)
    return found
