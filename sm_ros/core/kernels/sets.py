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
one-cluster pass ``fused._fused_range``): each particle read and written once, its
set's sums and damping sums taken in the same loop, all about one point per set; the
static colliders and the speed cap after the loop: the ground's projection corrects the
run's sums for what it moved, a run the cap or a box or sphere moved is summed again.
Every pass takes the runs' ends from ``runs`` (precomputed at build, ``first_run``) and
caps the speeds block by block before it sums the block, so the sums stay valid.
"""

from collections import namedtuple

import numpy as np
from numba import njit

from .jit import JIT, JIT_NO_REFCOUNT, U, claim_next
from .colliders import _collide_range, ground_height, ground_range_sums
from .damping import damp_acc_range, damp_kinematic, damp_towards
from .fused import _fused_range, damp_constants, damp_sums_uniform
from .integrate import BLOCK, _rest_sums, _zero_chunk, advance
from .limits import limit_speed_range
from .sets_sums import _add_row, _sets_acc_damp_lin, _sets_acc_range, first_run

#: A set-layout body's sets: each particle's set (``sid``), the ends of its runs of one set
#: (``runs``), each set's goal map (3 x 4 or 3 x 10, ``goal_maps``) and the point its sums
#: are taken about (``ref``), and the mass of every particle when all are alike
#: (``uniform_mass``; 0 when not: the one-loop pass sums unweighted).  The particles come
#: as ``integrate.BodyParticles`` with the set offsets y in place of x0.
Sets = namedtuple('Sets', 'sid runs goal_maps ref uniform_mass')
#: The step's motion: alpha, h, the acceleration ``acc`` and the angular one ``ang`` about
#: ``com``, and the speed cap ``v_max`` (0: none).
SetMotion = namedtuple('SetMotion', 'alpha h acc ang com v_max')


@njit(**JIT_NO_REFCOUNT)
def _sets_int_lin(start, end, particles, sets, alpha_h, h, accel, spin, damping):
    """Rigid/linear goals: each run of one set with its 3 x 4 map in registers.

    ``accel`` is the uniform acceleration (acc - ang x com), ``spin`` the angular one;
    with ``damping.on`` the velocities are first damped towards its field
    (``damp_velocity``).
    The loop over a run vectorises (module docstring): the set's map, reference and
    damping field in locals, the torque and damping branches outside it.
    """
    x, v, y0, sid, runs, gm, sref = _unpack(particles, sets)
    damp, k_damp, dmp = damping.on, damping.rate, damping.field
    ax, ay, az = accel
    w0, w1, w2 = spin
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
        field = (c0, c1, c2, o0, o1, o2)
        r += 1
        j = min(runs[r], end)                  # the run's end (``_SetLayout.runs``)
        if damp and not torque:
            for k in range(U(i), U(j)):
                y_0, y_1, y_2 = y0[k, 0], y0[k, 1], y0[k, 2]
                p0, p1, p2 = x[k, 0], x[k, 1], x[k, 2]
                damp_towards(v=v, i=k, r=(p0 - r0c, p1 - r1c, p2 - r2c),
                             field=field, k_damp=k_damp)
                err2 += advance(x=x, v=v, i=k, p=(p0, p1, p2),
                                g=(m00 + m01 * y_0 + m02 * y_1 + m03 * y_2,
                                   m10 + m11 * y_0 + m12 * y_1 + m13 * y_2,
                                   m20 + m21 * y_0 + m22 * y_1 + m23 * y_2),
                                alpha_h=alpha_h, h=h, dv=(hx, hy, hz))
        elif not torque:
            for k in range(U(i), U(j)):
                y_0, y_1, y_2 = y0[k, 0], y0[k, 1], y0[k, 2]
                p0, p1, p2 = x[k, 0], x[k, 1], x[k, 2]
                err2 += advance(x=x, v=v, i=k, p=(p0, p1, p2),
                                g=(m00 + m01 * y_0 + m02 * y_1 + m03 * y_2,
                                   m10 + m11 * y_0 + m12 * y_1 + m13 * y_2,
                                   m20 + m21 * y_0 + m22 * y_1 + m23 * y_2),
                                alpha_h=alpha_h, h=h, dv=(hx, hy, hz))
        else:
            for k in range(U(i), U(j)):
                y_0, y_1, y_2 = y0[k, 0], y0[k, 1], y0[k, 2]
                p0, p1, p2 = x[k, 0], x[k, 1], x[k, 2]
                if damp:
                    damp_towards(v=v, i=k, r=(p0 - r0c, p1 - r1c, p2 - r2c), field=field,
                                 k_damp=k_damp)
                err2 += advance(x=x, v=v, i=k, p=(p0, p1, p2),
                                g=(m00 + m01 * y_0 + m02 * y_1 + m03 * y_2,
                                   m10 + m11 * y_0 + m12 * y_1 + m13 * y_2,
                                   m20 + m21 * y_0 + m22 * y_1 + m23 * y_2),
                                alpha_h=alpha_h, h=h,
                                dv=(h * (ax + w1 * p2 - w2 * p1),
                                    h * (ay + w2 * p0 - w0 * p2),
                                    h * (az + w0 * p1 - w1 * p0)))
        i = j
    return err2


@njit(**JIT_NO_REFCOUNT)
def _sets_int_quad(start, end, particles, sets, alpha_h, h, accel, spin, damping):
    """Quadratic goals: gm[s] (3 x 10) times phi(y); damping as in ``_sets_int_lin``.

    Run by run like ``_sets_int_lin``: the set's map, reference and damping field are read
    into locals once a run, so the particle loop reads only x, v, y0 (with the map read
    from ``gm`` in the loop, every store to v could alias it: the damped loop reloaded the
    30 coefficients after each store and cost three times the undamped one).
    """
    x, v, y0, sid, runs, gm, sref = _unpack(particles, sets)
    damp, k_damp, dmp = damping.on, damping.rate, damping.field
    ax, ay, az = accel
    w0, w1, w2 = spin
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
        field = (c0, c1, c2, o0, o1, o2)
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
                damp_towards(v=v, i=k, r=(p0 - r0c, p1 - r1c, p2 - r2c),
                             field=field, k_damp=k_damp)
            err2 += advance(x=x, v=v, i=k, p=(p0, p1, p2), g=(g0, g1, g2), alpha_h=alpha_h, h=h,
                            dv=(h * (ax + w1 * p2 - w2 * p1),
                                h * (ay + w2 * p0 - w0 * p2),
                                h * (az + w0 * p1 - w1 * p0)))
        i = j
    return err2


@njit(inline='always', **JIT)
def _unpack(particles, sets):
    """The arrays the set passes read: x, v, y0, sid, runs, goal maps, references."""
    return (particles.x, particles.v, particles.x0, sets.sid, sets.runs, sets.goal_maps,
            sets.ref)


@njit(**JIT_NO_REFCOUNT)
def _sets_int_range(start, end, quad, particles, sets, motion, damping):
    """Eq. 13-14 for particles start..end with the set goal maps; returns sum |g - x|^2."""
    acc, ang, com, h = motion.acc, motion.ang, motion.com, motion.h
    w0, w1, w2 = ang[0], ang[1], ang[2]
    # acc + ang x (p - com) = (acc - ang x com) + ang x p
    ax = acc[0] - (w1 * com[2] - w2 * com[1])
    ay = acc[1] - (w2 * com[0] - w0 * com[2])
    az = acc[2] - (w0 * com[1] - w1 * com[0])
    if quad:
        return _sets_int_quad(start, end, particles, sets, motion.alpha / h, h, (ax, ay, az),
                              (w0, w1, w2), damping)
    return _sets_int_lin(start, end, particles, sets, motion.alpha / h, h, (ax, ay, az),
                         (w0, w1, w2), damping)


#: Particles a run of one set must hold on average for a body's pass to take
#: ``_sets_fused_lin``: each run has a fixed cost (the vector loops' setup, reductions and
#: remainders, the sums written out), a loss on short runs, where the two-loop pass finds
#: and sums the runs particle by particle.
FUSED_MIN_RUN = 32
#: Particles per block of ``_sets_fused_lin``: each block adds a segment to the runs (as
#: costly as a run), and a damped run is read twice, the second time from L2 either way (1024
#: particles' x and v alone fill L1); ``bench scaling --modes linear --clusters 2`` compares
#: block sizes.
FUSED_SETS_BLOCK = 4096


@njit(**JIT_NO_REFCOUNT)
def _sets_fused_lin(start, end, particles, sets, motion, damping, sums, dsums, col):
    """The whole pass of particles start..end of a rigid/linear set-layout body without
    torque, run by run (``fused._fused_range``: one loop reads and writes each particle
    once): the damping towards the set's field, Eq. 13-14 with the set's map, the count of
    speeds over ``v_max``, and the set's 12 sums of the new state; then the static
    colliders on the run (``colliders._collide_range``: a run no collider can reach costs
    one bounds pass) and the speed cap (``limits.limit_speed_range``, only where a speed
    was over it), in the order of the two-loop pass; the ground alone corrects the run's
    sums for the particles it projected (``colliders.ground_range_sums``), a run the cap
    or a box or sphere moved is summed again (``integrate._rest_sums``), so the step leaves
    sums of the final state.  Damped, the loop also takes the run's 12 damping sums and W
    (a moved run: ``fused.damp_sums_uniform``, while it is in cache).  Returns (sum of
    |g - x|^2, capped speeds).  ``col``: the colliders (``colliders.Colliders``); ``sums``,
    ``dsums``: the chunk's set sums and damping sums.

    The sums of a set are taken about one point P_s, its shape sums and damping sums alike
    (so the damping row's sum w d and W are the shape sums' own: 12 damping accumulators,
    not 16): undamped the set's reference ``sref[s]``; damped where the set goes, sref +
    h (c_s + h acc) with c_s the damping field's velocity at sref, so that the second
    moments of a body far out at huge speed do not lose it to rounding (as ``packed``).
    The damping row holds P_s (its entries 15-17); ``sets_integrate_*`` makes it the
    set's reference for the next step's ``sets_reduce``.
    """
    x, v, y0, sid, runs, gm, sref = _unpack(particles, sets)
    mass, wuni, v_max, h = particles.mass, sets.uniform_mass, motion.v_max, motion.h
    damp, k_damp, dmp = damping.on, damping.rate, damping.field
    alpha_h = motion.alpha / h
    hx, hy, hz = h * motion.acc[0], h * motion.acc[1], h * motion.acc[2]
    lim2 = v_max * v_max if v_max > 0.0 else np.inf
    ground_only = col.boxes.shape[0] == 0 and col.spheres.shape[0] == 0
    gz = ground_height(col)                  # -inf without a ground: nothing below
    err2, capped = 0.0, 0
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
        field = damp_constants(damp, k_damp, (dmp[s_d, 0], dmp[s_d, 1], dmp[s_d, 2],
                                              dmp[s_d, 3], dmp[s_d, 4], dmp[s_d, 5]),
                               (r0, r1, r2))
        if damp:
            r0 += h * (dmp[s, 0] + hx)
            r1 += h * (dmp[s, 1] + hy)
            r2 += h * (dmp[s, 2] + hz)
        t = _fused_range(i, j, (x, v, y0), wuni, gmap, damp, field, (alpha_h, h, hx, hy, hz),
                         (r0, r1, r2), (lim2, gz))
        err2 += t[0]
        ss = t[2:14]                   # the run's 12 shape sums: sum w d, sum w d y0^T
        dsum = t[15:]                  # and damping sums (damped)
        # a ground alone: only a run with a height below it can be moved (the loop counts
        # them): projected without the bounds pass, its sums corrected for what the
        # projection moved (``ground_range_sums``); the others skip the colliders
        moved = False
        if col.on and not ground_only:
            moved = _collide_range(i, j, x, v, col)
        elif t[14] > 0:
            g = ground_range_sums(i, j, x, v, y0, wuni, col, (r0, r1, r2), damp)
            ss, dsum = _with_ground(ss, dsum, g)
        # the loop counted the speeds before the colliders: a static collider never speeds
        # a particle up (``colliders.contact_velocity``: restitution <= 1, friction only
        # slows), so a run with none over the cap has none after them either
        if t[1] > 0:
            capped += limit_speed_range(i, j, x, v, h, v_max)
            moved = True
        if moved:
            ss = _rest_sums(i, j, x, y0, mass, r0, r1, r2)
            if damp:
                dsum = damp_sums_uniform(i, j, x, v, wuni, r0, r1, r2)
        # the set sums' layout: per row of d, [sum w d, sum w d y^T]
        _add_row(sums, s, (ss[0], ss[3], ss[4], ss[5], ss[1], ss[6], ss[7], ss[8], ss[2],
                           ss[9], ss[10], ss[11]))
        if damp:
            _add_damp_row(dsums[s], (r0, r1, r2), ss, dsum)
        i = j
    return err2, capped


@njit(inline='always', **JIT)
def _with_ground(ss, dsum, g):
    """A run's shape sums ``ss`` and damping sums ``dsum`` with what the ground's projection
    changed in them (``colliders.ground_range_sums``' ``g``)."""
    return ((ss[0], ss[1], ss[2] + g[0], ss[3], ss[4], ss[5], ss[6], ss[7], ss[8],
             ss[9] + g[1], ss[10] + g[2], ss[11] + g[3]),
            (dsum[0] + g[4], dsum[1] + g[5], dsum[2] + g[6], dsum[3] + g[7], dsum[4] + g[8],
             dsum[5] + g[9], dsum[6] + g[10], dsum[7] + g[11], dsum[8] + g[12],
             dsum[9] + g[13], dsum[10] + g[14], dsum[11] + g[15], dsum[12]))


@njit(inline='always', **JIT)
def _add_damp_row(row, point, ss, dsum):
    """A run's damping sums into its set's damping row (``damping.NDAMP``): the point they
    were taken about, sum w d (the shape sums' ``ss``), the 12 sums and W of ``dsum``."""
    row[15], row[16], row[17] = point
    row[18] = 1.0
    row[0] += ss[0]
    row[1] += ss[1]
    row[2] += ss[2]
    for k in range(12):
        row[3 + k] += dsum[k]
    row[19] += dsum[12]


@njit(inline='always', **JIT)
def _sets_int_chunk(chunk, quad, particles, sets, motion, part, err, col, damping):
    """Damp, integrate, collide, cap the speeds and accumulate a chunk block by block (one
    pass over memory); ``damping.part[chunk]`` receives the damping sums of the next step.
    Returns the capped speeds: the block's speeds are capped (``limits.limit_speed_range``)
    before its sums are taken, so the sums stay valid.  Rigid/linear without torque, long
    runs: ``_sets_fused_lin``."""
    x, v, y0, sid, runs, _, sref = _unpack(particles, sets)
    mass, h, v_max, damp = particles.mass, motion.h, motion.v_max, damping.on
    nchunks = part.shape[0]
    n = x.shape[0]
    start = (chunk * n) // nchunks
    end = ((chunk + 1) * n) // nchunks
    sums = _zero_chunk(part, chunk)
    dsums = _zero_chunk(damping.part, chunk) if damp else damping.part[chunk]
    err2 = 0.0
    capped = 0
    fused = _fused_pass(quad, sets.uniform_mass, motion.ang, runs)
    step = FUSED_SETS_BLOCK if fused else BLOCK
    for bs in range(start, end, step):
        be = min(bs + step, end)
        if fused:
            e, c = _sets_fused_lin(bs, be, particles, sets, motion, damping, sums, dsums, col)
            err2 += e
            capped += c
            continue
        err2 += _sets_int_range(bs, be, quad, particles, sets, motion, damping)
        if col.on:
            _collide_range(bs, be, x, v, col)
        if v_max > 0.0:
            capped += limit_speed_range(bs, be, x, v, h, v_max)
        if damp and not quad:
            _sets_acc_damp_lin(bs, be, particles, sets, sums, dsums)
            continue
        _sets_acc_range(start=bs, end=be, quad=quad, x=x, y0=y0, mass=mass, sid=sid, runs=runs,
                        sref=sref, sums=sums)
        if damp:
            damp_acc_range(start=bs, end=be, x=x, v=v, mass=mass, sid=sid, dsums=dsums)
    err[chunk] = err2
    return capped


@njit(**JIT_NO_REFCOUNT)
def long_runs(runs):
    """Whether the runs (``_SetLayout.runs``) hold ``FUSED_MIN_RUN`` particles or more on
    average: the run test of ``_fused_pass`` (callable from Python: the tests ask it)."""
    return (runs.shape[0] - 1) * FUSED_MIN_RUN <= runs[runs.shape[0] - 1]


@njit(inline='always', **JIT)
def _fused_pass(quad, wuni, ang, runs):
    """Whether a pass takes ``_sets_fused_lin``: rigid/linear, no torque, every particle
    of one mass (``wuni`` > 0: the loop sums unweighted), long runs (``long_runs``)."""
    return (not quad and wuni > 0.0 and ang[0] == 0.0 and ang[1] == 0.0 and ang[2] == 0.0
            and long_runs(runs))


@njit(**JIT_NO_REFCOUNT)
def _fused_refs(quad, wuni, ang, runs, damp, sref, dpart):
    """After a damped ``_sets_fused_lin`` pass: each set's reference becomes the point its
    sums were taken about (the damping row's P_s, alike in every chunk), which the next
    step's ``sets_reduce`` expects."""
    if not (damp and _fused_pass(quad, wuni, ang, runs)):
        return
    for s in range(sref.shape[0]):
        for c in range(dpart.shape[0]):
            row = dpart[c, s]
            if row[18] > 0.0:
                sref[s, 0] = row[15]
                sref[s, 1] = row[16]
                sref[s, 2] = row[17]
                break


@njit(**JIT_NO_REFCOUNT)
def sets_integrate_chunks(claim, capped, quad, particles, sets, motion, part, err, col,
                          damping):
    """Fused step pass of a set-layout body over the chunks this call claims (``claim``, as
    ``sets_sums.sets_accumulate_chunks``); ``capped[chunk]``: the speeds it capped there.  Once
    every chunk is done, ``_fused_refs`` completes the pass."""
    nchunks = part.shape[0]
    while True:
        chunk = claim_next(claim)
        if chunk >= nchunks:
            return
        capped[chunk] = _sets_int_chunk(chunk, quad, particles, sets, motion, part, err, col,
                                        damping)


@njit(**JIT_NO_REFCOUNT)
def sets_kinematic(quad, particles, sets, part, targets, h):
    """Kinematic particles onto their targets (``targets``: the particles, their targets and
    their positions before the step); their per-set sums moved to the target."""
    x, v, y0, sid, _, _, _ = _unpack(particles, sets)
    mass = particles.mass
    idx, tgt, prev = targets
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


@njit(**JIT_NO_REFCOUNT)
def sets_hold(quad, particles, sets, part, targets, h, damping):
    """``sets_kinematic``, and with ``damping`` = (damped, dpart) the held particles' damping
    sums moved with them (``damping.damp_kinematic``: out before, in after)."""
    damped, dpart = damping
    x, v, mass, idx = particles.x, particles.v, particles.mass, targets[0]
    if damped:
        damp_kinematic(x=x, v=v, mass=mass, sid=sets.sid, dpart=dpart, idx=idx, sign=-1.0)
    sets_kinematic(quad, particles, sets, part, targets, h)
    if damped:
        damp_kinematic(x=x, v=v, mass=mass, sid=sets.sid, dpart=dpart, idx=idx, sign=1.0)
