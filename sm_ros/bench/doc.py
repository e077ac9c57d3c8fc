"""
``python -m sm_ros.bench --write-doc [PATH]``: run a short fixed set of benchmarks, write
doc/benchmarks.md.

The page answers what a user asks (how fast for my scene size, how accurate for my step,
how it compares with pypbd; PyBullet and MuJoCo are on doc/peers.md) with figures of one
run of the existing subcommands (``scaling``, ``accuracy``, ``tick``, ``node``), each shown
with the command that reproduces it and the load average before and after it ran: the
machine may be shared, and the load says how far to trust a figure. ``--quick`` shrinks
every size (the smoke test); ``--work DIR`` keeps the subcommands' tables and plots.
"""

import argparse
import csv
import os
from pathlib import Path
import shlex
import subprocess
import sys
import tempfile
from typing import Any, Callable, Dict, List, Optional, Sequence

from . import common as bc

ROOT = Path(__file__).resolve().parents[2]
#: What the page runs; ``--quick`` replaces the sizes (``QUICK``).
FULL = {
    'scaling': ['--sizes', '1e3,1e4,1e5', '--variants', 'plain,damped', '--many', '64,384',
                '--numpy-sizes', '1e4', '--numpy-clusters', '1', '--pypbd-sizes', '1e4',
                '--bandwidth-mb', '64', '--min-time', '0.3'],
    'accuracy': ['--acc-modes', 'linear', '--acc-clusters', '1,2', '--substeps', '1',
                 '--dts', '30,60,120,240,480', '--ref-factor', '4'],
    'tick': ['--scene', 'paper_384', '--ticks', '600', '--json'],
    'node': ['--node-sizes', '1e4,1e5', '--node-rates', '60', '--node-seconds', '4'],
}
QUICK = {
    'scaling': ['--sizes', '343,1e3', '--variants', 'plain,damped', '--many', '2',
                '--numpy-sizes', '', '--pypbd-sizes', '', '--bandwidth-mb', '4',
                '--min-time', '0.02', '--modes', 'rigid,linear', '--clusters', '1,2'],
    'accuracy': ['--scenes', 'rigid_spin,soft_drop', '--acc-modes', 'linear',
                 '--acc-clusters', '1', '--substeps', '1', '--dts', '30,60',
                 '--ref-factor', '2', '--duration', '0.2', '--accuracy-points', '64'],
    'tick': ['--scene', 'default', '--ticks', '60', '--json'],
    'node': ['--node-sizes', ''],
}


def _load() -> str:
    try:
        return f'{os.getloadavg()[0]:.1f}'
    except OSError:
        return '?'


def _rows(path: Path) -> List[Dict[str, str]]:
    if not path.is_file():
        return []
    with open(path, newline='') as handle:
        return list(csv.DictReader(handle))


def _num(value: Any) -> Optional[float]:
    try:
        return float(value)
    except (TypeError, ValueError):
        return None


def _cell(value: Any, digits: int = 3) -> str:
    num = _num(value)
    return bc.fmt(num, digits) if num is not None else (value or '-')


def _table(header: Sequence[str], rows: List[Sequence[Any]]) -> List[str]:
    lines = ['| ' + ' | '.join(header) + ' |', '|' + '|'.join(' --- ' for _ in header) + '|']
    lines += ['| ' + ' | '.join(str(cell) for cell in row) + ' |' for row in rows]
    return lines + ['']


class Run:
    """The parts run so far: their commands, loads and output folders."""

    def __init__(self, work: Path, sizes: Dict[str, List[str]]):
        """Run into ``work`` with the flags ``sizes`` of each part."""
        self.work, self.sizes = work, sizes
        self.done: Dict[str, Dict[str, Any]] = {}

    def part(self, name: str, call: Callable[[List[str]], Any]) -> Dict[str, Any]:
        """Run part ``name`` through ``call(argv)``; record its command and loads."""
        argv = [name] + self.sizes[name]
        out = self.work / name
        before = _load()
        bc.log(f'[write-doc] {shlex.join(argv)}')
        result = call(argv + ['--out', str(out)] if name != 'tick' else argv)
        self.done[name] = {'command': 'python -m sm_ros.bench ' + shlex.join(argv),
                           'load': f'{before} before, {_load()} after', 'out': out,
                           'result': result}
        return self.done[name]

    def source(self, name: str) -> List[str]:
        """The line under a figure: its command and the machine's load."""
        done = self.done[name]
        return [f'Command: `{done["command"]}`; load average {done["load"]}.', '']


def _speed(run: Run) -> List[str]:
    out = run.done['scaling']['out']
    rows = [row for row in _rows(out / 'scaling.csv') if row.get('variant') == 'damped']
    lines = ['## How fast is a step for my scene size?', '',
             'One body, an n x n x n lattice, damping 0.05 (as the bundled scenes use), one '
             'step of 5 ms, gravity, no colliders; ms per step (median), per mode and number '
             'of clusters. Time per step grows about linearly with the particles.', '']
    modes = sorted({row['mode'] for row in rows}, key=['rigid', 'linear', 'quadratic'].index)
    keys = sorted({(int(row['N']), int(row['clusters'])) for row in rows})
    body = []
    for particles, clusters in keys:
        got = {row['mode']: row for row in rows
               if (int(row['N']), int(row['clusters'])) == (particles, clusters)}
        body.append([f'{particles:,}', clusters]
                    + [_cell(got.get(mode, {}).get('ms_median')) for mode in modes])
    lines += _table(['particles', 'clusters'] + [f'{mode} (ms)' for mode in modes], body)
    lines += _damping_cost(_rows(out / 'scaling.csv'))
    many = _rows(out / 'many.csv')
    if many:
        lines += ['Many small bodies in one world (144 particles each, linear, damping 0.05, '
                  'contact off), one step:', '']
        lines += _table(['bodies', 'particles', 'ms per step', 'us per body'],
                        [[row['bodies'], f"{int(row['particles']):,}", _cell(row['ms_median']),
                          _cell(row['us_per_body'])] for row in many])
    lines += run.source('scaling')
    return lines


def _damping_cost(rows: List[Dict[str, str]]) -> List[str]:
    """One line: the damped step against the undamped one (linear, 8 clusters)."""
    median = {(row['N'], row['variant']): _num(row['ms_median']) for row in rows
              if row['mode'] == 'linear' and row['clusters'] == '8'}
    ratios = [f'{int(size):,} particles {median[size, "damped"] / median[size, "plain"]:.2f}x'
              for size, variant in sorted(median, key=lambda key: int(key[0]))
              if variant == 'plain' and median.get((size, 'damped')) and median[size, 'plain']]
    if not ratios:
        return []
    return ['What damping 0.05 costs against none (linear, 8 clusters, timed round-robin in '
            'the same run): ' + ', '.join(ratios) + '.', '']


def _tick(run: Run) -> List[str]:
    res = run.done['tick']['result'] or {}
    lines = ['## What does one tick of a bundled scene cost?', '',
             "The node's tick without ROS (`Simulation.tick`: 2 substeps, checks, the live "
             "error estimate) from the scene's start: the median tick, the worst second "
             '(median of its ticks) and the bodies asleep at the end.', '']
    if res:
        lines += _table(['scene', 'particles', 'bodies', 'ticks', 'median (ms)',
                         'worst second (ms)', 'largest (ms)', 'asleep at the end'],
                        [[res['scene'], f"{res['points']:,}", res['bodies'], res['ticks'],
                          _cell(res['tick_ms_median']), _cell(res['second_ms_worst']),
                          _cell(res['tick_ms_max']), res['asleep_at_end']]])
    return lines + run.source('tick')


def _node(run: Run) -> List[str]:
    rows = _rows(run.done['node']['out'] / 'node.csv')
    lines = ['## What rate does the node hold?', '',
             '`sim_node` on one box of N particles resting on the ground (linear, 8 clusters, '
             'damping 0.05, 2 substeps), a subscriber to `points` in another process, Fast '
             'DDS shared-memory profile. Tick, step (both substeps) and publish in ms '
             "(medians); latency from the publish call to the subscriber's callback.", '']
    if not rows:
        status = (run.done['node']['result'] or {}).get('node', {})
        return lines + [f'Not measured in this run ({status.get("status", "skipped")}).', '']
    lines += _table(['particles', 'target (Hz)', 'achieved (Hz)', 'tick', 'tick p95', 'step',
                     'publish', 'latency'],
                    [[f"{int(row['points']):,}", _cell(row['rate_hz_target']),
                      _cell(row['rate_hz']),
                      _cell(row['tick_ms_median']), _cell(row['tick_ms_p95']),
                      _cell(row['step_ms_median']), _cell(row['publish_ms_median']),
                      _cell(row['latency_ms_median'])] for row in rows])
    return lines + run.source('node')


def _accuracy(run: Run) -> List[str]:
    out = run.done['accuracy']['out']
    rows = [row for row in _rows(out / 'accuracy.csv') if row.get('substeps') == '1']
    lines = ['## How accurate is my step?', '',
             'Largest RMS position error (m) over 2 s of simulated time against the exact '
             'motion (rigid scenes) or the same configuration at a much finer step, per '
             'frame rate (one step a frame). `rigid_spin`: a cube spinning freely; '
             '`ballistic`: thrown under gravity; `soft_drop`: a soft cube dropped on the '
             'ground; `cantilever`: a beam pinned at one end; `plastic_press`: a plastic '
             'cube squeezed by two jaws.', '']
    scenes = list(dict.fromkeys(row['scene'] for row in rows))
    rates = sorted({_num(row['rate_hz']) for row in rows})
    body = []
    for scene in scenes:
        for cfg in dict.fromkeys((row['mode'], row['clusters']) for row in rows
                                 if row['scene'] == scene):
            got = {_num(row['rate_hz']): row for row in rows
                   if row['scene'] == scene and (row['mode'], row['clusters']) == cfg}
            ref = next(iter(got.values()))['ref_err']
            body.append([scene, f'{cfg[0]}, {cfg[1]}'] +
                        [_cell(got[rate]['err_rms'], 2) if rate in got else '-'
                         for rate in rates] +
                        ['exact' if _num(ref) == 0 else _cell(ref, 2)])
    lines += _table(['scene', 'mode, clusters'] + [f'{rate:g} Hz' for rate in rates] +
                    ['reference error'], body)
    lines += ["An error within a few times the reference's own error (estimated by running "
              'the reference again at twice its step) is not resolved.', '']
    orders = _rows(out / 'accuracy_order.csv')
    if orders:
        lines += ['Convergence order (slope of log error against log step):', '']
        lines += _table(['scene', 'configuration', 'order'],
                        [[row['scene'], row['configuration'], _cell(row['order'], 2)]
                         for row in orders])
    budget = _rows(out / 'accuracy_budget.csv')
    met = [row for row in budget if _num(row.get('err_rms')) is not None]
    if met:
        lines += ['The cheapest configuration of the sweep that stays below an error budget '
                  '(solver ms per simulated second, one thread):', '']
        lines += _table(['scene', 'budget (m)', 'cheapest', 'error (m)', 'ms per sim. s'],
                        [[row['scene'], row['budget_m'], row['cheapest'], _cell(row['err_rms'], 2),
                          _cell(row['ms_per_sim_s'])] for row in met])
    missed = [f"{row['scene']} ({_cell(row['budget_m'])} m)" for row in budget if row not in met]
    if missed:
        lines += ['No configuration of this sweep stays below: ' + ', '.join(missed) +
                  '; they need finer steps or substeps (`--substeps 1,4` and higher '
                  '`--dts` extend the sweep).', '']
    return lines + run.source('accuracy')


def _peers(run: Run) -> List[str]:
    rows = _rows(run.done['scaling']['out'] / 'pypbd.csv')
    lines = ['## How does it compare with pypbd, PyBullet and MuJoCo?', '',
             'pypbd (the Python bindings of PositionBasedDynamics, `pip install pypbd`) '
             'simulates the same lattice with the same clusters, one solver iteration, 5 ms '
             'steps; it runs in its own process at its best thread count, and sm_ros right '
             'after it under the same load. Bodies are added with the plain '
             '`World.add_body`.', '']
    if rows:
        lines += _table(['particles', 'clusters', 'pypbd (ms)', 'sm_ros rigid (ms)',
                         'sm_ros rigid, damped (ms)', 'speed-up rigid', 'speed-up damped'],
                        [[f"{int(row['N']):,}", row['clusters'], _cell(row['pypbd_best_ms']),
                          _cell(row['ours_rigid_ms']), _cell(row.get('ours_rigid_damped_ms')),
                          _cell(row['speedup_rigid'], 2) + 'x',
                          _cell(row.get('speedup_rigid_damped'), 2) + 'x'] for row in rows])
        lines += run.source('scaling')
    else:
        lines += ['pypbd was not installed for this run (`pip install pypbd`, or the '
                  '`bench` extra), so there is no row here.', '']
    lines += ['PyBullet and MuJoCo simulate different models (rigid bodies, soft bodies of '
              'their own); [peers.md](peers.md) compares scenes that each can run, from '
              '`python -m sm_ros.bench peers`.', '']
    return lines


def _rest() -> List[str]:
    return ['## Start-up, contact and the rest', '',
            "- Start-up (cold and warm Numba cache, first cloud): the README's "
            '[Start-up](../README.md#start-up) section.',
            '- Body-body contact: [contact.md](contact.md) (`python -m sm_ros.bench contact`).',
            '- The live error estimate: [error_estimate.md](error_estimate.md).',
            '- Clouds across processes with and without the Fast DDS profile: '
            '`python -m sm_ros.bench transport --points 100000 --rate 60 --profile '
            "config/fastdds_shm.xml` (and `--profile ''` for the defaults).",
            '- A bundled scene in the node with a viewer: `python -m sm_ros.bench node '
            '--node-scene paper_384 --node-rates 60`.',
            "- Where a scene's time goes: `python -m sm_ros.bench profile --scene many`.",
            '- Every size, mode and variant with plots: `python -m sm_ros.bench all --out '
            'bench_out`; the material fit against FEM: `python -m sm_ros.bench material`; '
            'the soak test: `python -m sm_ros.bench soak`.', '']


def page(run: Run, command: str) -> str:
    """The whole page from the parts run."""
    info = bc.machine_info()
    lines = ['# Benchmarks', '',
             f'Generated by `{command}` (a few minutes) on {info["cpu"]}, {info["cpus"]} CPUs, '
             f'Python {info["python"]}, NumPy {info["numpy"]}, Numba {info["numba"]} '
             f'({info["numba_threads"]} threads). Every figure is from that one run; the load '
             "average beside it is the machine's (other jobs running raise it and the "
             'times). Figures are medians unless said otherwise. Rerun the command on your '
             'machine to get your own page.', '']
    for section in (_speed, _tick, _node, _accuracy, _peers):
        lines += section(run)
    lines += _rest()
    return '\n'.join(lines).rstrip('\n') + '\n'


def main(argv: List[str], bench_main: Callable[[List[str]], int]) -> int:
    """Entry point of ``python -m sm_ros.bench --write-doc [PATH]``; ``bench_main``: the
    bench's own entry (``sm_ros.bench.__main__.main``), which runs the parts."""
    parser = argparse.ArgumentParser(prog='python -m sm_ros.bench --write-doc',
                                     description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--write-doc', nargs='?', const=str(ROOT / 'doc' / 'benchmarks.md'),
                   required=True, metavar='PATH', help='the page (doc/benchmarks.md)')
    parser.add_argument('--quick', action='store_true', help='tiny sizes (the smoke test)')
    parser.add_argument('--work', default='', help="keep the parts' tables here (default: a "
                   'temporary folder)')
    args = parser.parse_args(argv)
    from . import tick

    def run_tick(tick_argv):
        tick_parser = argparse.ArgumentParser()
        tick.add_arguments(tick_parser)
        parsed = tick_parser.parse_args(tick_argv[1:])
        return tick.measure(parsed.scene, parsed.ticks, parsed.settle, parsed.sleep == 'on')

    if not args.quick:                 # compile every kernel first: no figure pays for it
        subprocess.run([sys.executable, '-m', 'sm_ros.warmup'], check=False)
    command = 'python -m sm_ros.bench --write-doc' + (' --quick' if args.quick else '')
    with tempfile.TemporaryDirectory() as tmp:
        run = Run(Path(args.work or tmp), QUICK if args.quick else FULL)
        run.part('scaling', bench_main)
        run.part('accuracy', bench_main)
        run.part('tick', run_tick)
        run.part('node', bench_main)
        text = page(run, command)
    Path(args.write_doc).write_text(text, encoding='utf-8')
    print(f'wrote {args.write_doc} ({text.count(chr(10))} lines)')
    return 0
