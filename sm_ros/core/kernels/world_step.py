"""One compiled call steps the bodies of a world (Eq. 7-14, 23, damping, limits).

A call of a Numba function from Python unboxes each of its array arguments, which for a
small body costs more than the body's own work, and a body's step calls dozens of
kernels.  ``step_single_bodies`` runs the whole step of
every body of a typed list of per-body records in one call, so the Python cost of a step
does not grow with the number of bodies.  It covers every body (grabbed, pinned, under a
torque, plastic) but the one-cluster rigid/linear bodies without those, which take the
packed step (``sm_ros.core.packed``: no per-body record); ``Body._step`` steps a body as a
list of one record, and a body built for threads by the record step's phases, its
particle passes on helper threads.

A record (``Body._fast_record``) is a ``StepRecord``, a named tuple of the body's own
buffers (x, v and the set offsets y0 as their (3, N) blocks, transposed back to (N, 3)
views of layout F here); ``state`` holds the body's numbers at the step (``R_*`` below),
``force`` the force over the total mass (divided in Python: fast math would round it
otherwise), ``flags`` the body's flags (``kernels.flags``: a sleeping record is not
stepped), ``counts`` the limit counters, ``s_*`` the set layout's buffers.
"""

from collections import namedtuple

import numba
import numpy as np
from numba import njit

from ..step_threads import HELPERS
from .flags import DIRTY, ERR_STALE, SLEEP, SUMS_PACKED
from .colliders import Colliders
from .damping import damp_accumulate, damping_fields, damping_targets
from .grabs import gather_rows, wrench_accelerations
from .goals import ClusterMatch, ClusterShape, MatchScratch, solve_clusters_warm
from .integrate import BodyParticles, ClusterRest, FusedDamping
from .jit import JIT, JIT_NO_REFCOUNT, claim_next
from .limits import limit_turn
from .plasticity import plastic_update, refresh_rest
from .sets import SetMotion, Sets, _fused_refs, sets_hold, sets_integrate_chunks
from .set_maps import SetClusters, sets_maps, sets_reduce
from .sets_sums import sets_accumulate_chunks

#: The buffers of one body that ``step_bodies_claimed`` steps (``body_build.fast_record``):
#: the names of ``Body``'s own attributes, the set layout's with ``s_``; ``kin_*`` its
#: grabbed and pinned particles, their targets and their positions before the step.
StepRecord = namedtuple('StepRecord', (
    'xt vt mass ptr cluster_ids rest_lin rest_off part wsum sum_q ref quat aqq3 aqq9 scale '
    'trans goal_lin goal_off apq accbuf m3a m3b m3c m3d m39 n4 v4 nmat cdet acc ang com err dpart '
    'dmp dref dacc lin w3 quat_prev flagged lim_lin lim_w force state flags '
    'counts rest_local_t sid goal_maps sref s_part s_ptr s_cluster_ids s_cnt s_phi s_org work '
    'quad_map s_pair_offsets s_cluster_maps s_runs '
    'udv match_work torque inertia inertia_inv kin_idx kin_tgt kin_prev').split())

#: What plastic flow (``flow_plastic_bodies``) reads and writes of a plastic body
#: (``body_build.plastic_record``): its record's ``state`` and ``flags``, the step's match
#: (A_pq-hat, A_qq, scale, rotations), scratch (three 3 x 3, two 4 x 4, two C-contiguous
#: 3 x 3), its rest shape (``plasticity.RestShape``) and buffers (``plasticity.PlasticWork``).
PlasticRecord = namedtuple('PlasticRecord',
                           'state flags apq aqq3 scale quat scratch rest_shape work')

#: Where ``StepRecord.state`` holds each number (``body_build.retime_record`` writes them):
#: the material at the step (alpha, beta, damping), the limits (max_speed, max_turn and
#: max_turn / h), the mode (0 rigid, 1 linear, 2 quadratic), quadratic, the particles' one
#: mass or 0 (``Body._wuni``), the radius the body meets the colliders with, and the
#: plastic law: whether the body flows, its yield, creep at the step and cap (Eq. 24-27).
(R_ALPHA, R_BETA, R_DAMPING, R_MAX_SPEED, R_MAX_TURN, R_TURN_RATE, R_MODE, R_QUAD, R_WUNI,
 R_RADIUS, R_PLASTIC, R_YIELD, R_CREEP, R_PLASTIC_MAX, R_SIZE) = range(15)


@njit(**JIT)
def step_bodies_claimed(bodies, claim, h, gravity, has_col, ground, boxes, spheres, thresh):
    """``Body._step`` for the records of ``bodies`` that this call claims: it takes the
    next unclaimed record (``claim[0]``, counted up atomically) until none is left.

    Called on one thread with ``claim`` = [0] it steps every record in order; called on
    several threads with one shared ``claim`` (``step_bodies_parallel``) each record is
    stepped exactly once, by whichever thread claims it.  Each record owns all the buffers
    it writes, so which thread steps it changes no result: every path runs this one
    compiled function (the kernels compiled into two callers can round differently under
    fast math), bit for bit.  Returns how many records this call stepped.
    """
    n = len(bodies)
    stepped = 0
    counters = np.zeros(8, dtype=np.int64)
    while True:
        b = claim_next(claim)
        if b >= n:
            return stepped
        rec = bodies[b]
        if counters.shape[0] < rec.s_part.shape[0] + 1:
            counters = np.zeros(rec.s_part.shape[0] + 1, dtype=np.int64)
        _step_record(rec, h, gravity, Colliders(has_col, ground, boxes, spheres, thresh,
                                                rec.state[R_RADIUS], h), counters)
        stepped += 1


def step_single_bodies(bodies, h, gravity, has_col, ground, boxes, spheres, thresh):
    """``Body._step`` for every record of ``bodies`` on the calling thread alone."""
    step_bodies_claimed(bodies, np.zeros(1, dtype=np.int64), h, gravity, has_col, ground,
                        boxes, spheres, thresh)


def step_bodies_parallel(bodies, h, gravity, has_col, ground, boxes, spheres, thresh,
                         before=None):
    """``Body._step`` for every record of ``bodies``, on the calling thread and up to
    ``numba.get_num_threads() - 1`` helper threads (``step_threads.Helpers``) that claim
    records one at a time (``step_bodies_claimed``; the kernels release the GIL).
    ``before()``, if given, runs on the calling thread after the helpers were woken and
    before it joins them (``World.step``: the packed bodies, while the helpers start).

    Unlike a ``prange`` loop (static halves, and a join that waits for every thread), the
    calling thread never waits for a helper that has not started: on shared cores where
    the helper gets no core it steps every record itself, and a helper that wakes after
    the last record was taken skips the job; it waits only for the records a helper is
    stepping.  The helpers sleep between jobs (no spinning that would slow the serial
    passes that follow).
    """
    threads = numba.get_num_threads()
    claim = np.zeros(1, dtype=np.int64)
    args = (bodies, claim, h, gravity, has_col, ground, boxes, spheres, thresh)
    if threads < 2 or len(bodies) < 2:
        if before is not None:
            before()
        step_bodies_claimed(*args)
        return
    HELPERS.run(min(threads, len(bodies)) - 1, step_bodies_claimed, args, before)


@njit(**JIT_NO_REFCOUNT)
def _step_record(rec, h, gravity, colliders, counters):
    """``Body._step`` for one record; ``colliders``: ``colliders.Colliders`` with the body's
    radius, ``counters`` int64 scratch of at least its chunks + 1 (the passes' claim and
    capped counts).  It allocates nothing, so it runs without reference counting: reading
    the record's arrays would otherwise cost an atomic operation each.

    The step's five phases are also called one by one (``body_step``), so that a body built
    for threads shares its two particle passes out to helper threads between them."""
    if not record_begins(rec):
        return
    if rec.flags[DIRTY] > 0.0:
        record_sums_chunks(rec, _claim(counters))
    record_goals(rec, h, gravity)
    chunk_capped = counters[1:1 + rec.s_part.shape[0]]
    chunk_capped[:] = 0
    record_integrate_chunks(rec, _claim(counters), chunk_capped, colliders)
    record_ends(rec, h, chunk_capped)


@njit(inline='always', **JIT_NO_REFCOUNT)
def record_begins(rec):
    """Whether the record is stepped (not asleep: ``sm_ros.core.sleep``); marks its sums
    to be taken afresh where the pack stepped it last."""
    if rec.flags[SLEEP] > 0.0:
        return False
    if rec.flags[SUMS_PACKED] > 0.0:           # last stepped by the pack: its sums are stale
        rec.flags[SUMS_PACKED] = 0.0
        rec.flags[DIRTY] = 1.0
    return True


@njit(inline='always', **JIT_NO_REFCOUNT)
def record_sums_chunks(rec, claim):
    """The per-set sums of the current state (Eq. 7-11), chunk by chunk as ``claim`` hands
    them out (a body whose state changed since the last pass summed it)."""
    sets_accumulate_chunks(claim=claim, quad=rec.state[R_QUAD] > 0.0, x=rec.xt.T,
                           y0=rec.rest_local_t.T, mass=rec.mass, sid=rec.sid,
                           runs=rec.s_runs, sref=rec.sref, part=rec.s_part)


@njit(inline='always', **JIT_NO_REFCOUNT)
def record_goals(rec, h, gravity):
    """Everything between the two particle passes: the clusters' sums, the shape match
    and turn limit, the goal maps, the step's accelerations, the damping field, the held
    particles' positions."""
    state = rec.state
    quad = state[R_QUAD] > 0.0
    sets_reduce(rec.s_part, _set_clusters(rec), rec.sref, rec.rest_lin, rec.ref, quad,
                rec.part, (rec.work, rec.quad_map))
    turned = _record_match(rec)
    sets_maps(_set_clusters(rec), rec.rest_lin, (rec.trans, rec.goal_lin, rec.goal_off),
              rec.ref, quad, (rec.goal_maps, rec.sref), (rec.quad_map, rec.s_cluster_maps))
    rec.counts[1] += wrench_accelerations(
        (rec.force, rec.torque), gravity, (rec.wsum, rec.ref), (rec.xt.T, rec.mass),
        (h, state[R_MAX_TURN]), (rec.acc, rec.ang, rec.com),
        (rec.inertia, rec.inertia_inv, rec.m3a, rec.m3b))
    if state[R_DAMPING] > 0.0:
        _record_damping(rec, rec.flags[DIRTY] > 0.0 or turned > 0)
    if rec.kin_idx.shape[0] > 0:
        gather_rows(rec.xt.T, rec.kin_idx, rec.kin_prev)


@njit(inline='always', **JIT_NO_REFCOUNT)
def record_integrate_chunks(rec, claim, chunk_capped, colliders):
    """Eq. 13-14 with the static colliders and the speed cap, set by set, chunk by chunk as
    ``claim`` hands them out; the speeds are capped block by block before the next step's
    sums are taken in the same loop, so the sums stay valid."""
    state = rec.state
    particles = BodyParticles(rec.xt.T, rec.vt.T, rec.rest_local_t.T, rec.mass)
    sets = Sets(rec.sid, rec.s_runs, rec.goal_maps, rec.sref, state[R_WUNI])
    motion = SetMotion(state[R_ALPHA], colliders.h, rec.acc, rec.ang, rec.com,
                       state[R_MAX_SPEED])
    sets_integrate_chunks(claim, chunk_capped, state[R_QUAD] > 0.0, particles, sets,
                          motion, rec.s_part, rec.err, colliders,
                          FusedDamping(state[R_DAMPING] > 0.0, state[R_DAMPING], rec.dmp,
                                       rec.dpart))


@njit(inline='always', **JIT_NO_REFCOUNT)
def record_ends(rec, h, chunk_capped):
    """After the particle pass: the sums' reference points, the capped count, the held
    particles onto their targets."""
    state = rec.state
    quad, damped = state[R_QUAD] > 0.0, state[R_DAMPING] > 0.0
    _fused_refs(quad, state[R_WUNI], rec.ang, rec.s_runs, damped, rec.sref, rec.dpart)
    rec.counts[0] += chunk_capped.sum()
    rec.flags[DIRTY] = 0.0
    if rec.kin_idx.shape[0] > 0:
        _record_held(rec, h, damped)
    rec.flags[ERR_STALE] = 1.0


@njit(**JIT)
def flow_plastic_bodies(bodies, h):
    """Plastic flow (Eq. 24-27) of plastic bodies (their ``PlasticRecord``s), after their
    step: from the step's match (A_pq-hat, rotations), S^P and the rest shape of the
    clusters that yielded (the next step's match reads them).  Kept out of the step's
    entry, so a world without plastic bodies does not compile it; its helpers are inlined
    (each compiled caller optimises its callees again)."""
    for b in range(len(bodies)):
        _record_plastic_flow(bodies[b], h)


@njit(inline='always', **JIT)
def _record_rest(rec):
    """A record's clusters as the shape match reads them (``integrate.ClusterRest``)."""
    return ClusterRest(rec.ptr, rec.cluster_ids, rec.rest_lin, rec.rest_off, rec.ref)


@njit(inline='always', **JIT)
def _set_clusters(rec):
    """A set-layout record's set-cluster pairs."""
    return SetClusters(rec.s_ptr, rec.s_cluster_ids, rec.s_cnt, rec.s_phi, rec.s_pair_offsets,
                       rec.s_org)


@njit(inline='always', **JIT)
def _claim(counters):
    """A fresh claim counter (``claim_next``) from ``counters``' first slot."""
    counters[0] = 0
    return counters[0:1]


@njit(inline='always', **JIT)
def _record_match(rec):
    """The shape match of every cluster, then the turn limit (as ``Body._step``); returns
    the clusters whose spin was capped."""
    state = rec.state
    turn = state[R_MAX_TURN]
    quat, quat_prev, flagged = rec.quat, rec.quat_prev, rec.flagged
    if turn > 0.0:
        for k in range(quat.shape[0]):
            for c in range(4):
                quat_prev[k, c] = quat[k, c]
    shape = ClusterShape(rec.wsum, rec.sum_q, rec.aqq3, rec.aqq9, rec.scale, rec.nmat, rec.cdet)
    match = ClusterMatch(quat, rec.trans, rec.goal_lin, rec.goal_off, rec.apq, rec.udv)
    scratch = MatchScratch(rec.accbuf, rec.m3a, rec.m3b, rec.m3c, rec.m39, rec.n4, rec.v4,
                           rec.match_work)
    solve_clusters_warm(rec.part, _record_rest(rec), shape, match, scratch,
                        int(state[R_MODE]), state[R_BETA],
                        np.bool_(True))        # bool, not a literal: Body._step's copy
    if turn <= 0.0:
        return 0
    # |q_prev . q| = cos(angle / 2), as Body._step
    limit = np.cos(0.5 * turn)
    any_flagged = False
    for k in range(quat.shape[0]):
        dot = (quat_prev[k, 0] * quat[k, 0] + quat_prev[k, 1] * quat[k, 1]
               + quat_prev[k, 2] * quat[k, 2] + quat_prev[k, 3] * quat[k, 3])
        flagged[k] = abs(dot) < limit
        any_flagged = any_flagged or flagged[k]
    if not any_flagged:
        return 0
    turned = limit_turn(rec.xt.T, rec.vt.T, rec.mass, (rec.ptr, rec.cluster_ids), flagged,
                        state[R_TURN_RATE],
                        (rec.lim_lin, rec.lim_w, rec.m3a, rec.m3b, rec.m3c, rec.m3d))
    rec.counts[1] += turned
    return turned


@njit(inline='always', **JIT)
def _record_plastic_flow(rec, h):
    """``flow_plastic_bodies`` for one ``PlasticRecord`` (not one asleep: it was not
    stepped)."""
    state, work = rec.state, rec.work
    if rec.flags[SLEEP] > 0.0 or not state[R_PLASTIC] > 0.0:
        return
    m3a, m3b, m3c, n4, v4, wa, wv = rec.scratch
    law = (state[R_YIELD], state[R_CREEP], state[R_PLASTIC_MAX], h)
    changed = plastic_update(rec.apq, (rec.aqq3, rec.scale, rec.quat),
                             rec.rest_shape.s_plastic, law, work.changed,
                             (work.quat, m3a, m3b, m3c, n4, v4, wa, wv))
    if changed > 0:
        refresh_rest(work.changed, rec.rest_shape, (True, state[R_QUAD] > 0.0),
                     state[R_MODE] == 1.0, (work.features9, m3a, m3b, work.m9a, work.m9b))


@njit(inline='always', **JIT)
def _record_damping(rec, stale):
    """The field of the damping towards each cluster's rigid motion, which the particle
    pass applies: from the last pass's sums, taken again where the state is ``stale``."""
    if stale:
        damp_accumulate(x=rec.xt.T, v=rec.vt.T, mass=rec.mass, sid=rec.sid, dpart=rec.dpart)
    damping_fields(rec.dpart, (rec.s_ptr, rec.s_cluster_ids, rec.s_cnt), rec.dref, rec.dacc,
                   (rec.lin, rec.w3, rec.m3a, rec.m3b, rec.m3c, rec.m3d))
    damping_targets(sptr=rec.s_ptr, scl=rec.s_cluster_ids, scnt=rec.s_cnt, lin=rec.lin,
                    w3=rec.w3, dref=rec.dref, sref=rec.sref, dmp=rec.dmp)


@njit(inline='always', **JIT)
def _record_held(rec, h, damped):
    """The grabbed and pinned particles onto their targets (their per-set sums, and damped
    their damping sums, follow them)."""
    particles = BodyParticles(rec.xt.T, rec.vt.T, rec.rest_local_t.T, rec.mass)
    sets_hold(rec.state[R_QUAD] > 0.0, particles,
              Sets(rec.sid, rec.s_runs, rec.goal_maps, rec.sref, rec.state[R_WUNI]),
              rec.s_part, (rec.kin_idx, rec.kin_tgt, rec.kin_prev), h, (damped, rec.dpart))
