"""
Part 3 of the benchmark: the node end to end.

For each size and rate: sim_node runs in one process on a scene of one box of N points
resting on the ground (mode, clusters, damping and substeps from the flags; by default
what users run: linear, 8 clusters, damping 0.05, 2 substeps; ``dt`` = 1 / (rate x
substeps) so simulated time keeps up with wall time); a subscriber in a second process
receives ``points``. ``--node-count N`` runs N such nodes side by side, each in its own
namespace (``/sim_<i>``) with its own subscriber process: a scene split over processes.
Reported: the achieved tick rate; the tick time split into step, cloud build
(``CloudBuffer.fill``) and publish; the subscriber's receive rate and the latency from the
node's publish call to the subscriber's callback (both processes read the same wall clock).
"""

import argparse
from pathlib import Path
import subprocess
import tempfile
import time
from typing import Any, Dict, List, Optional

import numpy as np

from . import common as bc, harness


def add_arguments(p: argparse.ArgumentParser):
    """Add the flags of the ``node`` subcommand."""
    p.add_argument('--node-sizes', default='1e4,1e5', help='points ("" to skip the node)')
    p.add_argument('--node-scene', default='',
                   help='a bundled scene name or scene file instead of the box of '
                        '--node-sizes points, e.g. paper_384 (--node-mode and --node-clusters '
                        'still apply to its bodies that set no mode or clusters of their own)')
    p.add_argument('--node-rates', default='30,60', help='tick rates in Hz')
    p.add_argument('--node-seconds', type=float, default=4.0, help='measured seconds')
    p.add_argument('--node-substeps', type=int, default=2)
    p.add_argument('--node-mode', default='linear')
    p.add_argument('--node-clusters', type=int, default=2,
                   help="the node's clusters parameter (cubes per axis: 2 = 8 clusters)")
    p.add_argument('--node-damping', type=float, default=0.05)
    p.add_argument('--node-count', type=int, default=1,
                   help='nodes side by side (namespaces sim_0, sim_1, ...)')
    p.add_argument('--node-threads', type=int, default=0,
                   help='NUMBA_NUM_THREADS of each node process (0: Numba decides; with '
                        'N nodes on C cores, C / N shares the cores without oversubscribing)')
    p.add_argument('--node-dds-profile', default=None,
                   help="Fast DDS profile for both processes (default: the repository's "
                        'config/fastdds_shm.xml, as the README recommends for large clouds; '
                        '"" for the DDS defaults)')


def node_ready() -> Optional[str]:
    """None if the node can run here, else the reason it cannot."""
    try:
        import rclpy  # noqa: F401
    except ImportError as exc:
        return f'rclpy is not importable ({exc})'
    try:
        import sm_ros.node as n
    except Exception as exc:  # noqa: BLE001 - any import failure means "not ready"
        return f'sm_ros.node does not import ({type(exc).__name__}: {exc})'
    if not hasattr(n, 'SimNode'):
        return 'sm_ros.node has no SimNode'
    return None


def measure(points: int, rate: float, args, tmp: Path) -> Optional[Dict[str, Any]]:
    """Run the node(s) and one subscriber process per node for one (size, rate)."""
    rows = measure_many(points, rate, args, tmp)
    if not rows:
        return None
    if len(rows) == 1:
        return rows[0]
    out = dict(rows[0])
    for k in out:
        if isinstance(out[k], float) and k not in ('rate_hz_target', 'period_ms'):
            out[k] = min(r[k] for r in rows) if k in ('rate_hz', 'rx_rate_hz') \
                else max(r[k] for r in rows)
    out['nodes'] = len(rows)
    out['per_node'] = rows
    return out


def measure_many(points: int, rate: float, args, tmp: Path) -> List[Dict[str, Any]]:
    """Start ``--node-count`` nodes (and their subscribers) at once; one row per node."""
    import json
    count = max(1, int(getattr(args, 'node_count', 1)))
    scene = getattr(args, 'node_scene', '')
    if not scene:
        scene = tmp / f'bench_{points}.yaml'
        harness.box_scene(bc.lattice_side(points) ** 3, scene,
                          getattr(args, 'node_damping', 0.0))
    env = harness.ros_env(profile=harness.dds_profile(args.node_dds_profile))
    node_env = dict(env)
    if getattr(args, 'node_threads', 0):
        node_env['NUMBA_NUM_THREADS'] = str(int(args.node_threads))
    warm = 2.0 + count * points / 2e5
    # the subscribers run until the nodes are done (SIGTERM), however long start-up takes
    sub_seconds = args.node_seconds + warm + 600.0
    spaces = ['' if count == 1 else f'/sim_{i}' for i in range(count)]
    procs = 'sm_ros.bench.node_procs'
    subs = [harness.spawn(procs, ['sub', '--seconds', f'{sub_seconds:.1f}', '--namespace', ns],
                          env) for ns in spaces]
    time.sleep(1.0)
    nodes = [harness.spawn(
        procs, ['node', '--scene', str(scene), '--rate', str(rate), '--seconds',
                str(args.node_seconds), '--warmup', f'{warm:.1f}', '--substeps',
                str(args.node_substeps), '--mode', args.node_mode, '--clusters',
                str(args.node_clusters), '--namespace', ns], node_env) for ns in spaces]
    results = []
    for proc in nodes:
        try:
            out, err = proc.communicate(timeout=120 + count * points / 1e4)
        except subprocess.TimeoutExpired:
            proc.kill()
            out, err = '', 'timeout'
        lines = [ln for ln in out.splitlines() if ln.startswith('{')]
        if proc.returncode != 0 or not lines:
            bc.log(f'[node] a node failed: {(err or out).strip().splitlines()[-1:]}')
            results.append(None)
        else:
            results.append(json.loads(lines[-1]))
    received_all = []
    for sub in subs:
        sub.terminate()
    for sub in subs:
        try:
            out, _ = sub.communicate(timeout=60)
        except subprocess.TimeoutExpired:
            sub.kill()
            out = ''
        lines = [ln for ln in out.splitlines() if ln.startswith('{')]
        received_all.append(json.loads(lines[-1])['received'] if lines else [])
    rows = []
    for node_res, received, ns in zip(results, received_all, spaces):
        if node_res is not None:
            row = _row(node_res, received, rate, args)
            row['namespace'] = ns or '/'
            rows.append(row)
    return rows


def _row(node_res, received, rate, args) -> Dict[str, Any]:
    """Turn one node's and its subscriber's records into a table row."""
    sent = node_res['sent']
    tick = np.array(node_res['tick_s']) * 1e3
    steps = np.array(node_res['step_s']) * 1e3
    fill = np.array(node_res['fill_s']) * 1e3
    pub = np.array(node_res['publish_s']) * 1e3
    other = np.array(node_res.get('other_s', [])) * 1e3
    est = np.array(node_res.get('estimate_s', [])) * 1e3
    lat = [t - sent[s] for s, t, _ in received if s in sent]
    # the subscriber's rate over the node's measured window
    in_window = [t for s, t, _ in received if s in sent]
    rx_rate = (len(in_window) - 1) / (max(in_window) - min(in_window)) \
        if len(in_window) > 2 else 0.0
    sub_steps = max(1, int(args.node_substeps))
    med = (lambda a: float(np.median(a)) if len(a) else float('nan'))   # noqa: E731
    p95 = (lambda a: float(np.percentile(a, 95)) if len(a) else float('nan'))  # noqa: E731
    return {'points': node_res['points'], 'rate_hz_target': rate,
            'rate_hz': node_res['ticks'] / node_res['elapsed_s'],
            'tick_ms_median': med(tick), 'tick_ms_p95': p95(tick),
            'step_ms_median': med(steps) * sub_steps, 'fill_ms_median': med(fill),
            'publish_ms_median': med(pub),
            # the tick minus its steps, fill, publish and error estimate, tick by tick
            'other_ms_median': med(other) if len(other) else
            med(tick) - med(steps) * sub_steps - med(fill) - med(pub),
            'estimate_ms_mean': float(np.mean(est)) if len(est) else 0.0,
            'period_ms': 1e3 / rate,
            'rx_rate_hz': rx_rate, 'rx_messages': len(lat),
            'latency_ms_median': 1e3 * med(lat), 'latency_ms_p95': 1e3 * p95(lat)}


def run(args, out: Path) -> Dict[str, Any]:
    """Every (size, rate); write the table; return findings."""
    sizes = [int(x) for x in bc.as_list(args.node_sizes)]
    if getattr(args, 'node_scene', ''):
        sizes = [0]                     # the scene says how many points
    if not sizes:
        return {'status': 'skipped (no --node-sizes)'}
    reason = node_ready()
    if reason:
        bc.log(f'[node] not run: {reason}')
        return {'status': f'not run: {reason}'}
    rates = bc.as_list(args.node_rates)
    t = bc.Table('node', ['points', 'rate_hz_target', 'rate_hz', 'tick_ms_median',
                          'tick_ms_p95', 'step_ms_median', 'fill_ms_median',
                          'publish_ms_median', 'other_ms_median', 'estimate_ms_mean',
                          'period_ms', 'rx_rate_hz',
                          'latency_ms_median', 'latency_ms_p95'],
                 f'sim_node end to end ({getattr(args, "node_scene", "") or "one box"}, '
                 f'{args.node_mode}, clusters {args.node_clusters}, '
                 f'damping {getattr(args, "node_damping", 0.0):g}, '
                 f'{args.node_substeps} step(s) per tick, '
                 f'{max(1, int(getattr(args, "node_count", 1)))} node(s) side by side, '
                 f'Numba threads {getattr(args, "node_threads", 0) or "default"} '
                 '(worst node shown), ground on, DDS profile: '
                 f'{Path(harness.dds_profile(args.node_dds_profile) or "defaults").name})')
    each = bc.Table('node_each', ['namespace'] + t.columns,
                    'Every node of the side-by-side runs (--node-count > 1)')
    findings: Dict[str, Any] = {'rows': []}
    with tempfile.TemporaryDirectory() as d:
        from sm_ros.progress import bar
        configs = [(n, rate) for n in sizes for rate in rates]
        for n, rate in bar(iterable=configs, total=len(configs), desc='node', unit='run'):
            bc.log(f'[node] {getattr(args, "node_scene", "") or f"{n} points"} at {rate:g} Hz')
            r = measure(n, rate, args, Path(d))
            if r is None:
                continue
            t.add(**{k: r[k] for k in t.columns})
            findings['rows'].append(r)
            for row in r.get('per_node', []):
                each.add(**{k: row[k] for k in each.columns})
            if n and bc.lattice_side(n) == 46 and rate == 60:
                findings['target'] = r
    t.write(out)
    if each.rows:
        each.write(out)
    findings['status'] = 'measured' if findings['rows'] else 'failed'
    return findings
