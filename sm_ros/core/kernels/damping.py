"""Damping towards each cluster's rigid motion (not an equation of the paper).

Velocities move a fraction ``k_damp`` towards v_cm + omega x r of their clusters (averaged
like the goals of Eq. 23), so damping removes deformation and spin-relative motion but
keeps every cluster's linear and angular momentum.
"""

import numpy as np
from numba import njit

from .jit import JIT, JIT_NO_REFCOUNT, U
from .linalg import ZERO16, add_damping, sym3_solve


@njit(**JIT_NO_REFCOUNT)
def _rigid_fields(scratch):
    """Each cluster's rigid velocity field from its sums about a reference point ref_k
    (``scratch`` = (lin, w3, four 3 x 3)).

    In: ``lin[k]`` = [W, sum w v (3), sum w r x v (3), sum w (|r|^2 - r_a^2) (3),
    -sum w r_0 r_1, -sum w r_1 r_2, -sum w r_2 r_0] and ``w3[k]`` = sum w r, r = x - ref_k.
    Out: ``lin[k, 1:4]`` = c_k and ``w3[k]`` = omega_k with the field c_k + omega_k x r.
    """
    lin, w3, m3a, m3b, m3c, m3d = scratch
    nk = lin.shape[0]
    for k in range(nk):
        wk = lin[k, 0]
        for j in range(1, 4):
            lin[k, j] /= wk
        u0, u1, u2 = lin[k, 1], lin[k, 2], lin[k, 3]
        d0, d1, d2 = w3[k, 0] / wk, w3[k, 1] / wk, w3[k, 2] / wk
        # about the centre of mass: L - W d x v_cm, I - W (|d|^2 - d d^T)
        l0 = lin[k, 4] - wk * (d1 * u2 - d2 * u1)
        l1 = lin[k, 5] - wk * (d2 * u0 - d0 * u2)
        l2 = lin[k, 6] - wk * (d0 * u1 - d1 * u0)
        dd = d0 * d0 + d1 * d1 + d2 * d2
        m3a[0, 0] = lin[k, 7] - wk * (dd - d0 * d0)
        m3a[1, 1] = lin[k, 8] - wk * (dd - d1 * d1)
        m3a[2, 2] = lin[k, 9] - wk * (dd - d2 * d2)
        m3a[0, 1] = m3a[1, 0] = lin[k, 10] + wk * d0 * d1
        m3a[1, 2] = m3a[2, 1] = lin[k, 11] + wk * d1 * d2
        m3a[2, 0] = m3a[0, 2] = lin[k, 12] + wk * d2 * d0
        # omega = I^+ L (the adjugate where I is well posed, else the pseudo-inverse)
        o0, o1, o2 = sym3_solve(mat=m3a, b0=l0, b1=l1, b2=l2, rcond=1e-12, wout=m3b, wa=m3c,
                                wv=m3d)
        w3[k, 0] = o0
        w3[k, 1] = o1
        w3[k, 2] = o2
        # rigid field v_cm + omega x (r - d) = (v_cm - omega x d) + omega x r
        lin[k, 1] = u0 - (o1 * d2 - o2 * d1)
        lin[k, 2] = u1 - (o2 * d0 - o0 * d2)
        lin[k, 3] = u2 - (o0 * d1 - o1 * d0)


# ---------------------------------------------------------------------------------------
# Damping fused into the step.  The sums damping needs
# are per-set sums of the state, accumulated in the integration pass of the previous step
# (``damp_acc_range``, block by block while the block is in L1).  Row ``dpart[chunk, s]``:
#   [sum m d (3), sum m v (3), sum m d x v (3), sum m d d^T (6: xx yy zz xy yz zx),
#    p (3), has p, sum m]
# with d = x - p about the position p of the first particle of the set that the chunk
# met after it moved: every reference stays inside the body, so the second moments keep
# their precision however far and fast the body flies (sums about last step's centre
# would lose it all to cancellation at 1e10 m/s).  Each cluster's sums about one point of
# its own follow by the parallel axis rules (``damping_fields``), its rigid field by
# ``_rigid_fields``, and each set's mean target velocity c_s + omega_s x (x - r_s) by
# ``damping_targets``: the particle pass then damps with 9 multiply-adds per particle.
# ---------------------------------------------------------------------------------------

#: Entries of a per-set damping row (see above).
NDAMP = 20


@njit(inline='always', **JIT)
def damp_velocity(v, i, r0, r1, r2, dmp, s, k_damp):
    """v_i moves the fraction ``k_damp`` towards its set's field c_s + omega_s x r (r = x -
    r_s, before the step), inlined into the particle pass."""
    damp_towards(v=v, i=i, r=(r0, r1, r2),
                 field=(dmp[s, 0], dmp[s, 1], dmp[s, 2], dmp[s, 3], dmp[s, 4], dmp[s, 5]),
                 k_damp=k_damp)


@njit(inline='always', **JIT)
def damp_towards(v, i, r, field, k_damp):
    """``damp_velocity`` with the field c + omega x r in scalars (``field``: c0 c1 c2 o0 o1
    o2, held in registers by the loops that vectorise: an array read in the loop may alias
    v and costs a memory check)."""
    r0, r1, r2 = r
    c0, c1, c2, o0, o1, o2 = field
    v[i, 0] += k_damp * (c0 + o1 * r2 - o2 * r1 - v[i, 0])
    v[i, 1] += k_damp * (c1 + o2 * r0 - o0 * r2 - v[i, 1])
    v[i, 2] += k_damp * (c2 + o0 * r1 - o1 * r0 - v[i, 2])


@njit(inline='always', **JIT)
def damp_sums_range(lo, hi, x, v, mass, k0, k1, k2):
    """The damping sums of particles lo..hi about the point k in the order of a row of
    ``NDAMP`` (``linalg.add_damping``'s: sum w d, sum w v, sum w d x v, the six second
    moments of d = x - k, rows 0-14), then their mass sum (row 19), w = ``mass``.
    Vectorises across particles (unit-stride columns of x, v, unsigned index: one lane a
    particle, a vector accumulator a sum).  Inlined by Numba into ``damp_acc_range``."""
    sums = ZERO16
    for k in range(U(lo), U(hi)):
        sums = add_damping(sums, mass[k], x[k, 0] - k0, x[k, 1] - k1, x[k, 2] - k2,
                           v[k, 0], v[k, 1], v[k, 2])
    return sums


@njit(**JIT_NO_REFCOUNT)
def damp_acc_range(start, end, x, v, mass, sid, dsums):
    """Rows ``dsums[s]`` += the particles start..end (``sid`` empty: all in set 0).

    One run of a set at a time, its sums about the set's row point (the first particle
    met) taken by ``damp_sums_range`` (in registers, vectorised across the particles of
    the run), so a one-cluster body (one run) pays little for it; short runs (set-layout
    bodies whose particle order jumps between sets) fall back to the scalar remainder loop.
    """
    single = sid.shape[0] == 0
    i = start
    while i < end:
        s = 0 if single else sid[i]
        row = dsums[s]
        if row[18] == 0.0:
            row[15] = x[i, 0]
            row[16] = x[i, 1]
            row[17] = x[i, 2]
            row[18] = 1.0
        r0, r1, r2 = row[15], row[16], row[17]
        j = end
        if not single:
            j = i + 1
            while j < end and sid[j] == s:
                j += 1
        t = damp_sums_range(i, j, x, v, mass, r0, r1, r2)
        for k in range(15):
            row[k] += t[k]
        row[19] += t[15]
        i = j


@njit(**JIT_NO_REFCOUNT)
def damp_accumulate(x, v, mass, sid, dpart):
    """The damping rows of the current state (changed outside a step) into chunk 0."""
    for c in range(dpart.shape[0]):
        for s in range(dpart.shape[1]):
            for j in range(NDAMP):
                dpart[c, s, j] = 0.0
    # start as int64, not the literal 0: the specialisation the particle passes call
    damp_acc_range(start=np.int64(0), end=x.shape[0], x=x, v=v, mass=mass, sid=sid,
                   dsums=dpart[0])


@njit(**JIT_NO_REFCOUNT)
def damp_kinematic(x, v, mass, sid, dpart, idx, sign):
    """Add (``sign`` 1) or remove (-1) the kinematic particles ``idx`` from chunk 0's rows."""
    single = sid.shape[0] == 0
    for p in range(idx.shape[0]):
        i = idx[p]
        s = 0 if single else sid[i]
        row = dpart[0, s]
        if row[18] == 0.0:
            row[15] = x[i, 0]
            row[16] = x[i, 1]
            row[17] = x[i, 2]
            row[18] = 1.0
        w = sign * mass[i]
        d0 = x[i, 0] - row[15]
        d1 = x[i, 1] - row[16]
        d2 = x[i, 2] - row[17]
        u0 = w * v[i, 0]
        u1 = w * v[i, 1]
        u2 = w * v[i, 2]
        row[0] += w * d0
        row[1] += w * d1
        row[2] += w * d2
        row[3] += u0
        row[4] += u1
        row[5] += u2
        row[6] += d1 * u2 - d2 * u1
        row[7] += d2 * u0 - d0 * u2
        row[8] += d0 * u1 - d1 * u0
        row[9] += w * d0 * d0
        row[10] += w * d1 * d1
        row[11] += w * d2 * d2
        row[12] += w * d0 * d1
        row[13] += w * d1 * d2
        row[14] += w * d2 * d0
        row[19] += w


@njit(inline='always', **JIT)
def _shift(acc, row, t0, t1, t2):
    """acc += ``row``'s sums moved to a reference ``t`` nearer (d -> d + t)."""
    ms = row[19]
    a0, a1, a2 = row[0], row[1], row[2]
    b0, b1, b2 = row[3], row[4], row[5]
    acc[0] += a0 + ms * t0
    acc[1] += a1 + ms * t1
    acc[2] += a2 + ms * t2
    acc[3] += b0
    acc[4] += b1
    acc[5] += b2
    acc[6] += row[6] + t1 * b2 - t2 * b1
    acc[7] += row[7] + t2 * b0 - t0 * b2
    acc[8] += row[8] + t0 * b1 - t1 * b0
    acc[9] += row[9] + 2.0 * t0 * a0 + ms * t0 * t0
    acc[10] += row[10] + 2.0 * t1 * a1 + ms * t1 * t1
    acc[11] += row[11] + 2.0 * t2 * a2 + ms * t2 * t2
    acc[12] += row[12] + t0 * a1 + a0 * t1 + ms * t0 * t1
    acc[13] += row[13] + t1 * a2 + a1 * t2 + ms * t1 * t2
    acc[14] += row[14] + t2 * a0 + a2 * t0 + ms * t2 * t0
    acc[19] += ms


@njit(**JIT_NO_REFCOUNT)
def damping_fields(dpart, set_clusters, dref, acc, scratch):
    """Every cluster's rigid field (``lin[k, 1:4]`` = c_k, ``w3[k]`` = omega_k, ``scratch``
    = (lin, w3, four 3 x 3)) about a point ``dref[k]`` inside it, from the damping rows of
    the last pass.

    The chunks' rows of a set are moved to one reference p_s; cluster k weighs a particle
    of set s by m / n_s (``set_clusters`` = (sptr, scl, scnt): the clusters of each set,
    n_s = ``scnt[s]`` of them) and takes its sums about the reference of its first set.
    ``acc`` (NDAMP,) is scratch.
    """
    sptr, scl, scnt = set_clusters
    lin, w3 = scratch[0], scratch[1]
    nk = lin.shape[0]
    for k in range(nk):
        for j in range(13):
            lin[k, j] = 0.0
        for j in range(3):
            w3[k, j] = 0.0
            dref[k, j] = 0.0
        lin[k, 0] = -1.0                       # no reference yet
    for s in range(dpart.shape[1]):
        for j in range(NDAMP):
            acc[j] = 0.0
        have = False
        for c in range(dpart.shape[0]):
            row = dpart[c, s]
            if row[18] == 0.0:
                continue
            if not have:
                acc[15], acc[16], acc[17] = row[15], row[16], row[17]
                have = True
            _shift(acc, row, row[15] - acc[15], row[16] - acc[16], row[17] - acc[17])
        if not have:
            continue
        inv_n = 1.0 / scnt[s]
        for j in range(sptr[s], sptr[s + 1]):
            k = scl[j]
            if lin[k, 0] < 0.0:
                lin[k, 0] = 0.0
                dref[k, 0], dref[k, 1], dref[k, 2] = acc[15], acc[16], acc[17]
            t0 = acc[15] - dref[k, 0]
            t1 = acc[16] - dref[k, 1]
            t2 = acc[17] - dref[k, 2]
            ms = acc[19]
            a0, a1, a2 = acc[0], acc[1], acc[2]
            b0, b1, b2 = acc[3], acc[4], acc[5]
            # second moments of r = d + t about dref[k]
            r00 = acc[9] + 2.0 * t0 * a0 + ms * t0 * t0
            r11 = acc[10] + 2.0 * t1 * a1 + ms * t1 * t1
            r22 = acc[11] + 2.0 * t2 * a2 + ms * t2 * t2
            r01 = acc[12] + t0 * a1 + a0 * t1 + ms * t0 * t1
            r12 = acc[13] + t1 * a2 + a1 * t2 + ms * t1 * t2
            r20 = acc[14] + t2 * a0 + a2 * t0 + ms * t2 * t0
            lin[k, 0] += inv_n * ms
            lin[k, 1] += inv_n * b0
            lin[k, 2] += inv_n * b1
            lin[k, 3] += inv_n * b2
            w3[k, 0] += inv_n * (a0 + ms * t0)
            w3[k, 1] += inv_n * (a1 + ms * t1)
            w3[k, 2] += inv_n * (a2 + ms * t2)
            lin[k, 4] += inv_n * (acc[6] + t1 * b2 - t2 * b1)
            lin[k, 5] += inv_n * (acc[7] + t2 * b0 - t0 * b2)
            lin[k, 6] += inv_n * (acc[8] + t0 * b1 - t1 * b0)
            lin[k, 7] += inv_n * (r11 + r22)
            lin[k, 8] += inv_n * (r00 + r22)
            lin[k, 9] += inv_n * (r00 + r11)
            lin[k, 10] -= inv_n * r01
            lin[k, 11] -= inv_n * r12
            lin[k, 12] -= inv_n * r20
    _rigid_fields(scratch)


@njit(**JIT_NO_REFCOUNT)
def damping_targets(sptr, scl, scnt, lin, w3, dref, sref, dmp):
    """Per set: the mean of its clusters' rigid fields as ``dmp[s]`` = [c_s, omega_s], the
    field c_s + omega_s x (x - sref[s]); the clusters' fields are about ``dref[k]``."""
    for s in range(dmp.shape[0]):
        c0 = c1 = c2 = o0 = o1 = o2 = 0.0
        for j in range(sptr[s], sptr[s + 1]):
            k = scl[j]
            t0 = sref[s, 0] - dref[k, 0]
            t1 = sref[s, 1] - dref[k, 1]
            t2 = sref[s, 2] - dref[k, 2]
            w0, w1, w2 = w3[k, 0], w3[k, 1], w3[k, 2]
            c0 += lin[k, 1] + w1 * t2 - w2 * t1
            c1 += lin[k, 2] + w2 * t0 - w0 * t2
            c2 += lin[k, 3] + w0 * t1 - w1 * t0
            o0 += w0
            o1 += w1
            o2 += w2
        inv_n = 1.0 / scnt[s]
        dmp[s, 0] = c0 * inv_n
        dmp[s, 1] = c1 * inv_n
        dmp[s, 2] = c2 * inv_n
        dmp[s, 3] = o0 * inv_n
        dmp[s, 4] = o1 * inv_n
        dmp[s, 5] = o2 * inv_n
