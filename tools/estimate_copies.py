"""
What making the live error estimate's copies costs: a deep copy against a sync into the
last estimate's copy (``sm_ros.world_sync.Twin``), side by side in one process.

Builds ``Simulation({'scene': --scene})`` (no ROS), steps the world ``--settle`` times and
makes a twin; then, ``--rounds`` times: the twin and the world step apart, and the world's
state is copied both ways, each followed by the copy's first step (where a deep copy
re-packs its bodies' buffers).  Prints the medians (ms) of the rounds after the first,
the first round's sync (it walks both worlds and records the plan the later ones replay)
and checks that the synced copy steps bit for bit as the deep copy.

    .venv/bin/python tools/estimate_copies.py --scene paper_384
"""

import argparse
import statistics
import time

import numpy as np

from sm_ros.error_estimate import copy_world
from sm_ros.sim import Simulation
from sm_ros.world_sync import Twin


def main():
    """Run the comparison and print it."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--scene', default='paper_384')
    ap.add_argument('--settle', type=int, default=30)
    ap.add_argument('--rounds', type=int, default=5)
    a = ap.parse_args()
    sim = Simulation({'scene': a.scene})
    world, sim_dt = sim.world, float(sim.params['dt'])
    for _ in range(a.settle):
        world.step(sim_dt)
    twin = Twin(copy_world(world))
    twin.world.step(sim_dt)
    rows = {'deep copy': [], 'deep copy, first step': [], 'sync': [],
            'sync, first step': []}
    walk = None
    same = True
    for r in range(a.rounds + 1):
        twin.world.step(sim_dt)
        world.step(sim_dt)
        t0 = time.perf_counter()
        fresh = copy_world(world)
        t1 = time.perf_counter()
        fresh.step(sim_dt)
        t2 = time.perf_counter()
        assert twin.sync(world), 'sync refused'
        t3 = time.perf_counter()
        twin.world.step(sim_dt)
        t4 = time.perf_counter()
        same = same and all(np.array_equal(p.x, q.x) and np.array_equal(p.v, q.v)
                            for p, q in zip(fresh.bodies, twin.world.bodies))
        if r:                                # the first sync walks; later ones replay
            for k, v in zip(rows, (t1 - t0, t2 - t1, t3 - t2, t4 - t3)):
                rows[k].append(1e3 * v)
        else:
            walk = 1e3 * (t3 - t2)
    for k, v in rows.items():
        print(f'{k:24s} median {statistics.median(v):7.1f} ms')
    print(f'{"first sync (the walk)":24s}        {walk:7.1f} ms')
    print('synced copy steps as the deep copy, bit for bit:', same)


if __name__ == '__main__':
    main()
