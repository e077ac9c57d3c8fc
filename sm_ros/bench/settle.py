"""How a scene comes to rest: per simulated second, the median and largest wall time of a
step, the bodies asleep, their kinetic energy and the median speed their particles report
above the speed their centres actually move (what a solve that did not converge leaves:
``python -m sm_ros.bench settle --scene paper_384 --seconds 12``)."""

import argparse
import time

import numpy as np


def _centres_and_velocities(flat):
    off = flat.off
    nb = len(off) - 1
    com = np.array([flat.X[:, off[b]:off[b + 1]].mean(axis=1) for b in range(nb)])
    vel = np.array([flat.V[:, off[b]:off[b + 1]].mean(axis=1) for b in range(nb)])
    return com, vel


def _kinetic_energy(flat):
    return 0.5 * float((flat.M * (flat.V ** 2).sum(axis=0)).sum())


def main(argv=None) -> int:
    """Print the table for ``--seconds`` simulated seconds of ``--scene``."""
    p = argparse.ArgumentParser(prog='python -m sm_ros.bench settle', description=__doc__)
    p.add_argument('--scene', default='paper_384')
    p.add_argument('--seconds', type=int, default=12, help='simulated seconds')
    args = p.parse_args(argv)
    from sm_ros.sim import Simulation
    sim = Simulation({'scene': args.scene, 'error_estimate.rate': 0.0})
    world = sim.world
    h = float(sim.params['dt'])
    world.step(h)
    flat = world._flat
    per = int(round(1.0 / h))
    print('second  median ms  max ms  asleep  kinetic J  reported-above-moved m/s')
    for sec in range(args.seconds):
        times = []
        c0, _ = _centres_and_velocities(flat)
        reported = np.zeros_like(c0)
        for _ in range(per):
            t = time.perf_counter()
            world.step(h)
            times.append(time.perf_counter() - t)
            reported += _centres_and_velocities(flat)[1] / per
        c1, _ = _centres_and_velocities(flat)
        moved = (c1 - c0) / (per * h)
        excess = float(np.median(np.linalg.norm(reported - moved, axis=1)))
        ms = 1e3 * np.array(times)
        print(f'{sec:6d}  {np.median(ms):9.1f}  {ms.max():6.1f}  {world.asleep_count:6d}  '
              f'{_kinetic_energy(flat):9.3f}  {excess:.4f}', flush=True)
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
