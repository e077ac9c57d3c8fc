"""
A scene's heap with sleeping bodies on and off: its shape after ``--ticks`` node ticks
(``Simulation.tick``) and what a ``World.step`` of it then costs (README "Sleeping
bodies"; doc/benchmarks.md "Sleeping bodies").

For each setting: bodies asleep, median centre height, particle pairs of two bodies
closer than ``--close`` m (cKDTree; scipy, extra ``bench``), the largest distance from a
body to its nearest particle of another body (a body floating above its support shows
here), and the median of ``--steps`` timed ``World.step`` calls after the ticks.

    .venv/bin/python tools/heap_shape.py --scene paper_384 --ticks 600
"""

import argparse
import time

import numpy as np


def shape(scene, sleep, ticks, close, steps):
    """The figures of one setting (a dict)."""
    from scipy.spatial import cKDTree

    from sm_ros.sim import Simulation
    sim = Simulation({'scene': scene, 'contact.sleep': sleep})
    w = sim.world
    for _ in range(ticks):
        sim.tick()
    X = np.concatenate([b.x for b in w.bodies])
    B = np.concatenate([np.full(b.n, k) for k, b in enumerate(w.bodies)])
    pairs = cKDTree(X).query_pairs(close, output_type='ndarray')
    apart = pairs[B[pairs[:, 0]] != B[pairs[:, 1]]]
    gaps = []
    for k, b in enumerate(w.bodies):
        d, _ = cKDTree(X[B != k]).query(b.x, k=1)
        gaps.append(float(d.min()))
    dt = float(sim.params['dt'])
    ts = []
    for _ in range(steps):
        t0 = time.perf_counter()
        w.step(dt)
        ts.append(time.perf_counter() - t0)
    return {'asleep': w.asleep_count, 'bodies': len(w.bodies),
            'median_centre_z': float(np.median([b.com()[2] for b in w.bodies])),
            'pairs_closer': len(apart), 'largest_gap': max(gaps),
            'step_ms': 1e3 * float(np.median(ts))}


def main():
    """Print the figures of both settings."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--scene', default='paper_384')
    ap.add_argument('--ticks', type=int, default=600)
    ap.add_argument('--close', type=float, default=0.03)
    ap.add_argument('--steps', type=int, default=60)
    a = ap.parse_args()
    for sleep in (True, False):
        r = shape(a.scene, sleep, a.ticks, a.close, a.steps)
        print(f"sleep {'on' if sleep else 'off'}: {r['asleep']} of {r['bodies']} asleep, "
              f"median centre z {r['median_centre_z']:.4f} m, {r['pairs_closer']} particle "
              f"pairs of two bodies closer than {a.close} m, every body within "
              f"{r['largest_gap']:.4f} m of another's particle, World.step "
              f"{r['step_ms']:.2f} ms (median of {a.steps})", flush=True)


if __name__ == '__main__':
    main()
