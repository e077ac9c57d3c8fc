"""
Part 2 of the benchmark: error against run time (work-precision), honestly.

Five scenes, each simulated for T seconds (2 s by default) with a sweep of frame rate
(1/30 ... 1/960 s), substeps per frame, mode and clusters:

- ``rigid_spin``: a rigid cube (alpha = 1) thrown and spinning without gravity (torque
  free; the cube's inertia is isotropic, so it turns at its constant initial angular
  velocity): exact solution.
- ``ballistic``: the same cube thrown upwards under gravity, spinning: exact solution
  (a parabola and a constant rotation).
- ``soft_drop``: a soft cube thrown sideways (0.5 m/s) from 15 cm onto the ground.
- ``cantilever``: a 0.6 m beam pinned at one end, sagging and swinging under gravity.
- ``plastic_press``: a plastic cube on the ground squeezed by two kinematic jaws for 1 s,
  then released.
- ``box_on_box``: contact between bodies: a rigid box dropped (10 cm, tilted) onto another
  resting on the ground; the error is the dropped box's (rigid: both carry their contacts
  as a whole at every step, the reference's too).
- ``ball_incline``: a soft ball rolling down a 20-degree incline (an oriented box of the
  collider pass) onto the ground.

What is measured, and how it can be trusted:

- **error** = the maximum over time (every 1/30 s) of the RMS position error over the
  particles, in metres (``err_rms``);
- the answer of the last three scenes is **the same configuration** (mode, clusters) run
  at a much finer step (the sweep's finest step / ``--ref-factor``). Its own error is
  estimated by running it again at twice its step (``ref_err``: the max-over-time RMS
  difference, which for a first-order method is about the error of the coarser of the two)
  and printed beside every figure: an error within a few ``ref_err`` is not resolved;
- the material is given at ``material_dt`` = 1/120 s and the core converts alpha, beta,
  damping and creep to each run's step (``BodyParams.at_step``: alpha/(1 - alpha) = k h^2).
  That map never produces an alpha above 1, so no run is clipped; ``alpha_h`` is the
  converted value and runs whose step does not resolve the material's time scale
  (k h^2 > 1, alpha_h > 0.5) are marked ``coarse`` in ``note``;
- cost on two axes: ``ms_per_sim_s`` = solver time (``World.step`` and the scene's
  driver, one Numba thread) per simulated second, the median step time times the steps;
  ``tick_ms`` = the solver time of one node tick at that frame rate (``substeps`` steps
  of ``dt``; publishing is in the node benchmark);
- outputs: one log-log plot per scene of error against ``ms_per_sim_s`` with one line per
  family (mode and clusters by colour and line style, substeps by marker, the points of a
  line are the frame rates), the measured convergence order (slope of log error against
  log step over the nominal configuration's frame rates, points above 3 ``ref_err``), and
  the table "cheapest configuration that keeps the error below 1 cm / 1 mm over T".
"""

import argparse
from dataclasses import dataclass, field
import math
from pathlib import Path
import time
from typing import Any, Callable, Dict, List, Optional

import numpy as np

from . import common as bc

SCENES = ('rigid_spin', 'ballistic', 'soft_drop', 'cantilever', 'plastic_press',
          'box_on_box', 'ball_incline')
#: The scenes of the live error estimate's accuracy (``test/test_error_estimate.py``).
ESTIMATE_SCENES = SCENES[:5]
#: Error budgets of the "cheapest configuration" table (m).
BUDGETS = (0.01, 0.001)
#: Samples of the error over time (Hz); every frame rate of the sweep is a multiple.
SAMPLE_RATE = 30.0


def add_arguments(p: argparse.ArgumentParser):
    """Add the flags of the ``accuracy`` subcommand."""
    p.add_argument('--scenes', default=','.join(SCENES))
    p.add_argument('--accuracy-points', type=int, default=343,
                   help='particles per body (approximate)')
    p.add_argument('--dts', default='30,60,120,240,480,960',
                   help='frame rates 1/dt in Hz (multiples of 30), comma separated')
    p.add_argument('--substeps', default='1,4', help='substeps per frame (kept while the '
                   'step is no smaller than the finest frame dt)')
    p.add_argument('--acc-modes', default='rigid,linear,quadratic')
    p.add_argument('--acc-clusters', default='1,2', help='cubes per axis')
    p.add_argument('--ref-factor', type=int, default=8,
                   help='reference step = finest step / this factor')
    p.add_argument('--duration', type=float, default=2.0, help='simulated seconds T')
    p.add_argument('--estimate', action='store_true', help='after the sweep, the live '
                   "error estimate's accuracy and cost (sm_ros.bench.estimate)")
    p.add_argument('--estimate-only', action='store_true',
                   help='only the live error estimate (no sweep)')
    p.add_argument('--estimate-seconds', type=float, default=15.0,
                   help='seconds of real-time ticks per scene for the estimate cost')


# ---------------------------------------------------------------------------------------
# Scenes
# ---------------------------------------------------------------------------------------

@dataclass
class Scene:
    """A scene: how to build it, its nominal parameters and, if known, its exact motion."""

    name: str
    build: Callable[[Dict[str, Any]], Any]        # params -> (world, body, driver)
    nominal: Dict[str, Any]
    sweep_modes: Optional[List[str]] = None       # None: the --acc-modes flag
    exact: Optional[Callable[[float], np.ndarray]] = None
    extra: Dict[str, Any] = field(default_factory=dict)


def _cube(points: int, side: float, origin=(0.0, 0.0, 0.0)) -> np.ndarray:
    return bc.cube_lattice(bc.lattice_side(points), side, origin)


def _rot(axis_angle) -> np.ndarray:
    w = np.asarray(axis_angle, dtype=float)
    th = float(np.linalg.norm(w))
    if th == 0.0:
        return np.eye(3)
    k = w / th
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(th) * kx + (1 - math.cos(th)) * kx @ kx


def make_scenes(points: int) -> Dict[str, Scene]:
    """Build the five scenes at about ``points`` particles each."""
    rigid = {'mode': 'rigid', 'alpha': 1.0, 'beta': 0.0, 'clusters': 1}
    spin_build, spin_exact = _thrown(points, np.array([0.6, 0.0, 0.3]), (0.0, 0.0, 0.0))
    ball_build, ball_exact = _thrown(points, np.array([0.5, 0.2, 9.0]), (0.0, 0.0, -9.81))
    box_build, incline_build = _contact_builds(points)
    return {
        'box_on_box': Scene('box_on_box', box_build, rigid, ['rigid']),
        'ball_incline': Scene('ball_incline', incline_build,
                              {'mode': 'linear', 'alpha': 0.5, 'beta': 0.5, 'clusters': 2}),
        'rigid_spin': Scene('rigid_spin', spin_build, rigid, ['rigid'], spin_exact),
        'ballistic': Scene('ballistic', ball_build, rigid, ['rigid'], ball_exact),
        'soft_drop': Scene('soft_drop', _drop_build(points),
                           {'mode': 'linear', 'alpha': 0.3, 'beta': 0.5, 'clusters': 2}),
        'cantilever': Scene('cantilever', _beam_build(points),
                            {'mode': 'linear', 'alpha': 0.5, 'beta': 0.5, 'clusters': 2}),
        'plastic_press': Scene('plastic_press', _press_build(points),
                               {'mode': 'linear', 'alpha': 0.5, 'beta': 0.3, 'clusters': 2,
                                'plastic_yield': 0.05, 'plastic_creep': 2.0,
                                'plastic_max': 0.3}),
    }


_SIDE = 0.2                 # m, the side of the cubes of the scenes


def _thrown(points: int, v0, gravity):
    """(build, exact motion) of a rigid cube thrown spinning from v0 under ``gravity``."""
    from sm_ros.core import BodyParams, World
    omega = np.array([0.0, 1.0, 4.0])
    spin_pts = _cube(points, _SIDE, (-_SIDE / 2,) * 3)
    c_spin = spin_pts.mean(axis=0)

    def build(params):
        world = World(gravity=gravity)
        vel = v0 + np.cross(omega, spin_pts - c_spin)
        body = world.add_body(spin_pts, 1.0 / len(spin_pts), BodyParams(**params), name='b',
                              velocities=vel)
        return world, body, None

    def exact(t):
        return (c_spin + v0 * t + 0.5 * np.asarray(gravity) * t * t
                + (spin_pts - c_spin) @ _rot(omega * t).T)
    return build, exact


def _drop_build(points: int):
    """A soft cube thrown sideways onto the ground."""
    from sm_ros.core import BodyParams, Ground, World
    drop_pts = _cube(points, _SIDE, (-_SIDE / 2, -_SIDE / 2, 0.15))
    drop_v = np.tile([0.5, 0.0, 0.0], (len(drop_pts), 1))

    def build(params):
        world = World(gravity=(0.0, 0.0, -9.81))
        world.set_colliders(ground=Ground(height=0.0, friction=0.5, restitution=0.0))
        body = world.add_body(drop_pts, 1.0 / len(drop_pts), BodyParams(**params), name='b',
                              velocities=drop_v)
        return world, body, None
    return build


def _beam_build(points: int):
    """A beam pinned at one end, sagging under gravity."""
    from sm_ros.core import BodyParams, World
    beam_len, beam_w = 0.6, 0.1
    spacing = (beam_len * beam_w * beam_w / points) ** (1.0 / 3.0)
    beam_pts = bc.box_lattice((beam_len, beam_w, beam_w), spacing, (0.0, -0.05, 0.5))
    pinned = np.nonzero(beam_pts[:, 0] <= beam_pts[:, 0].min() + 1e-9)[0]

    def build(params):
        world = World(gravity=(0.0, 0.0, -9.81))
        body = world.add_body(beam_pts, 1.0 / len(beam_pts), BodyParams(**params), name='b',
                              pinned=pinned)
        return world, body, None
    return build


def _press_build(points: int):
    """A plastic cube on the ground squeezed by two jaws (its end faces), then let go."""
    from sm_ros.core import BodyParams, Ground, World
    press_pts = _cube(points, _SIDE, (-_SIDE / 2, -_SIDE / 2, 0.0))
    xs = press_pts[:, 0]
    jaw_lo = np.nonzero(xs <= xs.min() + 1e-9)[0]
    jaw_hi = np.nonzero(xs >= xs.max() - 1e-9)[0]
    jaw = np.concatenate([jaw_lo, jaw_hi])
    sign = np.concatenate([np.ones(len(jaw_lo)), -np.ones(len(jaw_hi))])
    squeeze_speed, squeeze_time = 0.03, 1.0          # each jaw 3 cm/s for 1 s (30 % total)

    def build(params):
        world = World(gravity=(0.0, 0.0, -9.81))
        world.set_colliders(ground=Ground(height=0.0, friction=0.5, restitution=0.0))
        body = world.add_body(press_pts, 1.0 / len(press_pts), BodyParams(**params), name='b')
        start = press_pts[jaw].copy()
        state = {'held': True}

        def driver(world, body, t_next):
            if t_next <= squeeze_time + 1e-12:
                target = start.copy()
                target[:, 0] += sign * squeeze_speed * t_next
                body.set_kinematic(jaw, target)
            elif state['held']:
                body.clear_kinematic()
                state['held'] = False
        return world, body, driver
    return build


def _contact_builds(points: int):
    """The builds of the two contact scenes (box on box, ball on an incline)."""
    from sm_ros.core import BodyParams, Box, Ground, World

    side = 0.2
    lower = _cube(points, side, (-side / 2, -side / 2, 0.0))
    upper = (_cube(points, side, (-side / 2, -side / 2, -side / 2)) @ _rot([0.2, 0.1, 0.0]).T
             + [0.03, 0.0, side + side / 2 + 0.1])

    def box_build(p):
        world = World(gravity=(0.0, 0.0, -9.81))
        world.set_colliders(ground=Ground(height=0.0, friction=0.5))
        world.add_body(lower, 1.0 / len(lower), BodyParams(**p), name='lower')
        body = world.add_body(upper, 1.0 / len(upper), BodyParams(**p), name='upper')
        return world, body, None

    tilt = math.radians(20.0)
    ball = bc.cube_lattice(bc.lattice_side(2 * points), 0.16, (-0.08,) * 3)
    ball = ball[np.linalg.norm(ball, axis=1) <= 0.08 + 1e-9]
    normal = np.array([math.sin(tilt), 0.0, math.cos(tilt)])
    start = np.array([-0.6, 0.0, 0.6 * math.tan(tilt)]) + 0.081 * normal
    incline = Box(lo=(-1.0, -0.5, -0.05), hi=(1.0, 0.5, 0.0), friction=0.8,
                  orientation=(0.0, math.sin(tilt / 2), 0.0, math.cos(tilt / 2)))

    def incline_build(p):
        world = World(gravity=(0.0, 0.0, -9.81))
        world.set_colliders(ground=Ground(height=-0.4, friction=0.8), boxes=[incline])
        body = world.add_body(ball + start, 1.0 / len(ball), BodyParams(**p), name='ball')
        return world, body, None
    return box_build, incline_build


# ---------------------------------------------------------------------------------------
# Running one configuration
# ---------------------------------------------------------------------------------------

def simulate(scene: Scene, params: Dict[str, Any], h: float, duration: float,
             sample_dt: float = 1.0 / SAMPLE_RATE) -> Dict[str, Any]:
    """Run one configuration with the step ``h``; positions every ``sample_dt`` and cost."""
    every = int(round(sample_dt / h))
    if abs(every * h - sample_dt) > 1e-9 * sample_dt:
        raise ValueError(f'the step {h} does not divide the sample interval {sample_dt}')
    n_steps = int(round(duration / h))
    world, body, driver = scene.build(dict(params))
    samples, times = [], np.zeros(n_steps)
    clock = time.perf_counter
    for i in range(n_steps):
        t0 = clock()
        if driver is not None:
            driver(world, body, (i + 1) * h)
        world.step(h)
        times[i] = clock() - t0
        if (i + 1) % every == 0:
            samples.append(np.array(body.x))
    return {'x': np.array(samples), 't': (np.arange(len(samples)) + 1) * sample_dt,
            'finite': body.is_finite(), 'step_s': float(np.median(times)) if n_steps else 0.0,
            'steps': n_steps, 'N': body.n}


def max_rms(a: np.ndarray, b: np.ndarray) -> float:
    """Maximum over the samples of the RMS distance between two (S, N, 3) position sets."""
    if a.shape != b.shape:
        return float('inf')
    d = np.sqrt(((a - b) ** 2).sum(axis=2).mean(axis=1))
    return float(d.max()) if np.all(np.isfinite(d)) else float('inf')


def exact_samples(scene: Scene, t: np.ndarray) -> np.ndarray:
    """The exact positions at the sample times."""
    return np.array([scene.exact(float(ti)) for ti in t])


def converted_alpha(params: Dict[str, Any], h: float) -> float:
    """Alpha at the step h of the material (``BodyParams.at_step``)."""
    from sm_ros.core import BodyParams
    return BodyParams(**params).validate().at_step(h).alpha


def reference(scene: Scene, params: Dict[str, Any], h_ref: float, duration: float):
    """The answer for one configuration (mode, clusters) and the estimate of its error."""
    if scene.exact is not None:
        return None, 0.0
    fine = simulate(scene, params, h_ref, duration)
    half = simulate(scene, params, 2.0 * h_ref, duration)
    return fine['x'], max_rms(fine['x'], half['x'])


def order_of(rows: List[Dict[str, Any]]) -> Optional[float]:
    """Slope of log error against log step over rows resolved above the reference."""
    pts = [(r['dt_ms'], r['err_rms']) for r in rows
           if math.isfinite(r['err_rms']) and r['err_rms'] > 3.0 * r['ref_err']
           and r['err_rms'] > 0.0]
    if len(pts) < 2:
        return None
    return bc.loglog_slope([p[0] for p in pts], [p[1] for p in pts])


def run(args, out: Path) -> Dict[str, Any]:
    """Sweep every scene (none with ``--estimate-only``); write tables and one plot per
    scene; return findings.  The live error estimate's tables: ``estimate.run``."""
    if getattr(args, 'estimate_only', False):
        return {}
    with bc.one_numba_thread():               # solver time on one thread
        return _run(args, out)


def _run(args, out: Path) -> Dict[str, Any]:
    scenes = make_scenes(args.accuracy_points)
    names = [s for s in bc.as_list(args.scenes, str) if s]
    unknown = set(names) - set(scenes)
    if unknown:
        raise SystemExit(f'unknown accuracy scenes: {sorted(unknown)} (known: {SCENES})')
    rates = bc.as_list(args.dts)
    subs = bc.ints(args.substeps)
    modes = bc.as_list(args.acc_modes, str)
    ks = bc.ints(args.acc_clusters)
    finest = max(rates)
    h_ref = 1.0 / (finest * args.ref_factor)
    t = bc.Table('accuracy', ['scene', 'mode', 'clusters', 'rate_hz', 'substeps', 'dt_ms',
                              'N', 'alpha_h', 'err_rms', 'ref_err', 'ms_per_sim_s',
                              'tick_ms', 'note'],
                 f'Max-over-time RMS position error (m) over T = {args.duration:g} s against '
                 "compute; ref_err: the reference's own error estimate (0: exact solution)")
    cheap = bc.Table('accuracy_budget', ['scene', 'budget_m', 'cheapest', 'err_rms',
                                         'ref_err', 'ms_per_sim_s', 'tick_ms'],
                     f'Cheapest configuration that keeps the error below 1 cm / 1 mm over '
                     f'T = {args.duration:g} s')
    orders = bc.Table('accuracy_order', ['scene', 'configuration', 'order', 'points'],
                      'Measured convergence order: slope of log error against log step '
                      '(substeps 1, the frame rates; points above 3 ref_err)')
    findings: Dict[str, Any] = {'h_ref_s': h_ref}
    for name in names:
        scene = scenes[name]
        rows = []
        for mode in scene.sweep_modes or modes:
            for k in ks:
                params = dict(scene.nominal, mode=mode, clusters=k)
                ref_x, ref_err = None, 0.0
                if scene.exact is None:
                    bc.log(f'[accuracy] {name} {mode} k={k}: reference h = 1/{1 / h_ref:g} s '
                           f'and 2h')
                    ref_x, ref_err = reference(scene, params, h_ref, args.duration)
                fam = []
                for rate in rates:
                    for s in subs:
                        if rate * s > finest * (1 + 1e-9) and s > 1:
                            continue
                        row = dict(scene=name, mode=mode, clusters=k ** 3,
                                   **_measure(scene, params, rate, s, args.duration,
                                              (ref_x, ref_err)))
                        t.add(**row)
                        rows.append(row)
                        fam.append(row)
                        bc.log(f'[accuracy] {name} {mode} k={k} {rate:g} Hz x{s}: '
                               f'err {row["err_rms"]:.3g} m (ref {ref_err:.2g})')
                p = order_of([r for r in fam if r['substeps'] == 1])
                orders.add(scene=name, configuration=f'{mode}, {k ** 3} cl.', order=p,
                           points=sum(1 for r in fam if r['substeps'] == 1))
                if mode == scene.nominal['mode'] and k == scene.nominal['clusters']:
                    findings.setdefault('order', {})[name] = p
        _add_cheapest(cheap, name, rows)
        findings[name] = {'nominal': scene.nominal, 'rows': len(rows)}
        _plot(name, scene, rows, out, args.duration)
    t.write(out)
    cheap.write(out)
    orders.write(out)
    findings['budget'] = cheap.rows
    findings['orders'] = orders.rows
    return findings


def _measure(scene: Scene, params, rate: float, substeps: int, duration: float,
             reference) -> Dict[str, Any]:
    """One configuration's figures: its error against the exact motion, or against
    ``reference`` (positions, their own error) where there is none."""
    ref_x, ref_err = reference
    h = 1.0 / (rate * substeps)
    run = simulate(scene, params, h, duration)
    target = exact_samples(scene, run['t']) if scene.exact is not None else ref_x
    err = max_rms(run['x'], target) if run['finite'] else float('inf')
    alpha_h = converted_alpha(params, h)
    note = 'coarse' if 0.5 < alpha_h < 1.0 else ''
    if not run['finite']:
        note = 'not finite'
    return dict(rate_hz=rate, substeps=substeps, dt_ms=1e3 * h, N=run['N'], alpha_h=alpha_h,
                err_rms=err, ref_err=ref_err, ms_per_sim_s=1e3 * run['step_s'] / h,
                tick_ms=1e3 * run['step_s'] * substeps, note=note)


def _add_cheapest(cheap, name: str, rows: List[Dict[str, Any]]):
    """The cheapest row of a scene within each error budget (``BUDGETS``)."""
    for budget in BUDGETS:
        within = [r for r in rows if r['err_rms'] + r['ref_err'] <= budget]
        if within:
            best = min(within, key=lambda r: r['ms_per_sim_s'])
            cheap.add(scene=name, budget_m=budget,
                      cheapest=f'{best["mode"]}, {best["clusters"]} cl., '
                               f'{best["rate_hz"]:g} Hz x {best["substeps"]}',
                      err_rms=best['err_rms'], ref_err=best['ref_err'],
                      ms_per_sim_s=best['ms_per_sim_s'], tick_ms=best['tick_ms'])
        else:
            cheap.add(scene=name, budget_m=budget, cheapest='none in the sweep')


def _plot(name: str, scene: Scene, rows: List[Dict[str, Any]], out: Path, duration: float):
    plt = bc.pyplot()
    if plt is None or not rows:
        return
    fig, ax = plt.subplots(figsize=(6.4, 4.6))
    colors = {'rigid': 'tab:blue', 'linear': 'tab:green', 'quadratic': 'tab:red'}
    styles = {1: '-', 8: '--', 27: '-.', 64: ':'}
    markers = {1: 'o', 2: 'D', 4: 's', 8: '^'}
    keys = sorted({(r['mode'], r['clusters'], r['substeps']) for r in rows})
    for mode, k, s in keys:
        sel = sorted((r for r in rows if (r['mode'], r['clusters'], r['substeps'])
                      == (mode, k, s)), key=lambda r: r['ms_per_sim_s'])
        xs = [r['ms_per_sim_s'] for r in sel]
        ys = [max(r['err_rms'], 1e-12) if math.isfinite(r['err_rms']) else np.nan
              for r in sel]
        ax.loglog(xs, ys, styles.get(k, '-'), marker=markers.get(s, 'o'), ms=4,
                  color=colors.get(mode, 'k'), label=f'{mode}, {k} cl., x{s}')
        coarse = [(x, y) for x, y, r in zip(xs, ys, sel) if r['note'] == 'coarse']
        if coarse:
            ax.plot(*zip(*coarse), 'x', color='k', ms=7)
    for budget, label in ((0.01, '1 cm'), (0.001, '1 mm')):
        ax.axhline(budget, color='0.5', lw=0.8, ls=':')
        ax.text(ax.get_xlim()[0], budget, f' {label}', fontsize=7, va='bottom', color='0.4')
    finite = [r['err_rms'] for r in rows if 0.0 < r['err_rms'] < float('inf')]
    ref_err = max(r['ref_err'] for r in rows)
    lo = min(finite + [ref_err if ref_err > 0 else 1.0, 1e-3]) / 3.0
    ax.set_ylim(bottom=lo)
    if ref_err > 0:
        ax.axhspan(lo, ref_err, color='0.9', zorder=0)
    ref_txt = ('exact solution' if scene.exact is not None else
               'reference: same configuration at the finest step / ref-factor (grey: its '
               'own error)')
    ax.set_title(f'{name} ({ref_txt})', fontsize=8)
    ax.set_xlabel('ms of solver time (one thread) per simulated second')
    ax.set_ylabel(f'max over {duration:g} s of the RMS position error (m)')
    ax.grid(True, which='both', alpha=0.3)
    ax.legend(fontsize=6, ncol=2)
    bc.save_figure(fig, out / f'bench_accuracy_{name}.png')
