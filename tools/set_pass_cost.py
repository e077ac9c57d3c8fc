"""
Where the step of a set-layout body goes: the 8-cluster rigid lattice of ``bench scaling``
(22^3 = 10,648 particles, stored set by set: 27 runs), damped (0.05) or not, after 5 steps.

- ``stages``: each compiled stage of its world-step record (``kernels.world_step.
  _step_record``) called on the record's own arrays, the state restored before each call
  (us, medians of ``--rounds``, less an empty call): ``sets_reduce``, the clusters' solve,
  ``sets_maps``, ``damping_fields``, ``damping_targets``, the particle pass
  (``sets_integrate_serial``) and the whole record;
- ``runs``: the one-loop pass (``sets._sets_fused_lin``) of a 1,000-particle body over its
  27 runs against the same particles as one run, in a compiled loop (ns a run more).

The loops are compiled in the process (not cached).  Run from outside a checkout with
``PYTHONPATH=CHECKOUT`` (the working directory's ``sm_ros`` would shadow it):

    cd /tmp && NUMBA_NUM_THREADS=1 PYTHONPATH=CHECKOUT python CHECKOUT/tools/set_pass_cost.py
"""

import argparse
import json
import statistics
import time

import numpy as np
from numba import njit


def _body(n_side, damping):
    from sm_ros.bench import scaling as S
    world, body = S.build_world(n_side, 'rigid', 2, damping=damping, order='set')
    for _ in range(5):
        world.step(S.DT)
    return world, body, S.DT


def stages(damping, rounds):
    """{stage: us a call} for the 10k body."""
    from sm_ros.core.kernels.damping import damping_fields, damping_targets
    from sm_ros.core.kernels.goals import solve_clusters_warm
    from sm_ros.core.kernels.sets import sets_integrate_serial, sets_maps, sets_reduce
    from sm_ros.core.kernels.world_step import _step_record

    world, body, dt = _body(22, damping)
    rec = body._fast_record(dt)
    ground, boxes, spheres = np.zeros(4), np.zeros((0, 8)), np.zeros((0, 6))
    gravity = np.array(world.gravity, dtype=float)

    @njit
    def stage(record, which):
        (xt, vt, x0t, mass, ptr, cl, rest_lin, rest_off, part, wsum, sum_q, ref, quat, aqq3,
         aqq9, scale, trans, goal_lin, goal_off, apq, accbuf, m3a, m3b, m3c, m3d, m39, n4,
         v4, nmat, cdet, acc, ang, com, err, dpart, dmp, dref, dacc, lin, w3, sptr, scl,
         scnt, quat_prev, flagged, lim_lin, lim_w, force, state, flags, counts, y0t, sid, gm,
         sref, s_part, s_ptr, s_cl, s_cnt, s_phi, s_org, wk, pm, s_tp, s_ck, s_runs,
         udv) = record
        damp = state[7] > 0.0 and state[2] > 0.0
        if which == 0:
            sets_reduce(part=s_part, sptr=s_ptr, scl=s_cl, scnt=s_cnt, sphi=s_phi, sref=sref,
                        stp=s_tp, rest_lin=rest_lin, ref=ref, quad=False, out=part, wk=wk,
                        pm=pm)
        elif which == 1:
            solve_clusters_warm(part=part, wsum=wsum, sum_q=sum_q, ref=ref, quat=quat,
                                aqq3=aqq3, aqq9=aqq9, rest_lin=rest_lin, rest_off=rest_off,
                                scale=scale, trans=trans, goal_lin=goal_lin,
                                goal_off=goal_off, mode=int(state[6]), beta=state[1],
                                apq=apq, acc=accbuf, m3a=m3a, m3b=m3b, m3c=m3c, m39=m39,
                                n4=n4, v4=v4, nmat=nmat, cdet=cdet, udv=udv, warm=True)
        elif which == 2:
            sets_maps(sptr=s_ptr, scl=s_cl, scnt=s_cnt, sorg=s_org, stp=s_tp,
                      rest_lin=rest_lin, trans=trans, goal_lin=goal_lin, goal_off=goal_off,
                      ref=ref, quad=False, gm=gm, sref=sref, pm=pm, ck=s_ck)
        elif which == 3:
            damping_fields(dpart=dpart, sptr=sptr, scl=scl, scnt=scnt, lin=lin, w3=w3,
                           dref=dref, acc=dacc, m3a=m3a, m3b=m3b, m3c=m3c, m3d=m3d)
        elif which == 4:
            damping_targets(sptr=sptr, scl=scl, scnt=scnt, lin=lin, w3=w3, dref=dref,
                            sref=sref, dmp=dmp)
        elif which == 5:
            sets_integrate_serial(quad=False, x=xt.T, v=vt.T, y0=y0t.T, mass=mass,
                                  wuni=state[11], sid=sid, runs=s_runs, gm=gm, sref=sref,
                                  alpha=state[0], h=0.005, acc=acc, ang=ang, com=com,
                                  part=s_part, err=err, has_col=False, ground=ground,
                                  boxes=boxes, spheres=spheres, thresh=1e-3, damp=damp,
                                  k_damp=state[2], dmp=dmp, dpart=dpart, v_max=state[3])
        elif which == 6:
            _step_record(record, 0.005, gravity, False, ground, boxes, spheres, 1e-3)

    names = ['reduce', 'solve', 'maps', 'damping_fields', 'damping_targets',
             'particle pass', 'record']
    snap = [np.array(a, copy=True) for a in rec]

    def restore():
        for a, c in zip(rec, snap):
            if a.flags.writeable:
                a[...] = c

    for which in list(range(len(names))) + [99]:
        restore()
        stage(rec, which)
    got = {name: [] for name in names + ['empty']}
    for _ in range(rounds):
        for which, name in list(enumerate(names)) + [(99, 'empty')]:
            restore()
            t0 = time.perf_counter()
            stage(rec, which)
            got[name].append(time.perf_counter() - t0)
    base = statistics.median(got['empty'])
    return {name: round(1e6 * (statistics.median(got[name]) - base), 2) for name in names}


def run_cost(damping, rounds):
    """ns a run more: the 1,000-particle body's 27 runs against its particles as one run."""
    from sm_ros.core.kernels import sets as KS
    _, body, _ = _body(10, damping)
    st = body._sets
    x, v, y0, m = body._x, body._v, st.y0, body.m
    sums = np.zeros_like(st.part[0])
    ds = np.zeros_like(body._dpart[0])
    dmp = np.zeros_like(body._dmp)
    one_runs = np.array([0, body.n], dtype=np.int64)
    one_sid = np.zeros_like(st.sid)
    one_gm = np.zeros_like(st.gm)
    one_gm[:, 0, 1] = one_gm[:, 1, 2] = one_gm[:, 2, 3] = 1.0
    x_start, v_start = body._x.T.copy(), body._v.T.copy()
    gr, bx, sp = np.zeros(4), np.zeros((0, 8)), np.zeros((0, 6))
    sref = st.ref.copy()
    damp = damping > 0.0

    @njit
    def loop(k, x, v, x_start, v_start, y0, m, sid, runs, gm, sref, damp, dmp, sums, ds, gr,
             bx, sp, copy_only):
        for _ in range(k):
            x.T[:] = x_start
            v.T[:] = v_start
            if not copy_only:
                KS._sets_fused_lin(0, x.shape[0], x, v, y0, m, 1.0, sid, runs, gm, sref, 0.0,
                                   0.005, 0.0, 0.0, 0.0, damp, 0.03, dmp, 0.0, sums, ds, False,
                                   gr, bx, sp, 1e-3, None)

    out = {}
    for name, sid, runs, gm, copy_only in (('runs', st.sid, st.runs, st.gm, False),
                                           ('one', one_sid, one_runs, one_gm, False),
                                           ('copy', one_sid, one_runs, one_gm, True)):
        args = (x, v, x_start, v_start, y0, m, sid, runs, gm, sref, damp, dmp, sums, ds, gr,
                bx, sp, copy_only)
        loop(2, *args)
        t = []
        for _ in range(rounds):
            t0 = time.perf_counter()
            loop(1000, *args)
            t.append((time.perf_counter() - t0) / 1000)
        out[name] = statistics.median(t)
    return round(1e9 * (out['runs'] - out['one']) / (len(st.runs) - 2))


def main():
    """Print one JSON line per damping setting."""
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('--rounds', type=int, default=200)
    args = p.parse_args()
    for damping in (0.0, 0.05):
        print(json.dumps({'damping': damping, 'stages_us': stages(damping, args.rounds),
                          'ns_a_run': run_cost(damping, 7)}))


if __name__ == '__main__':
    main()
