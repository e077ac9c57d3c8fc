"""Multi-cluster bodies in the set layout: Eq. 7-9, 13-14, 21 and 23 at single-cluster cost.

Particles that belong to the same clusters form a *set* (on the paper's cube grid,
(k + 1)^3 sets for k^3 clusters).  Inside a set every cluster's goal is a polynomial of the
particle's rest offset y = x0 - o_s (degree 1 for rigid/linear, degree 2 for quadratic), so
the mean of its clusters' goals (Eq. 23 and its note) is one 3 x 4 (3 x 10) matrix M_s per
set, and the sums each cluster needs (Eq. 7-9, 21) follow from per-set sums
U_s = sum m (x - r_s) phi(y)^T with phi(y) = [1, y, y0^2, y1^2, y2^2, y0 y1, y1 y2, y2 y0].
A step then reads and writes each particle once and costs about as much per particle as a
single-cluster body, whatever the number of clusters per particle; the per-cluster work
moves to the few set-cluster pairs (``sets_reduce``, ``sets_maps``).  ``part`` is
(chunks, sets, 3 * nphi).  Vectorisation: the rigid/linear loops run over one run of a set
at a time (consecutive particles of one set) with the set's map, field and sums in
registers, and vectorise across the particles of the run as ``integrate.py``'s one-cluster
loops do (unit-stride columns, unsigned index, no array but x, v, y0, mass read in the
loop); runs shorter than a vector (lattice rows cut by the cluster faces) take the scalar
remainder loop.  The quadratic loops fetch the map per particle: scalar.

A rigid/linear body stored set by set (as ``Body`` stores it: one run a set)
without torque takes one loop a run (``_sets_fused_lin``, the loop of the
one-cluster pass ``integrate._fused_range``): each particle read and written once, its
set's sums and damping sums taken in the same loop, all about one point per set; the
static colliders and the speed cap after the loop: the ground's projection corrects the
run's sums for what it moved, a run the cap or a box or sphere moved is summed again.
Every pass takes the runs' ends from ``runs`` (precomputed at build, ``first_run``) and
caps the speeds block by block before it sums the block, so the sums stay valid.
"""

import numpy as np
from numba import njit, prange

from .jit import JIT, U
from .colliders import _collide_range, ground_range_sums
from .damping import damp_acc_range, damp_sums_range, damp_towards
from .integrate import BLOCK, _fused_range, _rest_sums, advance, damp_constants
from .limits import limit_speed_range


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


@njit(inline='always', **JIT)
def first_run(runs, start):
    """The run holding particle ``start`` (``runs``: the first particle of each run of one
    set, then N; ``_SetLayout.runs``): the loops over runs take each run's end from it,
    not from looking for it particle by particle."""
    return np.searchsorted(runs, start, side='right') - 1


@njit(**JIT)
def _sets_int_lin(start, end, x, v, y0, sid, runs, gm, alpha_h, h, ax, ay, az, w0, w1, w2, damp,
                  k_damp, dmp, sref):
    """Rigid/linear goals: each run of one set with its 3 x 4 map in registers.

    ``ax, ay, az`` is the uniform acceleration (acc - ang x com), ``w`` the angular one;
    with ``damp`` the velocities are first damped towards ``dmp`` (``damp_velocity``).
    The loop over a run vectorises (module docstring): the set's map, reference and
    damping field in locals, the torque and damping branches outside it.
    """
    torque = w0 != 0.0 or w1 != 0.0 or w2 != 0.0
    hx, hy, hz = h * ax, h * ay, h * az
    err2 = 0.0
    r = first_run(runs, start)
    i = start
    while i < end:
        s = sid[i]
        m00, m01, m02, m03 = gm[s, 0, 0], gm[s, 0, 1], gm[s, 0, 2], gm[s, 0, 3]
        m10, m11, m12, m13 = gm[s, 1, 0], gm[s, 1, 1], gm[s, 1, 2], gm[s, 1, 3]
        m20, m21, m22, m23 = gm[s, 2, 0], gm[s, 2, 1], gm[s, 2, 2], gm[s, 2, 3]
        r0c, r1c, r2c = sref[s, 0], sref[s, 1], sref[s, 2]
        s_d = s if damp else 0
        c0, c1, c2 = dmp[s_d, 0], dmp[s_d, 1], dmp[s_d, 2]
        o0, o1, o2 = dmp[s_d, 3], dmp[s_d, 4], dmp[s_d, 5]
        r += 1
        j = min(runs[r], end)                  # the run's end (``_SetLayout.runs``)
        if damp and not torque:
            for k in range(U(i), U(j)):
                y_0, y_1, y_2 = y0[k, 0], y0[k, 1], y0[k, 2]
                p0, p1, p2 = x[k, 0], x[k, 1], x[k, 2]
                damp_towards(v=v, i=k, r0=p0 - r0c, r1=p1 - r1c, r2=p2 - r2c, c0=c0, c1=c1,
                             c2=c2, o0=o0, o1=o1, o2=o2, k_damp=k_damp)
                err2 += advance(x=x, v=v, i=k, p0=p0, p1=p1, p2=p2,
                                g0=m00 + m01 * y_0 + m02 * y_1 + m03 * y_2,
                                g1=m10 + m11 * y_0 + m12 * y_1 + m13 * y_2,
                                g2=m20 + m21 * y_0 + m22 * y_1 + m23 * y_2, alpha_h=alpha_h,
                                h=h, dv0=hx, dv1=hy, dv2=hz)
        elif not torque:
            for k in range(U(i), U(j)):
                y_0, y_1, y_2 = y0[k, 0], y0[k, 1], y0[k, 2]
                p0, p1, p2 = x[k, 0], x[k, 1], x[k, 2]
                err2 += advance(x=x, v=v, i=k, p0=p0, p1=p1, p2=p2,
                                g0=m00 + m01 * y_0 + m02 * y_1 + m03 * y_2,
                                g1=m10 + m11 * y_0 + m12 * y_1 + m13 * y_2,
                                g2=m20 + m21 * y_0 + m22 * y_1 + m23 * y_2, alpha_h=alpha_h,
                                h=h, dv0=hx, dv1=hy, dv2=hz)
        else:
            for k in range(U(i), U(j)):
                y_0, y_1, y_2 = y0[k, 0], y0[k, 1], y0[k, 2]
                p0, p1, p2 = x[k, 0], x[k, 1], x[k, 2]
                if damp:
                    damp_towards(v=v, i=k, r0=p0 - r0c, r1=p1 - r1c, r2=p2 - r2c, c0=c0,
                                 c1=c1, c2=c2, o0=o0, o1=o1, o2=o2, k_damp=k_damp)
                err2 += advance(x=x, v=v, i=k, p0=p0, p1=p1, p2=p2,
                                g0=m00 + m01 * y_0 + m02 * y_1 + m03 * y_2,
                                g1=m10 + m11 * y_0 + m12 * y_1 + m13 * y_2,
                                g2=m20 + m21 * y_0 + m22 * y_1 + m23 * y_2, alpha_h=alpha_h,
                                h=h, dv0=h * (ax + w1 * p2 - w2 * p1),
                                dv1=h * (ay + w2 * p0 - w0 * p2),
                                dv2=h * (az + w0 * p1 - w1 * p0))
        i = j
    return err2


@njit(**JIT)
def _sets_int_quad(start, end, x, v, y0, sid, runs, gm, alpha_h, h, ax, ay, az, w0, w1, w2, damp,
                   k_damp, dmp, sref):
    """Quadratic goals: gm[s] (3 x 10) times phi(y); damping as in ``_sets_int_lin``.

    Run by run like ``_sets_int_lin``: the set's map, reference and damping field are read
    into locals once a run, so the particle loop reads only x, v, y0 (with the map read
    from ``gm`` in the loop, every store to v could alias it: the damped loop reloaded the
    30 coefficients after each store and cost three times the undamped one).
    """
    err2 = 0.0
    r = first_run(runs, start)
    i = start
    while i < end:
        s = sid[i]
        m00, m01, m02, m03, m04 = gm[s, 0, 0], gm[s, 0, 1], gm[s, 0, 2], gm[s, 0, 3], gm[s, 0, 4]
        m05, m06, m07, m08, m09 = gm[s, 0, 5], gm[s, 0, 6], gm[s, 0, 7], gm[s, 0, 8], gm[s, 0, 9]
        m10, m11, m12, m13, m14 = gm[s, 1, 0], gm[s, 1, 1], gm[s, 1, 2], gm[s, 1, 3], gm[s, 1, 4]
        m15, m16, m17, m18, m19 = gm[s, 1, 5], gm[s, 1, 6], gm[s, 1, 7], gm[s, 1, 8], gm[s, 1, 9]
        m20, m21, m22, m23, m24 = gm[s, 2, 0], gm[s, 2, 1], gm[s, 2, 2], gm[s, 2, 3], gm[s, 2, 4]
        m25, m26, m27, m28, m29 = gm[s, 2, 5], gm[s, 2, 6], gm[s, 2, 7], gm[s, 2, 8], gm[s, 2, 9]
        r0c, r1c, r2c = sref[s, 0], sref[s, 1], sref[s, 2]
        s_d = s if damp else 0
        c0, c1, c2 = dmp[s_d, 0], dmp[s_d, 1], dmp[s_d, 2]
        o0, o1, o2 = dmp[s_d, 3], dmp[s_d, 4], dmp[s_d, 5]
        r += 1
        j = min(runs[r], end)                  # the run's end (``_SetLayout.runs``)
        for k in range(U(i), U(j)):
            y_0, y_1, y_2 = y0[k, 0], y0[k, 1], y0[k, 2]
            f4 = y_0 * y_0
            f5 = y_1 * y_1
            f6 = y_2 * y_2
            f7 = y_0 * y_1
            f8 = y_1 * y_2
            f9 = y_2 * y_0
            g0 = (m00 + m01 * y_0 + m02 * y_1 + m03 * y_2 + m04 * f4 + m05 * f5 + m06 * f6
                  + m07 * f7 + m08 * f8 + m09 * f9)
            g1 = (m10 + m11 * y_0 + m12 * y_1 + m13 * y_2 + m14 * f4 + m15 * f5 + m16 * f6
                  + m17 * f7 + m18 * f8 + m19 * f9)
            g2 = (m20 + m21 * y_0 + m22 * y_1 + m23 * y_2 + m24 * f4 + m25 * f5 + m26 * f6
                  + m27 * f7 + m28 * f8 + m29 * f9)
            p0, p1, p2 = x[k, 0], x[k, 1], x[k, 2]
            if damp:
                damp_towards(v=v, i=k, r0=p0 - r0c, r1=p1 - r1c, r2=p2 - r2c, c0=c0, c1=c1,
                             c2=c2, o0=o0, o1=o1, o2=o2, k_damp=k_damp)
            err2 += advance(x=x, v=v, i=k, p0=p0, p1=p1, p2=p2, g0=g0, g1=g1, g2=g2,
                            alpha_h=alpha_h, h=h, dv0=h * (ax + w1 * p2 - w2 * p1),
                            dv1=h * (ay + w2 * p0 - w0 * p2), dv2=h * (az + w0 * p1 - w1 * p0))
        i = j
    return err2


@njit(**JIT)
def _sets_int_range(start, end, quad, x, v, y0, sid, runs, gm, alpha, h, acc, ang, com, damp,
                    k_damp, dmp, sref):
    """Eq. 13-14 for particles start..end with the set goal maps; returns sum |g - x|^2."""
    w0, w1, w2 = ang[0], ang[1], ang[2]
    # acc + ang x (p - com) = (acc - ang x com) + ang x p
    ax = acc[0] - (w1 * com[2] - w2 * com[1])
    ay = acc[1] - (w2 * com[0] - w0 * com[2])
    az = acc[2] - (w0 * com[1] - w1 * com[0])
    if quad:
        return _sets_int_quad(start=start, end=end, x=x, v=v, y0=y0, sid=sid, runs=runs, gm=gm,
                              alpha_h=alpha / h, h=h, ax=ax, ay=ay, az=az, w0=w0, w1=w1, w2=w2,
                              damp=damp, k_damp=k_damp, dmp=dmp, sref=sref)
    return _sets_int_lin(start=start, end=end, x=x, v=v, y0=y0, sid=sid, runs=runs, gm=gm,
                         alpha_h=alpha / h,
                         h=h, ax=ax, ay=ay, az=az, w0=w0, w1=w1, w2=w2, damp=damp,
                         k_damp=k_damp, dmp=dmp, sref=sref)


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


@njit(**JIT)
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
def sets_accumulate_serial(quad, x, y0, mass, sid, runs, sref, part):
    """Per-set sums of the current state (when it was changed outside a step), one thread."""
    nchunks = part.shape[0]
    for chunk in range(nchunks):
        _sets_acc_chunk(chunk=chunk, nchunks=nchunks, quad=quad, x=x, y0=y0, mass=mass, sid=sid,
                        runs=runs, sref=sref, part=part)


@njit(parallel=True, **JIT)
def sets_accumulate_parallel(quad, x, y0, mass, sid, runs, sref, part):
    """Per-set sums of the current state, one chunk per thread."""
    nchunks = part.shape[0]
    for chunk in prange(nchunks):
        _sets_acc_chunk(chunk=chunk, nchunks=nchunks, quad=quad, x=x, y0=y0, mass=mass, sid=sid,
                        runs=runs, sref=sref, part=part)


#: Particles a run of one set must hold on average for a body's pass to take
#: ``_sets_fused_lin``: each run costs it 73 ns undamped, 117 ns damped
#: (``tools/set_pass_cost.py``; the vector loops' setup, their reductions and remainders, the
#: sums written out), a loss on short runs (lattice order: runs of ~7), where the two-loop
#: pass finds and sums the runs particle by particle.
FUSED_MIN_RUN = 32
#: Particles per block of ``_sets_fused_lin``: each block adds a segment to the runs (as
#: costly as a run), and a damped run is read twice, the second time from L2 either way (1024
#: particles' x and v alone fill L1).  ``bench scaling --modes linear --clusters 2
#: --variants sorted,damped_sorted`` with this set to 1024 and to 4096, two runs each: 10k
#: damped 0.053 against 0.049-0.052 ms, 97k 0.290 / 0.366 against 0.276-0.279 / 0.345-0.351
#: (undamped / damped).
FUSED_SETS_BLOCK = 4096


@njit(**JIT)
def _sets_fused_lin(start, end, x, v, y0, mass, wuni, sid, runs, gm, sref, alpha_h, h, hx,
                    hy, hz, damp, k_damp, dmp, v_max, sums, dsums, has_col, ground, boxes,
                    spheres, thresh, gz):
    """The whole pass of particles start..end of a rigid/linear set-layout body without
    torque, run by run (``integrate._fused_range``: one loop reads and writes each particle
    once): the damping towards the set's field, Eq. 13-14 with the set's map, the count of
    speeds over ``v_max``, and the set's 12 sums of the new state; then the static
    colliders on the run (``colliders._collide_range``: a run no collider can reach costs
    one bounds pass) and the speed cap (``limits.limit_speed_range``, only where a speed
    was over it), in the order of the two-loop pass; the ground alone corrects the run's
    sums for the particles it projected (``colliders.ground_range_sums``), a run the cap
    or a box or sphere moved is summed again (``integrate._rest_sums``), so the sums are of
    the final state and the step
    leaves them valid.  Damped, the loop also takes the run's 12 damping sums and W (a run
    that was moved: ``damping.damp_sums_range``, while it is in cache).  Returns (sum of
    |g - x|^2, capped speeds).  ``gz``: the ground's height, None without a ground
    (compiled without the ground's test, ``integrate.below_ground``).

    The sums of a set are taken about one point P_s, its shape sums and damping sums alike
    (so the damping row's sum w d and W are the shape sums' own: 12 damping accumulators,
    not 16): undamped the set's reference ``sref[s]``; damped where the set goes, sref +
    h (c_s + h acc) with c_s the damping field's velocity at sref, so that the second
    moments of a body far out at huge speed do not lose it to rounding (as ``packed``).
    The damping row holds P_s (its entries 15-17); ``sets_integrate_*`` makes it the
    set's reference for the next step's ``sets_reduce``.  The runs' ends come from
    ``runs`` (looking for them particle by particle cost 0.3-0.5 ns a particle).
    """
    lim2 = v_max * v_max if v_max > 0.0 else np.inf
    ground_only = boxes.shape[0] == 0 and spheres.shape[0] == 0
    err2 = 0.0
    capped = 0
    r = first_run(runs, start)
    i = start
    while i < end:
        s = sid[i]
        r += 1
        j = min(runs[r], end)
        gmap = (gm[s, 0, 1], gm[s, 0, 2], gm[s, 0, 3], gm[s, 1, 1], gm[s, 1, 2], gm[s, 1, 3],
                gm[s, 2, 1], gm[s, 2, 2], gm[s, 2, 3], gm[s, 0, 0], gm[s, 1, 0], gm[s, 2, 0])
        r0, r1, r2 = sref[s, 0], sref[s, 1], sref[s, 2]
        s_d = s if damp else 0
        field = damp_constants(damp, k_damp, dmp[s_d, 0], dmp[s_d, 1], dmp[s_d, 2],
                               dmp[s_d, 3], dmp[s_d, 4], dmp[s_d, 5], r0, r1, r2)
        if damp:
            r0 += h * (dmp[s, 0] + hx)
            r1 += h * (dmp[s, 1] + hy)
            r2 += h * (dmp[s, 2] + hz)
        t = _fused_range(i, j, x, v, y0, mass, wuni, gmap, damp, field, alpha_h, h, hx, hy, hz, r0,
                         r1, r2, lim2, gz)
        err2 += t[0]
        ss = t[2:14]                   # the run's 12 shape sums: sum w d, sum w d y0^T
        dsum = t[15:]                  # and damping sums (damped)
        # a ground alone: only a run with a height below it can be moved (the loop counts
        # them): projected without the bounds pass, its sums corrected for what the
        # projection moved (``ground_range_sums``); the others skip the colliders
        moved = False
        if has_col and not ground_only:
            moved = _collide_range(start=i, end=j, x=x, v=v, ground=ground, boxes=boxes,
                                   spheres=spheres, thresh=thresh)
        elif t[14] > 0:
            g = ground_range_sums(i, j, x, v, y0, mass, wuni, ground, thresh, r0, r1, r2,
                                  damp)
            ss = (ss[0], ss[1], ss[2] + g[0], ss[3], ss[4], ss[5], ss[6], ss[7], ss[8],
                  ss[9] + g[1], ss[10] + g[2], ss[11] + g[3])
            dsum = (dsum[0] + g[4], dsum[1] + g[5], dsum[2] + g[6], dsum[3] + g[7],
                    dsum[4] + g[8], dsum[5] + g[9], dsum[6] + g[10], dsum[7] + g[11],
                    dsum[8] + g[12], dsum[9] + g[13], dsum[10] + g[14], dsum[11] + g[15],
                    dsum[12])
        # the loop counted the speeds before the colliders: a static collider never speeds
        # a particle up (``colliders.contact_velocity``: restitution <= 1, friction only
        # slows), so a run with none over the cap has none after them either
        if t[1] > 0:
            capped += limit_speed_range(i, j, x, v, h, v_max)
            moved = True
        if moved:
            ss = _rest_sums(i, j, x, y0, mass, r0, r1, r2)
            if damp:
                dsum = damp_sums_range(i, j, x, v, mass, wuni, r0, r1, r2)[:13]
        # the set sums' layout: per row of d, [sum w d, sum w d y^T]
        _add_lin_sums(sums, s, ss[0], ss[3], ss[4], ss[5], ss[1], ss[6], ss[7], ss[8], ss[2],
                      ss[9], ss[10], ss[11])
        if damp:
            row = dsums[s]
            row[15] = r0
            row[16] = r1
            row[17] = r2
            row[18] = 1.0
            row[0] += ss[0]
            row[1] += ss[1]
            row[2] += ss[2]
            for k in range(12):
                row[3 + k] += dsum[k]
            row[19] += dsum[12]
        i = j
    return err2, capped


@njit(**JIT)
def _sets_int_chunk(chunk, nchunks, quad, x, v, y0, mass, wuni, sid, runs, gm, sref, alpha, h,
                    acc, ang, com, part, err, has_col, ground, boxes, spheres, thresh, damp,
                    k_damp, dmp, dpart, v_max):
    """Damp, integrate, collide, cap the speeds and accumulate a chunk block by block (one
    pass over memory); ``dpart[chunk]`` receives the damping sums of the next step.
    Returns the capped speeds: the block's speeds are capped (``limits.limit_speed_range``)
    before its sums are taken, so the sums stay valid.  Rigid/linear without torque, long
    runs: ``_sets_fused_lin``."""
    n = x.shape[0]
    start = (chunk * n) // nchunks
    end = ((chunk + 1) * n) // nchunks
    sums = part[chunk]
    for s in range(sums.shape[0]):
        for j in range(sums.shape[1]):
            sums[s, j] = 0.0
    if damp:
        dsums = dpart[chunk]
        for s in range(dsums.shape[0]):
            for j in range(dsums.shape[1]):
                dsums[s, j] = 0.0
    err2 = 0.0
    capped = 0
    fused = _fused_pass(quad, has_col, ang, runs)
    grounded = has_col and ground[0] > 0.5
    step = FUSED_SETS_BLOCK if fused else BLOCK
    for bs in range(start, end, step):
        be = min(bs + step, end)
        if fused:
            if grounded:
                e, c = _sets_fused_lin(bs, be, x, v, y0, mass, wuni, sid, runs, gm, sref,
                                       alpha / h, h, h * acc[0], h * acc[1], h * acc[2], damp,
                                       k_damp, dmp, v_max, sums, dpart[chunk], has_col,
                                       ground, boxes, spheres, thresh, ground[1])
            else:                          # compiled without the ground's test
                e, c = _sets_fused_lin(bs, be, x, v, y0, mass, wuni, sid, runs, gm, sref,
                                       alpha / h, h, h * acc[0], h * acc[1], h * acc[2], damp,
                                       k_damp, dmp, v_max, sums, dpart[chunk], has_col,
                                       ground, boxes, spheres, thresh, None)
            err2 += e
            capped += c
            continue
        err2 += _sets_int_range(start=bs, end=be, quad=quad, x=x, v=v, y0=y0, sid=sid, runs=runs,
                                gm=gm,
                                alpha=alpha, h=h, acc=acc, ang=ang, com=com, damp=damp,
                                k_damp=k_damp, dmp=dmp, sref=sref)
        if has_col:
            _collide_range(start=bs, end=be, x=x, v=v, ground=ground, boxes=boxes, spheres=spheres,
                           thresh=thresh)
        if v_max > 0.0:
            capped += limit_speed_range(bs, be, x, v, h, v_max)
        if damp and not quad:
            _sets_acc_damp_lin(start=bs, end=be, x=x, v=v, y0=y0, mass=mass, sid=sid, runs=runs,
                               sref=sref, sums=sums, dsums=dpart[chunk])
            continue
        _sets_acc_range(start=bs, end=be, quad=quad, x=x, y0=y0, mass=mass, sid=sid, runs=runs,
                        sref=sref,
                        sums=sums)
        if damp:
            damp_acc_range(start=bs, end=be, x=x, v=v, mass=mass, sid=sid, dsums=dpart[chunk])
    err[chunk] = err2
    return capped


@njit(**JIT)
def long_runs(runs):
    """Whether the runs (``_SetLayout.runs``) hold ``FUSED_MIN_RUN`` particles or more on
    average: the run test of ``_fused_pass`` (callable from Python: the tests ask it)."""
    return (runs.shape[0] - 1) * FUSED_MIN_RUN <= runs[runs.shape[0] - 1]


@njit(inline='always', **JIT)
def _fused_pass(quad, has_col, ang, runs):
    """Whether a pass takes ``_sets_fused_lin``: rigid/linear, no torque, long runs
    (``long_runs``; ``has_col``: either way)."""
    return not quad and ang[0] == 0.0 and ang[1] == 0.0 and ang[2] == 0.0 and long_runs(runs)


@njit(**JIT)
def _fused_refs(quad, has_col, ang, runs, damp, sref, dpart):
    """After a damped ``_sets_fused_lin`` pass: each set's reference becomes the point its
    sums were taken about (the damping row's P_s, alike in every chunk), which the next
    step's ``sets_reduce`` expects."""
    if not (damp and _fused_pass(quad, has_col, ang, runs)):
        return
    for s in range(sref.shape[0]):
        for c in range(dpart.shape[0]):
            row = dpart[c, s]
            if row[18] > 0.0:
                sref[s, 0] = row[15]
                sref[s, 1] = row[16]
                sref[s, 2] = row[17]
                break


@njit(**JIT)
def sets_integrate_serial(quad, x, v, y0, mass, wuni, sid, runs, gm, sref, alpha, h, acc, ang,
                          com, part, err, has_col, ground, boxes, spheres, thresh, damp, k_damp,
                          dmp, dpart, v_max):
    """Fused step pass of a set-layout body, one thread; returns the capped speeds."""
    nchunks = part.shape[0]
    capped = 0
    for chunk in range(nchunks):
        capped += _sets_int_chunk(chunk=chunk, nchunks=nchunks, quad=quad, x=x, v=v, y0=y0,
                                  mass=mass, wuni=wuni, sid=sid, runs=runs, gm=gm, sref=sref,
                                  alpha=alpha,
                                  h=h, acc=acc, ang=ang, com=com, part=part, err=err,
                                  has_col=has_col, ground=ground, boxes=boxes, spheres=spheres,
                                  thresh=thresh, damp=damp, k_damp=k_damp, dmp=dmp,
                                  dpart=dpart, v_max=v_max)
    _fused_refs(quad, has_col, ang, runs, damp, sref, dpart)
    return capped


@njit(parallel=True, **JIT)
def sets_integrate_parallel(quad, x, v, y0, mass, wuni, sid, runs, gm, sref, alpha, h, acc, ang,
                            com, part, err, has_col, ground, boxes, spheres, thresh, damp, k_damp,
                            dmp, dpart, v_max):
    """Fused step pass of a set-layout body, one chunk per thread; returns the capped
    speeds."""
    nchunks = part.shape[0]
    capped = 0
    for chunk in prange(nchunks):
        capped += _sets_int_chunk(chunk=chunk, nchunks=nchunks, quad=quad, x=x, v=v, y0=y0,
                                  mass=mass, wuni=wuni, sid=sid, runs=runs, gm=gm, sref=sref,
                                  alpha=alpha,
                                  h=h, acc=acc, ang=ang, com=com, part=part, err=err,
                                  has_col=has_col, ground=ground, boxes=boxes, spheres=spheres,
                                  thresh=thresh, damp=damp, k_damp=k_damp, dmp=dmp,
                                  dpart=dpart, v_max=v_max)
    _fused_refs(quad, has_col, ang, runs, damp, sref, dpart)
    return capped


@njit(**JIT)
def sets_kinematic(quad, x, v, y0, mass, sid, sref, part, idx, tgt, prev, h):
    """Kinematic particles onto their targets; their per-set sums moved to the target."""
    sums = part[0]
    for p in range(idx.shape[0]):
        i = idx[p]
        s = sid[i]
        w = mass[i]
        y_0, y_1, y_2 = y0[i, 0], y0[i, 1], y0[i, 2]
        nphi = 10 if quad else 4
        for a in range(3):
            d = w * (tgt[p, a] - x[i, a])
            sums[s, a * nphi] += d
            sums[s, a * nphi + 1] += d * y_0
            sums[s, a * nphi + 2] += d * y_1
            sums[s, a * nphi + 3] += d * y_2
            if quad:
                sums[s, a * nphi + 4] += d * y_0 * y_0
                sums[s, a * nphi + 5] += d * y_1 * y_1
                sums[s, a * nphi + 6] += d * y_2 * y_2
                sums[s, a * nphi + 7] += d * y_0 * y_1
                sums[s, a * nphi + 8] += d * y_1 * y_2
                sums[s, a * nphi + 9] += d * y_2 * y_0
        for a in range(3):
            v[i, a] = (tgt[p, a] - prev[p, a]) / h
            x[i, a] = tgt[p, a]
