"""
``python -m sm_ros.bench tick``: the node's tick on a bundled scene, without ROS.

Builds ``Simulation({'scene': SCENE})`` as the node does and times ``--ticks`` calls of
``Simulation.tick`` (the substeps, the checks and the live error estimate at its default
budget; no publishing) from the scene's start, or after ``--settle`` world steps. Prints
the median, 90th percentile and largest tick, the median and the worst of the per-second
medians (one second = ``rate`` ticks), and how many bodies sleep at the end; with
``--timeline`` also every second's median as it goes; with ``--grab`` a gripper holds the
first body and moves it up and down every tick, as a driver node would (the grab is
timed with the tick). Run it on two checkouts in turn
(``PYTHONPATH=CHECKOUT``) to compare them::

    python -m sm_ros.bench tick --scene paper_384 --ticks 600 --timeline
"""

import argparse
import json
import os
import sys
import time
from typing import Any, Dict, List, Optional

import numpy as np


def add_arguments(parser: argparse.ArgumentParser):
    """Add the flags of the ``tick`` subcommand."""
    parser.add_argument('--scene', default='paper_384', help='bundled scene name or scene file')
    parser.add_argument('--ticks', type=int, default=600, help='ticks timed (600: 10 s at 60 Hz)')
    parser.add_argument('--settle', type=int, default=0,
                        help='world steps taken before timing (0: time from the start)')
    parser.add_argument('--sleep', choices=('on', 'off'), default='on',
                        help='sleeping bodies (contact.sleep)')
    parser.add_argument('--timeline', action='store_true', help="print every second's median")
    parser.add_argument('--grab', action='store_true',
                        help='a gripper holds the first body and moves it every tick')
    parser.add_argument('--json', action='store_true', help='print the figures as one JSON line')


def measure(scene: str, ticks: int, settle: int = 0, sleep: bool = True,
            timeline: bool = False, grab: bool = False) -> Dict[str, Any]:
    """Time ``ticks`` ticks of ``scene`` (with ``grab``, each after a gripper move);
    return the figures (ms)."""
    from sm_ros.sim import Simulation
    sim = Simulation({'scene': scene, 'contact.sleep': sleep})
    dt = float(sim.params['dt'])
    per_second = max(1, int(round(float(sim.params['rate']))))
    for _ in range(settle):
        sim.world.step(dt)
    wall: List[float] = []
    seconds: List[float] = []
    centre = sim.world.bodies[0].x.mean(axis=0)
    for k in range(ticks):
        start = time.perf_counter()
        if grab:
            lift = 0.05 * (1.0 - np.cos(k / 30.0))        # 0 at the first, attaching, grab
            sim.grab('bench', centre + (0.0, 0.0, lift), (0.0, 0.0, 0.0, 1.0))
        sim.tick()
        wall.append(1e3 * (time.perf_counter() - start))
        if len(wall) % per_second == 0:
            seconds.append(float(np.median(wall[-per_second:])))
            if timeline:
                print(f'second {len(seconds):3d}: median tick {seconds[-1]:7.2f} ms, '
                      f'{sim.world.asleep_count} bodies asleep', flush=True)
    times_ms = np.asarray(wall)
    return {'scene': scene, 'ticks': ticks, 'settle_steps': settle, 'sleep': sleep, 'grab': grab,
            'points': sim.num_points, 'bodies': len(sim.world.bodies),
            'tick_ms_median': float(np.median(times_ms)),
            'tick_ms_p90': float(np.percentile(times_ms, 90)),
            'tick_ms_max': float(times_ms.max()),
            'second_ms_median': float(np.median(seconds)) if seconds else None,
            'second_ms_worst': max(seconds) if seconds else None,
            'asleep_at_end': sim.world.asleep_count, 'loadavg_1min': _load(),
            'held_particles': sum(len(a.indices) for a in sim.grippers.get('bench', []))}


def _load() -> Optional[float]:
    try:
        return round(os.getloadavg()[0], 2)
    except OSError:
        return None


def main(argv: Optional[List[str]] = None) -> int:
    """Entry point of ``python -m sm_ros.bench tick``."""
    parser = argparse.ArgumentParser(prog='python -m sm_ros.bench tick', description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    add_arguments(parser)
    args = parser.parse_args(argv)
    res = measure(args.scene, args.ticks, args.settle, args.sleep == 'on', args.timeline,
                  args.grab)
    if args.json:
        print(json.dumps(res))
        return 0
    worst = res['second_ms_worst']
    print(f"{res['scene']} ({res['points']} points, {res['bodies']} bodies), {res['ticks']} "
          f"ticks: median {res['tick_ms_median']:.2f} ms, p90 {res['tick_ms_p90']:.2f}, largest "
          f"{res['tick_ms_max']:.2f}; per-second medians: median "
          f"{res['second_ms_median'] or float('nan'):.2f}, worst "
          f"{worst if worst is not None else float('nan'):.2f} ms; sleep "
          f"{'on' if res['sleep'] else 'off'}: {res['asleep_at_end']} of {res['bodies']} "
          f"bodies asleep at the end{'; a gripper moved every tick' if res['grab'] else ''}; "
          f"load average {res['loadavg_1min']}")
    return 0


if __name__ == '__main__':
    sys.exit(main())
