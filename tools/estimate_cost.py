"""
What the live error estimate adds to a tick, side by side in one process.

Builds ``Simulation({'scene': --scene})`` (no ROS), steps the world ``--settle`` times, then
times ``Simulation.tick()`` round-robin over ``--rounds`` rounds of ``--ticks`` ticks each
for: the estimate off (``error_estimate.rate`` 0); the copies at the simulation's pace (the
schedule before the budget: ``substeps`` coarse steps a tick, 3x the tick's steps while
a window runs); and within ``error_estimate.budget`` (``--budget``). Prints, per
configuration, the median / mean / largest tick (ms), the mean world steps the copies
added per tick and the ticks an estimate took; then the first step of a copy made with
``copy.deepcopy`` (writeable arrays: other kernel specialisations) against one made with
``sm_ros.error_estimate.copy_world``.

    .venv/bin/python tools/estimate_cost.py --scene paper_384
"""

import argparse
import copy
import statistics
import sys
import time
from pathlib import Path


def main(argv=None) -> int:
    """Run the measurement; print markdown tables."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--scene', default='paper_384')
    ap.add_argument('--settle', type=int, default=120)
    ap.add_argument('--rounds', type=int, default=3)
    ap.add_argument('--ticks', type=int, default=12)
    ap.add_argument('--budget', type=float, default=0.25)
    args = ap.parse_args(argv)
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
    from sm_ros import stats as stats_mod
    from sm_ros.error_estimate import copy_world
    from sm_ros.sim import Simulation

    sim = Simulation({'scene': args.scene})
    dt = float(sim.params['dt'])
    for _ in range(args.settle):
        sim.world.step(dt)
    configs = {'estimate off (rate 0)': (0.0, None),
               'copies at the simulation pace (before)': (1.0, None),
               f'within budget {args.budget:g} (now)': (1.0, args.budget)}
    ticks = {k: [] for k in configs}
    units = {k: [] for k in configs}
    done = {k: [] for k in configs}
    scheds = {}
    for name, (rate, budget) in configs.items():
        # each configuration keeps its own schedule (its estimate in progress); "before"
        # is the schedule without a budget (None), whatever the parameter says
        sched = scheds[name] = stats_mod.ErrorEstimateSchedule()
        orig = sched.advance

        def paced(world, dt_, substeps, rate_, clock, budget_=None, orig=orig, budget=budget):
            return orig(world, dt_, substeps, rate_, clock, budget)
        sched.advance = paced
    for _ in range(args.rounds):
        for name, (rate, budget) in configs.items():
            sched = sim._estimates = scheds[name]
            sim.params['error_estimate.rate'] = rate
            for _ in range(args.ticks):
                before = sched.result
                t0 = time.perf_counter()
                sim.tick()
                ticks[name].append(time.perf_counter() - t0)
                units[name].append(sched.units)
                if sched.result is not before:
                    done[name].append(sched.result['units'])
    steps_per_tick = int(sim.params['substeps'])
    print(f'{args.scene}: {sim.num_points} points, {len(sim.world.bodies)} bodies, '
          f'dt {dt:.6g} s x {steps_per_tick} substeps; {args.rounds} rounds of '
          f'{args.ticks} ticks round-robin\n')
    print('| configuration | tick median (ms) | tick mean (ms) | tick max (ms) | '
          'copy steps per tick (mean) | estimates done |')
    print('| --- | --- | --- | --- | --- | --- |')
    for name in configs:
        t = [1e3 * s for s in ticks[name]]
        print(f'| {name} | {statistics.median(t):.1f} | {statistics.mean(t):.1f} | '
              f'{max(t):.1f} | {statistics.mean(units[name]):.2f} | {len(done[name])} |')

    print('\n| first step of a copy | copy (ms) | first step (ms) | second step (ms) |')
    print('| --- | --- | --- | --- |')
    for name, make in (('copy_world (read-only flags kept)', copy_world),
                       ('copy.deepcopy', copy.deepcopy)):
        t0 = time.perf_counter()
        twin = make(sim.world)
        t1 = time.perf_counter()
        twin.step(dt)
        t2 = time.perf_counter()
        twin.step(dt)
        t3 = time.perf_counter()
        print(f'| {name} | {1e3 * (t1 - t0):.0f} | {1e3 * (t2 - t1):.0f} | '
              f'{1e3 * (t3 - t2):.0f} |')
    return 0


if __name__ == '__main__':
    sys.exit(main())
