"""The per-set sums of the set layout and what is made of them: Eq. 7-9 taken per set
(after the state was changed outside a step, ``sets_accumulate_chunks``, and inside the passes
run by run), turned into per-cluster sums (``sets_reduce``), and the per-set goal maps of
Eq. 23, one affine (or quadratic) map a set from its clusters' goals (``sets_maps``).

A run's 12 rigid/linear sums (sum w d and sum w d y0^T about the set's reference point
``sref``) stay in registers until the run ends (``_add_lin_sums``); quadratic sets take
the 30 sums of the nine features.  A body built for threads splits its particles in one
chunk per thread (``part`` holds a slot per chunk).
"""

import numpy as np
from numba import njit

from .jit import JIT, U, claim_next


@njit(inline='always', **JIT)
def first_run(runs, start):
    """The run holding particle ``start`` (``runs``: the first particle of each run of one
    set, then N; ``_SetLayout.runs``): the loops over runs take each run's end from it,
    not from looking for it particle by particle."""
    return np.searchsorted(runs, start, side='right') - 1


@njit(inline='always', **JIT)
def _add_lin_sums(sums, s, a00, a01, a02, a03, a10, a11, a12, a13, a20, a21, a22, a23):
    """Add a run's 12 rigid/linear set sums (sum w d and sum w d y0^T, rows d0..d2) to
    set ``s``'s row (the run loops keep them in registers until the run ends)."""
    sums[s, 0] += a00
    sums[s, 1] += a01
    sums[s, 2] += a02
    sums[s, 3] += a03
    sums[s, 4] += a10
    sums[s, 5] += a11
    sums[s, 6] += a12
    sums[s, 7] += a13
    sums[s, 8] += a20
    sums[s, 9] += a21
    sums[s, 10] += a22
    sums[s, 11] += a23


@njit(**JIT)
def _sets_acc_lin(start, end, x, y0, mass, sid, runs, sref, sums):
    """U_s += m (x - r_s) [1, y]^T for particles start..end, runs of one set in registers."""
    r = first_run(runs, start)
    i = start
    while i < end:
        s = sid[i]
        r0, r1, r2 = sref[s, 0], sref[s, 1], sref[s, 2]
        a00 = a01 = a02 = a03 = 0.0
        a10 = a11 = a12 = a13 = 0.0
        a20 = a21 = a22 = a23 = 0.0
        r += 1
        j = min(runs[r], end)                  # the run's end (``_SetLayout.runs``)
        # a reduction over the run: vectorises (module docstring)
        for k in range(U(i), U(j)):
            w = mass[k]
            d0 = w * (x[k, 0] - r0)
            d1 = w * (x[k, 1] - r1)
            d2 = w * (x[k, 2] - r2)
            y_0, y_1, y_2 = y0[k, 0], y0[k, 1], y0[k, 2]
            a00 += d0
            a01 += d0 * y_0
            a02 += d0 * y_1
            a03 += d0 * y_2
            a10 += d1
            a11 += d1 * y_0
            a12 += d1 * y_1
            a13 += d1 * y_2
            a20 += d2
            a21 += d2 * y_0
            a22 += d2 * y_1
            a23 += d2 * y_2
        i = j
        _add_lin_sums(sums, s, a00, a01, a02, a03, a10, a11, a12, a13, a20, a21, a22, a23)


@njit(**JIT)
def _sets_acc_damp_lin(start, end, x, v, y0, mass, sid, runs, sref, sums, dsums):
    """``_sets_acc_lin`` and ``damping.damp_acc_range`` in one loop over the runs: each run
    (particles of one set) is found once and read once, with its 12 set sums and 16
    damping sums (row layout of ``damping.NDAMP``; the reference p_s is the set's first
    particle met, as there) in registers.  Bodies of a few hundred particles have runs of
    1-3 particles, where finding the run and writing its sums cost more than its
    particles: one loop instead of two.  Vectorises across a long run like both."""
    r = first_run(runs, start)
    i = start
    while i < end:
        s = sid[i]
        r0, r1, r2 = sref[s, 0], sref[s, 1], sref[s, 2]
        row = dsums[s]
        if row[18] == 0.0:
            row[15] = x[i, 0]
            row[16] = x[i, 1]
            row[17] = x[i, 2]
            row[18] = 1.0
        q0, q1, q2 = row[15], row[16], row[17]
        a00 = a01 = a02 = a03 = 0.0
        a10 = a11 = a12 = a13 = 0.0
        a20 = a21 = a22 = a23 = 0.0
        e0 = e1 = e2 = b0 = b1 = b2 = c0 = c1 = c2 = 0.0
        e00 = e11 = e22 = e01 = e12 = e20 = ms = 0.0
        r += 1
        j = min(runs[r], end)                  # the run's end (``_SetLayout.runs``)
        for k in range(U(i), U(j)):
            w = mass[k]
            p0, p1, p2 = x[k, 0], x[k, 1], x[k, 2]
            d0 = w * (p0 - r0)
            d1 = w * (p1 - r1)
            d2 = w * (p2 - r2)
            y_0, y_1, y_2 = y0[k, 0], y0[k, 1], y0[k, 2]
            a00 += d0
            a01 += d0 * y_0
            a02 += d0 * y_1
            a03 += d0 * y_2
            a10 += d1
            a11 += d1 * y_0
            a12 += d1 * y_1
            a13 += d1 * y_2
            a20 += d2
            a21 += d2 * y_0
            a22 += d2 * y_1
            a23 += d2 * y_2
            # the damping sums about p_s (damping.damp_acc_range, same operations)
            f0 = p0 - q0
            f1 = p1 - q1
            f2 = p2 - q2
            u0 = w * v[k, 0]
            u1 = w * v[k, 1]
            u2 = w * v[k, 2]
            wf0 = w * f0
            wf1 = w * f1
            wf2 = w * f2
            ms += w
            e0 += wf0
            e1 += wf1
            e2 += wf2
            b0 += u0
            b1 += u1
            b2 += u2
            c0 += f1 * u2 - f2 * u1
            c1 += f2 * u0 - f0 * u2
            c2 += f0 * u1 - f1 * u0
            e00 += wf0 * f0
            e11 += wf1 * f1
            e22 += wf2 * f2
            e01 += wf0 * f1
            e12 += wf1 * f2
            e20 += wf2 * f0
        i = j
        _add_lin_sums(sums, s, a00, a01, a02, a03, a10, a11, a12, a13, a20, a21, a22, a23)
        row[0] += e0
        row[1] += e1
        row[2] += e2
        row[3] += b0
        row[4] += b1
        row[5] += b2
        row[6] += c0
        row[7] += c1
        row[8] += c2
        row[9] += e00
        row[10] += e11
        row[11] += e22
        row[12] += e01
        row[13] += e12
        row[14] += e20
        row[19] += ms


@njit(**JIT)
def _sets_acc_quad(start, end, x, y0, mass, sid, sref, sums):
    """U_s += m (x - r_s) phi(y)^T (3 x 10) for particles start..end."""
    i = start
    while i < end:
        s = sid[i]
        r0, r1, r2 = sref[s, 0], sref[s, 1], sref[s, 2]
        a00 = a01 = a02 = a03 = a04 = a05 = a06 = a07 = a08 = a09 = 0.0
        a10 = a11 = a12 = a13 = a14 = a15 = a16 = a17 = a18 = a19 = 0.0
        a20 = a21 = a22 = a23 = a24 = a25 = a26 = a27 = a28 = a29 = 0.0
        while i < end and sid[i] == s:
            w = mass[i]
            d0 = w * (x[i, 0] - r0)
            d1 = w * (x[i, 1] - r1)
            d2 = w * (x[i, 2] - r2)
            y_0, y_1, y_2 = y0[i, 0], y0[i, 1], y0[i, 2]
            f4 = y_0 * y_0
            f5 = y_1 * y_1
            f6 = y_2 * y_2
            f7 = y_0 * y_1
            f8 = y_1 * y_2
            f9 = y_2 * y_0
            a00 += d0
            a01 += d0 * y_0
            a02 += d0 * y_1
            a03 += d0 * y_2
            a04 += d0 * f4
            a05 += d0 * f5
            a06 += d0 * f6
            a07 += d0 * f7
            a08 += d0 * f8
            a09 += d0 * f9
            a10 += d1
            a11 += d1 * y_0
            a12 += d1 * y_1
            a13 += d1 * y_2
            a14 += d1 * f4
            a15 += d1 * f5
            a16 += d1 * f6
            a17 += d1 * f7
            a18 += d1 * f8
            a19 += d1 * f9
            a20 += d2
            a21 += d2 * y_0
            a22 += d2 * y_1
            a23 += d2 * y_2
            a24 += d2 * f4
            a25 += d2 * f5
            a26 += d2 * f6
            a27 += d2 * f7
            a28 += d2 * f8
            a29 += d2 * f9
            i += 1
        sums[s, 0] += a00
        sums[s, 1] += a01
        sums[s, 2] += a02
        sums[s, 3] += a03
        sums[s, 4] += a04
        sums[s, 5] += a05
        sums[s, 6] += a06
        sums[s, 7] += a07
        sums[s, 8] += a08
        sums[s, 9] += a09
        sums[s, 10] += a10
        sums[s, 11] += a11
        sums[s, 12] += a12
        sums[s, 13] += a13
        sums[s, 14] += a14
        sums[s, 15] += a15
        sums[s, 16] += a16
        sums[s, 17] += a17
        sums[s, 18] += a18
        sums[s, 19] += a19
        sums[s, 20] += a20
        sums[s, 21] += a21
        sums[s, 22] += a22
        sums[s, 23] += a23
        sums[s, 24] += a24
        sums[s, 25] += a25
        sums[s, 26] += a26
        sums[s, 27] += a27
        sums[s, 28] += a28
        sums[s, 29] += a29


@njit(**JIT)
def _sets_acc_range(start, end, quad, x, y0, mass, sid, runs, sref, sums):
    if quad:
        _sets_acc_quad(start=start, end=end, x=x, y0=y0, mass=mass, sid=sid, sref=sref, sums=sums)
    else:
        _sets_acc_lin(start=start, end=end, x=x, y0=y0, mass=mass, sid=sid, runs=runs, sref=sref,
                      sums=sums)


@njit(inline='always', **JIT)
def _sets_acc_chunk(chunk, nchunks, quad, x, y0, mass, sid, runs, sref, part):
    n = x.shape[0]
    sums = part[chunk]
    for s in range(sums.shape[0]):
        for j in range(sums.shape[1]):
            sums[s, j] = 0.0
    _sets_acc_range(start=(chunk * n) // nchunks, end=((chunk + 1) * n) // nchunks, quad=quad, x=x,
                    runs=runs,
                    y0=y0, mass=mass, sid=sid, sref=sref, sums=sums)


@njit(**JIT)
def sets_accumulate_chunks(claim, quad, x, y0, mass, sid, runs, sref, part):
    """Per-set sums of the current state (when it was changed outside a step) over the
    chunks this call claims (``claim``, counted up atomically; as
    ``integrate.accumulate_chunks``)."""
    nchunks = part.shape[0]
    while True:
        chunk = claim_next(claim)
        if chunk >= nchunks:
            return
        _sets_acc_chunk(chunk=chunk, nchunks=nchunks, quad=quad, x=x, y0=y0, mass=mass, sid=sid,
                        runs=runs, sref=sref, part=part)


@njit(**JIT)
def _quad_map(rest_lin, k, pm):
    """Cluster k's quadratic features as polynomials of z = x0 - cm0_k: q~ = P phi(z) with
    P into ``pm`` (9 x 10); q-hat = G_k z has no constant term (rest_off = -G_k cm0_k), so
    column 0 is zero, rows 0-2 are [0, G_k] and rows 3-8 (q_a q_c) hold only the degree-2
    columns 4-9."""
    for r in range(9):
        for fi in range(10):
            pm[r, fi] = 0.0
    for a in range(3):
        for j in range(3):
            pm[a, 1 + j] = rest_lin[k, a, j]
    for r in range(6):
        a = r if r < 3 else r - 3                  # features 3..8: q0^2, q1^2, q2^2,
        c = r if r < 3 else (r - 2) % 3            # q0 q1, q1 q2, q2 q0
        row = 3 + r
        for j in range(3):
            pm[row, 4 + j] = rest_lin[k, a, j] * rest_lin[k, c, j]
        pm[row, 7] = rest_lin[k, a, 0] * rest_lin[k, c, 1] + rest_lin[k, a, 1] * rest_lin[k, c, 0]
        pm[row, 8] = rest_lin[k, a, 1] * rest_lin[k, c, 2] + rest_lin[k, a, 2] * rest_lin[k, c, 1]
        pm[row, 9] = rest_lin[k, a, 2] * rest_lin[k, c, 0] + rest_lin[k, a, 0] * rest_lin[k, c, 2]


@njit(**JIT)
def sets_reduce(part, sptr, scl, scnt, sphi, sref, stp, rest_lin, ref, quad, out, wk, pm):
    """Per-cluster accumulators ``out`` (1, clusters, 12 or 30) from the per-set sums.

    Set s contributes sum_{i in s} w (x - ref_k) phi(y)^T = (U_s + (r_s - ref_k) Phi_s^T) /
    n_s (w = m / n_s) to each of its clusters k.  That polynomial of the set's rest offset
    y is re-expanded about cluster k's rest centre, z = x0 - cm0_k = y + t_ks (``stp``,
    per set-cluster pair): 12 (30) multiply-adds a pair, summed per cluster in ``out``
    itself (3 x 4 or 3 x 10, the size of the final row).  Only then is each cluster's sum
    mapped once to its features q-hat = G_k z (and q~ = P_k phi(z)): the map, 9 x 10 in
    the quadratic mode, costs per cluster instead of per pair.  ``wk`` (2, 3, 10) and
    ``pm`` (9, 10) scratch.
    """
    nchunks = part.shape[0]
    ns = part.shape[1]
    nk = out.shape[1]
    for k in range(nk):
        for a in range(out.shape[2]):
            out[0, k, a] = 0.0
    u = wk[0]
    if quad:
        for s in range(ns):
            for a in range(3):
                for fi in range(10):
                    acc = 0.0
                    for chunk in range(nchunks):
                        acc += part[chunk, s, a * 10 + fi]
                    u[a, fi] = acc
            inv_n = 1.0 / scnt[s]
            for j in range(sptr[s], sptr[s + 1]):
                k = scl[j]
                t0, t1, t2 = stp[j, 0], stp[j, 1], stp[j, 2]
                for a in range(3):
                    dr = sref[s, a] - ref[k, a]
                    v0 = inv_n * (u[a, 0] + dr * sphi[s, 0])
                    v1 = inv_n * (u[a, 1] + dr * sphi[s, 1])
                    v2 = inv_n * (u[a, 2] + dr * sphi[s, 2])
                    v3 = inv_n * (u[a, 3] + dr * sphi[s, 3])
                    v4 = inv_n * (u[a, 4] + dr * sphi[s, 4])
                    v5 = inv_n * (u[a, 5] + dr * sphi[s, 5])
                    v6 = inv_n * (u[a, 6] + dr * sphi[s, 6])
                    v7 = inv_n * (u[a, 7] + dr * sphi[s, 7])
                    v8 = inv_n * (u[a, 8] + dr * sphi[s, 8])
                    v9 = inv_n * (u[a, 9] + dr * sphi[s, 9])
                    row = out[0, k]
                    b = 10 * a
                    # phi(y + t): z_j = y_j + t_j, z_a z_c = y_a y_c + t_c y_a + t_a y_c + t_a t_c
                    row[b] += v0
                    row[b + 1] += v1 + t0 * v0
                    row[b + 2] += v2 + t1 * v0
                    row[b + 3] += v3 + t2 * v0
                    row[b + 4] += v4 + 2.0 * t0 * v1 + t0 * t0 * v0
                    row[b + 5] += v5 + 2.0 * t1 * v2 + t1 * t1 * v0
                    row[b + 6] += v6 + 2.0 * t2 * v3 + t2 * t2 * v0
                    row[b + 7] += v7 + t1 * v1 + t0 * v2 + t0 * t1 * v0
                    row[b + 8] += v8 + t2 * v2 + t1 * v3 + t1 * t2 * v0
                    row[b + 9] += v9 + t0 * v3 + t2 * v1 + t2 * t0 * v0
        for k in range(nk):
            _quad_map(rest_lin=rest_lin, k=k, pm=pm)
            row = out[0, k]
            for a in range(3):
                for fi in range(10):
                    u[a, fi] = row[10 * a + fi]
            for a in range(3):
                row[a] = u[a, 0]
                for jj in range(3):
                    row[3 + 9 * a + jj] = (pm[jj, 1] * u[a, 1] + pm[jj, 2] * u[a, 2]
                                           + pm[jj, 3] * u[a, 3])
                for jj in range(3, 9):
                    acc = 0.0
                    for fi in range(4, 10):
                        acc += pm[jj, fi] * u[a, fi]
                    row[3 + 9 * a + jj] = acc
        return
    for s in range(ns):
        for a in range(3):
            for fi in range(4):
                acc = 0.0
                for chunk in range(nchunks):
                    acc += part[chunk, s, a * 4 + fi]
                u[a, fi] = acc
        inv_n = 1.0 / scnt[s]
        for j in range(sptr[s], sptr[s + 1]):
            k = scl[j]
            t0, t1, t2 = stp[j, 0], stp[j, 1], stp[j, 2]
            row = out[0, k]
            for a in range(3):
                dr = sref[s, a] - ref[k, a]
                v0 = inv_n * (u[a, 0] + dr * sphi[s, 0])
                b = 4 * a
                row[b] += v0
                row[b + 1] += inv_n * (u[a, 1] + dr * sphi[s, 1]) + t0 * v0
                row[b + 2] += inv_n * (u[a, 2] + dr * sphi[s, 2]) + t1 * v0
                row[b + 3] += inv_n * (u[a, 3] + dr * sphi[s, 3]) + t2 * v0
    for k in range(nk):
        row = out[0, k]
        for a in range(3):
            for fi in range(4):
                u[a, fi] = row[4 * a + fi]
        for a in range(3):
            row[a] = u[a, 0]
            for jj in range(3):
                row[3 + 3 * a + jj] = (rest_lin[k, jj, 0] * u[a, 1] + rest_lin[k, jj, 1] * u[a, 2]
                                       + rest_lin[k, jj, 2] * u[a, 3])


@njit(**JIT)
def sets_maps(sptr, scl, scnt, sorg, stp, rest_lin, trans, goal_lin, goal_off, ref, quad, gm,
              sref, pm, ck):
    """Goal maps ``gm`` (sets, 3, 10): mean over the set's clusters of each goal polynomial.

    Also ``sref`` <- mean of the set's cluster centres (the reference point of the per-set
    sums of the next step).  Rigid/linear: goal_k = goal_lin_k (y + o_s) + goal_off_k.
    Quadratic: each cluster's goal T_k q~ + goal_off_k as a polynomial of z = x0 - cm0_k,
    ``ck`` (clusters, 3, 10), once per cluster; per set-cluster pair only its re-expansion
    about the set's origin (z = y + t_ks, ``stp``: 20 multiply-adds a row).
    """
    ns = gm.shape[0]
    nphi = 10 if quad else 4
    if quad:
        for k in range(ck.shape[0]):
            _quad_map(rest_lin=rest_lin, k=k, pm=pm)
            for a in range(3):
                ck[k, a, 0] = goal_off[k, a]
                for fi in range(1, 4):
                    ck[k, a, fi] = (trans[k, a, 0] * pm[0, fi] + trans[k, a, 1] * pm[1, fi]
                                    + trans[k, a, 2] * pm[2, fi])
                for fi in range(4, 10):
                    acc = 0.0
                    for jj in range(3, 9):
                        acc += trans[k, a, jj] * pm[jj, fi]
                    ck[k, a, fi] = acc
    for s in range(ns):
        for a in range(3):
            sref[s, a] = 0.0
            for fi in range(nphi):
                gm[s, a, fi] = 0.0
        o0, o1, o2 = sorg[s, 0], sorg[s, 1], sorg[s, 2]
        for j in range(sptr[s], sptr[s + 1]):
            k = scl[j]
            for a in range(3):
                sref[s, a] += ref[k, a]
            if quad:
                t0, t1, t2 = stp[j, 0], stp[j, 1], stp[j, 2]
                for a in range(3):
                    c0, c1, c2, c3 = ck[k, a, 0], ck[k, a, 1], ck[k, a, 2], ck[k, a, 3]
                    c4, c5, c6 = ck[k, a, 4], ck[k, a, 5], ck[k, a, 6]
                    c7, c8, c9 = ck[k, a, 7], ck[k, a, 8], ck[k, a, 9]
                    # c phi(y + t) as a polynomial of y
                    gm[s, a, 0] += (c0 + c1 * t0 + c2 * t1 + c3 * t2 + c4 * t0 * t0
                                    + c5 * t1 * t1 + c6 * t2 * t2 + c7 * t0 * t1 + c8 * t1 * t2
                                    + c9 * t2 * t0)
                    gm[s, a, 1] += c1 + 2.0 * c4 * t0 + c7 * t1 + c9 * t2
                    gm[s, a, 2] += c2 + 2.0 * c5 * t1 + c7 * t0 + c8 * t2
                    gm[s, a, 3] += c3 + 2.0 * c6 * t2 + c8 * t1 + c9 * t0
                    gm[s, a, 4] += c4
                    gm[s, a, 5] += c5
                    gm[s, a, 6] += c6
                    gm[s, a, 7] += c7
                    gm[s, a, 8] += c8
                    gm[s, a, 9] += c9
            else:
                # goal_k = goal_lin_k x0 + goal_off_k with x0 = y + o
                for a in range(3):
                    gm[s, a, 0] += (goal_lin[k, a, 0] * o0 + goal_lin[k, a, 1] * o1
                                    + goal_lin[k, a, 2] * o2 + goal_off[k, a])
                    gm[s, a, 1] += goal_lin[k, a, 0]
                    gm[s, a, 2] += goal_lin[k, a, 1]
                    gm[s, a, 3] += goal_lin[k, a, 2]
        inv_n = 1.0 / scnt[s]
        for a in range(3):
            sref[s, a] *= inv_n
            for fi in range(nphi):
                gm[s, a, fi] *= inv_n
