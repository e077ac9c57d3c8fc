"""
Part 2 of the benchmark: error against run time (work-precision).

Four scenes, each simulated for T seconds (2 s by default) with a sweep of frame rate
(dt = 1/30 ... 1/960 s), substeps per frame, mode and clusters:

- ``rigid_spin``: a rigid cube (alpha = 1) thrown and spinning without gravity. Known
  answer: the centre of mass moves on a straight line and, the cube's inertia being
  isotropic, the body turns at the constant initial angular velocity; linear and angular
  momentum and volume are conserved (their drift is measured against t = 0).
- ``soft_drop``: a soft cube thrown sideways (0.5 m/s) from 15 cm onto the ground
  (friction 0.5): it lands, squashes, slides and stops.
- ``pinned_beam``: a beam pinned at one end sagging under gravity.
- ``plastic_press``: a plastic cube on the ground squeezed by a two-jaw gripper
  (kinematic particles) for 1 s, then released.

The last three have no closed form: the answer is a reference run of the scene's nominal
configuration with a step 16x smaller than the finest of the sweep; momentum, angular
momentum and volume are compared with the reference's at T. The error is the RMS position
error over the particles at T divided by the body's size. The cost is the measured ms of
compute (``World.step`` and the gripper update) per simulated second.

Shape matching's stiffness alpha acts per step: v += alpha (g - x) / h is a spring of
stiffness alpha / h^2 (per unit mass). With a fixed alpha a smaller step is a stiffer
material and no dt sweep converges to anything but the rigid limit. So that every
configuration simulates the same material, the soft scenes give alpha at h0 = 1/60 s and
each run uses alpha(h) = min(1, alpha0 (h / h0)^2) (``--alpha-scaling fixed`` turns this
off). The rigid scene keeps alpha = 1.

The cost is the median of the measured per-step times (``World.step`` and the gripper
update) times the number of steps, per simulated second: the median keeps the figure
stable on a shared machine where single steps are sometimes preempted.
"""

import argparse
from dataclasses import dataclass, field
import math
from pathlib import Path
import time
from typing import Any, Callable, Dict, List, Optional

import numpy as np

from . import common as bc

SCENES = ('rigid_spin', 'soft_drop', 'pinned_beam', 'plastic_press')
BUDGETS = (0.1, 0.03, 0.01, 0.003, 0.001)


def add_arguments(p: argparse.ArgumentParser):
    """Add the flags of the ``accuracy`` subcommand."""
    p.add_argument('--scenes', default=','.join(SCENES))
    p.add_argument('--accuracy-points', type=int, default=1000,
                   help='particles per body (approximate)')
    p.add_argument('--dts', default='30,60,120,240,480,960',
                   help='frame rates 1/dt in Hz, comma separated')
    p.add_argument('--substeps', default='1,4', help='substeps per frame (kept while the '
                   'step is no smaller than the finest frame dt)')
    p.add_argument('--acc-modes', default='rigid,linear,quadratic')
    p.add_argument('--acc-clusters', default='1,2', help='cubes per axis')
    p.add_argument('--ref-factor', type=int, default=16,
                   help='reference step = finest dt / this factor')
    p.add_argument('--duration', type=float, default=2.0, help='simulated seconds T')
    p.add_argument('--alpha-scaling', choices=('h2', 'fixed'), default='h2',
                   help='h2: alpha(h) = min(1, alpha0 (60 h)^2), the same material at every '
                        'step; fixed: alpha as given at every step')


# ---------------------------------------------------------------------------------------
# Scenes
# ---------------------------------------------------------------------------------------

@dataclass
class Scene:
    """A scene: how to build it, what to do each step, and its nominal parameters."""

    name: str
    build: Callable[[Dict[str, Any]], Any]        # params -> (world, body, driver)
    nominal: Dict[str, Any]
    size: float
    sweep_modes: Optional[List[str]] = None       # None: the --acc-modes flag
    exact: Optional[Callable[[Any, float], np.ndarray]] = None
    conserved: bool = False
    p_scale: float = 1.0
    l_scale: float = 1.0
    extra: Dict[str, Any] = field(default_factory=dict)


def _cube(points: int, side: float, origin=(0.0, 0.0, 0.0)) -> np.ndarray:
    n = bc.lattice_side(points)
    return bc.cube_lattice(n, side, origin)


def _rot(axis_angle) -> np.ndarray:
    w = np.asarray(axis_angle, dtype=float)
    th = float(np.linalg.norm(w))
    if th == 0.0:
        return np.eye(3)
    k = w / th
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(th) * kx + (1 - math.cos(th)) * kx @ kx


def make_scenes(points: int) -> Dict[str, Scene]:
    """Build the four scenes at about ``points`` particles each."""
    from sm_ros.core import BodyParams, Ground, World

    side = 0.2
    v0 = np.array([0.6, 0.0, 0.3])
    omega = np.array([0.0, 1.0, 4.0])
    spin_pts = _cube(points, side, (-side / 2,) * 3)

    def spin_build(p):
        world = World(gravity=(0.0, 0.0, 0.0))
        c = spin_pts.mean(axis=0)
        vel = v0 + np.cross(omega, spin_pts - c)
        body = world.add_body(spin_pts, 1.0 / len(spin_pts), BodyParams(**p), name='b',
                              velocities=vel)
        return world, body, None

    def spin_exact(body, t):
        c = spin_pts.mean(axis=0)
        return c + v0 * t + (spin_pts - c) @ _rot(omega * t).T

    drop_pts = _cube(points, side, (-side / 2, -side / 2, 0.15))
    drop_v = np.tile([0.5, 0.0, 0.0], (len(drop_pts), 1))

    def drop_build(p):
        world = World(gravity=(0.0, 0.0, -9.81))
        world.set_colliders(ground=Ground(height=0.0, friction=0.5, restitution=0.0))
        body = world.add_body(drop_pts, 1.0 / len(drop_pts), BodyParams(**p), name='b',
                              velocities=drop_v)
        return world, body, None

    beam_len, beam_w = 0.6, 0.1
    spacing = (beam_len * beam_w * beam_w / points) ** (1.0 / 3.0)
    beam_pts = bc.box_lattice((beam_len, beam_w, beam_w), spacing, (0.0, -0.05, 0.5))
    pinned = np.nonzero(beam_pts[:, 0] <= beam_pts[:, 0].min() + 1e-9)[0]

    def beam_build(p):
        world = World(gravity=(0.0, 0.0, -9.81))
        body = world.add_body(beam_pts, 1.0 / len(beam_pts), BodyParams(**p), name='b',
                              pinned=pinned)
        return world, body, None

    press_pts = _cube(points, side, (-side / 2, -side / 2, 0.0))
    xs = press_pts[:, 0]
    jaw_lo = np.nonzero(xs <= xs.min() + 1e-9)[0]
    jaw_hi = np.nonzero(xs >= xs.max() - 1e-9)[0]
    jaw = np.concatenate([jaw_lo, jaw_hi])
    sign = np.concatenate([np.ones(len(jaw_lo)), -np.ones(len(jaw_hi))])
    squeeze_speed, squeeze_time = 0.03, 1.0          # each jaw 3 cm/s for 1 s (30 % total)

    def press_build(p):
        world = World(gravity=(0.0, 0.0, -9.81))
        world.set_colliders(ground=Ground(height=0.0, friction=0.5, restitution=0.0))
        body = world.add_body(press_pts, 1.0 / len(press_pts), BodyParams(**p), name='b')
        start = press_pts[jaw].copy()
        state = {'held': True}

        def driver(world, body, t_next):
            if t_next <= squeeze_time + 1e-12:
                tgt = start.copy()
                tgt[:, 0] += sign * squeeze_speed * t_next
                body.set_kinematic(jaw, tgt)
            elif state['held']:
                body.clear_kinematic()
                state['held'] = False
        return world, body, driver

    g_imp = 9.81 * 2.0            # momentum scale: M g T (M = 1 kg in every scene)
    soft = {'mode': 'linear', 'alpha': 0.3, 'beta': 0.5, 'clusters': 2}
    return {
        'rigid_spin': Scene('rigid_spin', spin_build,
                            {'mode': 'rigid', 'alpha': 1.0, 'beta': 0.0, 'clusters': 1}, side,
                            sweep_modes=['rigid'], exact=spin_exact, conserved=True),
        'soft_drop': Scene('soft_drop', drop_build, soft, side, p_scale=g_imp,
                           l_scale=g_imp * side),
        'pinned_beam': Scene('pinned_beam', beam_build,
                             {'mode': 'linear', 'alpha': 0.5, 'beta': 0.5, 'clusters': 2},
                             beam_len,
                             p_scale=g_imp, l_scale=g_imp * beam_len),
        'plastic_press': Scene('plastic_press', press_build,
                               {'mode': 'linear', 'alpha': 0.5, 'beta': 0.3, 'clusters': 2,
                                'plastic_yield': 0.05, 'plastic_creep': 2.0, 'plastic_max': 0.3},
                               side, p_scale=g_imp, l_scale=g_imp * side),
    }


# ---------------------------------------------------------------------------------------
# Running one configuration
# ---------------------------------------------------------------------------------------

def volume_proxy(x: np.ndarray, m: np.ndarray) -> float:
    """sqrt(det(mass-weighted covariance)): proportional to volume for affine motions."""
    c = m @ x / m.sum()
    d = x - c
    cov = (m[:, None] * d).T @ d / m.sum()
    return float(math.sqrt(max(np.linalg.det(cov), 0.0)))


ALPHA_H0 = 1.0 / 60.0


def simulate(scene: Scene, params: Dict[str, Any], rate: float, substeps: int,
             duration: float, alpha_scaling: str = 'h2') -> Dict[str, Any]:
    """Run one configuration to T; the state at T, its invariants and the compute time."""
    frames = int(round(duration * rate))
    h = 1.0 / (rate * substeps)
    params = dict(params)
    if alpha_scaling == 'h2' and params['alpha'] < 1.0:
        params['alpha'] = min(1.0, params['alpha'] * (h / ALPHA_H0) ** 2)
    params.setdefault('material_dt', 0.0)     # this sweep converts alpha itself
    world, body, driver = scene.build(params)
    p0, l0 = body.momentum(), body.angular_momentum()
    vol0 = volume_proxy(body.x, body.m)
    step = world.step
    steps = 0
    times = np.zeros(frames * substeps)
    clock = time.perf_counter
    for _ in range(frames):
        for _ in range(substeps):
            t0 = clock()
            if driver is not None:
                driver(world, body, (steps + 1) * h)
            step(h)
            times[steps] = clock() - t0
            steps += 1
    cost = float(np.median(times)) * steps if steps else 0.0
    return {'x': np.array(body.x), 'p': body.momentum(), 'L': body.angular_momentum(),
            'vol': volume_proxy(body.x, body.m), 'p0': p0, 'L0': l0, 'vol0': vol0, 'm': body.m,
            'finite': body.is_finite(), 'cost_s': cost, 'steps': steps, 't': frames / rate}


def _metrics(scene: Scene, run: Dict[str, Any], ref: Optional[Dict[str, Any]],
             exact: Optional[np.ndarray]) -> Dict[str, float]:
    target = exact if exact is not None else ref['x']
    err = float(np.sqrt(np.mean(np.sum((run['x'] - target) ** 2, axis=1)))) / scene.size
    if scene.conserved:
        p_err = np.linalg.norm(run['p'] - run['p0']) / max(np.linalg.norm(run['p0']), 1e-30)
        l_err = np.linalg.norm(run['L'] - run['L0']) / max(np.linalg.norm(run['L0']), 1e-30)
        v_err = run['vol'] / run['vol0'] - 1.0
    else:
        p_err = np.linalg.norm(run['p'] - ref['p']) / scene.p_scale
        l_err = np.linalg.norm(run['L'] - ref['L']) / scene.l_scale
        v_err = run['vol'] / ref['vol'] - 1.0
    return {'err_rms': err if run['finite'] else float('inf'), 'p_drift': float(p_err),
            'L_drift': float(l_err), 'vol_drift': float(v_err)}


def run(args, out: Path) -> Dict[str, Any]:
    """Sweep every scene; write tables and one plot per scene; return findings."""
    scenes = make_scenes(args.accuracy_points)
    names = [s for s in bc.as_list(args.scenes, str) if s]
    rates = bc.as_list(args.dts)
    subs = bc.ints(args.substeps)
    modes = bc.as_list(args.acc_modes, str)
    ks = bc.ints(args.acc_clusters)
    finest = max(rates)
    t = bc.Table('accuracy', ['scene', 'mode', 'clusters', 'rate_hz', 'substeps', 'dt_ms',
                              'N', 'err_rms', 'p_drift', 'L_drift', 'vol_drift',
                              'ms_per_sim_s', 'ms_per_step'],
                 'Error at T against compute (err_rms: RMS position error / body size)')
    cheap = bc.Table('accuracy_budget', ['scene', 'budget', 'cheapest', 'err_rms',
                                         'ms_per_sim_s'],
                     'Cheapest configuration per error budget (RMS error / body size at T)')
    findings: Dict[str, Any] = {}
    for name in names:
        scene = scenes[name]
        ref = None
        if scene.exact is None:
            bc.log(f'[accuracy] {name}: reference run (dt = 1/{finest * args.ref_factor:g} s)')
            ref = simulate(scene, scene.nominal, finest, args.ref_factor, args.duration,
                           args.alpha_scaling)
            if not ref['finite']:
                bc.log(f'[accuracy] {name}: reference is not finite; skipped')
                continue
        rows = []
        sweep_modes = scene.sweep_modes or modes
        for mode in sweep_modes:
            for k in ks:
                params = dict(scene.nominal, mode=mode, clusters=k)
                for rate in rates:
                    for s in subs:
                        if rate * s > finest * (1 + 1e-9) and s > 1:
                            continue
                        bc.log(f'[accuracy] {name} {mode} k={k} 1/dt={rate:g} x{s}')
                        r = simulate(scene, params, rate, s, args.duration,
                                     args.alpha_scaling)
                        ex = scene.exact(None, r['t']) if scene.exact is not None else None
                        mt = _metrics(scene, r, ref, ex)
                        row = dict(scene=name, mode=mode, clusters=k ** 3, rate_hz=rate,
                                   substeps=s, dt_ms=1e3 / (rate * s), N=len(r['m']),
                                   ms_per_sim_s=1e3 * r['cost_s'] / r['t'],
                                   ms_per_step=1e3 * r['cost_s'] / r['steps'], **mt)
                        t.add(**row)
                        rows.append(row)
        for budget in BUDGETS:
            ok = [r for r in rows if r['err_rms'] <= budget]
            if ok:
                b = min(ok, key=lambda r: r['ms_per_sim_s'])
                cheap.add(scene=name, budget=budget,
                          cheapest=f'{b["mode"]}, {b["clusters"]} cl., '
                                   f'{b["rate_hz"]:g} Hz x {b["substeps"]}',
                          err_rms=b['err_rms'], ms_per_sim_s=b['ms_per_sim_s'])
            else:
                cheap.add(scene=name, budget=budget, cheapest='none in the sweep')
        findings[name] = {'nominal': scene.nominal, 'rows': len(rows),
                          'ref_cost_ms_per_sim_s': None if ref is None else
                          1e3 * ref['cost_s'] / ref['t']}
        _plot(name, scene, rows, out)
    t.write(out)
    cheap.write(out)
    findings['budget'] = cheap.rows
    return findings


def _plot(name: str, scene: Scene, rows: List[Dict[str, Any]], out: Path):
    plt = bc.pyplot()
    if plt is None or not rows:
        return
    fig, ax = plt.subplots(figsize=(6.4, 4.6))
    colors = {'rigid': 'tab:blue', 'linear': 'tab:green', 'quadratic': 'tab:red'}
    styles = {1: '-', 8: '--', 27: '-.', 64: ':'}
    markers = {1: 'o', 2: 's', 4: '^', 8: 'v'}
    keys = sorted({(r['mode'], r['clusters'], r['substeps']) for r in rows})
    for mode, k, s in keys:
        sel = sorted((r for r in rows if (r['mode'], r['clusters'], r['substeps'])
                      == (mode, k, s)), key=lambda r: r['ms_per_sim_s'])
        xs = [r['ms_per_sim_s'] for r in sel]
        ys = [max(r['err_rms'], 1e-12) if math.isfinite(r['err_rms']) else np.nan
              for r in sel]
        ax.loglog(xs, ys, styles.get(k, '-'), marker=markers.get(s, 'o'), ms=4,
                  color=colors.get(mode, 'k'), label=f'{mode}, {k} cl., x{s}')
    nominal = scene.nominal
    ref_txt = ('exact solution' if scene.exact is not None else
               f'reference: {nominal["mode"]}, {nominal["clusters"] ** 3} cl., dt/16')
    ax.set_title(f'{name} ({ref_txt})', fontsize=9)
    ax.set_xlabel('ms of compute per simulated second')
    ax.set_ylabel('RMS position error at T / body size')
    ax.grid(True, which='both', alpha=0.3)
    ax.legend(fontsize=6, ncol=2)
    bc.save_figure(fig, out / f'bench_accuracy_{name}.png')
