"""Where a packed ``many`` step goes: the packed call alone, per body, by feature.

Builds worlds of BODIES one-cluster lattices of SHAPE particles (as ``sm_ros.bench
scaling``'s ``many``: linear, alpha 0.5, beta 0.5, damping 0.05, contact off) in variants
that switch features off (damping, speed and turn limits, linear -> rigid), and times the
compiled call over the packed rows (``Pack.step``, no ``World.step`` Python around it)
round-robin: 40 rounds of 10 calls, the minimum of the rounds (the machine is shared:
medians move with the load, minima are the cost without preemption).  Prints one JSON
line, microseconds per body.  Differences of variants give a feature's cost; a run with
SHAPE 1,1,1 gives the fixed cost of a body, and BODIES 1 the fixed cost of a call.

    PYTHONPATH=. .venv/bin/python tools/many_profile.py 64
    PYTHONPATH=. .venv/bin/python tools/many_profile.py 64 1,1,1
"""

import json
import sys
import time

import numpy as np


def build(bodies, shape, **changes):
    """A world of ``bodies`` lattices of ``shape`` particles, the bench's parameters."""
    from sm_ros.bench import scaling
    from sm_ros.core import BodyParams, World
    from sm_ros.core.contact import ContactParams
    world = World(gravity=scaling.GRAVITY)
    world.contact_params = ContactParams(enabled=False)
    g = [np.arange(n) * 0.02 for n in shape]
    x0 = np.stack(np.meshgrid(*g, indexing='ij'), axis=-1).reshape(-1, 3)
    kw = dict(mode='linear', clusters=1, alpha=0.5, beta=0.5, damping=0.05)
    kw.update(changes)
    params = BodyParams(**kw)
    side = int(np.ceil(np.sqrt(bodies)))
    for b in range(bodies):
        world.add_body(x0 + (0.2 * (b % side), 0.2 * (b // side), 1.0), masses=0.01,
                       params=params, name=f'b{b}')
    return world


VARIANTS = {
    'full': {},
    'bare (rigid, no damping, no limits)': dict(damping=0.0, max_speed=0.0, max_turn=0.0,
                                                mode='rigid'),
    'linear, no damping, no limits': dict(damping=0.0, max_speed=0.0, max_turn=0.0),
    'rigid, damping only': dict(max_speed=0.0, max_turn=0.0, mode='rigid'),
    'rigid, speed limit only': dict(damping=0.0, max_turn=0.0, mode='rigid'),
    'rigid, turn limit only': dict(damping=0.0, max_speed=0.0, mode='rigid'),
}


def main(argv=None) -> int:
    """Print us per body of each variant (minimum of 40 rounds of 10 calls)."""
    from sm_ros.bench import scaling
    argv = sys.argv[1:] if argv is None else argv
    bodies = int(argv[0]) if argv else 64
    shape = tuple(int(a) for a in argv[1].split(',')) if len(argv) > 1 else scaling.MANY_BODY
    worlds = {k: build(bodies, shape, **v) for k, v in VARIANTS.items()}
    for w in worlds.values():
        for _ in range(3):
            w.step(scaling.DT)
    samples = {k: [] for k in worlds}
    for _ in range(40):
        for k, w in worlds.items():
            pack = w._split_bodies(scaling.DT)[0]
            args = (scaling.DT, w._gravity, w._has_col, w._ground_row, w._box_rows,
                    w._sphere_rows, 1e-3)
            t0 = time.perf_counter()
            for _ in range(10):
                pack.step(*args)
            samples[k].append((time.perf_counter() - t0) / 10)
    print(json.dumps({'bodies': bodies, 'shape': shape,
                      'us_per_body': {k: round(1e6 * min(v) / bodies, 3)
                                      for k, v in samples.items()}}))
    return 0


if __name__ == '__main__':
    sys.exit(main())
