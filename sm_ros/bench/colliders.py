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

``--motion``: what moving colliders cost per step, the compiled pose update
(``collider_motion.advance_poses``) side by side with its Python twin (the former
per-collider loop): K = 1..32 capsules on scripted paths or under commanded moves, and the
grasp scene's whole step with its two fingers moving and at rest.
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


def _motion_set(k: int, kind: str):
    from sm_ros.core import Capsule, World
    rz = (0.0, 0.0, 0.0499792, 0.9987503)
    path = ((100.0, (0.0, 1.0, 1.0), rz),) if kind == 'path' else ()
    caps = [Capsule(center=(float(i), 0.0, 1.0), radius=0.02, length=0.1, name=f'c{i}',
                    kinematic=True, path=path) for i in range(k)]
    world = World()
    world.set_colliders(capsules=caps)
    return world._cset


def motion(rounds: int = 7, calls: int = 300, dt: float = 1.0 / 120.0):
    """{(K, kind): (compiled us, Python us)} median per advance, and the grasp scene's
    {variant: ms/step} (fingers moving / at rest, compiled / Python)."""
    from sm_ros.core import collider_motion as CM
    from sm_ros.core.colliders import ColliderSet
    from sm_ros.scene import build_world, load_scene

    def args(colliders, t):
        return colliders.motion_arrays(), colliders.keys, colliders.rows, dt, t

    out = {}
    for k in (1, 2, 8, 32):
        for kind in ('path', 'move'):
            sets = {f: _motion_set(k, kind) for f in ('compiled', 'python')}
            times: Dict[str, List[float]] = {f: [] for f in sets}
            fns = {'compiled': CM.advance_poses, 'python': CM.advance_reference}
            fns['compiled'](*args(sets['compiled'], 0.0))          # compile / load
            for _ in range(rounds):
                for f, cs in sets.items():
                    for i in range(calls):
                        if kind == 'move':           # a new move each step, like the node
                            for c in range(k):
                                cs.move(f'c{c}', (float(c), 0.001 * (i % 7), 1.0),
                                        (0.0, 0.0, 0.0499792, 0.9987503), dt)
                        t0 = time.perf_counter()
                        fns[f](*args(cs, 0.5))
                        times[f].append(time.perf_counter() - t0)
                        cs.done[:] = 0
            out[(k, kind)] = tuple(1e6 * statistics.median(times[f]) for f in sets)
    python_advance = ColliderSet.advance

    def advance_python(self, h, t=0.0):
        python_advance(self, h, t, CM.advance_reference)

    worlds = {}
    for v in ('moving', 'at rest'):
        w, _ = build_world(load_scene('grasp'))
        for _ in range(5 if v == 'moving' else 200):         # the path is over at 1.5 s
            w.step(dt)
        worlds[v] = w
    start = worlds['moving'].time
    grasp: Dict[str, List[float]] = {}
    try:
        for _ in range(rounds):
            for impl in ('compiled', 'python'):
                ColliderSet.advance = python_advance if impl == 'compiled' else advance_python
                for v, w in worlds.items():
                    for _ in range(calls // 5):
                        if v == 'moving' and w.time > 0.45:          # fingers still closing
                            w.reset()
                            while w.time < start:
                                w.step(dt)
                        t0 = time.perf_counter()
                        w.step(dt)
                        grasp.setdefault(f'{v}, {impl}', []).append(time.perf_counter() - t0)
    finally:
        ColliderSet.advance = python_advance
    return out, {k: 1e3 * statistics.median(v) for k, v in grasp.items()}


def main(argv: Optional[List[str]] = None) -> int:
    """Print the table; returns 0."""
    parser = argparse.ArgumentParser(prog='python -m sm_ros.bench.colliders', description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--side', type=int, default=30, help='particles per box edge (30: 27k)')
    parser.add_argument('--steps', type=int, default=60, help='steps per variant per round')
    parser.add_argument('--rounds', type=int, default=5, help='round-robin rounds')
    parser.add_argument('--motion', action='store_true',
                    help='moving colliders: compiled pose update against the Python loop')
    args = parser.parse_args(argv)
    if args.motion:
        us, grasp = motion(args.rounds)
        print('moving colliders: pose update per step (median us), compiled and Python')
        print('| colliders | motion | compiled us | Python us | Python / compiled |')
        print('| --- | --- | --- | --- | --- |')
        for (k, kind), (a, b) in us.items():
            print(f'| {k} | {kind} | {a:.2f} | {b:.1f} | {b / a:.0f} |')
        print('grasp scene, whole World.step (median ms)')
        print('| fingers | compiled | Python |')
        print('| --- | --- | --- |')
        for v in ('moving', 'at rest'):
            print(f'| {v} | {grasp[f"{v}, compiled"]:.4f} | {grasp[f"{v}, python"]:.4f} |')
        return 0
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
