"""Compile (or load from Numba's on-disk cache) every solver kernel the node can need.

``python -m sm_ros.warmup`` (or ``ros2 run sm_ros warmup`` after ``colcon build``) does
ahead of time what the node's first start would otherwise do: on 2 cores compiling the
kernels takes about a minute once; afterwards the node starts in a few seconds.  The
README's ``make run`` / ``make test`` run it when they create the environment.
"""

import argparse
import sys
import time
from typing import Optional, Sequence

import numpy as np


def warm_up() -> float:
    """
    Compile the solver's Numba kernels on a throwaway world; return the seconds it took.

    Covers every deformation mode, clusters, plasticity, colliders, wrenches and kinematic
    particles, so the node's first tick does not pay for compilation. With Numba's on-disk
    cache warm this takes a fraction of a second.
    """
    from sm_ros.core import BodyParams, Box, Ground, Sphere, World
    t0 = time.perf_counter()
    g = np.linspace(-0.05, 0.05, 3)
    cube = np.stack(np.meshgrid(g, g, g, indexing='ij'), axis=-1).reshape(-1, 3)
    world = World(gravity=(0.0, 0.0, -9.81))
    world.set_colliders(ground=Ground(height=0.0, friction=0.5, restitution=0.0),
                        boxes=[Box(lo=(1.0, 1.0, 0.0), hi=(2.0, 2.0, 1.0))],
                        spheres=[Sphere(center=(-1.0, -1.0, 0.0), radius=0.5)])
    configs = [BodyParams(mode='rigid'), BodyParams(mode='linear'),
               BodyParams(mode='quadratic', clusters=2, plastic_yield=0.01,
                          plastic_creep=1.0, plastic_max=0.5),
               BodyParams(mode='linear', clusters=2, plastic_creep=1.0, plastic_max=0.5)]
    bodies = [world.add_body(cube + (0.3 * i, 0.0, 0.1), masses=0.01, params=p,
                             name=f'warm{i}') for i, p in enumerate(configs)]
    bodies[0].set_wrench((0.0, 0.0, 1.0), (0.0, 0.0, 0.1))
    bodies[1].set_kinematic(np.array([0]), cube[:1] + (0.3, 0.0, 0.12))
    for _ in range(2):
        world.step(1.0 / 120.0)
    for b in bodies:
        b.com(), b.rotation(), b.shape_error_rms(), b.momentum(), b.is_finite()
    return time.perf_counter() - t0


def warm_scene(name: str) -> float:
    """Build a scene with the node's default parameters and step it (its own variants)."""
    from sm_ros.scene import build_world, load_scene
    t0 = time.perf_counter()
    world, _ = build_world(load_scene(name))
    world.step(1.0 / 120.0)
    return time.perf_counter() - t0


def main(argv: Optional[Sequence[str]] = None) -> int:
    """Warm the generic kernels and the given bundled scenes (default: 'default')."""
    ap = argparse.ArgumentParser(prog='python -m sm_ros.warmup', description=__doc__)
    ap.add_argument('scenes', nargs='*', default=['default'],
                    help="bundled scene names or YAML paths (default: 'default')")
    args = ap.parse_args(argv)
    print('sm_ros: compiling the solver kernels (once per install)...', flush=True)
    total = warm_up()
    for name in args.scenes:
        total += warm_scene(name)
    print(f'sm_ros: kernels ready ({total:.1f} s)', flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
