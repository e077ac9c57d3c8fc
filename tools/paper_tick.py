"""
The node's tick on a scene, as users run it: ``Simulation.tick`` (substeps, checks, the
live error estimate with its default budget; no ROS publishing), after pouring.

Builds ``Simulation({'scene': --scene})``, steps the world ``--settle`` times, runs 3
ticks, then times ``--ticks`` ticks and prints the median, 90th percentile and largest
tick (wall) and the median process CPU (above wall when the record helpers had a core).
Run it for two checkouts in turn (``PYTHONPATH=CHECKOUT``) to compare them.
``--sleep off`` turns sleeping bodies off (``contact.sleep``, README "Sleeping bodies");
``--settle 0 --ticks 1200`` times the first 20 s from the start (the pour, then the heap
at rest), and prints how many bodies sleep at the end.

    .venv/bin/python tools/paper_tick.py --scene paper_384 --ticks 90
    .venv/bin/python tools/paper_tick.py --scene paper_384 --settle 0 --ticks 1200 --timeline
"""

import argparse
import time

import numpy as np

from sm_ros.sim import Simulation


def main():
    """Time the ticks and print the figures."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--scene', default='paper_384')
    ap.add_argument('--settle', type=int, default=360)
    ap.add_argument('--ticks', type=int, default=90)
    ap.add_argument('--sleep', choices=('on', 'off'), default='on')
    ap.add_argument('--timeline', action='store_true',
                    help='also print the median tick and the bodies asleep every 60 ticks')
    a = ap.parse_args()
    sim = Simulation({'scene': a.scene, 'contact.sleep': a.sleep == 'on'})
    dt = float(sim.params['dt'])
    for _ in range(a.settle):
        sim.world.step(dt)
    for _ in range(3 if a.settle else 0):
        sim.tick()
    wall, cpu = [], []
    for _ in range(a.ticks):
        t, c = time.perf_counter(), time.process_time()
        sim.tick()
        wall.append(time.perf_counter() - t)
        cpu.append(time.process_time() - c)
        if a.timeline and len(wall) % 60 == 0:
            print(f'ticks {len(wall) - 59}-{len(wall)}: median '
                  f'{1e3 * np.median(wall[-60:]):.2f} ms, {sim.world.asleep_count} asleep',
                  flush=True)
    w, c = 1e3 * np.array(wall), 1e3 * np.array(cpu)
    print(f'{a.scene}: tick median {np.median(w):.1f} ms, p90 {np.percentile(w, 90):.1f}, '
          f'largest {w.max():.1f} | process CPU median {np.median(c):.1f} ms | sleep '
          f'{a.sleep}: {sim.world.asleep_count} of {len(sim.world.bodies)} bodies asleep '
          f'at the end')


if __name__ == '__main__':
    main()
