"""Compiled kernels of body-body contact: the pair solve.

The model, the parameters and the Python-side pass (``Contact``) are in ``contact.py``;
the pair list (a Verlet list on a cell grid, sorted by lower index) is built by
``contact_build.py``; this file holds what runs per step on that list.  Serial; nothing
allocates (``solve_bodies`` takes the buffers of its compact rows from ``Contact``).  A
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

from .kernels.colliders import collide_point
from .kernels.jit import JIT, U
from .kernels.spread import moved_box, spread_of


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
            nx, ny, nz = _pair_normal(sx, sy, sz, dx, dy, dz, d2, rr)
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
    _collide_moved(X, V, W, pi, pj, npairs, moved, has_col, ground, boxes, spheres, thresh)
    return found


@njit(inline='always', **JIT)
def _collide_moved(X, V, W, pi, pj, npairs, moved, has_col, ground, boxes, spheres, thresh):
    """The static colliders, once per particle the solve moved (``moved``, cleared), in
    pair order (deterministic); kinematic particles (W = 0) stay where they were put."""
    for k in range(npairs):
        for p in (pi[k], pj[k]):
            if moved[p]:
                moved[p] = 0
                if has_col and W[p] > 0.0:
                    X[0, p], X[1, p], X[2, p], V[0, p], V[1, p], V[2, p] = collide_point(
                        X[0, p], X[1, p], X[2, p], V[0, p], V[1, p], V[2, p], ground, boxes,
                        spheres, thresh)


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


@njit(**JIT)
def solve_bodies(X, V, W, R, B, pi, pj, npairs, mu, e, thresh, h, iters, touched, count,
                 deepest, has_col, ground, boxes, spheres, moved, off, bw, cpl, dv, pend,
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
                for t in range(cptr[b], cptr[b + 1]):
                    p = cand[t]
                    x0 = X[0, p] + h * dv[b, 0] + dv[b, 3]
                    x1 = X[1, p] + h * dv[b, 1] + dv[b, 4]
                    x2 = X[2, p] + h * dv[b, 2] + dv[b, 5]
                    y0, y1, y2, _, _, _ = collide_point(x0, x1, x2, 0.0, 0.0, 0.0, noground,
                                                        boxes, spheres, thresh)
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
        gon = ground[0] > 0.5
        gh = ground[1]
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
            if has_col and (near or mp or (gon and X[2, p] < gh)
                            or not d0 * d0 + d1 * d1 + d2 * d2 < m2):
                X[0, p], X[1, p], X[2, p], V[0, p], V[1, p], V[2, p] = collide_point(
                    X[0, p], X[1, p], X[2, p], V[0, p], V[1, p], V[2, p], ground, boxes,
                    spheres, thresh)
    _collide_moved(X, V, W, pi, pj, npairs, moved, has_col, ground, boxes, spheres, thresh)
    return found


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


@njit(**JIT)
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
def body_velocities(X, V, M, off, cpl, bw, vb, zlo, bc, bom, biv, Xref, act, dbox):
    """For the bodies ``solve_bodies`` carries as a whole (``cpl[b]``, ``bw[b]`` > 0):
    vb[b] the velocity of the centre of mass (momentum / mass), zlo[:, b] the lowest
    particle's height and vertical velocity, bc[b] the centre of mass, biv[b] (9,) the
    inverse of the inertia tensor about it, bom[b] its spin (angular momentum about it
    times that) from the particles' masses ``M`` (a carried body has no pinned or grabbed
    particle).  Returns what ``contact_build.moved_spread2`` returns for the colliding
    bodies (``act``) and ``Xref``, and writes the displacements' bounding box to ``dbox``
    (6,) (lo x y z, hi x y z; for ``wall_candidates``): body by body, the displacements
    (``kernels.spread.moved_box``) and then the sums over the same particles, in cache,
    so the contact pass reads its positions from memory once for both (a loop of its
    own each: within 2 % of one fused loop, ``tools/contact_pieces.py``).  The sums
    about the first particle, for round-off; then a search for the first particle at
    the lowest height."""
    a = np.zeros(9)
    dlo = np.full(3, np.inf)
    dhi = np.full(3, -np.inf)
    nan = 0.0
    for b in range(off.shape[0] - 1):
        vb[b, 0] = vb[b, 1] = vb[b, 2] = 0.0
        bom[b, 0] = bom[b, 1] = bom[b, 2] = 0.0
        o = off[b]
        if act[b]:
            # the displacements since Xref; the sums below then find the body's particles
            # in cache (one pass over memory for both)
            nan += moved_box(X, Xref, o, off[b + 1], dlo, dhi)
        if not cpl[b] or not bw[b] > 0.0:
            continue
        q0, q1, q2 = X[0, o], X[1, o], X[2, o]
        p0 = p1 = p2 = 0.0             # momentum
        s0 = s1 = s2 = 0.0             # first moment about q
        l0 = l1 = l2 = 0.0             # angular momentum about q
        xx = yy = zz = xy = yz = zx = 0.0   # second moments about q
        lo = np.inf                    # the lowest height
        for k in range(U(o), U(off[b + 1])):
            x0, x1, x2 = X[0, k], X[1, k], X[2, k]
            lo = min(lo, x2)
            m = M[k]
            y0 = x0 - q0
            y1 = x1 - q1
            y2 = x2 - q2
            u0 = m * V[0, k]
            u1 = m * V[1, k]
            u2 = m * V[2, k]
            p0 += u0
            p1 += u1
            p2 += u2
            s0 += m * y0
            s1 += m * y1
            s2 += m * y2
            l0 += y1 * u2 - y2 * u1
            l1 += y2 * u0 - y0 * u2
            l2 += y0 * u1 - y1 * u0
            xx += m * y0 * y0
            yy += m * y1 * y1
            zz += m * y2 * y2
            xy += m * y0 * y1
            yz += m * y1 * y2
            zx += m * y2 * y0
        klo = o
        while klo < off[b + 1] - 1 and not X[2, klo] == lo:
            klo += 1
        iw = bw[b]
        vb[b, 0] = p0 * iw
        vb[b, 1] = p1 * iw
        vb[b, 2] = p2 * iw
        zlo[0, b] = lo
        zlo[1, b] = V[2, klo]
        g0 = s0 * iw                   # centre of mass, relative to q
        g1 = s1 * iw
        g2 = s2 * iw
        bc[b, 0] = q0 + g0
        bc[b, 1] = q1 + g1
        bc[b, 2] = q2 + g2
        # moments about the centre: shift by the total mass M = 1 / iw
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
    for r in range(3):
        dbox[r] = dlo[r] if dlo[0] <= dhi[0] else 0.0    # empty: nothing colliding
        dbox[3 + r] = dhi[r] if dlo[0] <= dhi[0] else 0.0
    return spread_of(dlo, dhi, nan)


@njit(**JIT)
def wall_candidates(X, off, cpl, bw, boxes, spheres, margin, cand, cptr, act, bbox, dbox):
    """The particles of the bodies ``solve_bodies`` carries as a whole (``cpl[b]``,
    ``bw[b]`` > 0) that are within ``margin`` of a box or a sphere, body by body:
    ``cand[cptr[b]:cptr[b + 1]]``; returns their number.  A body's bounding box is
    tested first, so a body far from them costs nothing more: for a colliding body
    (``act``) its box at the last pair-list build (``bbox[b]``, ``body_overlaps``: the
    box grown by its radius and half the skin) widened by the bounding box of every
    colliding particle's displacement since then (``dbox``, ``body_velocities``), which
    holds each of its particles now without a pass over them; for another, a pass over
    its particles."""
    m = 0
    for b in range(off.shape[0] - 1):
        cptr[b] = m
        if not cpl[b] or not bw[b] > 0.0:
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
