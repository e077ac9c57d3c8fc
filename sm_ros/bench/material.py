"""
Beyond the paper: the alpha that is a material of Young's modulus E.

Shape matching is only geometrically motivated: alpha is not a material constant and a
higher mode is not more physical. This benchmark builds the bridge for one case, the
cantilever of the accuracy benchmark (0.6 x 0.1 x 0.1 m, 1 kg, clamped at x = 0, gravity):

* a linear-elastic finite-element reference (scikit-fem, triquadratic hexahedra, Poisson
  ratio ``--nu``) gives the static tip sag and the first vibration frequency. Linear
  elasticity makes sag proportional to 1/E and the frequency to sqrt(E), so one solve
  serves every E;
* for each step, mode, cluster count and particle spacing, the alpha (given at
  ``material_dt`` = 1/120 s, beta ``--beta``) whose static sag (mean z displacement
  of the free end, settled with damping 0.3) equals the FEM sag is found by bisection;
  ``unreachable`` when even alpha = 1 sags more (the configuration is too soft for that E);
* with the fitted alpha and no damping, the body is released undeformed and its tip
  oscillation frequency (zero crossings about the mean) is compared with the FEM one.

Needs the ``bench`` extra's scikit-fem (``pip install scikit-fem``); nothing else imports it.
"""

import argparse
import math
from pathlib import Path
from typing import Any, Dict, Tuple

import numpy as np

from . import common as bc

LENGTH, WIDTH, MASS = 0.6, 0.1, 1.0
G = 9.81
H = 1.0 / 120.0


def add_arguments(p: argparse.ArgumentParser):
    """Add the flags of the ``material`` subcommand."""
    p.add_argument('--young', default='3e4,1e5,3e5,1e6', help="Young's moduli E (Pa)")
    p.add_argument('--nu', type=float, default=0.3, help='Poisson ratio of the FEM reference')
    p.add_argument('--mat-modes', default='rigid,linear,quadratic')
    p.add_argument('--mat-clusters', default='1,2', help='cubes per axis')
    p.add_argument('--spacings', default='0.05,0.025', help='particle spacings (m)')
    p.add_argument('--mat-rates', default='120,1920', help='steps per second 1/h')
    p.add_argument('--beta', type=float, default=0.5)
    p.add_argument('--fem-cells', type=int, default=12, help='hexahedra along the beam')


def fem_reference(nu: float = 0.3, cells: int = 12, young: float = 1e6) -> Tuple[float, float]:
    """(tip sag in m, first frequency in Hz) of the clamped beam at Young's modulus ``young``."""
    from scipy.sparse.linalg import eigsh
    from skfem import (Basis, BilinearForm, ElementHex2, ElementVector, LinearForm, MeshHex,
                       asm, condense, solve)
    from skfem.models.elasticity import lame_parameters, linear_elasticity
    rho = MASS / (LENGTH * WIDTH * WIDTH)
    across = max(1, cells // 6)
    mesh = MeshHex.init_tensor(np.linspace(0.0, LENGTH, cells + 1),
                               np.linspace(0.0, WIDTH, across + 1),
                               np.linspace(0.0, WIDTH, across + 1))
    basis = Basis(mesh, ElementVector(ElementHex2()), intorder=4)
    stiff = asm(linear_elasticity(*lame_parameters(young, nu)), basis)

    @LinearForm
    def weight(v, w):
        return -rho * G * v[2]

    @BilinearForm
    def mass(u, v, w):
        return rho * (u[0] * v[0] + u[1] * v[1] + u[2] * v[2])

    clamped = basis.get_dofs(lambda x: x[0] < 1e-9).all()
    u = solve(*condense(stiff, asm(weight, basis), D=clamped))
    tip = basis.get_dofs(lambda x: np.abs(x[0] - LENGTH) < 1e-9).nodal['u^3']
    free = np.setdiff1d(np.arange(stiff.shape[0]), clamped)
    m = asm(mass, basis)
    w2 = eigsh(stiff[free][:, free], k=1, M=m[free][:, free], sigma=0.0, which='LM')[0][0]
    return float(-u[tip].mean()), float(math.sqrt(w2) / (2.0 * math.pi))


def _beam(spacing: float):
    pts = bc.box_lattice((LENGTH, WIDTH, WIDTH), spacing, (0.0, 0.0, 0.0))
    pinned = np.nonzero(pts[:, 0] <= 1e-9)[0]
    tip = np.nonzero(pts[:, 0] >= pts[:, 0].max() - 1e-9)[0]
    return pts, pinned, tip


def sm_tip(params: Dict[str, Any], spacing: float, seconds: float, damping: float,
           h: float = H):
    """Tip z displacement over time (every step) of the shape-matched cantilever."""
    from sm_ros.core import BodyParams, World
    pts, pinned, tip = _beam(spacing)
    world = World(gravity=(0.0, 0.0, -G))
    body = world.add_body(pts, MASS / len(pts), BodyParams(**params, damping=damping),
                          pinned=pinned)
    z0 = pts[tip, 2].mean()
    out = np.zeros(int(round(seconds / h)))
    for i in range(len(out)):
        world.step(h)
        out[i] = body.x[tip, 2].mean() - z0
    return out


def static_sag(params: Dict[str, Any], spacing: float, h: float = H) -> float:
    """Settled tip sag (m, positive down): damped run, mean over its last half second."""
    z = sm_tip(params, spacing, 4.0, 0.3, h)
    return float(-z[-int(0.5 / h):].mean())


def frequency(params: Dict[str, Any], spacing: float, h: float = H,
              seconds: float = 3.0) -> float:
    """Tip oscillation frequency (Hz) released undeformed, undamped: zero crossings."""
    z = sm_tip(params, spacing, seconds, 0.0, h)
    z = z - z.mean()
    s = np.signbit(z)
    crossings = np.nonzero(s[1:] != s[:-1])[0]
    if len(crossings) < 3:
        return float('nan')
    return float((len(crossings) - 1) / 2.0 / ((crossings[-1] - crossings[0]) * h))


def fit_alpha(target: float, mode: str, clusters: int, spacing: float, beta: float = 0.5,
              h: float = H, iters: int = 12):
    """The alpha whose static sag is ``target``; (alpha, sag) or (None, sag at alpha = 1)."""
    def sag(a):
        return static_sag({'mode': mode, 'alpha': a, 'beta': beta, 'clusters': clusters},
                          spacing, h)
    stiffest = sag(1.0)
    if stiffest > target:
        return None, stiffest
    lo, hi = 1e-4, 1.0                      # sag falls as alpha rises; bisect on log alpha
    for _ in range(iters):
        mid = math.sqrt(lo * hi)
        if sag(mid) > target:
            lo = mid
        else:
            hi = mid
    a = math.sqrt(lo * hi)
    return a, sag(a)


def run(args, out: Path) -> Dict[str, Any]:
    """Fit alpha against the FEM cantilever for every configuration; write the table."""
    sag1, f1 = fem_reference(args.nu, args.fem_cells, 1.0)   # E = 1 Pa, scaled below
    ys = bc.as_list(args.young)
    t = bc.Table('material', ['E_Pa', 'rate_hz', 'mode', 'clusters', 'spacing_m', 'N',
                              'fem_sag_m', 'alpha', 'sm_sag_m', 'fem_f1_hz', 'sm_f1_hz',
                              'f1_ratio'],
                 f'Alpha that matches the static sag of a linear-elastic cantilever '
                 f'(nu = {args.nu:g}; beta = {args.beta:g}; material given at 1/120 s)')
    for young in ys:
        target, f_ref = sag1 / young, f1 * math.sqrt(young)
        for rate in bc.as_list(args.mat_rates):
            h = 1.0 / rate
            for mode in bc.as_list(args.mat_modes, str):
                for k in bc.ints(args.mat_clusters):
                    for spacing in bc.as_list(args.spacings):
                        a, sag = fit_alpha(target, mode, k, spacing, args.beta, h)
                        n = len(_beam(spacing)[0])
                        f_sm = (frequency({'mode': mode, 'alpha': a, 'beta': args.beta,
                                           'clusters': k}, spacing, h) if a is not None
                                else float('nan'))
                        t.add(E_Pa=young, rate_hz=rate, mode=mode, clusters=k ** 3,
                              spacing_m=spacing, N=n, fem_sag_m=target,
                              alpha='unreachable' if a is None else a, sm_sag_m=sag,
                              fem_f1_hz=f_ref, sm_f1_hz=f_sm,
                              f1_ratio=f_sm / f_ref if a is not None else float('nan'))
                        bc.log(f'[material] E={young:g} {rate:g} Hz {mode} k={k} '
                               f's={spacing:g}: alpha {a} sag {sag:.4g} (FEM {target:.4g}) '
                               f'f1 {f_sm:.3g} (FEM {f_ref:.3g})')
    t.write(out)
    return {'fem_sag_at_1Pa': sag1, 'fem_f1_at_1Pa': f1, 'rows': t.rows}
