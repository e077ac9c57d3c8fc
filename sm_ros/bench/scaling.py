"""
Part 1 of the benchmark: ms/step against N (the paper's Fig. 6 on this machine).

Bodies are n x n x n lattices on the unit cube (the lattice pypbd's peer script builds),
unit masses, gravity, no colliders, alpha = 1 (pypbd's stiffness 1), beta = 0.5. The
cluster parameter is the number of cubes per axis: 1, 2, 4 give 1, 8, 64 clusters. Every
configuration runs in four variants by default, timed round-robin in one run: ``plain`` (no
damping, one step per tick), ``damped`` (damping 0.05, what 6 of the 7 bundled scenes use),
``substeps2`` (damping 0.05, two steps of dt / 2 per tick, the node's default) and
``damped_ground`` (damped, the lattice settling on a ground, as the bundled scenes run
bodies); the times are per tick.  ``--variants`` adds ``ground`` (plain, on a ground) and
``damped_pass`` (damped in the separate pass the solver takes for small one-cluster bodies,
beside the pass fused into the particle pass).  Every body is built through
``World.add_body``, which picks its storage order.  ``many``: 64 and 384 bodies of 144
particles in one world (the paper's Fig. 7 body count, contact off), timed round-robin too.

In the same run: the NumPy reference (``sm_ros.core.reference``), the peer pypbd (one
configuration per subprocess: ``sm_ros.bench.pypbd_driver``), and the memory bandwidth of a
streaming copy with the fraction of it the single-cluster linear step reaches.
"""

import argparse
import contextlib
import os
from pathlib import Path
import sys
import time
from typing import Any, Dict, List, Optional

import numpy as np

from . import common as bc

DT = 0.005                      # pypbd's default step (its TimeManager), used for both
GRAVITY = (0.0, 0.0, -9.81)
MODES = ('rigid', 'linear', 'quadratic')
CLUSTER_NAMES = {1: 1, 2: 8, 3: 27, 4: 64}
#: variant -> (damping, steps per tick); ``damped_pass`` is ``damped`` with the damping in
#: the separate pass (the one of one-cluster bodies below ``sm_ros.core.body``'s
#: ``FUSED_DAMPING_MIN`` and of membership-layout bodies; set-layout bodies always fuse),
#: for the side-by-side figure of what the fused pass saves
VARIANTS = {'plain': (0.0, 1), 'damped': (0.05, 1), 'substeps2': (0.05, 2),
            'damped_pass': (0.05, 1), 'ground': (0.0, 1), 'damped_ground': (0.05, 1)}
#: the variants with a ground under the lattice (the bundled scenes all have one): the
#: lattice's lowest layer starts on it, and it settles onto it within each timed batch
GROUND_VARIANTS = ('ground', 'damped_ground')
#: the columns of the variants table: each variant's ms, then these ratios (num / den)
VARIANT_COLUMNS = tuple(VARIANTS)
VARIANT_RATIOS = (('damped', 'plain'), ('substeps2', 'damped'), ('damped_pass', 'damped'),
                  ('ground', 'plain'), ('damped_ground', 'ground'))
#: what ``bench scaling`` / ``bench all`` time by default: the plain lattice, and as the
#: bundled scenes run bodies (damped, on a ground)
DEFAULT_VARIANTS = ('plain', 'damped', 'substeps2', 'damped_ground')
#: particles of one body of the ``many`` rows (4 x 6 x 6 lattice)
MANY_BODY = (4, 6, 6)


def add_arguments(p: argparse.ArgumentParser):
    """Add the flags of the ``scaling`` subcommand."""
    p.add_argument('--sizes', default='1e3,1e4,1e5,1e6',
                   help='particle counts (rounded to n^3 lattices), comma separated')
    p.add_argument('--modes', default=','.join(MODES))
    p.add_argument('--clusters', default='1,2,4', help='cubes per axis (1, 8, 64 clusters)')
    p.add_argument('--min-time', type=float, default=0.3,
                   help='seconds of timed steps per configuration (at least 3 samples)')
    p.add_argument('--numpy-sizes', default='1e4,1e5',
                   help='sizes for the NumPy reference ("" to skip)')
    p.add_argument('--numpy-clusters', default='1,2')
    p.add_argument('--pypbd-sizes', default='1e4,1e5', help='sizes for pypbd ("" to skip)')
    p.add_argument('--pypbd-steps', type=int, default=30)
    p.add_argument('--pypbd-threads', default='1,2',
                   help='OMP_NUM_THREADS settings for pypbd (its best is compared)')
    p.add_argument('--bandwidth-mb', type=float, default=256.0,
                   help='array size of the streaming copy (MB)')
    p.add_argument('--variants', default=','.join(DEFAULT_VARIANTS),
                   help='plain (no damping), damped (0.05), substeps2 (0.05, 2 substeps), '
                        'damped_pass (0.05 in the separate pass of small bodies), ground '
                        'and damped_ground (plain and damped, settling on a ground, as in '
                        'the bundled scenes)')
    p.add_argument('--many', default='64,384',
                   help='body counts of the many-bodies rows ("" to skip)')


# ---------------------------------------------------------------------------------------
# Memory bandwidth
# ---------------------------------------------------------------------------------------

def _numba_copy():
    from numba import njit, prange

    @njit(parallel=True, cache=False)
    def pcopy(src, dst):
        n = src.shape[0]
        for i in prange(n):
            dst[i] = src[i]
    return pcopy


def measure_bandwidth(mb: float) -> Dict[str, float]:
    """Streaming copy bandwidth in GB/s (bytes read + bytes written, STREAM's convention)."""
    n = int(mb * 1e6 / 8)
    src = np.random.default_rng(0).random(n)
    dst = np.empty_like(src)
    moved = 2 * src.nbytes
    t_np = bc.time_calls(lambda: np.copyto(dst, src), min_time=0.5, min_reps=5)
    pcopy = _numba_copy()
    pcopy(src, dst)
    t_nb = bc.time_calls(lambda: pcopy(src, dst), min_time=0.5, min_reps=5)
    return {'numpy_copy_GBps': moved / t_np.min() / 1e9,
            'numba_parallel_copy_GBps': moved / t_nb.min() / 1e9,
            'array_MB': src.nbytes / 1e6}


def bandwidth_fraction(n_side: int, mb: float, rounds: int = 8) -> Dict[str, Any]:
    """
    Time copies and single-cluster linear steps in alternation; best of each; ratios.

    The machine is shared: measuring the copy and the step in alternation, and taking the
    best of each, compares them under the same load. The body is timed as ``World.step``
    builds it (multi-threaded from 262144 particles) and built on one thread.
    """
    import numba
    n = int(mb * 1e6 / 8)
    src = np.random.default_rng(0).random(n)
    dst = np.empty_like(src)
    moved = 2 * src.nbytes
    pcopy = _numba_copy()
    pcopy(src, dst)
    threads = numba.get_num_threads()
    w_built, b_built = build_world(n_side, 'linear', 1)
    numba.set_num_threads(1)
    try:
        w_ser, b_ser = build_world(n_side, 'linear', 1)
    finally:
        numba.set_num_threads(threads)
    for w in (w_built, w_ser):
        for _ in range(3):
            w.step(DT)
    t = {'np': [], 'nb': [], 'built': [], 'serial': []}
    clock = time.perf_counter
    for _ in range(rounds):
        for key, fn in (('np', lambda: np.copyto(dst, src)), ('nb', lambda: pcopy(src, dst)),
                        ('built', lambda: w_built.step(DT)),
                        ('serial', lambda: w_ser.step(DT))):
            t0 = clock()
            fn()
            t[key].append(clock() - t0)
    res = {'N': b_built.n, 'bpp': bytes_per_particle(b_built),
           'threads_built': threads if b_built._parallel else 1,
           'numpy_copy_GBps': moved / min(t['np']) / 1e9,
           'numba_parallel_copy_GBps': moved / min(t['nb']) / 1e9}
    res['best_copy_GBps'] = max(res['numpy_copy_GBps'], res['numba_parallel_copy_GBps'])
    for key in ('built', 'serial'):
        best, med = min(t[key]), float(np.median(t[key]))
        res[f'{key}_ms_min'] = 1e3 * best
        res[f'{key}_ms_median'] = 1e3 * med
        res[f'{key}_GBps'] = res['bpp'] * res['N'] / best / 1e9
        res[f'{key}_fraction'] = res[f'{key}_GBps'] / res['best_copy_GBps']
        res[f'{key}_fraction_median'] = res['bpp'] * res['N'] / med / 1e9 / \
            res['best_copy_GBps']
    return res


def bytes_per_particle(body) -> int:
    """
    Bytes one step moves per particle in the fused pass (single cluster, no collider).

    Read x, v, x0 (3 float64 each) and m (float64); write x and v: 6 x 24 - 16 = 128 B
    for float64. Counted from the arrays the body really holds.
    """
    x, v, x0, m = body._x, body._v, body._x0, body.m
    row = lambda a: a.itemsize * (a.shape[1] if a.ndim > 1 else 1)   # noqa: E731
    return 2 * row(x) + 2 * row(v) + row(x0) + row(m)


# ---------------------------------------------------------------------------------------
# sm_ros (Numba)
# ---------------------------------------------------------------------------------------

def build_world(n_side: int, mode: str, k: int, alpha: float = 1.0, damping: float = 0.0,
                ground: bool = False):
    """Build a world with one n^3 lattice body (unit masses) and gravity; no colliders, or
    with ``ground`` a ground at the lattice's lowest layer (friction 0.5, restitution 0.1)."""
    from sm_ros.core import BodyParams, Ground, World
    world = World(gravity=GRAVITY)
    if ground:
        world.set_colliders(ground=Ground(height=0.0, friction=0.5, restitution=0.1))
    body = world.add_body(bc.cube_lattice(n_side), masses=1.0, name='cube',
                          params=BodyParams(mode=mode, alpha=alpha, beta=0.5, clusters=k,
                                            damping=damping))
    return world, body


@contextlib.contextmanager
def separate_damping(on: bool):
    """Bodies built inside (``on``) damp in the separate pass: the fused pass's size
    thresholds (``sm_ros.core.body``, read at each build) out of reach."""
    from sm_ros.core import body as body_mod
    saved = body_mod.FUSED_DAMPING_MIN, body_mod.FUSED_DAMPING_MIN_SETS
    if on:
        body_mod.FUSED_DAMPING_MIN = body_mod.FUSED_DAMPING_MIN_SETS = 2 ** 62
    try:
        yield
    finally:
        body_mod.FUSED_DAMPING_MIN, body_mod.FUSED_DAMPING_MIN_SETS = saved


def damping_pass(body) -> str:
    """'fused' (damped in the particle pass), 'separate' (a pass of its own) or ''."""
    if body.params.damping <= 0.0:
        return ''
    return 'fused' if body._damp_fused else 'separate'


def tick_function(world, substeps: int):
    """One tick of ``world``: ``substeps`` steps of DT / substeps."""
    if substeps == 1:
        return lambda: world.step(DT)
    h = DT / substeps

    def tick():
        for _ in range(substeps):
            world.step(h)
    return tick


def time_numba(n_side: int, mode: str, k: int, min_time: float) -> Dict[str, Any]:
    """ms/step of ``World.step`` for one configuration (``time_size`` with one entry)."""
    return time_size(n_side, [mode], [k], min_time)[0]


def time_size(n_side: int, modes, ks, min_time: float,
              variants=('plain',)) -> List[Dict[str, Any]]:
    """
    Time every (mode, clusters, variant) configuration of one size, interleaved.

    All bodies are built first, then stepped round-robin so that the load of a shared
    machine falls on every configuration alike and their ratios (quadratic / linear,
    clusters) hold within the run. Each turn makes one untimed step (the body's arrays
    back in cache, as in a simulation loop that steps one body) and then times a batch of
    steps one by one.  Each turn starts from the initial state (``World.reset``, untimed):
    the lattice falls freely, and after 10 s (2,000 steps) every particle would run at the
    speed cap (``max_speed`` 100 m/s) and every step pay the capping, which no simulation
    does for long.
    """
    cfgs = []
    for mode in modes:
        for k in ks:
            for variant in variants:
                damping, substeps = VARIANTS[variant]
                t0 = time.perf_counter()
                with separate_damping(variant == 'damped_pass'):
                    world, body = build_world(n_side, mode, k, damping=damping,
                                              ground=variant in GROUND_VARIANTS)
                build_s = time.perf_counter() - t0
                tick = tick_function(world, substeps)
                for _ in range(3):
                    tick()
                cfgs.append((mode, k, variant, tick, body, build_s, [], world))
    n = n_side ** 3
    batch = max(3, min(50, int(2e6 // n)))
    clock = time.perf_counter
    t_end = clock() + min_time * len(cfgs)
    rounds = 0
    while rounds < 3 or (clock() < t_end and rounds < 400):
        for mode, k, variant, tick, body, build_s, samples, world in cfgs:
            with separate_damping(variant == 'damped_pass'):
                world.reset()             # rebuilds the body
            tick()
            for _ in range(batch):
                t0 = clock()
                tick()
                samples.append(clock() - t0)
        rounds += 1
    out = []
    for mode, k, variant, tick, body, build_s, samples, world in cfgs:
        s = np.asarray(samples)
        memberships = len(body._cl) if len(getattr(body, '_cl', ())) else n
        layout = 'single' if k == 1 else ('sets' if getattr(body, '_sets', None) is not None
                                          else 'memberships')
        # runs of consecutive particles of one set (the set-layout loops' unit)
        sid = body._sets.sid if getattr(body, '_sets', None) is not None else None
        set_runs = 1 + int(np.count_nonzero(np.diff(sid))) if sid is not None else None
        out.append({'N': n, 'mode': mode, 'k': k, 'clusters': body.num_clusters,
                    'variant': variant, 'damping': VARIANTS[variant][0],
                    'substeps': VARIANTS[variant][1],
                    'memberships': memberships, 'layout': layout, 'set_runs': set_runs,
                    'damping_pass': damping_pass(body),
                    'ms_median': 1e3 * float(np.median(s)), 'ms_min': 1e3 * float(s.min()),
                    'ns_per_particle': 1e9 * float(np.median(s)) / n, 'build_s': build_s,
                    'parallel': bool(getattr(body, '_parallel', False)),
                    'bytes_per_particle': bytes_per_particle(body),
                    'finite': body.is_finite(), 'rounds': rounds})
    return out


def build_many(bodies: int):
    """A world of ``bodies`` lattices of MANY_BODY particles side by side, contact off."""
    from sm_ros.core import BodyParams, World
    from sm_ros.core.contact import ContactParams
    world = World(gravity=GRAVITY)
    world.contact_params = ContactParams(enabled=False)
    nx, ny, nz = MANY_BODY
    g = [np.arange(n) * 0.02 for n in MANY_BODY]
    x0 = np.stack(np.meshgrid(*g, indexing='ij'), axis=-1).reshape(-1, 3)
    params = BodyParams(mode='linear', clusters=1, alpha=0.5, beta=0.5, damping=0.05)
    side = int(np.ceil(np.sqrt(bodies)))
    for b in range(bodies):
        world.add_body(x0 + (0.2 * (b % side), 0.2 * (b // side), 1.0), masses=0.01,
                       params=params, name=f'b{b}')
    return world


def time_many(counts, min_time: float) -> List[Dict[str, Any]]:
    """ms per step of worlds of many small bodies, stepped round-robin."""
    worlds = []
    for c in counts:
        world = build_many(c)
        for _ in range(3):
            world.step(DT)
        worlds.append((c, world, []))
    clock = time.perf_counter
    t_end = clock() + min_time * len(worlds)
    rounds = 0
    while rounds < 3 or (clock() < t_end and rounds < 400):
        for c, world, samples in worlds:
            world.step(DT)
            for _ in range(5):
                t0 = clock()
                world.step(DT)
                samples.append(clock() - t0)
        rounds += 1
    out = []
    for c, world, samples in worlds:
        s = np.asarray(samples)
        n = sum(b.n for b in world.bodies)
        out.append({'bodies': c, 'particles': n, 'ms_median': 1e3 * float(np.median(s)),
                    'ms_min': 1e3 * float(s.min()),
                    'us_per_body': 1e6 * float(np.median(s)) / c,
                    'ns_per_particle': 1e9 * float(np.median(s)) / n})
    return out


# ---------------------------------------------------------------------------------------
# NumPy reference
# ---------------------------------------------------------------------------------------

def time_numpy(n_side: int, mode: str, k: int, min_time: float) -> Optional[Dict[str, Any]]:
    """ms/step of the NumPy reference body (full step, and the goals alone)."""
    try:
        from sm_ros.core.reference import ReferenceBody
    except ImportError:
        return None
    from sm_ros.core import BodyParams
    ref = ReferenceBody(bc.cube_lattice(n_side), 1.0,
                        BodyParams(mode=mode, alpha=1.0, beta=0.5, clusters=k))
    ref.step(DT, GRAVITY)
    s_step = bc.time_calls(lambda: ref.step(DT, GRAVITY), min_time=min_time, min_reps=2,
                           max_reps=20)
    s_goal = bc.time_calls(lambda: ref.goals(), min_time=min_time, min_reps=2, max_reps=20)
    return {'numpy_step_ms': 1e3 * float(np.median(s_step)),
            'numpy_goals_ms': 1e3 * float(np.median(s_goal))}


# ---------------------------------------------------------------------------------------
# pypbd peer
# ---------------------------------------------------------------------------------------

def time_pypbd(n_side: int, k: int, steps: int,
               threads: Optional[int] = None) -> Optional[Dict[str, Any]]:
    """Run the pypbd driver for one configuration in its own process (pypbd needs that)."""
    cmd = [sys.executable, '-m', 'sm_ros.bench.pypbd_driver', '--n', str(n_side), '--k',
           str(k), '--steps', str(steps), '--warmup', '3']
    timeout = 60 + 0.5 * n_side ** 3 / 1e3
    env = dict(os.environ)
    repo = str(Path(__file__).resolve().parents[2])
    env['PYTHONPATH'] = os.pathsep.join(filter(None, [repo, env.get('PYTHONPATH')]))
    if threads:
        env['OMP_NUM_THREADS'] = str(threads)
    return bc.run_json_subprocess(cmd, timeout=timeout, env=env)


# ---------------------------------------------------------------------------------------
# Driver
# ---------------------------------------------------------------------------------------

def run(args, out: Path) -> Dict[str, Any]:
    """Run every part of the scaling benchmark; write tables and plots; return findings."""
    sizes = sorted({bc.lattice_side(s) for s in bc.as_list(args.sizes)})
    modes = list(bc.as_list(args.modes, str))
    ks = bc.ints(args.clusters)
    variants = list(bc.as_list(args.variants, str))
    unknown = set(variants) - set(VARIANTS)
    if unknown or not variants:
        raise SystemExit(f'--variants: choose from {", ".join(VARIANTS)}, got {args.variants}')
    findings: Dict[str, Any] = {}

    bc.log('[scaling] memory bandwidth (streaming copy)')
    bw = measure_bandwidth(args.bandwidth_mb)
    bw_best = max(bw['numpy_copy_GBps'], bw['numba_parallel_copy_GBps'])
    findings['bandwidth'] = bw

    t = bc.Table('scaling', ['N', 'mode', 'clusters', 'variant', 'memberships', 'layout',
                             'damping_pass', 'set_runs', 'ms_median', 'ms_min',
                             'ns_per_particle', 'parallel', 'build_s'],
                 'ms per tick against N (World.step, dt = 5 ms per tick, gravity, no '
                 'colliders but in the ground variants; variants: plain, damped = damping '
                 '0.05, substeps2 = damping 0.05 in two steps of 2.5 ms, damped_pass = '
                 'damped in the separate pass, ground / damped_ground = plain / damped '
                 'settling on a ground; damping_pass: fused into the particle pass or '
                 'separate; set_runs: runs of one set in the set layout; the '
                 'configurations of one N timed round-robin)')
    results: List[Dict[str, Any]] = []
    for n_side in sizes:
        bc.log(f'[scaling] sm_ros N={n_side ** 3}: {len(modes) * len(ks) * len(variants)} '
               'configurations, interleaved')
        for r in time_size(n_side, modes, ks, args.min_time, variants):
            results.append(r)
            t.add(N=r['N'], mode=r['mode'], clusters=r['clusters'], variant=r['variant'],
                  memberships=r['memberships'], layout=r['layout'],
                  damping_pass=r['damping_pass'], set_runs=r['set_runs'],
                  ms_median=r['ms_median'],
                  ms_min=r['ms_min'], ns_per_particle=r['ns_per_particle'],
                  parallel=r['parallel'], build_s=r['build_s'])
    t.write(out)
    findings['scaling'] = results

    def pick(n, mode, k, variant=None):
        variant = variant or variants[0]
        for r in results:
            if r['N'] == n and r['mode'] == mode and r['k'] == k and r['variant'] == variant:
                return r
        return None

    # the variants side by side: what damping and substeps cost (same run, round-robin)
    vt = bc.Table('scaling_variants', ['N', 'mode', 'clusters']
                  + [f'{v}_ms' for v in VARIANT_COLUMNS]
                  + [f'{num}_over_{den}' for num, den in VARIANT_RATIOS],
                  'ms per tick of the variants (medians of one interleaved run) and their '
                  'ratios')
    findings['variants'] = []
    for n_side in sizes:
        for mode in modes:
            for k in ks:
                got = {v: pick(n_side ** 3, mode, k, v) for v in VARIANTS}
                ms = {v: (r['ms_median'] if r else None) for v, r in got.items()}
                row = dict(N=n_side ** 3, mode=mode, clusters=CLUSTER_NAMES.get(k, k ** 3),
                           **{f'{v}_ms': ms[v] for v in VARIANT_COLUMNS})
                for num, den in VARIANT_RATIOS:        # None where one was not run
                    row[f'{num}_over_{den}'] = (ms[num] / ms[den] if ms[num] and ms[den]
                                                else None)
                vt.add(**row)
                findings['variants'].append(row)
    vt.write(out)

    # many bodies in one world, interleaved
    counts = bc.ints(args.many) if args.many else []
    mt = bc.Table('many', ['bodies', 'particles', 'ms_median', 'ms_min', 'us_per_body',
                           'ns_per_particle'],
                  f'many bodies of {np.prod(MANY_BODY)} particles (linear, 1 cluster, '
                  'damping 0.05, contact off, one step of 5 ms; timed round-robin)')
    findings['many'] = time_many(counts, args.min_time) if counts else []
    for r in findings['many']:
        mt.add(**r)
    mt.write(out)

    # slopes and quadratic/linear ratios
    s = bc.Table('scaling_summary', ['mode', 'clusters', 'slope_loglog', 'slope_upper_half',
                                     'quad_over_linear_at_max_N'],
                 f'log-log slope of ms/step against N, and quadratic / linear ({variants[0]})')
    nmax = max(r['N'] for r in results) if results else 0
    for mode in modes:
        for k in ks:
            rows = [r for r in results if r['mode'] == mode and r['k'] == k
                    and r['variant'] == variants[0]]
            ns = [r['N'] for r in rows]
            ms = [r['ms_median'] for r in rows]
            upper = [(a, b) for a, b in zip(ns, ms) if a >= 1e4]
            ratio = None
            if mode == 'quadratic' and pick(nmax, 'linear', k) and pick(nmax, mode, k):
                ratio = pick(nmax, mode, k)['ms_median'] / pick(nmax, 'linear', k)['ms_median']
            s.add(mode=mode, clusters=CLUSTER_NAMES.get(k, k ** 3),
                  slope_loglog=bc.loglog_slope(ns, ms),
                  slope_upper_half=bc.loglog_slope(*zip(*upper)) if len(upper) > 1 else None,
                  quad_over_linear_at_max_N=ratio)
    s.write(out)
    findings['summary'] = s.rows

    # bandwidth fraction of the single-cluster linear step, interleaved with the copies
    b = bc.Table('bandwidth', ['what', 'value', 'unit'],
                 'memory bandwidth and the fraction the single-cluster linear step reaches '
                 '(copies and steps interleaved, best of each)')
    if 1 in ks and 'linear' in modes:
        bc.log(f'[scaling] bandwidth fraction, linear, 1 cluster, N={nmax} (interleaved)')
        inter = bandwidth_fraction(bc.lattice_side(nmax), args.bandwidth_mb)
        for key, label in (('numpy_copy_GBps', 'streaming copy, NumPy (1 thread)'),
                           ('numba_parallel_copy_GBps', 'streaming copy, Numba prange')):
            b.add(what=label, value=inter[key], unit='GB/s')
        b.add(what='bytes per particle per step (layout)', value=inter['bpp'], unit='B')
        for tag, label in (('built', f'as built ({inter["threads_built"]} thread(s))'),
                           ('serial', 'one thread')):
            b.add(what=f'linear, 1 cluster, N={inter["N"]}, {label}: ms/step (best)',
                  value=inter[f'{tag}_ms_min'], unit='ms')
            b.add(what='  same, median', value=inter[f'{tag}_ms_median'], unit='ms')
            b.add(what='  achieved (best step)', value=inter[f'{tag}_GBps'], unit='GB/s')
            b.add(what='  fraction of the best copy bandwidth (best step)',
                  value=inter[f'{tag}_fraction'], unit='')
            b.add(what='  fraction of the best copy bandwidth (median step)',
                  value=inter[f'{tag}_fraction_median'], unit='')
        findings['bw_interleaved'] = inter
        findings['bw_fraction'] = max(inter['built_fraction'], inter['serial_fraction'])
        findings['bw_fraction_median'] = max(inter['built_fraction_median'],
                                             inter['serial_fraction_median'])
        findings['bw_N'] = inter['N']
        bw_best = inter['best_copy_GBps']
    else:
        b.add(what='streaming copy, NumPy (1 thread)', value=bw['numpy_copy_GBps'],
              unit='GB/s')
        b.add(what='streaming copy, Numba prange', value=bw['numba_parallel_copy_GBps'],
              unit='GB/s')
    b.write(out)

    # NumPy reference
    np_sizes = sorted({bc.lattice_side(x) for x in bc.as_list(args.numpy_sizes)})
    npt = bc.Table('numpy_reference', ['N', 'mode', 'clusters', 'numba_ms', 'numpy_step_ms',
                                       'numpy_goals_ms', 'speedup_step', 'speedup_goals'],
                   'Numba step against the NumPy reference (sm_ros.core.reference)')
    findings['numpy'] = []
    for n_side in np_sizes:
        for mode in modes:
            for k in bc.ints(args.numpy_clusters):
                bc.log(f'[scaling] numpy N={n_side ** 3} {mode} k={k}')
                ref = time_numpy(n_side, mode, k, min(args.min_time, 1.0))
                if ref is None:
                    bc.log('  sm_ros.core.reference not importable: skipped')
                    break
                ours = pick(n_side ** 3, mode, k) or time_numba(n_side, mode, k, args.min_time)
                row = dict(N=n_side ** 3, mode=mode, clusters=CLUSTER_NAMES.get(k, k ** 3),
                           numba_ms=ours['ms_median'], **ref,
                           speedup_step=ref['numpy_step_ms'] / ours['ms_median'],
                           speedup_goals=ref['numpy_goals_ms'] / ours['ms_median'])
                npt.add(**row)
                findings['numpy'].append(row)
    npt.write(out)

    # pypbd
    pp_sizes = sorted({bc.lattice_side(x) for x in bc.as_list(args.pypbd_sizes)})
    ppt = bc.Table('pypbd', ['N', 'clusters', 'memberships_pypbd', 'memberships_ours',
                             'pypbd_1thread_ms', 'pypbd_2threads_ms', 'pypbd_best_ms',
                             'ours_rigid_ms', 'ours_linear_ms', 'ours_rigid_damped_ms',
                             'speedup_rigid', 'speedup_linear', 'speedup_rigid_damped'],
                   'sm_ros against pypbd (same lattice and clusters, 1 iteration, dt 5 ms; '
                   'medians; speedup = pypbd at its best thread count / ours; ours built '
                   'through World.add_body; rigid_damped: damping 0.05)')
    findings['pypbd'] = []
    if pp_sizes:
        try:
            import pypbd  # noqa: F401
            have = True
        except ImportError:
            have = False
            bc.log('[scaling] pypbd not installed (pip install pypbd): skipped')
        for n_side in (pp_sizes if have else []):
            for k in ks:
                per = {}
                for thr in bc.ints(args.pypbd_threads):
                    bc.log(f'[scaling] pypbd N={n_side ** 3} k={k} OMP_NUM_THREADS={thr}')
                    peer = time_pypbd(n_side, k, args.pypbd_steps, thr)
                    if peer is not None:
                        per[thr] = peer
                if not per:
                    continue
                peer = min(per.values(), key=lambda r: r['median_ms'])
                # ours timed again right after the peer, under the same load
                rig, rig_d, lin, _ = time_size(n_side, ['rigid', 'linear'], [k],
                                               args.min_time, ('plain', 'damped'))
                row = {'N': n_side ** 3, 'clusters': peer['clusters'],
                       'memberships_pypbd': peer['memberships'],
                       'memberships_ours': rig['memberships'],
                       'pypbd_1thread_ms': per[1]['median_ms'] if 1 in per else None,
                       'pypbd_2threads_ms': per[2]['median_ms'] if 2 in per else None,
                       'pypbd_best_ms': peer['median_ms'],
                       'ours_rigid_ms': rig['ms_median'], 'ours_linear_ms': lin['ms_median'],
                       'ours_rigid_damped_ms': rig_d['ms_median'],
                       'speedup_rigid': peer['median_ms'] / rig['ms_median'],
                       'speedup_linear': peer['median_ms'] / lin['ms_median'],
                       'speedup_rigid_damped': peer['median_ms'] / rig_d['ms_median']}
                ppt.add(**row)
                findings['pypbd'].append(row)
    ppt.write(out)

    _plot(results, findings, bw_best, out)
    return findings


def _plot(results, findings, bw_best, out: Path):
    plt = bc.pyplot()
    if plt is None or not results:
        return
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.5))
    colors = {'rigid': 'tab:blue', 'linear': 'tab:green', 'quadratic': 'tab:red'}
    styles = {1: '-', 2: '--', 3: '-.', 4: ':'}
    ax = axes[0]
    for mode in MODES:
        for k in sorted({r['k'] for r in results}):
            rows = sorted((r for r in results if r['mode'] == mode and r['k'] == k),
                          key=lambda r: r['N'])
            if rows:
                ax.loglog([r['N'] for r in rows], [r['ms_median'] for r in rows],
                          styles.get(k, '-'), marker='o', ms=3, color=colors[mode],
                          label=f'{mode}, {CLUSTER_NAMES.get(k, k ** 3)} cl.')
    ns = np.array(sorted({r['N'] for r in results}), dtype=float)
    bpp = results[0]['bytes_per_particle']
    ax.loglog(ns, bpp * ns / (bw_best * 1e9) * 1e3, 'k:', lw=1,
              label=f'memory bound ({bpp} B/particle)')
    ax.set_xlabel('particles N')
    ax.set_ylabel('ms / step')
    ax.set_title('sm_ros World.step (Numba)')
    ax.grid(True, which='both', alpha=0.3)
    ax.legend(fontsize=7, ncol=2)
    ax = axes[1]
    for row in findings.get('numpy', []):
        ax.loglog(row['N'], row['numpy_step_ms'], 's', color=colors[row['mode']], mfc='none')
        ax.loglog(row['N'], row['numba_ms'], 'o', color=colors[row['mode']])
    for row in findings.get('pypbd', []):
        ax.loglog(row['N'], row['pypbd_best_ms'], '^', color='k', mfc='none')
        ax.loglog(row['N'], row['ours_rigid_ms'], 'o', color=colors['rigid'])
    ax.plot([], [], 's', color='gray', mfc='none', label='NumPy reference')
    ax.plot([], [], '^', color='k', mfc='none', label='pypbd (1 iteration)')
    ax.plot([], [], 'o', color='gray', label='sm_ros (Numba)')
    ax.set_xlabel('particles N')
    ax.set_ylabel('ms / step')
    ax.set_title('against the NumPy reference and pypbd')
    ax.grid(True, which='both', alpha=0.3)
    ax.legend(fontsize=7)
    bc.save_figure(fig, out / 'bench_scaling.png')
