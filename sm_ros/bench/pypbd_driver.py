"""
The pypbd peer of the scaling benchmark: one configuration per process.

pypbd (the Python bindings of PositionBasedDynamics 2.2.2) simulates the benchmark's body
with shape-matching constraints only: an n x n x n particle lattice on the unit cube
(pypbd's regular tet model; its tets are not used), unit masses, pypbd's gravity and step
(5 ms), one solver iteration, no collision detection. The clusters are the ones sm_ros
builds for the same lattice (``sm_ros.core.clusters.build_memberships``: k cubes per axis,
each enlarged by half a cube), each particle weighted by the number of clusters it is in,
so both sides solve the same cluster layout.

pypbd keeps its simulation, time manager and timers as process-wide singletons, so
``python -m sm_ros.bench.scaling`` runs this module once per configuration::

    python -m sm_ros.bench.pypbd_driver --n 22 --k 2 --steps 30

It prints one JSON line: the lattice and cluster figures (``N``, ``clusters``,
``memberships``), the step times in ms (``median_ms``, ``min_ms``, ``first_step_ms``) and
a sanity check (the centre of mass falls as symplectic Euler drops it, the shape is kept). Set
``OMP_NUM_THREADS`` to choose pypbd's threads.
"""

import argparse
import json
import os
import sys
import time
from typing import Any, Dict, List, Optional, Sequence

import numpy as np


def lattice(pbd, model, n: int) -> np.ndarray:
    """Add an n x n x n particle lattice on the unit cube to ``model``; return its points."""
    model.addRegularTetModel(n, n, n, scale=[1.0, 1.0, 1.0])
    return np.array(model.getParticles().getVertices(), dtype=np.float64, copy=True)


def clusters(points: np.ndarray, k: int) -> List[np.ndarray]:
    """Return the particle indices of each cluster, as sm_ros builds them for ``points``."""
    from sm_ros.core.clusters import build_memberships
    ptr, cluster_ids, n_clusters = build_memberships(points, k)
    owner = np.repeat(np.arange(len(points)), np.diff(ptr))
    order = np.argsort(cluster_ids, kind='stable')
    bounds = np.searchsorted(cluster_ids[order], np.arange(n_clusters + 1))
    return [owner[order[bounds[c]:bounds[c + 1]]] for c in range(n_clusters)]


def run(n: int, k: int, steps: int, warmup: int, substeps: int = 1,
        iterations: int = 1) -> Dict[str, Any]:
    """Build the model, step it, and return the figures."""
    import pypbd as pbd
    t0 = time.perf_counter()
    sim = pbd.Simulation.getCurrent()
    model = pbd.SimulationModel()
    model.init()
    sim.setModel(model)                       # no initDefault(): no collision detection
    step = sim.getTimeStep()
    step.setValueUInt(pbd.TimeStepController.NUM_SUB_STEPS, substeps)
    step.setValueUInt(pbd.TimeStepController.MAX_ITERATIONS, iterations)
    step.setValueUInt(pbd.TimeStepController.MAX_ITERATIONS_V, 0)
    dt = pbd.TimeManager.getCurrent().getTimeStepSize()
    x0 = lattice(pbd, model, n)
    members = clusters(x0, k)
    count = np.zeros(len(x0), dtype=np.int64)
    for idx in members:
        count[idx] += 1
    for idx in members:
        model.addShapeMatchingConstraint(len(idx), idx.tolist(), count[idx].tolist(), 1.0)
    build_s = time.perf_counter() - t0

    t1 = time.perf_counter()
    step.step(model)                          # the first step also groups the constraints
    first_ms = 1e3 * (time.perf_counter() - t1)
    for _ in range(max(warmup - 1, 0)):
        step.step(model)
    times = []
    for _ in range(steps):
        t = time.perf_counter()
        step.step(model)
        times.append(1e3 * (time.perf_counter() - t))
    x = np.array(model.getParticles().getVertices(), dtype=np.float64, copy=True)
    total = max(warmup, 1) + steps            # steps taken, each x += h (v + h g)
    shape = (x - x.mean(axis=0)) - (x0 - x0.mean(axis=0))
    return {
        'n': n, 'N': len(x0), 'k': k, 'clusters': len(members),
        'memberships': int(count.sum()), 'substeps': substeps, 'iterations': iterations,
        'dt': dt, 'omp_threads': os.environ.get('OMP_NUM_THREADS', 'default'),
        'build_s': build_s, 'first_step_ms': first_ms, 'steps': steps,
        'median_ms': float(np.median(times)), 'min_ms': float(np.min(times)),
        'mean_ms': float(np.mean(times)),
        'com_drop_m': float(x0[:, 1].mean() - x[:, 1].mean()),
        'com_drop_expected_m': 9.81 * dt ** 2 * total * (total + 1) / 2,
        'shape_rms_m': float(np.sqrt((shape ** 2).sum(axis=1).mean())),
    }


def main(argv: Optional[Sequence[str]] = None) -> int:
    """Run one configuration and print its JSON line."""
    ap = argparse.ArgumentParser(prog='python -m sm_ros.bench.pypbd_driver',
                                 description=__doc__.strip().splitlines()[0])
    ap.add_argument('--n', type=int, required=True, help='particles per lattice edge')
    ap.add_argument('--k', type=int, default=1, help='cluster cubes per axis')
    ap.add_argument('--steps', type=int, default=30, help='timed steps')
    ap.add_argument('--warmup', type=int, default=3, help='untimed steps first')
    ap.add_argument('--substeps', type=int, default=1)
    ap.add_argument('--iterations', type=int, default=1)
    args = ap.parse_args(argv)
    try:
        import pypbd  # noqa: F401
    except ImportError:
        print('pypbd is not installed (pip install pypbd, the bench extra)', file=sys.stderr)
        return 2
    print(json.dumps(run(args.n, args.k, args.steps, args.warmup, args.substeps,
                         args.iterations)), flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
