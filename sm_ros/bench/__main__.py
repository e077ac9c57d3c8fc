"""
``python -m sm_ros.bench``: speed, scaling, error against run time, the node end to end.

Subcommands (each writes markdown + CSV tables and PNG plots into ``--out``):

- ``scaling``   ms/step against N for rigid/linear/quadratic x 1/8/64 clusters, log-log
  slope, quadratic/linear, the NumPy reference, pypbd, memory bandwidth;
- ``accuracy``  work-precision: error at T = 2 s against ms of compute per simulated
  second for a dt/substeps/mode/clusters sweep, one plot per scene;
- ``node``      the ROS node publishing clouds at 30/60 Hz (needs rclpy);
- ``soak``      hands over to ``sm_ros.bench.soak:main`` (the soak test);
- ``contact``   body-body contact against scipy's cKDTree (``sm_ros.bench.contact``);
- ``tick``      the node's tick on a bundled scene without ROS (``sm_ros.bench.tick``);
- ``transport`` clouds across a process boundary, DDS profiles (``sm_ros.bench.transport``);
- ``profile``   cProfile of a scene's ticks, the top entries (``sm_ros.bench.profile``);
- ``startup``   seconds to sim_node's first cloud, cold and warm, and the full warm-up
  (``sm_ros.bench.startup``);
- ``peers``     the contact cases in PyBullet, MuJoCo and sm_ros (``sm_ros.bench.peers``);
- ``all``       scaling + accuracy + node (the default).

``--write-doc [PATH]`` runs a short fixed set of these and writes doc/benchmarks.md
(``sm_ros.bench.doc``).

``targets.md`` lists the benchmark's targets with the figures this run measured.
"""

import argparse
import json
from pathlib import Path
import shlex
import sys
import time
from typing import Any, Dict, List, Optional

from . import common as bc


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog='python -m sm_ros.bench', description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest='command')
    from . import accuracy, material, node_bench, scaling
    parts = {
        'scaling': (scaling, 'ms/step against N, NumPy reference, pypbd, bandwidth'),
        'accuracy': (accuracy, 'error against run time (work-precision)'),
        'node': (node_bench, 'the node end to end (needs rclpy)'),
        'material': (material, 'alpha against a FEM cantilever of modulus E (scikit-fem)'),
    }
    for name, (mod, helptext) in parts.items():
        sp = sub.add_parser(name, help=helptext)
        sp.add_argument('--out', default='bench_out', help='output directory')
        mod.add_arguments(sp)
    sp = sub.add_parser('all', help='scaling + accuracy + node with their default flags')
    sp.add_argument('--out', default='bench_out', help='output directory')
    sp.add_argument('--quick', action='store_true', help='tiny sizes (a smoke run)')
    for mod, _ in parts.values():
        mod.add_arguments(sp)
    sub.add_parser('soak', help='long-running soak test (sm_ros.bench.soak)', add_help=False)
    sub.add_parser('contact', help='body-body contact against cKDTree (sm_ros.bench.contact)',
                   add_help=False)
    for name, helptext in HANDED_OVER.items():
        sub.add_parser(name, help=helptext, add_help=False)
    return p


#: Subcommands that parse their own arguments: ``python -m sm_ros.bench NAME --help``.
HANDED_OVER = {
    'tick': "the node's tick on a bundled scene, without ROS (sm_ros.bench.tick)",
    'transport': 'clouds across a process boundary (sm_ros.bench.transport)',
    'profile': "cProfile of a scene's ticks (sm_ros.bench.profile)",
    'startup': 'first cloud cold and warm, full warm-up (sm_ros.bench.startup)',
    'peers': 'contact cases in PyBullet, MuJoCo and sm_ros (sm_ros.bench.peers)',
}


def _run_soak(argv: List[str]) -> int:
    from sm_ros.bench import soak
    return int(soak.main(argv) or 0)


def main(argv: Optional[List[str]] = None) -> int:
    """Entry point; returns the exit status."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ['soak']:
        return _run_soak(argv[1:])
    if argv[:1] == ['contact']:
        from . import contact
        return contact.main(argv[1:])
    if argv[:1] and argv[0] in HANDED_OVER:
        import importlib
        return int(importlib.import_module(f'sm_ros.bench.{argv[0]}').main(argv[1:]) or 0)
    if '--write-doc' in argv:
        from . import doc
        return doc.main(argv, main)
    if not argv or argv[0] not in ('scaling', 'accuracy', 'node', 'material', 'all', '-h',
                                   '--help'):
        argv = ['all'] + argv
    args = _parser().parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    from . import accuracy, estimate, material, node_bench, scaling
    cmd = 'python -m sm_ros.bench ' + shlex.join(argv)
    info = bc.machine_info()
    findings: Dict[str, Any] = {'command': cmd, 'machine': info}
    t0 = time.perf_counter()
    if args.command == 'all' and getattr(args, 'quick', False):
        _quick(args)
    from sm_ros.progress import bar
    parts = [(name, mod) for name, mod in (('scaling', scaling), ('accuracy', accuracy),
                                           ('node', node_bench))
             if args.command in (name, 'all')]
    if args.command == 'material':            # not in 'all': needs scikit-fem
        parts = [('material', material)]
    with bar(total=len(parts), desc='bench', unit='part') as progress:
        for name, mod in parts:
            progress.set_postfix_str(name)
            findings[name] = mod.run(args, out)
            if name == 'accuracy':             # the live estimate's tables, if asked
                findings[name].update(estimate.run(args, out))
            progress.update()
    findings['wall_s'] = time.perf_counter() - t0
    _write_targets(findings, out)
    (out / 'findings.json').write_text(json.dumps(findings, indent=1, default=str))
    print((out / 'targets.md').read_text())
    return 0


def _quick(args):
    """Shrink every size for a smoke run (used by the tests)."""
    args.sizes = '343,1e3'
    args.min_time = 0.02
    args.numpy_sizes = '1e3'
    args.numpy_clusters = '1'
    args.pypbd_sizes = ''
    args.bandwidth_mb = 8.0
    args.accuracy_points = 125
    args.scenes = 'rigid_spin,soft_drop'
    args.dts = '30,60'
    args.substeps = '1'
    args.acc_modes = 'linear'
    args.acc_clusters = '1'
    args.ref_factor = 2
    args.duration = 0.2
    args.node_sizes = ''
    args.many = '2,6'


def _fmt_ms(v):
    return '-' if v is None else f'{v:.3g} ms'


def _write_targets(f: Dict[str, Any], out: Path):
    """targets.md: each target beside the figure this run measured."""
    t = bc.Table('targets', ['target', 'goal', 'measured', 'met'],
                 'Targets and what this run measured')
    sc = f.get('scaling') or {}
    _step_targets(t, sc)
    _reference_targets(t, sc)
    _node_target(t, f.get('node') or {})
    t.write(out)
    with open(out / 'targets.md', 'a') as fh:
        m = f['machine']
        fh.write(f'\nCommand: `{f["command"]}`  \nMachine: {m["cpu"]}, {m["cpus"]} CPUs, '
                 f'Numba {m["numba"]} ({m["numba_threads"]} threads), NumPy {m["numpy"]}, '
                 f'load average at start {m.get("loadavg_1min", "?")}; '
                 f'wall time {f["wall_s"]:.0f} s.\n')


def _step_targets(t, sc: Dict[str, Any]):
    """The targets of the scaling run's steps: per particle, damping, many bodies, 1M."""
    res = sc.get('scaling', [])

    def pick(n_side, mode, k, variant='plain'):
        for r in res:
            if (r['N'] == n_side ** 3 and r['mode'] == mode and r['k'] == k
                    and r.get('variant', 'plain') == variant):
                return r
        return None

    # what users run: damping, substeps, many bodies
    r = pick(22, 'rigid', 1)
    t.add(target='rigid, 1 cluster, 10k points', goal='<= 1.5 ns/particle',
          measured='-' if not r else f'{r["ns_per_particle"]:.2f} ns/particle',
          met=None if not r else r['ns_per_particle'] <= 1.5)
    r, r0 = pick(46, 'linear', 2, 'damped'), pick(46, 'linear', 2)
    t.add(target='linear, 8 clusters, damping 0.05, 100k points', goal='<= 0.9 ms/step',
          measured=_fmt_ms(r and r['ms_median']), met=None if not r else r['ms_median'] <= 0.9)
    over = r['ms_median'] / r0['ms_median'] if r and r0 else None
    t.add(target='damping overhead (same, damped / undamped)', goal='<= 1.15x',
          measured='-' if over is None else f'{over:.2f}x',
          met=None if over is None else over <= 1.15)
    for row in sc.get('many', []):
        goal = 0.2 if row['bodies'] <= 64 else 1.0
        t.add(target=f'{row["bodies"]} bodies of {row["particles"] // row["bodies"]} '
                     'particles, one step', goal=f'<= {goal} ms',
              measured=_fmt_ms(row['ms_median']), met=row['ms_median'] <= goal)

    r = pick(22, 'quadratic', 2)
    t.add(target='paper scene: 10,648 points, 8 clusters, quadratic', goal='<= 1.0 ms/step',
          measured=_fmt_ms(r and r['ms_median']), met=None if not r else r['ms_median'] <= 1.0)
    if 'bw_fraction' in sc:
        t.add(target=f'1 cluster, linear, {sc["bw_N"]} points: share of copy bandwidth',
              goal='>= 60 %',
              measured=(f'{100 * sc["bw_fraction"]:.0f} % (best step; '
                        f'median step {100 * sc["bw_fraction_median"]:.0f} %)'),
              met=sc['bw_fraction'] >= 0.6)
    r = pick(100, 'linear', 2)
    t.add(target='8 clusters, linear, 1M points', goal='<= 20 ms/step',
          measured=_fmt_ms(r and r['ms_median']), met=None if not r else r['ms_median'] <= 20)


def _reference_targets(t, sc: Dict[str, Any]):
    """The targets against the NumPy reference and pypbd."""
    rows = [x for x in sc.get('numpy', []) if x['N'] == 46 ** 3]
    if rows:
        worst = min(rows, key=lambda x: x['speedup_step'])
        worst_g = min(rows, key=lambda x: x['speedup_goals'])
        t.add(target='Numba / NumPy reference step at 97,336 points', goal='>= 10x',
              measured=f'{worst["speedup_step"]:.0f}x worst ({worst["mode"]}, '
                       f'{worst["clusters"]} cl.); against the reference\'s goals alone '
                       f'(no per-particle Python loop) {worst_g["speedup_goals"]:.0f}x worst',
              met=worst['speedup_step'] >= 10)
    else:
        t.add(target='Numba / NumPy reference at 97,336 points', goal='>= 10x',
              measured='not run', met=None)
    rows = [x for x in sc.get('pypbd', []) if x['N'] == 22 ** 3 and x['clusters'] == 8]
    if rows:
        x = rows[0]
        t.add(target='rigid, 8 clusters, damping 0.05, 10k points, against pypbd '
                     '(through the plain World.add_body)', goal='>= 8x',
              measured=f'{x["speedup_rigid_damped"]:.1f}x',
              met=x['speedup_rigid_damped'] >= 8)
    rows = sc.get('pypbd', [])
    if rows:
        worst = min(rows, key=lambda x: x['speedup_rigid'])
        t.add(target='faster than pypbd (10k, 100k; 1/8/64 clusters)', goal='>= 2x',
              measured=f'{worst["speedup_rigid"]:.1f}x worst (rigid, N={worst["N"]}, '
                       f'{worst["clusters"]} cl.)', met=worst['speedup_rigid'] >= 2)
    else:
        t.add(target='faster than pypbd', goal='>= 2x', measured='not run', met=None)


def _node_target(t, nd: Dict[str, Any]):
    """The node's target: 100k points at 60 Hz with a subscriber in another process."""
    row = nd.get('target')
    what = ('node: 100k points, 8 clusters, damping 0.05, 2 substeps, 60 Hz, one '
            'subscriber in another process')
    goal = '60 Hz held, tick <= 8.33 ms, other (beyond step + fill + publish) <= 0.2 ms'
    if row:
        t.add(target=what, goal=goal,
              measured=f'{row["rate_hz"]:.1f} Hz, tick {row["tick_ms_median"]:.2f} ms median '
                       f'({row["tick_ms_p95"]:.2f} ms p95), other '
                       f'{row["other_ms_median"]:.2f} ms',
              met=(row['rate_hz'] >= 59.4 and row['tick_ms_median'] <= 1e3 / 120
                   and row['other_ms_median'] <= 0.2))
    else:
        t.add(target=what, goal=goal, measured=nd.get('status', 'not run'), met=None)


if __name__ == '__main__':
    sys.exit(main())
