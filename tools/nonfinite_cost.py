"""
The per-tick non-finite check, side by side in one process: every body asked in turn
(``Body.is_finite``, what ``Simulation.reset_nonfinite`` did) against one compiled call
over all bodies (``sm_ros.nonfinite.NonFiniteCheck``), on bundled scenes and a 100k box,
after a step of each world (medians of ``--rounds`` rounds, microseconds).

    .venv/bin/python tools/nonfinite_cost.py --scenes many,paper_384
"""

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path


def main(argv=None) -> int:
    """Run the measurement; print a markdown table."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--scenes', default='many,paper_384')
    ap.add_argument('--box', type=int, default=97336, help='particles of the box (0: none)')
    ap.add_argument('--rounds', type=int, default=50)
    args = ap.parse_args(argv)
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
    from sm_ros.bench import harness
    from sm_ros.nonfinite import NonFiniteCheck
    from sm_ros.sim import Simulation

    scenes = [s for s in args.scenes.split(',') if s]
    tmp = tempfile.TemporaryDirectory()
    if args.box:
        path = Path(tmp.name) / 'box.yaml'
        harness.box_scene(args.box, path, 0.05)
        scenes.append(str(path))
    print('| scene | bodies | points | every body asked (us) | one call (us) | ratio |')
    print('| --- | --- | --- | --- | --- | --- |')
    for scene in scenes:
        sim = Simulation({'scene': scene, 'clusters': 2 if scene.endswith('box.yaml') else 1})
        world, dt = sim.world, float(sim.params['dt'])
        check = NonFiniteCheck()
        check.bad_bodies(world.bodies)
        old, new = [], []
        for _ in range(args.rounds):
            world.step(dt)
            t0 = time.perf_counter()
            a = [b.name for b in world.bodies if not b.is_finite()]
            t1 = time.perf_counter()
            world.step(dt)
            t2 = time.perf_counter()
            b = [x.name for x in check.bad_bodies(world.bodies)]
            t3 = time.perf_counter()
            assert a == b == []
            old.append(t1 - t0)
            new.append(t3 - t2)
        mo, mn = 1e6 * statistics.median(old), 1e6 * statistics.median(new)
        name = 'box' if scene.endswith('box.yaml') else scene
        print(f'| {name} | {len(world.bodies)} | {sim.num_points} | {mo:.1f} | {mn:.1f} | '
              f'{mo / mn:.1f}x |')
    return 0


if __name__ == '__main__':
    sys.exit(main())
