"""
The contact pair-list rebuild of a moving heap, builder against builder, in CPU time.

Builds ``Simulation({'scene': --scene})`` (no ROS), steps its world ``--seconds`` of
simulated time (pouring), then times on that one state, round-robin over ``--rounds``
rounds: the counting sort by cell alone (``contact_build.grid_sort``), the previous builder
(``build_pairs_cells``) and the current one (``build_pairs_grid``), one thread each, in
CPU time of this process (``time.process_time``: on a shared machine, waiting for a core
is not counted; a threaded builder cannot be timed this way, see ``python -m sm_ros.bench
contact`` for wall time with threads). Prints the fastest and the median call (ms) and the
pairs each builder listed (they must be equal), then how many bodies moved more than half
the skin between two steps over ``--moves`` more steps (per-body reference positions, as a
per-body rebuild would keep them): the share of the rebuild a per-body trigger could save.

    .venv/bin/python tools/contact_rebuild.py --scene paper_384 --seconds 2
"""

import argparse
from pathlib import Path
import statistics
import sys
import time


def main(argv=None) -> int:
    """Run the measurement; print a markdown table."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--scene', default='paper_384')
    ap.add_argument('--seconds', type=float, default=2.0)
    ap.add_argument('--rounds', type=int, default=40)
    ap.add_argument('--moves', type=int, default=20)
    args = ap.parse_args(argv)
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
    import numba
    import numpy as np
    from sm_ros.core import contact_build as cb
    from sm_ros.core.contact import SELF_REST_FACTOR
    from sm_ros.sim import Simulation

    numba.set_num_threads(1)
    sim = Simulation({'scene': args.scene})
    world = sim.world
    dt = float(sim.params['dt'])
    for _ in range(int(round(args.seconds / dt))):
        world.step(dt)
    c = world.contact
    f = world._flat
    f.gather()
    X = f.X.copy()
    dims = np.zeros(3, dtype=np.int64)
    common = (X, f.R, f.B, c.act, c.selfc, f.X0, c.cell, c.skin, SELF_REST_FACTOR, c._hb,
              c._cnt, c._srt)
    calls = {
        'grid_sort (counting sort by cell)': lambda: cb.grid_sort(
            X, f.R, f.B, c.act, c.cell, c._hb, c._cnt, c._srt, c._P, c._sb, c._cb, dims),
        'build_pairs_cells (before)': lambda: cb.build_pairs_cells(
            *common, c._sco, c._pi, c._pj),
        'build_pairs_grid (now)': lambda: cb.build_pairs_grid(
            *common, c._P, c._sb, c._cb, c._pi, c._pj),
    }
    out = {k: fn() for k, fn in calls.items()}          # compiles; the pairs listed
    times = {k: [] for k in calls}
    for _ in range(args.rounds):
        for k, fn in calls.items():
            t0 = time.process_time()
            fn()
            times[k].append(time.process_time() - t0)
    print(f'{args.scene} after {args.seconds:g} s: {f.n:,} particles, cell {c.cell:g} m, '
          f'skin {c.skin:g} m; CPU time of {args.rounds} calls each, one thread\n')
    print('| call | fastest ms | median ms | returned |')
    print('| --- | --- | --- | --- |')
    for k, v in times.items():
        print(f'| {k} | {1e3 * min(v):.2f} | {1e3 * statistics.median(v):.2f} | {out[k]:,} |')
    # per-body trigger: bodies past half the skin since their own last rebuild
    half2 = (0.5 * c.skin) ** 2
    xref = f.X.copy()
    moved = []
    for _ in range(args.moves):
        world.step(dt)
        f.gather()
        d2 = ((f.X - xref) ** 2).sum(axis=0)
        past = np.maximum.reduceat(d2, f.off[:-1]) > half2
        moved.append(int(past.sum()))
        for k in np.nonzero(past)[0]:
            xref[:, f.off[k]:f.off[k + 1]] = f.X[:, f.off[k]:f.off[k + 1]]
    print(f'\nbodies past half the skin since their last rebuild, per step over '
          f'{args.moves} steps: {min(moved)}-{max(moved)} of {len(f.bodies)} '
          f'(median {statistics.median(moved):g})')
    return 0


if __name__ == '__main__':
    sys.exit(main())
