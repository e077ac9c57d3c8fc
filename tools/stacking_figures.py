"""
Body-body contact per particle (``ContactParams(stacking=False)``) against stacking (the
default), side by side in one process (issue 13: stacks and resting piles at 1/120 s).

Prints, for each of the two settings:

- ``stack``: five stacked boxes (4 x 4 x 3, rigid, alpha 0.99, every other one put 7 mm
  off), settled 4 s, then the top box's sinking and its height's range over 10 s and the
  closest particles of neighbouring boxes (in spacings) (``test/test_contact.py``);
- ``pile``: 27 stiff balls poured into a bin, 4 s: kinetic energy of the last 0.5 s over
  the peak, its RMS speed;
- ``pile8``: the same with balls of 8 clusters (linear, alpha 0.9, as ``paper_384``'s);
- ``bin``: the contact benchmark's bin of 384 blocks (``sm_ros.bench.contact.block_bin``),
  200 steps, then the contact pass per step over 120 steps (median), rebuilds, pairs
  touching, kinetic energy;
- ``bin2``: the same bin in two layers (8 x 24 x 2 blocks);
- ``paper_384`` (``--paper-seconds``, 0 to skip): kinetic energy after pouring, every
  0.5 s, the contact pass per step (median of the last 60 steps) and the pair-list
  rebuilds in those 60 steps.

Sleeping bodies are off in every world here (``ContactParams(sleep=False)``): these are
the contact solver's own figures (asleep, a heap's kinetic energy is zero and its contact
pass skipped; README "Sleeping bodies").

    .venv/bin/python tools/stacking_figures.py --paper-seconds 4
"""

import argparse
import dataclasses
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), '..'))

from sm_ros.bench.contact import ball_pile, block_bin  # noqa: E402
from sm_ros.core import BodyParams, Ground, World  # noqa: E402
from sm_ros.core import contact as contact_mod  # noqa: E402
from sm_ros.core.contact import ContactParams  # noqa: E402

S = 0.02
H = 1 / 120
_TIMES = []


def _timed_run(run):
    def wrapper(self, *a, **k):
        t0 = time.perf_counter()
        out = run(self, *a, **k)
        _TIMES.append(time.perf_counter() - t0)
        return out
    return wrapper


contact_mod.Contact.run = _timed_run(contact_mod.Contact.run)


def _lattice(nx, ny, nz, center):
    g = np.stack(np.meshgrid(np.arange(nx), np.arange(ny), np.arange(nz), indexing='ij'),
                 -1).reshape(-1, 3) * S
    return g - g.mean(axis=0) + np.asarray(center, dtype=float)


def _ke(bodies):
    return sum(0.5 * float((b.m[:, None] * b.v ** 2).sum()) for b in bodies)


def stack(stacking):
    """Five stacked boxes: the top box over 10 s after 4 s of settling."""
    w = World()
    w.contact_params = ContactParams(stacking=stacking, sleep=False)
    w.set_colliders(ground=Ground())
    p = BodyParams(mode='rigid', alpha=0.99, damping=0.5)
    boxes = [w.add_body(_lattice(4, 4, 3, (0.007 * (k % 2), 0.004 * (k % 2), 0.02 + 3 * S * k)),
                        0.01, p, f'b{k}') for k in range(5)]
    for _ in range(4 * 120):
        w.step(H)
    top = []
    for _ in range(10 * 120):
        w.step(H)
        top.append(boxes[-1].com()[2])
    gaps = [float(np.sqrt(((a.x[:, None] - b.x[None]) ** 2).sum(-1)).min()) / S
            for a, b in zip(boxes, boxes[1:])]
    return (f'top box at {top[0]:.4f} m (five high: > {0.02 + 9 * S:.2f}), sinks '
            f'{1e3 * (top[0] - top[-1]):.2f} mm, range {1e3 * (max(top) - min(top)):.2f} mm '
            f'over 10 s; closest neighbours {min(gaps):.2f} spacings')


def pile(stacking, clusters=1):
    """27 balls poured into a bin: their kinetic energy after 4 s."""
    w, bodies = ball_pile(stacking, clusters, sleep=False)
    ke = []
    for _ in range(4 * 120):
        w.step(H)
        ke.append(_ke(bodies))
    m = float(sum(b.m.sum() for b in bodies))
    last = float(np.mean(ke[-60:]))
    return (f'kinetic energy of the last 0.5 s of 4 s: {100 * last / max(ke):.3f} % of the '
            f'peak, {np.sqrt(2 * last / m):.3f} m/s RMS')


def bin_(stacking, layers=1):
    """The contact benchmark's bin: the contact pass per step after 200 steps."""
    w = block_bin(384, layers=layers)
    w.contact_params = ContactParams(stacking=stacking, sleep=False)
    for _ in range(200):
        w.step(H)
    b0 = w.contact.builds
    _TIMES.clear()
    for _ in range(120):
        w.step(H)
    return (f'contact per step {1e3 * np.median(_TIMES):.2f} ms (median of 120), '
            f'{w.contact.builds - b0} rebuilds, {w.contact.found} pairs touching, kinetic '
            f'energy {_ke(w.bodies):.3f} J')


def paper(stacking, seconds):
    """paper_384 poured for ``seconds``: kinetic energy and contact cost every 0.5 s."""
    from sm_ros.scene import build_world, load_scene
    w, _ = build_world(load_scene('paper_384'))
    w.contact_params = dataclasses.replace(w.contact_params, stacking=stacking, sleep=False)
    _TIMES.clear()
    rows = []
    b0 = 0
    for k in range(int(round(seconds / H))):
        w.step(H)
        if k % 60 == 59:
            c = w.contact
            rows.append(f'{(k + 1) * H:.1f} s: {_ke(w.bodies):.3f} J '
                        f'({1e3 * np.median(_TIMES[-60:]):.1f} ms, {c.builds - b0} rebuilds)')
            b0 = c.builds
    return ('kinetic energy (contact per step, rebuilds in the last 60 steps): '
            + ', '.join(rows))


def main():
    """Run the parts for both settings and print one line each."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--paper-seconds', type=float, default=0.0,
                    help='pouring of paper_384 (0: skip)')
    ap.add_argument('--only', default='stack,pile,pile8,bin,bin2,paper',
                    help='parts to run')
    ap.add_argument('--settings', default='per-particle,stacking',
                    help='which settings to run (per-particle, stacking or both)')
    args = ap.parse_args()
    parts = args.only.split(',')
    settings = args.settings.split(',')
    for stacking in (False, True):
        if ('stacking' if stacking else 'per-particle') not in settings:
            continue
        name = 'stacking (default)' if stacking else 'per particle (stacking=False)'
        if 'stack' in parts:
            print(f'{name}: stack: {stack(stacking)}', flush=True)
        if 'pile' in parts:
            print(f'{name}: pile: {pile(stacking)}', flush=True)
        if 'pile8' in parts:
            print(f'{name}: pile of 8-cluster balls: {pile(stacking, 2)}', flush=True)
        if 'bin' in parts:
            print(f'{name}: bin: {bin_(stacking)}', flush=True)
        if 'bin2' in parts:
            print(f'{name}: two-layer bin: {bin_(stacking, 2)}', flush=True)
        if 'paper' in parts and args.paper_seconds > 0:
            print(f'{name}: paper_384: {paper(stacking, args.paper_seconds)}', flush=True)


if __name__ == '__main__':
    main()
