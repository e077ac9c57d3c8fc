"""
The compiled world step on one thread against all of Numba's threads, side by side.

``World.step`` spreads its bodies over the Numba threads only from
``world.WORLD_PARALLEL_MIN_WORK`` particles (the compiled records alone, on helper
threads, from ``world.RECORDS_PARALLEL_MIN_WORK``; ``--threads-for records`` times that
alone); a body's own kernels from
``body.PARALLEL_MIN_WORK``. This script times, in one process and round-robin (blocks of
``--steps`` steps, medians over ``--rounds`` rounds), each scene with the bodies on one
thread (``serial``) and on all threads (``threads``):

- ``paper_384``: the paper's scene (384 bodies, 55,680 particles, contact), after
  ``--settle`` steps so that the bodies are in their heap; the bodies' own step (the
  compiled world step) is timed apart from the whole ``World.step`` (contact included);
- ``many_64``, ``many_384``: ``sm_ros.bench.scaling.build_many`` (144-particle bodies,
  contact off);
- ``box_100k``: one body of 97,336 particles, 8 clusters, damping 0.05 (the body's own
  threaded kernels against its serial ones; two worlds, stepped alternately); ``box_1m``
  the same with 1,000,000 particles (threaded by default: ``body.PARALLEL_MIN_WORK``).

With ``--env A=1,B=2 --env ...`` it runs itself once per environment (each in a fresh
process, as OpenMP reads its settings when it starts), alternating the processes
``--repeat`` times, and prints one table. Example (the figures in doc/benchmarks.md)::

    .venv/bin/python tools/world_threads.py --env '' --env OMP_WAIT_POLICY=passive --repeat 2
"""

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def _scenes(names, settle):
    import numpy as np
    import sm_ros.core.body as body_mod
    from sm_ros.bench import scaling
    from sm_ros.core import BodyParams, Ground, World
    from sm_ros.core.contact import ContactParams
    out = {}
    for name in names:
        if name == 'paper_384':
            from sm_ros.sim import Simulation
            sim = Simulation({'scene': 'paper_384'})
            w, dt = sim.world, float(sim.params['dt'])
            for _ in range(settle):
                w.step(dt)
            out[name] = ('world', w, dt)
        elif name.startswith('many_'):
            out[name] = ('world', scaling.build_many(int(name[5:])), scaling.DT)
        elif name in ('box_100k', 'box_1m'):
            g = np.arange(46 if name == 'box_100k' else 100) * 0.01
            x0 = np.stack(np.meshgrid(g, g, g, indexing='ij'), axis=-1).reshape(-1, 3)
            pair = []
            for par in (False, True):
                body_mod.PARALLEL_MIN_WORK = 0 if par else 1 << 40
                w = World()
                w.set_colliders(ground=Ground(height=0.0))
                w.contact_params = ContactParams(enabled=False)
                w.add_body(x0 + (0.0, 0.0, 0.01), masses=0.01,
                           params=BodyParams(mode='linear', clusters=2, damping=0.05))
                assert w.bodies[0]._parallel == par or not par
                pair.append(w)
            body_mod.PARALLEL_MIN_WORK = 262144
            out[name] = ('pair', pair, 1.0 / 120.0)
    return out


def _measure(a) -> dict:
    """Time the scenes in this process; return {scene/variant: [ms per step, ...]}."""
    import numba
    import sm_ros.core.world as world_mod
    from sm_ros.core.kernels import world_step as ws
    scenes = _scenes(a.scenes.split(','), a.settle)
    # the threads variant uses the helpers whatever the load average (step_threads)
    world_mod.step_threads.LOAD_MARGIN = float('inf')
    res = {}
    clock = time.perf_counter

    def bodies_step(w, dt, parallel):
        # the bodies' own step alone (what the thresholds decide), as World.step runs it:
        # the packed one-cluster bodies, the compiled records, the bodies stepped alone
        pack, records, slow, parallel = w._split_bodies(dt)
        helpers = w._split[5]
        args = (dt, w._gravity, w._has_col, w._ground_row, w._box_rows, w._sphere_rows,
                max(1e-3, 2.0 * float((w._gravity ** 2).sum()) ** 0.5 * dt))
        t0 = clock()
        if pack is not None:
            pack.step(*args, parallel)
        if len(records):
            (ws.step_bodies_parallel if helpers else ws.step_single_bodies)(records, *args)
        for body in slow:
            body._step(*args)
        return clock() - t0

    for _ in range(a.rounds):
        for name, (kind, obj, dt) in scenes.items():
            for variant in ('serial', 'threads'):
                par = variant == 'threads'
                if kind == 'pair':
                    w = obj[1 if par else 0]
                    w.step(dt)
                    for _ in range(a.steps):
                        t0 = clock()
                        w.step(dt)
                        res.setdefault(f'{name} {variant}', []).append(clock() - t0)
                    continue
                w = obj
                # threads: everything (--threads-for all) or the records alone (helper
                # threads, ``kernels.world_step.step_bodies_parallel``; as World.step
                # runs paper_384 by default)
                world_mod.WORLD_PARALLEL_MIN_WORK = (0 if par and a.threads_for == 'all'
                                                     else 1 << 40)
                world_mod.RECORDS_PARALLEL_MIN_WORK = 0 if par else 1 << 40
                w._split = None                 # the dispatch is decided when rebuilt
                w.step(dt)
                assert w._split[5] == (par and numba.get_num_threads() > 1
                                       and len(w._split[2]) > 1)
                for _ in range(a.steps):
                    t0 = clock()
                    w.step(dt)
                    res.setdefault(f'{name} {variant}', []).append(clock() - t0)
                if name == 'paper_384':
                    for _ in range(a.steps):
                        res.setdefault(f'{name} {variant} (bodies only)', []).append(
                            bodies_step(w, dt, par))
    return {'layer': numba.threading_layer(), 'threads': numba.get_num_threads(),
            'load': os.getloadavg()[0], 'ms': {k: [1e3 * s for s in v] for k, v in res.items()}}


def main(argv=None) -> int:
    """Run the measurement (or, with --env, one process per environment)."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--scenes', default='paper_384,many_64,many_384,box_100k')
    ap.add_argument('--rounds', type=int, default=10)
    ap.add_argument('--steps', type=int, default=5)
    ap.add_argument('--settle', type=int, default=360,
                    help='paper_384 steps before timing (the heap forms)')
    ap.add_argument('--env', action='append', default=None,
                    help="environment of one process: 'A=1,B=2' ('' = as inherited)")
    ap.add_argument('--repeat', type=int, default=1)
    ap.add_argument('--threads-for', choices=('all', 'records'), default='all',
                    help='threads variant: every body (the packed step too) or only the '
                         'compiled records (helper threads)')
    ap.add_argument('--json', action='store_true', help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.env is None:
        r = _measure(a)
        if a.json:
            sys.stdout.write(json.dumps(r) + '\n')
            return 0
        _table({'': [r]})
        return 0
    rows = {e: [] for e in a.env}
    for _ in range(a.repeat):
        for e in a.env:
            env = dict(os.environ)
            env['PYTHONPATH'] = str(ROOT)
            for kv in filter(None, e.split(',')):
                k, v = kv.split('=', 1)
                env[k] = v
            args = [sys.executable, __file__, '--json', '--scenes', a.scenes,
                    '--rounds', str(a.rounds), '--steps', str(a.steps),
                    '--settle', str(a.settle), '--threads-for', a.threads_for]
            p = subprocess.run(args, env=env, capture_output=True, text=True, check=True)
            rows[e].append(json.loads(p.stdout.strip().splitlines()[-1]))
    _table(rows)
    return 0


def _table(rows):
    print('| environment | run | layer | load | what | median ms | best ms | serial / threads |')
    print('| --- | --- | --- | --- | --- | --- | --- | --- |')
    for e, runs in rows.items():
        for i, r in enumerate(runs):
            ms = r['ms']
            for k, v in ms.items():
                ratio = ''
                if ' threads' in k:
                    s = ms[k.replace(' threads', ' serial')]
                    ratio = f'{statistics.median(s) / statistics.median(v):.2f}x'
                print(f"| {e or '(inherited)'} | {i + 1} | {r['layer']} x{r['threads']} | "
                      f"{r['load']:.1f} | {k} | {statistics.median(v):.2f} | {min(v):.2f} | "
                      f'{ratio} |')


if __name__ == '__main__':
    sys.exit(main())
