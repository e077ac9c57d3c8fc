"""
The measurements of ``python -m sm_ros.bench scaling`` (``sm_ros.bench.scaling``): lattice
worlds in every variant timed round-robin, many small bodies, the NumPy reference, the
peer pypbd in a subprocess, and the memory bandwidth of a streaming copy beside the
single-cluster linear step.
"""

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
#: variant -> (damping, steps per tick)
VARIANTS = {'plain': (0.0, 1), 'damped': (0.05, 1), 'substeps2': (0.05, 2),
            'ground': (0.0, 1), 'damped_ground': (0.05, 1)}
#: the variants with a ground under the lattice (the bundled scenes all have one): the
#: lattice's lowest layer starts on it, and it settles onto it within each timed batch
GROUND_VARIANTS = ('ground', 'damped_ground')
#: particles of one body of the ``many`` rows (4 x 6 x 6 lattice)
MANY_BODY = (4, 6, 6)


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
            world.reset()                 # rebuilds the body
            tick()
            for _ in range(batch):
                t0 = clock()
                tick()
                samples.append(clock() - t0)
        rounds += 1
    out = []
    for mode, k, variant, tick, body, build_s, samples, world in cfgs:
        s = np.asarray(samples)
        memberships = len(body._cluster_ids) if len(getattr(body, '_cluster_ids', ())) else n
        layout = 'single' if k == 1 else ('sets' if getattr(body, '_sets', None) is not None
                                          else 'memberships')
        # runs of consecutive particles of one set (the set-layout loops' unit)
        sid = body._sets.sid if getattr(body, '_sets', None) is not None else None
        set_runs = 1 + int(np.count_nonzero(np.diff(sid))) if sid is not None else None
        out.append({'N': n, 'mode': mode, 'k': k, 'clusters': body.num_clusters,
                    'variant': variant, 'damping': VARIANTS[variant][0],
                    'substeps': VARIANTS[variant][1],
                    'memberships': memberships, 'layout': layout, 'set_runs': set_runs,
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
