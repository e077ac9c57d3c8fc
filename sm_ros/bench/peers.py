"""
``python -m sm_ros.bench peers``: the contact cases in PyBullet, MuJoCo and sm_ros.

One run builds every case of ``sm_ros/bench/cases.py`` in each engine (PyBullet and MuJoCo
with their defaults, ``peer_engines.py``; sm_ros at the node's step, rigid alpha 0.9) and
prints each outcome beside the others with the wall time per simulated second, then:

- ``paper_384``'s pile: the 384 bodies as rigid primitives of the particles' outline in
  the engines (boxes, balls, capsules, cylinders; the scene's walls, ground and friction
  0.6), the scene itself in sm_ros (world steps of the node's ``dt`` on ``--threads``),
  wall time per simulated second while it pours, settles and rests (``--pile-times``) and
  the kinetic energy at each of those times;
- a soft cube of 13^3 = 2,197 nodes dropped on the ground: PyBullet's Neo-Hookean soft
  body on a tetrahedral mesh (its default step), MuJoCo's 3-D flex (0.25 ms steps), the
  ``default`` scene in sm_ros (``--soft-seconds``).

PyBullet and MuJoCo are the ``bench`` extra (``pip install -e .[bench]``) and are imported
only by ``peer_engines.py``: a missing one is named and its column left empty.
``--engines sm_ros`` runs sm_ros alone.  ``--write-doc`` writes ``doc/peers.md``.
"""

import argparse
import json
from pathlib import Path
import shlex
import sys
import time
from typing import Any, Dict, List, Optional

import numpy as np

from . import cases as cs
from . import common as bc

ENGINES = ('pybullet', 'mujoco', 'sm_ros')
LABELS = {'pybullet': 'PyBullet', 'mujoco': 'MuJoCo', 'sm_ros': 'sm_ros'}
DOC = Path(__file__).resolve().parents[2] / 'doc' / 'peers.md'


def add_arguments(p: argparse.ArgumentParser):
    """Options of the peers benchmark."""
    p.add_argument('--out', default='bench_out', help='output directory')
    p.add_argument('--engines', default=','.join(ENGINES),
                   help='comma-separated engines among ' + ', '.join(ENGINES))
    p.add_argument('--cases', default='all', help="comma-separated case names, 'all' or ''")
    p.add_argument('--time-scale', type=float, default=1.0,
                   help='multiply every case duration (a smoke run: small)')
    p.add_argument('--pile-times', default='3,6,7',
                   help='end of the pour, of settling and of the rest of paper_384 (s); '
                        "'' skips the pile")
    p.add_argument('--soft-seconds', type=float, default=0.5,
                   help='simulated seconds of the soft cube (0 skips it)')
    p.add_argument('--threads', type=int, default=1, help='Numba threads of sm_ros')
    p.add_argument('--pybullet-damping', type=float, default=None,
                   help="linear and angular damping of PyBullet's solids (default: its own, "
                        '0.04)')
    p.add_argument('--write-doc', action='store_true', help='write doc/peers.md')


def engine_classes(names: List[str], bullet_damping=None) -> Dict[str, Any]:
    """{engine: class or None}; a missing library is reported once and gets None.
    ``bullet_damping``: PyBullet's solids take this damping instead of its default."""
    from . import peer_engines as pe
    out = {}
    for name in names:
        if name == 'sm_ros':
            out[name] = cs.SmRos
            continue
        try:
            __import__('pybullet' if name == 'pybullet' else 'mujoco')
            out[name] = pe.Bullet if name == 'pybullet' else pe.MuJoCo
            if name == 'pybullet' and bullet_damping is not None:
                out[name] = type('Bullet', (pe.Bullet,), {'damping': bullet_damping})
        except ImportError:
            print(f'peers: {LABELS[name]} is not installed (pip install -e .[bench]); its '
                  'column stays empty', file=sys.stderr)
            out[name] = None
    return out


class Timed:
    """An engine's case whose ``step`` calls are timed (sampling the state is not)."""

    def __init__(self, sim):
        self.sim, self.wall = sim, 0.0

    @property
    def time(self):
        """The engine's simulated time."""
        return self.sim.time

    def step(self):
        """One engine step, timed."""
        t0 = time.perf_counter()
        self.sim.step()
        self.wall += time.perf_counter() - t0

    def state(self):
        """The engine's state."""
        return self.sim.state()


def run_cases(names: List[str], engines: Dict[str, Any], scale: float) -> Dict[str, Any]:
    """{case: {engine: outcomes + wall_per_sim_s}} for every case and available engine."""
    out = {}
    for case in [c for c in cs.all_cases() if c.name in names]:
        out[case.name] = {}
        for name, cls in engines.items():
            if cls is None:
                continue
            bc.log(f'peers: {case.name} in {LABELS[name]}')
            _warm(cls(case), 3)
            sim = Timed(cls(case))
            track = cs.simulate(sim, case, case.duration * scale)
            res = case.measure(case, track)
            res['wall_per_sim_s'] = sim.wall / max(sim.time, 1e-12)
            getattr(sim.sim, 'close', lambda: None)()
            out[case.name][name] = res
    return out


def _warm(sim, steps: int):
    """A few untimed steps of a throwaway copy (compiles or loads what the first step
    needs), then release it."""
    for _ in range(steps):
        sim.step()
    getattr(sim, 'close', lambda: None)()


# --- paper_384's pile ---

def pile_case(path: Optional[Path] = None) -> cs.Case:
    """``paper_384`` as rigid primitives: each body's outline (its particles' lattice grown
    by their contact radius, half a spacing), the scene's poses, masses, walls, friction."""
    import yaml
    from sm_ros.shapes import rpy_to_matrix
    from .peer_engines import _matrix_quat
    path = path or Path(__file__).resolve().parents[2] / 'config' / 'scenes' / 'paper_384.yaml'
    spec = yaml.safe_load(path.read_text())
    solids = []
    for b in spec['bodies']:
        pad = b['spacing']
        shape, size = {
            'box': ('box', tuple(s + pad for s in b.get('size', ()))),
            'sphere': ('ball', (b.get('radius', 0) + pad / 2,)),
            'capsule': ('capsule', (b.get('radius', 0) + pad / 2, b.get('length', 0))),
            'cylinder': ('cylinder', (b.get('radius', 0) + pad / 2, b.get('length', 0) + pad)),
        }[b['shape']]
        quat = _matrix_quat(rpy_to_matrix(b.get('orientation', (0, 0, 0))))
        counts, step = b['copies']['count'], np.asarray(b['copies']['step'], dtype=float)
        for idx in np.ndindex(*counts):
            pos = np.asarray(b['position'], dtype=float) + np.array(idx) * step
            solids.append(cs.Solid(f'{b["name"]}{len(solids)}', shape, size, b['mass'],
                                   tuple(pos), tuple(float(q) for q in quat)))
    walls = tuple(cs.Fixed(f'wall{k}', 'box', tuple(np.subtract(w['hi'], w['lo'])),
                           tuple((np.add(w['hi'], w['lo'])) / 2))
                  for k, w in enumerate(spec['colliders']['boxes']))
    return cs.Case('paper_384', "paper_384's 384 bodies poured into a bin", 'timing',
                   tuple(solids), cs.measure_stack, 0.0, walls,
                   friction=float(spec['contact']['friction']))


def _kinetic(state) -> float:
    return float(np.sum(state['ke']))


def pile_engine(cls, case: cs.Case, times: List[float]) -> Dict[str, Any]:
    """Wall s per simulated s of each phase of the pile in an engine, and the kinetic energy
    (J) at the end of each."""
    sim = cls(case)
    walls, kes = [], []
    start = 0.0
    for end in times:
        t0 = time.perf_counter()
        while sim.time < end - 1e-9:
            sim.step()
        walls.append((time.perf_counter() - t0) / (end - start))
        kes.append(_kinetic(sim.state()))
        start = end
    getattr(sim, 'close', lambda: None)()
    return {'wall_per_sim_s': walls, 'ke_j': kes}


def pile_sm_ros(times: List[float]) -> Dict[str, Any]:
    """The same for the ``paper_384`` scene in sm_ros: world steps of the node's ``dt``
    (sleeping bodies on, as users run it; no ROS, no error estimate)."""
    from sm_ros.sim import Simulation
    world = Simulation({'scene': 'paper_384'}).world
    world.step(cs.DT)                        # untimed: the first step loads the kernels
    walls, kes, start = [], [], world.time
    for end in times:
        t0 = time.perf_counter()
        while world.time < end - 1e-9:
            world.step(cs.DT)
        walls.append((time.perf_counter() - t0) / (end - start))
        kes.append(sum(0.5 * float(b.m @ (b.v * b.v).sum(axis=1)) for b in world.bodies))
        start = end
    return {'wall_per_sim_s': walls, 'ke_j': kes, 'asleep': world.asleep_count}


def soft_sm_ros(seconds: float) -> Dict[str, Any]:
    """The ``default`` scene (a soft block of 2,197 particles) dropped, world steps."""
    from sm_ros.sim import Simulation
    Simulation({'scene': 'default'}).world.step(cs.DT)      # untimed: loads the kernels
    world = Simulation({'scene': 'default'}).world
    steps = max(1, int(round(seconds / cs.DT)))
    t0 = time.perf_counter()
    for _ in range(steps):
        world.step(cs.DT)
    wall = (time.perf_counter() - t0) / (steps * cs.DT)
    x = world.bodies[0].x
    return {'wall_per_sim_s': wall, 'nodes': int(x.shape[0]), 'dt': cs.DT,
            'com_z_end': float(x[:, 2].mean()), 'lowest_z_end': float(x[:, 2].min())}


# --- tables ---

NOTES = """\
- The engines' solids are the cases' outlines.  sm_ros fills them with particles 2 cm
  apart, of contact radius 1 cm, that touch the colliders, and one another across a face,
  with their lattice cells (a ball: as one sphere), so its solids rest and tip on their
  outlines.
- PyBullet's default damping (0.04, linear and angular) slows fast bodies: the rolling
  ball and the sliding box lose speed and the zero-g hit momentum.  Without it
  (`--engines pybullet --cases incline_ball,incline_mu0.2 --pybullet-damping 0`) the ball
  rolls at 1.00 of (5/7) g sin and the box slides at 1.00 of g(sin - mu cos).
- MuJoCo's contacts are soft: momentum is kept to about 1e-6, and a restitution e > 0 is
  a spring-damper of that damping ratio (it has no restitution coefficient).
- `paper_384`: sm_ros runs the scene (stiff shape-matched bodies, sleeping on); the
  engines its bodies as rigid primitives.  PyBullet deactivates bodies at rest; MuJoCo
  does not sleep by default.
- Outcomes in one table are measured the same way for every engine from a track sampled
  once per node tick (1/60 s; `sm_ros/bench/cases.py`); the targets are `cases.py`'s.
  A dropped ball's energy is read at the top of its first bounce (its height above the
  contact, and the kinetic energy of all but the vertical speed): read at any sample,
  kinetic plus potential energy swings by g h v (2 % at the contact) in every engine, whose
  semi-implicit Euler holds the velocity half a step ahead of the position."""


def differences() -> str:
    """What differs between the engines as this benchmark runs them (markdown)."""
    rows = [
        ('bodies', 'rigid bodies of primitive shapes', 'rigid bodies of primitive shapes',
         'particles (2 cm lattice) held by shape matching: `rigid`, alpha 0.9'),
        ('soft cube', 'Neo-Hookean FEM on 10,368 tetrahedra (E 10 kPa, nu 0.3)',
         '3-D flex, linear elasticity on the grid (E 10 kPa, nu 0.3)',
         '`default` scene: shape matching, `linear`, alpha 0.5, beta 0.5, 1 cluster'),
        ('step', '1/240 s', '0.002 s (soft cube: 0.25 ms, the largest that stays stable)',
         '1/120 s (the node: 2 steps a tick at 60 Hz)'),
        ('contact solver', 'sequential impulses, 50 iterations, split impulse',
         'Newton, up to 100 iterations, pyramidal friction cones, soft constraints',
         'stiff bodies: sequential impulses on their rigid frames, up to 9 points a '
         'pair, warm-started, split impulse, up to 100 sweeps (a ball: one sphere '
         'against colliders); soft bodies: particle pairs, 1 sweep'),
        ('friction of a pair', 'product of the two (each object: sqrt(mu))',
         'the larger of the two (each geom: mu)', "the collider's, or contact.friction"),
        ('restitution', 'product of the two (each: sqrt(e))',
         'none: e > 0 as a spring-damper contact of that damping ratio (solref < 0)',
         "the collider's, or contact.restitution"),
        ('damping', 'linear and angular 0.04 (default)', 'none', 'none (damping 0)'),
        ('sleeping', 'on (Bullet deactivation)', 'off (mjENBL_SLEEP not set)',
         'on (contact.sleep)'),
        ('kinematic finger', 'a body held by a fixed constraint moved each step',
         'a mocap body', 'a kinematic capsule collider with a path'),
    ]
    lines = ['| | PyBullet 3.2.7 | MuJoCo | sm_ros |', '| --- | --- | --- | --- |']
    lines += [f'| {a} | {b} | {c} | {d} |' for a, b, c, d in rows]
    return '\n'.join(lines) + '\n'


def case_table(results: Dict[str, Any], engines: List[str]) -> bc.Table:
    """One row per outcome of each case, the engines side by side."""
    t = bc.Table('peers_cases', ['case', 'outcome', 'target'] + [LABELS[e] for e in engines],
                 'Contact cases side by side')
    targets = {c.name: c.target for c in cs.all_cases()}
    for name, per in results.items():
        keys = []
        for res in per.values():
            keys += [k for k in res if k not in keys]
        for k in keys:
            row = {LABELS[e]: per.get(e, {}).get(k) for e in engines}
            t.add(case=name, outcome=k, target=targets[name] if k == keys[0] else '', **row)
    return t


def pile_table(pile: Dict[str, Any], times: List[float], engines: List[str]) -> bc.Table:
    """Wall s per simulated s and kinetic energy of each pile phase per engine."""
    t = bc.Table('peers_pile', ['phase'] + [LABELS[e] for e in engines],
                 "paper_384's pile: wall s per simulated s (kinetic energy at its end, J)")
    starts = [0.0] + times[:-1]
    for k, (a, b) in enumerate(zip(starts, times)):
        phase = ('pour', 'settling', 'at rest')[min(k, 2)] + f' ({a:g}-{b:g} s)'
        row = {}
        for e in engines:
            r = pile.get(e)
            row[LABELS[e]] = (None if r is None else
                              f'{bc.fmt(r["wall_per_sim_s"][k])} ({bc.fmt(r["ke_j"][k])} J)')
        t.add(phase=phase, **row)
    return t


def soft_table(soft: Dict[str, Any], engines: List[str]) -> bc.Table:
    """The soft cube per engine."""
    t = bc.Table('peers_soft', ['engine', 'nodes', 'step (s)', 'wall s / sim s',
                                'mean z at the end (m)', 'lowest z (m)'],
                 'Soft cube of 2,197 nodes dropped on the ground')
    for e in engines:
        r = soft.get(e)
        if r:
            t.add(engine=LABELS[e], nodes=r['nodes'], **{
                'step (s)': r['dt'], 'wall s / sim s': r['wall_per_sim_s'],
                'mean z at the end (m)': r['com_z_end'], 'lowest z (m)': r['lowest_z_end']})
    return t


def _versions(engines: Dict[str, Any]) -> str:
    out = []
    for name, mod in (('pybullet', 'pybullet'), ('mujoco', 'mujoco')):
        if engines.get(name) is not None:
            from importlib.metadata import version
            out.append(f'{LABELS[name]} {version(mod)}')
    return ', '.join(out) or 'no peer engine'


def report(res: Dict[str, Any]) -> str:
    """The whole run as markdown (what ``--write-doc`` puts in ``doc/peers.md``)."""
    m = res['machine']
    parts = ['# sm_ros beside PyBullet and MuJoCo', '',
             '<!-- generated by python -m sm_ros.bench peers --write-doc -->', '',
             f'Command: `{res["command"]}`  ',
             f'Machine: {m["cpu"]}, {m["cpus"]} CPUs, load average {m.get("loadavg_1min", "?")}'
             f' at the start and {res.get("load_end", "?")} at the end; {res["versions"]}; '
             f'sm_ros on {res["threads"]} Numba thread(s); wall time {res["wall_s"]:.0f} s.', '',
             'The cases are `sm_ros/bench/cases.py` (sizes, masses, poses, friction, '
             'restitution, durations, measurements); `wall_per_sim_s` is the wall time of '
             'the steps per simulated second.', '', '## What differs', '', differences(), '',
             res['tables']['cases']]
    for key in ('pile', 'soft'):
        if key in res['tables']:
            parts += ['', res['tables'][key]]
    return '\n'.join(parts + ['', '## Notes', '', NOTES]) + '\n'


def main(argv: Optional[List[str]] = None) -> int:
    """Entry point (``python -m sm_ros.bench peers``); returns the exit status."""
    p = argparse.ArgumentParser(prog='python -m sm_ros.bench peers', description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    add_arguments(p)
    argv = list(sys.argv[1:] if argv is None else argv)
    args = p.parse_args(argv)
    names = [e for e in bc.as_list(args.engines, str) if e]
    bad = [e for e in names if e not in ENGINES]
    known = [c.name for c in cs.all_cases()]
    picked = known if args.cases == 'all' else [c for c in bc.as_list(args.cases, str) if c]
    bad += [c for c in picked if c not in known]
    if bad:
        p.error(f'unknown engine or case: {", ".join(bad)} (cases: {", ".join(known)})')
    import numba
    numba.set_num_threads(max(1, min(args.threads, numba.config.NUMBA_NUM_THREADS)))
    engines = engine_classes(names, args.pybullet_damping)
    res: Dict[str, Any] = {'command': 'python -m sm_ros.bench peers ' + shlex.join(argv),
                           'machine': bc.machine_info(), 'versions': _versions(engines),
                           'threads': numba.get_num_threads(), 'tables': {}}
    t0 = time.perf_counter()
    res['cases'] = run_cases(picked, engines, args.time_scale)
    res['tables']['cases'] = case_table(res['cases'], names).markdown()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    times = bc.as_list(args.pile_times)
    if times:
        case = pile_case()
        res['pile'] = {}
        for e, cls in engines.items():
            bc.log(f'peers: paper_384 in {LABELS[e]}')
            res['pile'][e] = (pile_sm_ros(times) if e == 'sm_ros' else
                              None if cls is None else pile_engine(cls, case, times))
        res['tables']['pile'] = pile_table(res['pile'], times, names).markdown()
    if args.soft_seconds > 0:
        res['soft'] = soft_runs(engines, args.soft_seconds, out)
        res['tables']['soft'] = soft_table(res['soft'], names).markdown()
    res['wall_s'] = time.perf_counter() - t0
    res['load_end'] = round(__import__('os').getloadavg()[0], 2)
    text = report(res)
    (out / 'peers.md').write_text(text)
    (out / 'peers.json').write_text(json.dumps(res, indent=1, default=str))
    if args.write_doc:
        DOC.write_text(text)
    print(text)
    return 0


def soft_runs(engines: Dict[str, Any], seconds: float, out: Path) -> Dict[str, Any]:
    """The soft cube in every available engine."""
    from . import peer_engines as pe
    res = {}
    for e, cls in engines.items():
        if cls is None:
            continue
        bc.log(f'peers: soft cube in {LABELS[e]}')
        res[e] = (soft_sm_ros(seconds) if e == 'sm_ros' else
                  pe.bullet_soft_cube(seconds, out) if e == 'pybullet' else
                  pe.mujoco_soft_cube(seconds))
    return res


if __name__ == '__main__':
    sys.exit(main())
