"""
``World.step`` of one lattice body resting on a ground, as the bundled scenes have one:
a 22^3 lattice (10,648 particles; ``--side 46``: 97,336, the node benchmark's size; unit
masses, spanning 1 m), one cluster or 8 linear
clusters stored set by set, alpha 0.5, damping 0 and 0.05, ground friction 0.5 and
restitution 0.1, after ``--settle`` steps of 5 ms; medians of ``--steps`` steps, one
thread, every configuration round-robin in one process (us a step).  Prints one JSON line,
so that two checkouts can be compared run against run (``--compare A B``: alternate
processes, medians); run it from outside a checkout (the working directory's ``sm_ros``
would shadow the one compared).

    NUMBA_NUM_THREADS=1 PYTHONPATH=. .venv/bin/python tools/ground_step.py
    cd /tmp && NUMBA_NUM_THREADS=1 python /path/to/tools/ground_step.py --compare OLD NEW
"""

import argparse
import json
import os
import statistics
import subprocess
import sys
import time

CONFIGS = [(clusters, damping) for clusters in (1, 2) for damping in (0.0, 0.05)]


def measure(settle, steps, rounds, side=22):
    """{config name: median us a step}."""
    import numpy as np
    from sm_ros.core import BodyParams, Ground, World
    worlds = {}
    for clusters, damping in CONFIGS:
        world = World(gravity=(0.0, 0.0, -9.81))
        world.set_colliders(ground=Ground(height=0.0, friction=0.5, restitution=0.1))
        a = np.linspace(0.0, 1.0, side)
        x = np.stack(np.meshgrid(a, a, a, indexing='ij'), axis=-1).reshape(-1, 3)
        world.add_body(x + (0.0, 0.0, 0.01), masses=1.0, order='set',
                       params=BodyParams(mode='linear', alpha=0.5, beta=0.5,
                                         clusters=clusters, damping=damping))
        for _ in range(settle):
            world.step(0.005)
        worlds[f'{clusters ** 3} cl, damping {damping}'] = (world, [])
    for _ in range(rounds):
        for world, samples in worlds.values():
            for _ in range(steps):
                t0 = time.perf_counter()
                world.step(0.005)
                samples.append(time.perf_counter() - t0)
    return {name: 1e6 * statistics.median(s) for name, (_, s) in worlds.items()}


def main():
    """Measure here, or compare two checkouts (``--compare``)."""
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('--settle', type=int, default=150)
    p.add_argument('--steps', type=int, default=50)
    p.add_argument('--rounds', type=int, default=8)
    p.add_argument('--compare', nargs=2, metavar=('A', 'B'))
    p.add_argument('--runs', type=int, default=2)
    p.add_argument('--side', type=int, default=22,
                   help='lattice side (22: 10,648 particles; 46: 97,336)')
    args = p.parse_args()
    if not args.compare:
        print(json.dumps(measure(args.settle, args.steps, args.rounds, args.side)))
        return
    got = {path: [] for path in args.compare}
    for _ in range(args.runs):
        for path in args.compare:
            env = dict(os.environ, PYTHONPATH=os.path.abspath(path))
            out = subprocess.run([sys.executable, os.path.abspath(__file__), '--settle',
                                  str(args.settle), '--steps', str(args.steps), '--rounds',
                                  str(args.rounds), '--side', str(args.side)], env=env,
                                 capture_output=True, text=True,
                                 check=True)
            got[path].append(json.loads(out.stdout.strip().splitlines()[-1]))
    names = list(got[args.compare[0]][0])
    print(f'{"us a step (median of runs)":28s}' + ''.join(f'{p[-24:]:>26s}'
                                                         for p in args.compare))
    for name in names:
        print(f'{name:28s}' + ''.join(
            f'{statistics.median(r[name] for r in got[p]):26.1f}' for p in args.compare))


if __name__ == '__main__':
    main()
