"""
Stages of the compiled-step records of ``paper_384`` (``kernels.world_step._step_record``)
per kind of body, after ``--steps`` world steps of pouring: the cluster solve
(``goals.solve_clusters_warm``, as the record calls it), the whole record step, and the
record's unpacking alone (a typed-list item of 66 arrays), each looped over the 96 records
of a kind on one thread (us per body, medians of ``--rounds``, the calling thread's CPU
time).  The loop is compiled in each process (not cached), so two checkouts can be
compared run against run (``--compare A B``: alternating processes, medians).

    .venv/bin/python tools/record_stages.py
    .venv/bin/python tools/record_stages.py --compare /path/to/old/checkout . --runs 3
"""

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

STAGES = ('solve', 'record', 'unpack')


def measure(steps, rounds):
    """us per body of each stage and kind of body (medians)."""
    from numba import njit
    from numba.typed import List as TypedList

    from sm_ros.core.kernels.goals import solve_clusters_warm
    from sm_ros.core.kernels.world_step import _step_record

    from bodies_step import paper_records      # tools/: the same bodies as bodies_step

    @njit
    def stage(recs, which, h, gravity, has_col, ground, boxes, spheres, thresh):
        # which: 0 the cluster solve, 1 the whole record step, 2 only the unpacking
        for record in recs:
            (xt, vt, x0t, mass, ptr, cl, rest_lin, rest_off, part, wsum, sum_q, ref, quat,
             aqq3, aqq9, scale, trans, goal_lin, goal_off, apq, accbuf, m3a, m3b, m3c, m3d,
             m39, n4, v4, nmat, cdet, acc, ang, com, err, dpart, dmp, dref, dacc, lin, w3,
             sptr, scl, scnt, quat_prev, flagged, lim_lin, lim_w, force, state, flags,
             counts, y0t, sid, gm, sref, s_part, s_ptr, s_cl, s_cnt, s_phi, s_org, wk, pm,
             s_tp, s_ck, s_runs, udv) = record
            if which == 0:
                solve_clusters_warm(part=part, wsum=wsum, sum_q=sum_q, ref=ref, quat=quat,
                                    aqq3=aqq3, aqq9=aqq9, rest_lin=rest_lin,
                                    rest_off=rest_off, scale=scale, trans=trans,
                                    goal_lin=goal_lin, goal_off=goal_off,
                                    mode=int(state[6]), beta=state[1], apq=apq, acc=accbuf,
                                    m3a=m3a, m3b=m3b, m3c=m3c, m39=m39, n4=n4, v4=v4,
                                    nmat=nmat, cdet=cdet, udv=udv, warm=True)
            elif which == 1:
                _step_record(record, h, gravity, has_col, ground, boxes, spheres, thresh)

    dt, pack, records, packed, slow, args, kinds = paper_records(steps)
    out = {}
    for kind, recs in kinds.items():
        tl = TypedList(recs)
        for which in range(len(STAGES)):
            stage(tl, which, *args)
        for which, name in enumerate(STAGES):
            ts = []
            for _ in range(rounds):
                t0 = time.thread_time()
                stage(tl, which, *args)
                ts.append(time.thread_time() - t0)
            out[f'{kind} {name}'] = 1e6 * statistics.median(ts) / len(recs)
    return out


def main(argv=None) -> int:
    """Measure this checkout, or compare two (alternating processes)."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--steps', type=int, default=120, help='world steps of pouring first')
    ap.add_argument('--rounds', type=int, default=41)
    ap.add_argument('--compare', nargs=2, metavar=('BEFORE', 'AFTER'))
    ap.add_argument('--runs', type=int, default=3, help='processes per checkout (--compare)')
    ap.add_argument('--root', help='checkout whose sm_ros is measured (default: this one)')
    args = ap.parse_args(argv)
    if not args.compare:
        sys.path.insert(0, args.root or str(Path(__file__).resolve().parent.parent))
        print(json.dumps(measure(args.steps, args.rounds)))
        return 0
    me = Path(__file__).resolve()
    got = {c: [] for c in args.compare}
    for _ in range(args.runs):
        for c in args.compare:
            root = str(Path(c).resolve())
            env = dict(os.environ, PYTHONPATH=root)
            out = subprocess.run([sys.executable, str(me), '--steps', str(args.steps),
                                  '--rounds', str(args.rounds), '--root', root], env=env,
                                 cwd=c, capture_output=True, text=True, check=True)
            got[c].append(json.loads(out.stdout.strip().splitlines()[-1]))
    before, after = args.compare
    print(f'| us per body (median of {args.runs} runs) | before | after | before / after |')
    print('| --- | --- | --- | --- |')
    for k in got[after][0]:
        b = statistics.median(r[k] for r in got[before])
        a = statistics.median(r[k] for r in got[after])
        print(f'| {k} | {b:.2f} | {a:.2f} | {b / a:.2f} |')
    return 0


if __name__ == '__main__':
    sys.exit(main())
