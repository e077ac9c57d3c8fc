"""
``python -m sm_ros.bench.colliders``: what the collider pass costs, side by side.

One soft box body (linear, damping 0.05 like the bundled scenes) rests on a table; the
table is, in turn:

- ``plain``: an unnamed axis-aligned box, resolved inside the body's fused step;
- ``named``: the same box with a name (reports a wrench), through the collider pass;
- ``kinematic``: the named box moving sideways every tick (collider_pose-like moves);
- ``capsules``: the plain table plus two named capsules squeezing the body's sides.

Each is stepped in turn (round-robin, so machine load hits every variant alike) and the
median ms per step is printed with the ratio to ``plain``, plus the grasp scene's step.
"""

import argparse
import statistics
import time
from typing import Dict, List, Optional

import numpy as np


def _world(variant: str, n_side: int):
    from sm_ros.core import BodyParams, Box, Capsule, World
    spacing = 0.01
    half = 0.5 * spacing * (n_side - 1)
    a = np.linspace(-half, half, n_side)
    pts = np.stack(np.meshgrid(a, a, a, indexing='ij'), -1).reshape(-1, 3)
    pts[:, 2] += half + 1e-4
    world = World()
    table = dict(lo=(-1.0, -1.0, -0.1), hi=(1.0, 1.0, 0.0))
    caps = []
    if variant in ('named', 'kinematic'):
        box = Box(**table, name='table', kinematic=variant == 'kinematic')
    else:
        box = Box(**table)
    if variant == 'capsules':
        r = 0.02
        caps = [Capsule(center=(s * (half + r - 0.005), 0.0, half), radius=r,
                        length=2 * half, orientation=(0.7071068, 0.0, 0.0, 0.7071068),
                        name=f'finger{k}') for k, s in enumerate((1.0, -1.0))]
    world.set_colliders(boxes=[box], capsules=caps)
    world.add_body(pts, masses=1.0 / len(pts), params=BodyParams(damping=0.05))
    return world


def run(n_side: int = 30, steps: int = 60, rounds: int = 5,
        dt: float = 1.0 / 120.0) -> Dict[str, float]:
    """Return the median ms/step of each variant (and 'grasp')."""
    from sm_ros.scene import build_world, load_scene
    variants = ['plain', 'named', 'kinematic', 'capsules']
    worlds = {v: _world(v, n_side) for v in variants}
    worlds['grasp'], _ = build_world(load_scene('grasp'))
    times: Dict[str, List[float]] = {k: [] for k in worlds}
    for w in worlds.values():                 # compile / load the kernels, settle
        for _ in range(5):
            w.step(dt)
    for _ in range(rounds):
        for name, w in worlds.items():
            for _ in range(steps):
                if name == 'kinematic':
                    p, _q = w.collider_pose('table')
                    w.move_collider('table', p + (0.001, 0.0, 0.0), duration=dt)
                t0 = time.perf_counter()
                w.step(dt)
                times[name].append(time.perf_counter() - t0)
    return {k: 1e3 * statistics.median(v) for k, v in times.items()}


def main(argv: Optional[List[str]] = None) -> int:
    """Print the table; returns 0."""
    ap = argparse.ArgumentParser(prog='python -m sm_ros.bench.colliders', description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument('--side', type=int, default=30, help='particles per box edge (30: 27k)')
    ap.add_argument('--steps', type=int, default=60, help='steps per variant per round')
    ap.add_argument('--rounds', type=int, default=5, help='round-robin rounds')
    args = ap.parse_args(argv)
    ms = run(args.side, args.steps, args.rounds)
    n = args.side ** 3
    base = ms['plain']
    print(f'collider pass, one body of {n} particles resting on a table (median ms/step)')
    print('| variant | ms/step | / plain |')
    print('| --- | --- | --- |')
    for k in ('plain', 'named', 'kinematic', 'capsules'):
        print(f'| {k} | {ms[k]:.3f} | {ms[k] / base:.2f} |')
    print(f'| grasp scene (515 particles, 2 moving capsules) | {ms["grasp"]:.3f} | |')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
