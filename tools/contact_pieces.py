"""
Where the contact pass of a resting bin goes, kernel by kernel: the bin of ``python -m
sm_ros.bench contact`` (384 blocks of 144 particles, 55,296 particles, sleeping off),
settled for ``--settle`` steps, then ``--steps`` steps of ``World.step`` at 1/120 s with
``Contact.run`` and the kernels it calls (as ``sm_ros.core.contact`` names them) wrapped
in ``time.perf_counter``.  Prints ms a step for the pass and each kernel, and the pairs
listed and touching.  Run it for two checkouts in turn (``PYTHONPATH=CHECKOUT``, from
outside a checkout) to compare them.

    .venv/bin/python tools/contact_pieces.py
"""

import argparse
import collections
import time

import sm_ros.core.contact as C
from sm_ros.bench.contact import block_bin

#: the kernels ``Contact.run`` calls (a checkout without one skips it; ``max_moved2``: the
#: rebuild test before 3ade5c5)
KERNELS = ('max_moved2', 'moved_spread2', 'body_inverse_masses', 'body_velocities',
           'wall_candidates', 'solve_bodies', 'solve_pairs')


def main():
    """Settle the bin, time its steps, print the pieces."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--settle', type=int, default=200)
    ap.add_argument('--steps', type=int, default=240)
    a = ap.parse_args()
    acc = collections.defaultdict(float)

    def wrap(owner, name, key):
        f = getattr(owner, name)

        def timed(*args, **kw):
            t = time.perf_counter()
            r = f(*args, **kw)
            acc[key] += time.perf_counter() - t
            return r
        setattr(owner, name, timed)

    for name in KERNELS:
        if hasattr(C, name):
            wrap(C, name, name)
    wrap(C.Contact, 'run', 'Contact.run')
    world = block_bin()
    for _ in range(a.settle):
        world.step(1.0 / 120.0)
    acc.clear()
    for _ in range(a.steps):
        world.step(1.0 / 120.0)
    c = world.contact
    print(f'resting bin, {world._flat.n:,} particles, {c.npairs:,} pairs listed, {c.found} '
          f'touching; ms a step over {a.steps} steps:')
    for key in ('Contact.run',) + KERNELS:
        if key in acc:
            print(f'  {key:22s} {1e3 * acc[key] / a.steps:7.3f}')


if __name__ == '__main__':
    main()
