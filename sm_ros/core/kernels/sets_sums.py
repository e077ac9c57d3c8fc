"""The per-set sums of the set layout: Eq. 7-9 taken per set (after the state was changed
outside a step, ``sets_accumulate_chunks``, and inside the passes run by run);
``set_maps.py`` turns them into per-cluster sums and makes the per-set goal maps.

A run's 12 rigid/linear sums (sum w d and sum w d y0^T about the set's reference point
``sref``) stay in registers until the run ends (then ``_add_row``); quadratic sets take
the 30 sums of the nine features.  A body built for threads splits its particles in one
chunk per thread (``part`` holds a slot per chunk).
"""

import numpy as np
from numba import njit

from .jit import JIT, JIT_NO_REFCOUNT, U, claim_next
from .linalg import ZERO12, ZERO16, add_damping, add_outer


@njit(inline='always', **JIT)
def first_run(runs, start):
    """The run holding particle ``start`` (``runs``: the first particle of each run of one
    set, then N; ``_SetLayout.runs``): the loops over runs take each run's end from it,
    not from looking for it particle by particle."""
    return np.searchsorted(runs, start, side='right') - 1


@njit(inline='always', **JIT)
def _add_row(sums, s, values):
    """sums[s, 0:12] += the 12 values of a run's rigid/linear sums (kept in registers by the
    run loops until the run ends; written out: each value a register, no tuple indexed at
    run time)."""
    sums[s, 0] += values[0]
    sums[s, 1] += values[1]
    sums[s, 2] += values[2]
    sums[s, 3] += values[3]
    sums[s, 4] += values[4]
    sums[s, 5] += values[5]
    sums[s, 6] += values[6]
    sums[s, 7] += values[7]
    sums[s, 8] += values[8]
    sums[s, 9] += values[9]
    sums[s, 10] += values[10]
    sums[s, 11] += values[11]


@njit(inline='always', **JIT)
def _add_shape_sums(sums, s, shape):
    """sums[s, 0:12] += a run's shape sums (``linalg.add_outer``'s), in the row's order:
    per axis, sum w d and then sum w d y^T."""
    _add_row(sums, s, (shape[0], shape[3], shape[4], shape[5], shape[1], shape[6],
                       shape[7], shape[8], shape[2], shape[9], shape[10], shape[11]))


#: Ten zeros: the start of a row of ``_add_features``.
ZERO10 = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)


@njit(inline='always', **JIT)
def _add_features(row, d, phi):
    """A row of the quadratic sums (sum d phi(y)^T, phi = 1, y, y^2 terms) with one more
    particle: its offset component d and its nine features ``phi`` after the 1."""
    return (row[0] + d, row[1] + d * phi[0], row[2] + d * phi[1], row[3] + d * phi[2],
            row[4] + d * phi[3], row[5] + d * phi[4], row[6] + d * phi[5],
            row[7] + d * phi[6], row[8] + d * phi[7], row[9] + d * phi[8])


@njit(inline='always', **JIT)
def _add_damping_sums(row, values):
    """row[0:15] += a run's 15 damping sums (``_add_row``'s rule)."""
    row[0] += values[0]
    row[1] += values[1]
    row[2] += values[2]
    row[3] += values[3]
    row[4] += values[4]
    row[5] += values[5]
    row[6] += values[6]
    row[7] += values[7]
    row[8] += values[8]
    row[9] += values[9]
    row[10] += values[10]
    row[11] += values[11]
    row[12] += values[12]
    row[13] += values[13]
    row[14] += values[14]


@njit(inline='always', **JIT)
def _add_quad_row(sums, s, values):
    """sums[s, 0:30] += a run's 30 quadratic sums (``_add_row``'s rule)."""
    _add_row(sums, s, values[:12])
    sums[s, 12] += values[12]
    sums[s, 13] += values[13]
    sums[s, 14] += values[14]
    sums[s, 15] += values[15]
    sums[s, 16] += values[16]
    sums[s, 17] += values[17]
    sums[s, 18] += values[18]
    sums[s, 19] += values[19]
    sums[s, 20] += values[20]
    sums[s, 21] += values[21]
    sums[s, 22] += values[22]
    sums[s, 23] += values[23]
    sums[s, 24] += values[24]
    sums[s, 25] += values[25]
    sums[s, 26] += values[26]
    sums[s, 27] += values[27]
    sums[s, 28] += values[28]
    sums[s, 29] += values[29]


@njit(**JIT_NO_REFCOUNT)
def _sets_acc_lin(start, end, x, y0, mass, sid, runs, sref, sums):
    """U_s += m (x - r_s) [1, y]^T for particles start..end, runs of one set in registers."""
    r = first_run(runs, start)
    i = start
    while i < end:
        s = sid[i]
        r0, r1, r2 = sref[s, 0], sref[s, 1], sref[s, 2]
        shape = ZERO12
        r += 1
        j = min(runs[r], end)                  # the run's end (``_SetLayout.runs``)
        # a reduction over the run: vectorises (module docstring)
        for k in range(U(i), U(j)):
            w = mass[k]
            shape = add_outer(shape, w * (x[k, 0] - r0), w * (x[k, 1] - r1),
                              w * (x[k, 2] - r2), y0[k, 0], y0[k, 1], y0[k, 2])
        i = j
        _add_shape_sums(sums, s, shape)


@njit(**JIT_NO_REFCOUNT)
def _sets_acc_damp_lin(start, end, particles, sets, sums, dsums):
    """``_sets_acc_lin`` and ``damping.damp_acc_range`` in one loop over the runs: each run
    (particles of one set) is found once and read once, with its 12 set sums and 16
    damping sums (row layout of ``damping.NDAMP``; the reference p_s is the set's first
    particle met, as there) in registers.  Bodies of a few hundred particles have runs of
    1-3 particles, where finding the run and writing its sums cost more than its
    particles: one loop instead of two.  Vectorises across a long run like both.
    ``particles``, ``sets``: ``integrate.BodyParticles`` (x0 the set offsets y),
    ``sets.Sets``."""
    x, v, y0, mass = particles.x, particles.v, particles.x0, particles.mass
    sid, runs, sref = sets.sid, sets.runs, sets.ref
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
        shape, damp = ZERO12, ZERO16
        r += 1
        j = min(runs[r], end)                  # the run's end (``_SetLayout.runs``)
        for k in range(U(i), U(j)):
            w = mass[k]
            p0, p1, p2 = x[k, 0], x[k, 1], x[k, 2]
            shape = add_outer(shape, w * (p0 - r0), w * (p1 - r1), w * (p2 - r2),
                              y0[k, 0], y0[k, 1], y0[k, 2])
            # the damping sums about p_s (damping.damp_acc_range's)
            damp = add_damping(damp, w, p0 - q0, p1 - q1, p2 - q2, v[k, 0], v[k, 1], v[k, 2])
        i = j
        _add_shape_sums(sums, s, shape)
        _add_damping_sums(row, damp[:15])
        row[19] += damp[15]


@njit(**JIT_NO_REFCOUNT)
def _sets_acc_quad(start, end, x, y0, mass, sid, sref, sums):
    """U_s += m (x - r_s) phi(y)^T (3 x 10) for particles start..end."""
    i = start
    while i < end:
        s = sid[i]
        r0, r1, r2 = sref[s, 0], sref[s, 1], sref[s, 2]
        row0 = row1 = row2 = ZERO10
        while i < end and sid[i] == s:
            w = mass[i]
            y_0, y_1, y_2 = y0[i, 0], y0[i, 1], y0[i, 2]
            phi = (y_0, y_1, y_2, y_0 * y_0, y_1 * y_1, y_2 * y_2, y_0 * y_1, y_1 * y_2,
                   y_2 * y_0)
            row0 = _add_features(row0, w * (x[i, 0] - r0), phi)
            row1 = _add_features(row1, w * (x[i, 1] - r1), phi)
            row2 = _add_features(row2, w * (x[i, 2] - r2), phi)
            i += 1
        _add_quad_row(sums, s, row0 + row1 + row2)


@njit(**JIT_NO_REFCOUNT)
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


@njit(**JIT_NO_REFCOUNT)
def sets_accumulate_chunks(claim, quad, x, y0, mass, sid, runs, sref, part):
    """Per-set sums of the current state (when it was changed outside a step) over the
    chunks this call claims (``claim``, counted up atomically: called once it does every
    chunk; called on several threads with one ``claim``, each chunk once)."""
    nchunks = part.shape[0]
    while True:
        chunk = claim_next(claim)
        if chunk >= nchunks:
            return
        _sets_acc_chunk(chunk=chunk, nchunks=nchunks, quad=quad, x=x, y0=y0, mass=mass, sid=sid,
                        runs=runs, sref=sref, part=part)
