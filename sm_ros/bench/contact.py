"""
``python -m sm_ros.bench contact``: body-body contact against scipy's cKDTree, side by side.

The bin scene: 384 blocks of 6 x 6 x 4 = 144 particles (55,296) touching in a bin
(one layer, side by side), spacing 2 cm, contact radius 1 cm, one thread. Printed and
written to ``--out``:

- cKDTree baseline: build + ``query_pairs(2 r)`` + dropping same-body pairs, per call, on
  the resting bin squeezed by 5 % (``squeezed``: thousands of facing pairs overlapping);
- sm_ros: the contact pass (Verlet list check, rebuild when needed, projection) per step
  of the blocks resting under gravity, median and mean, with its count of rebuilds; the
  rebuild alone and the per-step part alone; the flat-state copies (gather/scatter) that
  the World needs until it owns the flat arrays; the bodies' own step (shape matching)
  of the same scene;
- the pair-list builder: the rebuild alone and a step that rebuilds (bodies moving), on
  the resting bin and on ``paper_384`` while it pours;
- one body without self-collision: world step with contact on and off;
- scaling: the contact pass on 1x, 2x, 4x, 10x the blocks (log-log slope in N);
- ``paper_384``: the node's tick (``Simulation.tick``: 2 substeps, no ROS publishing) once
  the heap has formed (``--paper-seconds`` of simulated pouring first), and the contact
  pass's share of it, sleeping bodies off (``contact.sleep``: the contact pass is what is
  timed);
- sleeping bodies: ``--sleep-scene`` (``paper_384``) as users run it, from the start for
  ``--sleep-seconds`` of simulated time, with sleeping on and off (two simulations ticked
  in turn): the median tick over the whole run and once every body sleeps.

The bin, the scaling and the builders time the contact pass, so their worlds do not sleep
(asleep, a resting bin would skip the pass).

``--write-doc`` replaces the contact section of ``doc/benchmarks.md`` with the tables.
scipy is needed for the baseline (extra ``bench``); without it that column is empty.
"""

import argparse
import json
from pathlib import Path
import shlex
import sys
import time
from typing import Any, Dict, List, Optional

import numpy as np

from . import common as bc
from .contact_doc import markdown, write_doc
from .contact_scenes import ball_pile, block_bin, SPACING, squeezed  # noqa: F401



def add_arguments(p: argparse.ArgumentParser):
    """Options of the contact benchmark."""
    p.add_argument('--out', default='bench_out', help='output directory')
    p.add_argument('--steps', type=int, default=240, help='timed steps of the resting bin')
    p.add_argument('--settle', type=int, default=200, help='untimed steps before them')
    p.add_argument('--scales', default='1,2,4,10',
                   help='block-count multiples for the scaling table')
    p.add_argument('--paper-seconds', type=float, default=3.0,
                   help='simulated pouring of paper_384 before its ticks are timed '
                        '(0: skip paper_384)')
    p.add_argument('--paper-ticks', type=int, default=60, help='timed ticks of paper_384')
    p.add_argument('--sleep-scene', default='paper_384',
                   help='scene of the sleeping-bodies rows')
    p.add_argument('--sleep-seconds', type=float, default=20.0,
                   help='simulated time of the sleeping-bodies rows (0: skip them)')
    p.add_argument('--threads', type=int, default=1, help='Numba threads')
    p.add_argument('--blocks', type=int, default=384, help='blocks in the bin (a smoke run: few)')
    p.add_argument('--one-body-side', type=int, default=38,
                   help='side of the one-body lattice (38^3 = 54,872 particles)')
    p.add_argument('--write-doc', action='store_true',
                   help='write the tables into doc/benchmarks.md')


def _median_ms(samples) -> float:
    return 1e3 * float(np.median(samples))


def ckdtree_ms(X: np.ndarray, B: np.ndarray, r: float) -> Optional[Dict[str, float]]:
    """Median ms of cKDTree build + query_pairs(2 r) + dropping same-body pairs."""
    try:
        from scipy.spatial import cKDTree
    except ImportError:
        return None
    pts = np.ascontiguousarray(X.T)

    def once():
        tree = cKDTree(pts)
        p = tree.query_pairs(2.0 * r, output_type='ndarray')
        return p[B[p[:, 0]] != B[p[:, 1]]]
    pairs = len(once())
    t = bc.time_calls(once, min_time=1.0, min_reps=5, max_reps=30)
    return {'ms': _median_ms(t), 'ms_min': 1e3 * float(t.min()), 'pairs': pairs}


def _timed(obj, name, into):
    """Wrap the method ``name`` of ``obj`` (an instance) so each call appends its time."""
    fn = getattr(obj, name)

    def wrapper(*a, **k):
        t0 = time.perf_counter()
        r = fn(*a, **k)
        into.append(time.perf_counter() - t0)
        return r
    setattr(obj, name, wrapper)


def settle_and_time(world, steps: int, h: float = 1.0 / 120.0) -> Dict[str, Any]:
    """Step the world; time each step and its contact pass, gather and scatter."""
    c = world.contact
    f = world._flat
    parts = {k: [] for k in ('gather', 'contact', 'scatter')}
    _timed(f, 'gather', parts['gather'])
    _timed(c, 'run', parts['contact'])
    _timed(f, 'scatter', parts['scatter'])
    builds0 = c.builds
    found, total = [], []
    for _ in range(steps):
        t0 = time.perf_counter()
        world.step(h)
        total.append(time.perf_counter() - t0)
        found.append(c.found)
    for k in parts:
        delattr(f if k != 'contact' else c, 'run' if k == 'contact' else k)
    parts['bodies'] = [t - g - r - s for t, g, r, s in
                       zip(total, parts['gather'], parts['contact'], parts['scatter'])]
    out = {k: {'median_ms': _median_ms(v), 'mean_ms': 1e3 * float(np.mean(v)),
               'p90_ms': 1e3 * float(np.percentile(v, 90))} for k, v in parts.items()}
    out['rebuilds'] = c.builds - builds0
    out['steps'] = steps
    out['pairs_touching'] = int(np.median(found))
    out['pairs_listed'] = int(c.npairs)
    return out


def contact_parts(world) -> Dict[str, float]:
    """The rebuild alone, and the per-step part (check + projection) alone.

    The per-step part runs on a snapshot of the resting bin squeezed towards its centre by
    5 % in x and y (``squeezed``), so that thousands of facing block pairs overlap a
    little (as in a packed bin), restored before every call.
    """
    c = world.contact
    f = world._flat
    f.gather()
    Xs, Vs = squeezed(f.X), f.V.copy()
    tb = bc.time_calls(c._build, min_time=0.5, min_reps=5, max_reps=40)

    def per_step():
        f.X[:] = Xs
        f.V[:] = Vs
        c.run(1.0 / 120.0, 0.16, world._contact_colliders(0.16), world._gravity)

    def restore():
        f.X[:] = Xs
        f.V[:] = Vs
    ts = bc.time_calls(per_step, min_time=0.5, min_reps=10, max_reps=200)
    tr = bc.time_calls(restore, min_time=0.2, min_reps=10, max_reps=200)
    # overlapping pairs of the squeezed state, counted directly (with stacking the
    # solver's own count misses the pairs an earlier one in the sweep already freed)
    pi, pj = c._pair_i[:c.npairs], c._pair_j[:c.npairs]
    rr = f.R[pi] + f.R[pj]
    over = int((((Xs[:, pi] - Xs[:, pj]) ** 2).sum(axis=0) < rr * rr).sum())
    return {'rebuild_ms': _median_ms(tb),
            'step_ms': max(0.0, _median_ms(ts) - _median_ms(tr)),
            'pairs_listed': int(c.npairs), 'pairs_touching': over}


def builders(world, rounds: int = 5) -> Dict[str, Any]:
    """The pair-list builder on the world's present state: the rebuild alone and a step
    that rebuilds (``Contact.invalidate`` + ``run``: bodies that move more than a quarter
    radius a step), median ms, and its counting sort by cell; the state is put back
    before every call."""
    from sm_ros.core.contact_build import GridScratch, PairSource
    from sm_ros.core.contact_build import grid_sort as grid_sort_kernel
    c = world.contact
    f = world._flat
    f.gather()
    Xs, Vs = f.X.copy(), f.V.copy()

    def restore():
        f.X[:] = Xs
        f.V[:] = Vs

    def moving():
        restore()
        c.invalidate()
        c.run(1.0 / 120.0, 0.16, world._contact_colliders(0.16), world._gravity)

    def grid_sort():
        src = PairSource(f.X, f.R, f.B, c.act, c.selfc, f.X0, c.cell, c.skin, 0.0)
        grid = GridScratch(c._particle_cell, c._cnt, c._srt, c._sorted_points,
                           c._sorted_body, c._cell_body)
        grid_sort_kernel(src, grid, dims)
    dims = np.zeros(6, dtype=np.int64)        # cells per axis, which axes wrap
    samples = {'rebuild': [], 'moving': [], 'sort': []}
    tr = bc.time_calls(restore, min_time=0.1, min_reps=10, max_reps=100)
    try:
        restore()
        c._build()
        listed = c.npairs
        for _ in range(rounds):
            samples['rebuild'] += bc.time_calls(c._build, min_time=0.05, min_reps=3,
                                                max_reps=10).tolist()
            samples['moving'] += bc.time_calls(moving, min_time=0.05, min_reps=3,
                                               max_reps=10).tolist()
            restore()
            samples['sort'] += bc.time_calls(grid_sort, min_time=0.05, min_reps=3,
                                             max_reps=10).tolist()
    finally:
        restore()
        c.invalidate()
    return {'rebuild_ms': _median_ms(samples['rebuild']),
            'rebuild_min_ms': 1e3 * float(np.min(samples['rebuild'])),
            'moving_ms': max(0.0, _median_ms(samples['moving']) - _median_ms(tr)),
            'moving_min_ms': max(0.0, 1e3 * float(np.min(samples['moving']) - np.min(tr))),
            'grid_sort_ms': _median_ms(samples['sort']),
            'grid_sort_min_ms': 1e3 * float(np.min(samples['sort'])),
            'pairs_listed': int(listed), 'N': f.n}


def one_body(n_side: int = 38) -> Dict[str, float]:
    """World step of one 38^3 (54,872) body with contact on and off, round-robin."""
    from sm_ros.core import BodyParams, Ground, World
    from sm_ros.core.contact import ContactParams
    pts = bc.box_lattice([SPACING * (n_side - 1)] * 3, SPACING, (0, 0, 0.1))
    worlds = {}
    for on in (True, False):
        w = World()
        w.set_colliders(ground=Ground())
        w.contact_params = ContactParams(enabled=on)
        w.add_body(pts, 0.01, BodyParams(mode='linear', damping=0.05))
        w.step(1 / 120)
        worlds[on] = w
    samples = {True: [], False: []}
    for _ in range(15):
        for on in (True, False):
            t = bc.time_calls(lambda w=worlds[on]: w.step(1 / 120), min_time=0.05,
                              min_reps=3, max_reps=10)
            samples[on].extend(t.tolist())
    on, off = _median_ms(samples[True]), _median_ms(samples[False])
    return {'n': len(pts), 'on_ms': on, 'off_ms': off, 'ratio': on / off}


def scaling(scales: List[int], blocks: int = 384) -> List[Dict[str, Any]]:
    """Rebuild and per-step contact cost against N (blocks packed, at rest)."""
    rows = []
    for s in scales:
        w = block_bin(blocks * s)
        w.step(1 / 120)
        parts = contact_parts(w)
        rows.append({'blocks': blocks * s, 'N': w._flat.n, **parts})
        bc.log(f'contact scaling: {w._flat.n} particles: rebuild {parts["rebuild_ms"]:.1f} '
               f'ms, per step {parts["step_ms"]:.2f} ms')
    return rows


def paper_tick(seconds: float, ticks: int) -> Optional[Dict[str, Any]]:
    """Simulation.tick of paper_384 (2 substeps of 1/120 s) after pouring ``seconds``.

    The contact passes' time per tick (all substeps, and those of the live error
    estimate's steps within the tick), their rebuilds per tick and the rebuild alone per
    call.  Then the builder on the state reached (``builders``).
    """
    if seconds <= 0:
        return None
    from sm_ros.sim import Simulation
    sim = Simulation({'scene': 'paper_384', 'contact.sleep': False})
    world = sim.world
    dt = float(sim.params['dt'])
    for _ in range(int(round(seconds / dt))):
        world.step(dt)
    c = world.contact
    # timed on the class, so that every contact pass within the tick counts
    from sm_ros.core.contact import Contact
    runs, builds = [], []
    saved = Contact.run, Contact._build

    def timed(fn, into):
        def wrapper(self, *a, **k):
            t0 = time.perf_counter()
            r = fn(self, *a, **k)
            into.append(time.perf_counter() - t0)
            return r
        return wrapper
    ts, contact, built = [], [], []
    try:
        Contact.run = timed(saved[0], runs)
        Contact._build = timed(saved[1], builds)
        for _ in range(ticks):
            del runs[:], builds[:]
            t0 = time.perf_counter()
            sim.tick()
            ts.append(time.perf_counter() - t0)
            contact.append(sum(runs))
            built += builds
    finally:
        Contact.run, Contact._build = saved
    ke = sum(0.5 * float((b.m[:, None] * b.v ** 2).sum()) for b in world.bodies)
    out = {'points': sim.num_points, 'bodies': len(world.bodies),
           'clusters': sum(b.num_clusters for b in world.bodies),
           'tick_median_ms': _median_ms(ts), 'tick_p90_ms': 1e3 * float(np.percentile(ts, 90)),
           'substeps': int(sim.params['substeps']), 'pairs_touching': int(c.found),
           'kinetic_energy_j': ke, 'poured_s': seconds,
           'contact_ms_per_tick': _median_ms(contact),
           'rebuild_ms': _median_ms(built) if built else 0.0,
           'rebuilds_per_tick': len(built) / max(1, ticks)}
    bc.log('contact: paper_384 pair-list builder')
    out['builders'] = builders(world)
    return out


def sleeping(scene: str, seconds: float) -> Optional[Dict[str, Any]]:
    """The node's tick of ``scene`` from the start for ``seconds`` of simulated time with
    sleeping bodies on and off (``contact.sleep``), the two simulations ticked in turn:
    median and 90th percentile over the run, the median once every body sleeps and when
    that happened (doc/sleeping.md)."""
    if seconds <= 0:
        return None
    from sm_ros.sim import Simulation
    sims = {on: Simulation({'scene': scene, 'contact.sleep': on}) for on in (True, False)}
    dt = float(sims[True].params['dt']) * int(sims[True].params['substeps'])
    ticks = max(1, int(round(seconds / dt)))
    ts = {True: [], False: []}
    all_at = None
    for k in range(ticks):
        for on in (True, False):
            t0 = time.perf_counter()
            sims[on].tick()
            ts[on].append(time.perf_counter() - t0)
        w = sims[True].world
        if all_at is None and w.asleep_count == len(w.bodies):
            all_at = k + 1
    out = {'scene': scene, 'seconds': ticks * dt, 'ticks': ticks,
           'bodies': len(sims[True].world.bodies),
           'asleep_end': sims[True].world.asleep_count,
           'all_asleep_s': None if all_at is None else all_at * dt}
    for on, name in ((True, 'on'), (False, 'off')):
        t = ts[on]
        out[name] = {'median_ms': _median_ms(t), 'p90_ms': 1e3 * float(np.percentile(t, 90))}
    out['on']['asleep_median_ms'] = _median_ms(ts[True][all_at:]) \
        if all_at is not None and all_at < ticks else None
    return out


def run(args, out: Path) -> Dict[str, Any]:
    """Run every part; return the findings (also written as JSON and markdown)."""
    import numba
    threads = numba.get_num_threads()
    numba.set_num_threads(max(1, min(args.threads, numba.config.NUMBA_NUM_THREADS)))
    try:
        return _run(args, out)
    finally:
        numba.set_num_threads(threads)       # a caller in the same process keeps its threads


def _run(args, out: Path) -> Dict[str, Any]:
    import numba
    res: Dict[str, Any] = {'threads': numba.get_num_threads(), 'settle_steps': args.settle,
                           'blocks': args.blocks, 'paper_ticks': args.paper_ticks}
    bc.log(f'contact: building {args.blocks} blocks')
    w = block_bin(args.blocks)
    for _ in range(max(1, args.settle)):              # compiles, settles
        w.step(1 / 120)
    f = w._flat
    res['N'] = f.n
    base = ckdtree_ms(squeezed(f.X), f.B, SPACING / 2)
    res['ckdtree'] = base
    res['settle'] = settle_and_time(w, args.steps)
    res['parts'] = contact_parts(w)
    res['builders'] = builders(w)
    bc.log('contact: one body')
    res['one_body'] = one_body(args.one_body_side)
    res['scaling'] = scaling([int(s) for s in bc.as_list(args.scales, int)], args.blocks)
    xs = [r['N'] for r in res['scaling']]
    if len(xs) > 1:
        res['slope_rebuild'] = bc.loglog_slope(xs, [r['rebuild_ms'] for r in res['scaling']])
        res['slope_step'] = bc.loglog_slope(xs, [r['step_ms'] for r in res['scaling']])
    bc.log('contact: paper_384')
    res['paper_384'] = paper_tick(args.paper_seconds, args.paper_ticks)
    bc.log('contact: sleeping bodies')
    res['sleeping'] = sleeping(args.sleep_scene, args.sleep_seconds)
    text = markdown(res)
    (out / 'contact.md').write_text(text)
    (out / 'contact.json').write_text(json.dumps(res, indent=1, default=float))
    return res


def main(argv: Optional[List[str]] = None) -> int:
    """Entry point of ``python -m sm_ros.bench contact``."""
    p = argparse.ArgumentParser(prog='python -m sm_ros.bench contact', description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    add_arguments(p)
    args = p.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    res = run(args, out)
    text = markdown(res)
    print(text)
    if args.write_doc:
        cmd = 'python -m sm_ros.bench contact ' + shlex.join(list(argv or sys.argv[2:]))
        write_doc(text, cmd.strip(), Path(__file__).resolve().parent.parent.parent)
    return 0
