"""
The contact pass and its pair-list rebuilds per step of a bundled scene, as it pours:
``Contact.run`` and ``Contact._build`` wrapped in ``time.thread_time`` (thread CPU time,
less sensitive to a shared machine than wall time), ``World.step`` at ``--dt``, sleeping
bodies off (they would skip the pass; ``--sleep on``: as the scene has it).  Every 60
steps: the pass per step, a rebuild and how many, how many bodies the last rebuild's
broad phase put into the grid and how many are asleep.  Run it
for two checkouts in turn (``PYTHONPATH=CHECKOUT``) to compare them.

    .venv/bin/python tools/contact_pass_cost.py --scene many --steps 180
"""

import argparse
import dataclasses
import time

from sm_ros.core import contact as C
from sm_ros.scene import build_world, load_scene


def main():
    """Step the scene and print the figures every 60 steps."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--scene', default='paper_384')
    ap.add_argument('--steps', type=int, default=360)
    ap.add_argument('--dt', type=float, default=1 / 120)
    ap.add_argument('--sleep', choices=('on', 'off'), default='off')
    a = ap.parse_args()
    acc = {'build': 0.0, 'run': 0.0, 'n': 0}
    build, run = C.Contact._build, C.Contact.run

    def timed_build(self):
        t = time.thread_time()
        build(self)
        acc['build'] += time.thread_time() - t
        acc['n'] += 1

    def timed_run(self, *args, **kw):
        t = time.thread_time()
        run(self, *args, **kw)
        acc['run'] += time.thread_time() - t

    C.Contact._build, C.Contact.run = timed_build, timed_run
    w, _ = build_world(load_scene(a.scene))
    w.contact_params = dataclasses.replace(w.contact_params, sleep=a.sleep == 'on')
    for k in range(a.steps):
        w.step(a.dt)
        if k % 60 == 59:
            c = w.contact
            inside = int(c._act_eff[:len(w.bodies)].sum()) if c is not None and hasattr(
                c, '_act_eff') else -1
            print(f"steps {k - 59}-{k}: contact pass {1e3 * acc['run'] / 60:.2f} ms a step, "
                  f"a rebuild {1e3 * acc['build'] / max(acc['n'], 1):.2f} ms x {acc['n']}, "
                  f"bodies in the last build {inside} of {len(w.bodies)}, "
                  f"{len(w.asleep)} asleep", flush=True)
            acc.update(build=0.0, run=0.0, n=0)


if __name__ == '__main__':
    main()
