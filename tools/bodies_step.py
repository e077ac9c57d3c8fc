"""
The bodies' own compiled step of ``paper_384`` (``kernels.world_step`` and, for its
one-cluster bodies, ``sm_ros.core.packed``; contact and the collider pass left out), after
``--steps`` world steps of pouring: all bodies on one thread and on every Numba thread,
and each kind of body (96 of each) on one thread, round-robin in one process (medians of
``--rounds`` rounds, ms per world step); then the ``many`` worlds of ``sm_ros.bench
scaling`` (64 and 384 one-cluster bodies of 144 particles, ``World.step``, contact off).
Prints one JSON line, so that two checkouts can
be compared run against run (``--compare A B``: alternate processes, medians).  On a
loaded machine (other processes on the same cores) wall-clock times include the time the
process waited for a core: ``--clock thread`` times with the calling thread's CPU time
instead (``time.thread_time``; the threaded run then counts only the calling thread).

    .venv/bin/python tools/bodies_step.py
    .venv/bin/python tools/bodies_step.py --compare /path/to/old/checkout . --runs 3
"""

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path


def paper_records(steps):
    """``paper_384`` after ``steps`` world steps of pouring: (dt, its pack, its typed list
    of compiled-step records, the packed bodies, the bodies stepped apart, the step's
    arguments, {kind: records}) (also ``tools/record_stages.py``'s bodies)."""
    from sm_ros.sim import Simulation
    sim = Simulation({'scene': 'paper_384'})
    world = sim.world
    dt = float(sim.params['dt'])
    for _ in range(steps):
        world.step(dt)
    pack, records, slow, _ = world._split_bodies(dt)
    packed = pack.bodies if pack is not None else []
    bodies = [b for b in world.bodies if b not in slow and b not in packed]
    args = (dt, world._gravity, world._has_col, world._ground_row, world._box_rows,
            world._sphere_rows, 1e-3)
    kinds = {}
    for b, r in zip(bodies, records):
        kinds.setdefault(b.name.rstrip('0123456789_'), []).append(r)
    return dt, pack, records, packed, slow, args, kinds


def measure(steps, rounds, clock='wall'):
    """The figures of this checkout (ms per world step, medians)."""
    now = time.thread_time if clock == 'thread' else time.perf_counter
    import numba
    from numba.typed import List as TypedList

    from sm_ros.bench.scaling import build_many
    from sm_ros.core.kernels.world_step import step_bodies_parallel, step_single_bodies

    dt, pack, records, packed, slow, args, kinds = paper_records(steps)

    def step_all():
        if pack is not None:
            pack.step(*args)
        step_single_bodies(records, *args)

    runs = {'all, 1 thread': step_all}
    for kind, recs in kinds.items():
        tl = TypedList(recs)
        runs[f'{kind} ({len(recs)}), 1 thread'] = (lambda t=tl: step_single_bodies(t, *args))
    if pack is not None:
        names = sorted({b.name.rstrip('0123456789_') for b in packed})
        runs[f'{"+".join(names)} ({len(packed)}, packed), 1 thread'] = lambda: pack.step(*args)
    many = {c: build_many(c) for c in (64, 384)}
    for c, w in many.items():
        runs[f'many {c}, World.step'] = (lambda w=w: w.step(dt))
    # last in each round, then a pause: the threads spin a while after a parallel loop and
    # slow the serial runs that follow (OpenMP layer on 2 shared cores)
    threaded = f'all, {numba.get_num_threads()} threads'

    def step_threaded():
        # as World.step runs paper_384: the pack on one thread (below
        # WORLD_PARALLEL_MIN_WORK), the records shared with helper threads
        if pack is not None:
            pack.step(*args)
        step_bodies_parallel(records, *args)

    runs[threaded] = step_threaded
    samples = {k: [] for k in runs}
    for fn in runs.values():
        fn()
    for _ in range(rounds):
        for k, fn in runs.items():
            t0 = now()
            fn()
            samples[k].append(now() - t0)
            if k == threaded:
                time.sleep(0.3)
    return {'records': len(records), 'packed': len(packed), 'stepped apart': len(slow),
            'ms': {k: 1e3 * statistics.median(v) for k, v in samples.items()}}


def main(argv=None) -> int:
    """Measure this checkout, or compare two (alternating processes)."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--steps', type=int, default=120, help='world steps of pouring first')
    ap.add_argument('--rounds', type=int, default=40)
    ap.add_argument('--compare', nargs=2, metavar=('BEFORE', 'AFTER'))
    ap.add_argument('--runs', type=int, default=3, help='processes per checkout (--compare)')
    ap.add_argument('--root', help='checkout whose sm_ros is measured (default: this one)')
    ap.add_argument('--clock', choices=('wall', 'thread'), default='wall',
                    help="wall-clock time or the calling thread's CPU time (loaded machine)")
    args = ap.parse_args(argv)
    if not args.compare:
        sys.path.insert(0, args.root or str(Path(__file__).resolve().parent.parent))
        print(json.dumps(measure(args.steps, args.rounds, args.clock)))
        return 0
    me = Path(__file__).resolve()
    got = {c: [] for c in args.compare}
    for _ in range(args.runs):
        for c in args.compare:
            root = str(Path(c).resolve())
            env = dict(os.environ, PYTHONPATH=root)
            out = subprocess.run([sys.executable, str(me), '--steps', str(args.steps),
                                  '--rounds', str(args.rounds), '--root', root,
                                  '--clock', args.clock], env=env, cwd=c,
                                 capture_output=True, text=True, check=True)
            got[c].append(json.loads(out.stdout.strip().splitlines()[-1])['ms'])
    before, after = args.compare
    print(f'| ms per step (median of {args.runs} runs) | before | after | before / after |')
    print('| --- | --- | --- | --- |')
    for k in got[after][0]:
        b = statistics.median(r[k] for r in got[before] if k in r) if k in got[before][0] \
            else float('nan')
        a = statistics.median(r[k] for r in got[after])
        print(f'| {k} | {b:.2f} | {a:.2f} | {b / a:.2f} |')
    return 0


if __name__ == '__main__':
    sys.exit(main())
