"""Compiled kernels of body-body contact: the pair solve.

The model, the parameters and the Python-side pass (``Contact``) are in ``contact.py``;
the pair list (a Verlet list on a cell grid, sorted by lower index) is built by
``contact_build.py``; this file holds what runs per step on that list.  Serial; nothing
allocates.  A world with one colliding body and no self-collision does not run the pass at
all.

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
from .kernels.jit import JIT


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
