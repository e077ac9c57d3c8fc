"""One compiled call steps the bodies of a world (Eq. 7-14, 23, damping, limits).

Each call of a Numba function with 10-30 array arguments from Python costs several
microseconds in the dispatcher, while a 144-particle body's own work is about one, and a
body's step calls 4-6 kernels.  ``step_single_bodies`` runs the same
kernels, in the same order and with the same arguments as ``Body._step``, for every body
of a typed list of per-body records, so the Python cost of a step does not grow with the
number of such bodies.  It covers set-layout bodies (and one-cluster quadratic ones)
without plasticity, kinematic particles or torque, on one thread (``Body._fast_ok``);
one-cluster rigid/linear bodies take the packed step (``sm_ros.core.packed``: no per-body
record) and the others keep ``Body._step``, which steps a covered body as a list of one
record.

A record (``Body._fast_record``) is a tuple of the body's own buffers (x, v, x0, y0 as their
(3, N) blocks, transposed back to (N, 3) views of layout F here); ``state`` holds
[alpha, beta, damping (per step), max_speed, max_turn, 1 / total mass, mode, fused
damping, quadratic, set layout, max_turn / h, the particles' one mass or 0
(``Body._wuni``)], ``force`` the force over the total mass (both divided in Python, as
``Body._step`` does: fast math would round them otherwise), ``flags`` the body's flags
(``kernels.flags``: a sleeping record is not stepped),
``counts`` the limit counters; the set-layout buffers (``s_*``) are empty for one-cluster bodies.
"""

import numba
import numpy as np
from numba import njit

from ..step_threads import HELPERS
from .flags import DIRTY, ERR_STALE, SLEEP
from .damping import damp_accumulate, damp_rigid, damping_fields, damping_targets
from .goals import solve_clusters_warm
from .integrate import accumulate_chunks, integrate_chunks
from .jit import JIT, claim_next
from .limits import limit_speed, limit_turn
from .sets import _fused_refs, sets_integrate_chunks
from .sets_sums import sets_accumulate_chunks, sets_maps, sets_reduce


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
    while True:
        b = claim_next(claim)
        if b >= n:
            return stepped
        _step_record(bodies[b], h, gravity, has_col, ground, boxes, spheres, thresh)
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


@njit(inline='always', **JIT)
def _step_record(record, h, gravity, has_col, ground, boxes, spheres, thresh):
    """``Body._step`` for one record (inlined into ``step_bodies_claimed`` by Numba: one
    compiled function, not a second one linked and optimised again into it)."""
    (xt, vt, x0t, mass, ptr, cl, rest_lin, rest_off, part, wsum, sum_q, ref, quat, aqq3,
     aqq9, scale, trans, goal_lin, goal_off, apq, accbuf, m3a, m3b, m3c, m3d, m39, n4, v4,
     nmat, cdet, acc, ang, com, err, dpart, dmp, dref, dacc, lin, w3, sptr, scl, scnt,
     quat_prev, flagged, lim_lin, lim_w, force, state, flags, counts, y0t, sid, gm, sref,
     s_part, s_ptr, s_cl, s_cnt, s_phi, s_org, wk, pm, s_tp, s_ck, s_runs, udv) = record
    if flags[SLEEP] > 0.0:                     # asleep (``sm_ros.core.sleep``): not stepped
        return
    # the (3, N) blocks seen as (N, 3) arrays of layout F, as the bodies' own x, v
    x, v, x0, y0 = xt.T, vt.T, x0t.T, y0t.T
    alpha, beta, k_damp = state[0], state[1], state[2]
    v_max, turn = state[3], state[4]
    mode = int(state[6])
    fused = state[7] > 0.0 and k_damp > 0.0
    quad = state[8] > 0.0
    sets = state[9] > 0.0
    dirty = flags[DIRTY] > 0.0
    if sets:
        if dirty:
            sets_accumulate_chunks(claim=np.zeros(1, dtype=np.int64), quad=quad, x=x, y0=y0,
                                   mass=mass, sid=sid, runs=s_runs, sref=sref, part=s_part)
        sets_reduce(part=s_part, sptr=s_ptr, scl=s_cl, scnt=s_cnt, sphi=s_phi, sref=sref,
                    stp=s_tp, rest_lin=rest_lin, ref=ref, quad=quad, out=part, wk=wk, pm=pm)
    elif dirty:
        accumulate_chunks(claim=np.zeros(1, dtype=np.int64), quad=quad, x=x, x0=x0, mass=mass,
                          ptr=ptr, cl=cl, rest_lin=rest_lin, rest_off=rest_off, ref=ref,
                          part=part)
    if turn > 0.0:
        quat_prev[:, :] = quat
    solve_clusters_warm(part=part, wsum=wsum, sum_q=sum_q, ref=ref, quat=quat, aqq3=aqq3,
                        aqq9=aqq9, rest_lin=rest_lin, rest_off=rest_off, scale=scale,
                        trans=trans, goal_lin=goal_lin, goal_off=goal_off, mode=mode,
                        beta=beta, apq=apq, acc=accbuf, m3a=m3a, m3b=m3b, m3c=m3c, m39=m39,
                        n4=n4, v4=v4, nmat=nmat, cdet=cdet, udv=udv,
                        warm=np.bool_(True))       # bool, not a literal: Body._step's copy
    turned = 0
    if turn > 0.0:
        # |q_prev . q| = cos(angle / 2), as Body._step
        limit = np.cos(0.5 * turn)
        any_flagged = False
        for k in range(quat.shape[0]):
            dot = (quat_prev[k, 0] * quat[k, 0] + quat_prev[k, 1] * quat[k, 1]
                   + quat_prev[k, 2] * quat[k, 2] + quat_prev[k, 3] * quat[k, 3])
            flagged[k] = abs(dot) < limit
            any_flagged = any_flagged or flagged[k]
        if any_flagged:
            turned = limit_turn(x=x, v=v, mass=mass, ptr=ptr, cl=cl, flagged=flagged,
                                w_max=state[10], lin=lim_lin, w3=lim_w, m3a=m3a, m3b=m3b,
                                m3c=m3c, m3d=m3d)
            counts[1] += turned
    if sets:
        sets_maps(sptr=s_ptr, scl=s_cl, scnt=s_cnt, sorg=s_org, stp=s_tp, rest_lin=rest_lin,
                  trans=trans, goal_lin=goal_lin, goal_off=goal_off, ref=ref, quad=quad,
                  gm=gm, sref=sref, pm=pm, ck=s_ck)
    for i in range(3):
        acc[i] = force[i] + gravity[i]
        ang[i] = 0.0
    if fused:
        if dirty or turned:
            if sets:
                damp_accumulate(x=x, v=v, mass=mass, sid=sid, dpart=dpart)
            else:
                damp_accumulate(x=x, v=v, mass=mass, sid=np.zeros(0, dtype=np.int32),
                                dpart=dpart)
        damping_fields(dpart=dpart, sptr=sptr, scl=scl, scnt=scnt, lin=lin, w3=w3,
                       dref=dref, acc=dacc, m3a=m3a, m3b=m3b, m3c=m3c, m3d=m3d)
        damping_targets(sptr=sptr, scl=scl, scnt=scnt, lin=lin, w3=w3, dref=dref,
                        sref=sref if sets else ref, dmp=dmp)
    elif k_damp > 0.0:
        damp_rigid(x=x, v=v, mass=mass, ptr=ptr, cl=cl, ref=ref, k_damp=k_damp, lin=lin,
                   w3=w3, m3a=m3a, m3b=m3b, m3c=m3c, m3d=m3d)
    capped = 0
    if sets:
        # the speeds capped block by block before the sums are taken: the sums stay valid
        chunk_capped = np.zeros(s_part.shape[0], dtype=np.int64)
        sets_integrate_chunks(claim=np.zeros(1, dtype=np.int64), capped=chunk_capped,
                              quad=quad, x=x, v=v, y0=y0, mass=mass, wuni=state[11], sid=sid,
                              runs=s_runs, gm=gm, sref=sref, alpha=alpha, h=h, acc=acc,
                              ang=ang, com=com, part=s_part, err=err, has_col=has_col,
                              ground=ground, boxes=boxes, spheres=spheres, thresh=thresh,
                              damp=fused, k_damp=k_damp, dmp=dmp, dpart=dpart, v_max=v_max)
        _fused_refs(quad, state[11], ang, s_runs, fused, sref, dpart)
        capped = chunk_capped.sum()
        counts[0] += capped
        flags[DIRTY] = 0.0
    else:
        integrate_chunks(claim=np.zeros(1, dtype=np.int64), quad=quad, x=x, v=v, x0=x0,
                         mass=mass, ptr=ptr, cl=cl, rest_lin=rest_lin, rest_off=rest_off,
                         trans=trans, goal_lin=goal_lin, goal_off=goal_off, ref=ref,
                         alpha=alpha, h=h, acc=acc, ang=ang, com=com, part=part, err=err,
                         has_col=has_col, ground=ground, boxes=boxes, spheres=spheres,
                         thresh=thresh, damp=fused, k_damp=k_damp, dmp=dmp, dpart=dpart)
        if v_max > 0.0:
            capped = limit_speed(x=x, v=v, h=h, v_max=v_max)
            counts[0] += capped
        flags[DIRTY] = 1.0 if capped > 0 else 0.0
    flags[ERR_STALE] = 1.0
