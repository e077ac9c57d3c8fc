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
"""

from numba import njit, prange

from .jit import JIT, U
from .colliders import _collide_range
from .damping import damp_acc_range, damp_towards, damp_velocity
from .integrate import BLOCK, advance


@njit(**JIT)
def _feature_map(rest_lin, rest_off, k, o0, o1, o2, quad, pm):
    """Cluster k's features in set coordinates: q~ = P phi(y) with P into ``pm`` (9 x 10).

    q-hat = G_k (y + o) + h_k = G_k y + b; the quadratic rows expand q-hat_a q-hat_c.
    """
    for a in range(3):
        pm[a, 0] = (rest_lin[k, a, 0] * o0 + rest_lin[k, a, 1] * o1 + rest_lin[k, a, 2] * o2
                    + rest_off[k, a])
        pm[a, 1] = rest_lin[k, a, 0]
        pm[a, 2] = rest_lin[k, a, 1]
        pm[a, 3] = rest_lin[k, a, 2]
    if not quad:
        return
    for a in range(3):
        for fi in range(4, 10):
            pm[a, fi] = 0.0
    for r in range(6):
        a = r if r < 3 else r - 3                  # features 3..8: q0^2, q1^2, q2^2,
        c = r if r < 3 else (r - 2) % 3            # q0 q1, q1 q2, q2 q0
        ba = pm[a, 0]
        bc = pm[c, 0]
        row = 3 + r
        pm[row, 0] = ba * bc
        for j in range(3):
            pm[row, 1 + j] = ba * rest_lin[k, c, j] + bc * rest_lin[k, a, j]
            pm[row, 4 + j] = rest_lin[k, a, j] * rest_lin[k, c, j]
        pm[row, 7] = rest_lin[k, a, 0] * rest_lin[k, c, 1] + rest_lin[k, a, 1] * rest_lin[k, c, 0]
        pm[row, 8] = rest_lin[k, a, 1] * rest_lin[k, c, 2] + rest_lin[k, a, 2] * rest_lin[k, c, 1]
        pm[row, 9] = rest_lin[k, a, 2] * rest_lin[k, c, 0] + rest_lin[k, a, 0] * rest_lin[k, c, 2]


@njit(**JIT)
def sets_reduce(part, sptr, scl, scnt, sphi, sref, sorg, rest_lin, rest_off, ref, quad, out, wk,
                pm):
    """Per-cluster accumulators ``out`` (1, clusters, 12 or 30) from the per-set sums.

    sum_{i in s} w (x - ref_k) phi^T = (U_s + (r_s - ref_k) Phi_s^T) / n_s (w = m / n_s),
    then mapped to cluster k's features by its P.  ``wk`` (2, 3, 10), ``pm`` (9, 10).
    """
    nchunks = part.shape[0]
    ns = part.shape[1]
    nphi = 10 if quad else 4
    nq = 9 if quad else 3
    for k in range(out.shape[1]):
        for a in range(out.shape[2]):
            out[0, k, a] = 0.0
    u = wk[0]
    vb = wk[1]
    for s in range(ns):
        for a in range(3):
            for fi in range(nphi):
                acc = 0.0
                for chunk in range(nchunks):
                    acc += part[chunk, s, a * nphi + fi]
                u[a, fi] = acc
        inv_n = 1.0 / scnt[s]
        for j in range(sptr[s], sptr[s + 1]):
            k = scl[j]
            _feature_map(rest_lin=rest_lin, rest_off=rest_off, k=k, o0=sorg[s, 0], o1=sorg[s, 1],
                         o2=sorg[s, 2], quad=quad, pm=pm)
            for a in range(3):
                dr = sref[s, a] - ref[k, a]
                for fi in range(nphi):
                    vb[a, fi] = inv_n * (u[a, fi] + dr * sphi[s, fi])
                out[0, k, a] += vb[a, 0]
                for jj in range(nq):
                    # P's rows of q-hat itself are affine in y: 4 features, not 10
                    nf = 4 if jj < 3 else nphi
                    acc = 0.0
                    for fi in range(nf):
                        acc += vb[a, fi] * pm[jj, fi]
                    out[0, k, 3 + a * nq + jj] += acc


@njit(**JIT)
def sets_maps(sptr, scl, scnt, sorg, rest_lin, rest_off, trans, goal_lin, goal_off, ref, quad, gm,
              sref, pm):
    """Goal maps ``gm`` (sets, 3, 10): mean over the set's clusters of each goal polynomial.

    Also ``sref`` <- mean of the set's cluster centres (the reference point of the per-set
    sums of the next step).
    """
    ns = gm.shape[0]
    nphi = 10 if quad else 4
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
                # goal_k = T_k q~ + goal_off_k = (T_k P) phi + goal_off_k
                _feature_map(rest_lin=rest_lin, rest_off=rest_off, k=k, o0=o0, o1=o1, o2=o2,
                             quad=True, pm=pm)
                for a in range(3):
                    for fi in range(10):
                        acc = 0.0
                        # the quadratic features (fi >= 4) come from P's rows 3-8 only
                        for jj in range(0 if fi < 4 else 3, 9):
                            acc += trans[k, a, jj] * pm[jj, fi]
                        gm[s, a, fi] += acc
                    gm[s, a, 0] += goal_off[k, a]
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


@njit(**JIT)
def _sets_int_lin(start, end, x, v, y0, sid, gm, alpha_h, h, ax, ay, az, w0, w1, w2, damp,
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
        j = i + 1
        while j < end and sid[j] == s:
            j += 1
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
def _sets_int_quad(start, end, x, v, y0, sid, gm, alpha_h, h, ax, ay, az, w0, w1, w2, damp,
                   k_damp, dmp, sref):
    """Quadratic goals: gm[s] (3 x 10) times phi(y); damping as in ``_sets_int_lin``."""
    err2 = 0.0
    for i in range(start, end):
        s = sid[i]
        y_0, y_1, y_2 = y0[i, 0], y0[i, 1], y0[i, 2]
        f4 = y_0 * y_0
        f5 = y_1 * y_1
        f6 = y_2 * y_2
        f7 = y_0 * y_1
        f8 = y_1 * y_2
        f9 = y_2 * y_0
        g0 = (gm[s, 0, 0] + gm[s, 0, 1] * y_0 + gm[s, 0, 2] * y_1 + gm[s, 0, 3] * y_2
              + gm[s, 0, 4] * f4 + gm[s, 0, 5] * f5 + gm[s, 0, 6] * f6 + gm[s, 0, 7] * f7
              + gm[s, 0, 8] * f8 + gm[s, 0, 9] * f9)
        g1 = (gm[s, 1, 0] + gm[s, 1, 1] * y_0 + gm[s, 1, 2] * y_1 + gm[s, 1, 3] * y_2
              + gm[s, 1, 4] * f4 + gm[s, 1, 5] * f5 + gm[s, 1, 6] * f6 + gm[s, 1, 7] * f7
              + gm[s, 1, 8] * f8 + gm[s, 1, 9] * f9)
        g2 = (gm[s, 2, 0] + gm[s, 2, 1] * y_0 + gm[s, 2, 2] * y_1 + gm[s, 2, 3] * y_2
              + gm[s, 2, 4] * f4 + gm[s, 2, 5] * f5 + gm[s, 2, 6] * f6 + gm[s, 2, 7] * f7
              + gm[s, 2, 8] * f8 + gm[s, 2, 9] * f9)
        p0, p1, p2 = x[i, 0], x[i, 1], x[i, 2]
        if damp:
            damp_velocity(v=v, i=i, r0=p0 - sref[s, 0], r1=p1 - sref[s, 1], r2=p2 - sref[s, 2],
                          dmp=dmp, s=s, k_damp=k_damp)
        err2 += advance(x=x, v=v, i=i, p0=p0, p1=p1, p2=p2, g0=g0, g1=g1, g2=g2, alpha_h=alpha_h,
                        h=h, dv0=h * (ax + w1 * p2 - w2 * p1), dv1=h * (ay + w2 * p0 - w0 * p2),
                        dv2=h * (az + w0 * p1 - w1 * p0))
    return err2


@njit(**JIT)
def _sets_int_range(start, end, quad, x, v, y0, sid, gm, alpha, h, acc, ang, com, damp, k_damp,
                    dmp, sref):
    """Eq. 13-14 for particles start..end with the set goal maps; returns sum |g - x|^2."""
    w0, w1, w2 = ang[0], ang[1], ang[2]
    # acc + ang x (p - com) = (acc - ang x com) + ang x p
    ax = acc[0] - (w1 * com[2] - w2 * com[1])
    ay = acc[1] - (w2 * com[0] - w0 * com[2])
    az = acc[2] - (w0 * com[1] - w1 * com[0])
    if quad:
        return _sets_int_quad(start=start, end=end, x=x, v=v, y0=y0, sid=sid, gm=gm,
                              alpha_h=alpha / h, h=h, ax=ax, ay=ay, az=az, w0=w0, w1=w1, w2=w2,
                              damp=damp, k_damp=k_damp, dmp=dmp, sref=sref)
    return _sets_int_lin(start=start, end=end, x=x, v=v, y0=y0, sid=sid, gm=gm, alpha_h=alpha / h,
                         h=h, ax=ax, ay=ay, az=az, w0=w0, w1=w1, w2=w2, damp=damp,
                         k_damp=k_damp, dmp=dmp, sref=sref)


@njit(**JIT)
def _sets_acc_lin(start, end, x, y0, mass, sid, sref, sums):
    """U_s += m (x - r_s) [1, y]^T for particles start..end, runs of one set in registers."""
    i = start
    while i < end:
        s = sid[i]
        r0, r1, r2 = sref[s, 0], sref[s, 1], sref[s, 2]
        a00 = a01 = a02 = a03 = 0.0
        a10 = a11 = a12 = a13 = 0.0
        a20 = a21 = a22 = a23 = 0.0
        j = i + 1
        while j < end and sid[j] == s:
            j += 1
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
def _sets_acc_range(start, end, quad, x, y0, mass, sid, sref, sums):
    if quad:
        _sets_acc_quad(start=start, end=end, x=x, y0=y0, mass=mass, sid=sid, sref=sref, sums=sums)
    else:
        _sets_acc_lin(start=start, end=end, x=x, y0=y0, mass=mass, sid=sid, sref=sref, sums=sums)


@njit(**JIT)
def _sets_acc_chunk(chunk, nchunks, quad, x, y0, mass, sid, sref, part):
    n = x.shape[0]
    sums = part[chunk]
    for s in range(sums.shape[0]):
        for j in range(sums.shape[1]):
            sums[s, j] = 0.0
    _sets_acc_range(start=(chunk * n) // nchunks, end=((chunk + 1) * n) // nchunks, quad=quad, x=x,
                    y0=y0, mass=mass, sid=sid, sref=sref, sums=sums)


@njit(**JIT)
def sets_accumulate_serial(quad, x, y0, mass, sid, sref, part):
    """Per-set sums of the current state (when it was changed outside a step), one thread."""
    nchunks = part.shape[0]
    for chunk in range(nchunks):
        _sets_acc_chunk(chunk=chunk, nchunks=nchunks, quad=quad, x=x, y0=y0, mass=mass, sid=sid,
                        sref=sref, part=part)


@njit(parallel=True, **JIT)
def sets_accumulate_parallel(quad, x, y0, mass, sid, sref, part):
    """Per-set sums of the current state, one chunk per thread."""
    nchunks = part.shape[0]
    for chunk in prange(nchunks):
        _sets_acc_chunk(chunk=chunk, nchunks=nchunks, quad=quad, x=x, y0=y0, mass=mass, sid=sid,
                        sref=sref, part=part)


@njit(**JIT)
def _sets_int_chunk(chunk, nchunks, quad, x, v, y0, mass, sid, gm, sref, alpha, h, acc, ang, com,
                    part, err, has_col, ground, boxes, spheres, thresh, damp, k_damp, dmp, dpart):
    """Damp, integrate, collide and accumulate a chunk block by block (one pass over
    memory); ``dpart[chunk]`` receives the damping sums of the next step."""
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
    for bs in range(start, end, BLOCK):
        be = min(bs + BLOCK, end)
        err2 += _sets_int_range(start=bs, end=be, quad=quad, x=x, v=v, y0=y0, sid=sid, gm=gm,
                                alpha=alpha, h=h, acc=acc, ang=ang, com=com, damp=damp,
                                k_damp=k_damp, dmp=dmp, sref=sref)
        if has_col:
            _collide_range(start=bs, end=be, x=x, v=v, ground=ground, boxes=boxes, spheres=spheres,
                           thresh=thresh)
        _sets_acc_range(start=bs, end=be, quad=quad, x=x, y0=y0, mass=mass, sid=sid, sref=sref,
                        sums=sums)
        if damp:
            damp_acc_range(start=bs, end=be, x=x, v=v, mass=mass, sid=sid, dsums=dpart[chunk])
    err[chunk] = err2


@njit(**JIT)
def sets_integrate_serial(quad, x, v, y0, mass, sid, gm, sref, alpha, h, acc, ang, com, part, err,
                          has_col, ground, boxes, spheres, thresh, damp, k_damp, dmp, dpart):
    """Fused step pass of a set-layout body, one thread."""
    nchunks = part.shape[0]
    for chunk in range(nchunks):
        _sets_int_chunk(chunk=chunk, nchunks=nchunks, quad=quad, x=x, v=v, y0=y0, mass=mass,
                        sid=sid, gm=gm, sref=sref, alpha=alpha, h=h, acc=acc, ang=ang, com=com,
                        part=part, err=err, has_col=has_col, ground=ground, boxes=boxes,
                        spheres=spheres, thresh=thresh, damp=damp, k_damp=k_damp, dmp=dmp,
                        dpart=dpart)


@njit(parallel=True, **JIT)
def sets_integrate_parallel(quad, x, v, y0, mass, sid, gm, sref, alpha, h, acc, ang, com, part,
                            err, has_col, ground, boxes, spheres, thresh, damp, k_damp, dmp,
                            dpart):
    """Fused step pass of a set-layout body, one chunk per thread."""
    nchunks = part.shape[0]
    for chunk in prange(nchunks):
        _sets_int_chunk(chunk=chunk, nchunks=nchunks, quad=quad, x=x, v=v, y0=y0, mass=mass,
                        sid=sid, gm=gm, sref=sref, alpha=alpha, h=h, acc=acc, ang=ang, com=com,
                        part=part, err=err, has_col=has_col, ground=ground, boxes=boxes,
                        spheres=spheres, thresh=thresh, damp=damp, k_damp=k_damp, dmp=dmp,
                        dpart=dpart)


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
