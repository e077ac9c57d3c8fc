"""
Soak test of sim_node (endurance): the node under abuse for a bounded time.

``python -m sm_ros.bench.soak --seconds 60`` (or ``python -m sm_ros.bench soak --seconds
60``) runs, each in a process of its own (``sm_ros.bench.soak_procs``, started through
``sm_ros.bench.harness`` like the node benchmark's), all on this host
(``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` and a ROS domain of its own):

- ``node``: sim_node at ``--rate`` Hz on one box of ``--points`` particles resting on the
  ground (damping 0.05 as in the bundled scenes);
  it records every tick (duration, wall time), the resident memory at the start and at
  the end of the measured window, the refused messages per topic, where the box is and its
  fastest particle (about once a second), and checks that every parameter change it
  accepted took effect at the next tick (the node's parameter, the bodies' parameters,
  gravity and ground);
- ``driver``: sends ``--forces`` force messages per second (2 % of them bad: NaN, an unknown
  body), changes parameters at ``--param-rate`` Hz through the parameter service (alpha,
  beta, gravity, ground friction, plastic yield, force timeout; every tenth change out of
  range, which must be refused), grabs the box where it is (its centre from ``poses``),
  moves the gripper on a circle at 20 Hz and releases it once a second;
- ``sub`` x ``--subscribers``: read the clouds (one reliable, the next best effort, ...),
  count them and check that they hold every particle and finite coordinates.

The node measures for ``--seconds`` after a lead-in of ``--lead`` seconds in which the other
processes connect. The report (stdout; ``--json FILE`` for the figures) gives dropped ticks
(ticks the wall clock asked for and the node did not run), the worst and the 99th
percentile tick time, resident memory at start and end, messages refused, parameter
changes sent / accepted / refused / applied, and what the subscribers received. The exit
status is 0 when no process crashed, the state stayed finite, every accepted parameter was
applied and the node held its rate: at most ``--max-dropped`` (1 % by default) of the
ticks the wall clock asked for were dropped (a soak that held 52 of 60 Hz fails); else 1,
with the reasons on stderr.
"""

import argparse
import json
from pathlib import Path
import sys
import tempfile
from typing import Any, Dict, List, Optional

from . import harness
from .harness import box_side  # noqa: F401 - the soak box's edge (test/test_soak.py)
from .soak_procs import BODY


# ----------------------------------------------------------------------------------------
# orchestration
# ----------------------------------------------------------------------------------------

def summarise(node: Dict[str, Any], driver: Optional[Dict[str, Any]],
              subs: List[Optional[Dict[str, Any]]], a) -> Dict[str, Any]:
    """Turn the processes' records into the report's figures."""
    ticks = node['tick_s']
    period = 1.0 / node['rate_hz_target']
    expected = int(node['elapsed_s'] / period)
    starts = node['tick_start_s']
    gaps = [b - a_ for a_, b in zip(starts, starts[1:])]
    late = sum(max(0, int(round(g / period)) - 1) for g in gaps)
    fig = {
        'command': 'python -m sm_ros.bench.soak ' + ' '.join(a.argv),
        'points': node['points'], 'seconds': round(node['elapsed_s'], 3),
        'rate_hz_target': node['rate_hz_target'],
        'ticks': node['ticks'], 'ticks_expected': expected,
        'dropped_ticks': max(0, expected - node['ticks']),
        'skipped_periods': late,
        'rate_hz_achieved': node['ticks'] / node['elapsed_s'] if node['elapsed_s'] else 0.0,
        'tick_ms_worst': 1e3 * max(ticks) if ticks else float('nan'),
        'tick_ms_p99': 1e3 * harness.percentile(ticks, 99),
        'tick_ms_median': 1e3 * harness.percentile(ticks, 50),
        'overruns': sum(1 for t in ticks if t > period),
        'rss_start_mb': node['rss_start_bytes'] / 2**20,
        'rss_end_mb': node['rss_end_bytes'] / 2**20,
        'rss_growth_mb': (node['rss_end_bytes'] - node['rss_start_bytes']) / 2**20,
        'refused': node['refused'], 'refused_total': sum(node['refused'].values()),
        'params_accepted': node['params_accepted'], 'params_applied': node['params_applied'],
        'params_superseded': node['params_superseded'],
        'params_mismatch': node['params_mismatch'],
        'state_finite': node['finite'],
    }
    if driver is not None:
        fig['driver'] = driver
    fig['subscribers'] = subs
    fig['received'] = node.get('received', {})
    fig['every_accepted_parameter_applied'] = bool(
        node['params_accepted'] is not None and not node['params_mismatch']
        and node['params_applied'] + node['params_superseded'] == node['params_accepted']
        and (driver is None or (
            # every answer the driver got agrees; answers lost on the way back (the
            # service's depth-10 history) still count on the node's side
            driver['params_accepted'] <= node['params_accepted']
            <= driver['params_accepted'] + driver['params_unanswered']
            and not driver['params_unexpected']
            and all(ok for _, ok in driver.get('final_values_match', [])))))
    return fig


def report(fig: Dict[str, Any]) -> str:
    """Return the figures as a few human-readable lines."""
    d = fig.get('driver') or {}
    lines = [
        f"soak: {fig['points']} points at {fig['rate_hz_target']:g} Hz for "
        f"{fig['seconds']:.1f} s ({fig['command']})",
        f"  ticks {fig['ticks']} of {fig['ticks_expected']} expected: dropped "
        f"{fig['dropped_ticks']}, achieved {fig['rate_hz_achieved']:.1f} Hz; tick median "
        f"{fig['tick_ms_median']:.2f} ms, p99 {fig['tick_ms_p99']:.2f} ms, worst "
        f"{fig['tick_ms_worst']:.2f} ms, overruns {fig['overruns']}",
        f"  resident memory {fig['rss_start_mb']:.1f} MB at start, {fig['rss_end_mb']:.1f} MB "
        f"at end ({fig['rss_growth_mb']:+.1f} MB)",
        f"  messages received in the window {fig['received']}, refused "
        f"{fig['refused_total']} {fig['refused']}",
        f"  driver (whole run): forces sent {d.get('forces_sent', '?')} "
        f"({d.get('forces_bad_sent', '?')} bad), grabs {d.get('grabs_sent', '?')}, "
        f"releases {d.get('releases_sent', '?')}",
        f"  parameter changes sent {d.get('params_sent', '?')}: accepted "
        f"{d.get('params_accepted', '?')}, refused {d.get('params_refused', '?')}, "
        f"unanswered {d.get('params_unanswered', '?')}, unexpected outcome "
        f"{len(d.get('params_unexpected', []))}; node applied "
        f"{fig['params_applied']} + superseded {fig['params_superseded']} of "
        f"{fig['params_accepted']} accepted, mismatches {len(fig['params_mismatch'])} -> "
        f"{'all applied' if fig['every_accepted_parameter_applied'] else 'NOT all applied'}",
    ]
    run = fig.get('node_all_run') or {}
    if run.get('com_trace'):
        fastest = max(r[4] for r in run['com_trace'])
        end = run['com_trace'][-1]
        lines.append(f'  box centre at the end ({end[1]:.3g}, {end[2]:.3g}, {end[3]:.3g}) m, '
                     f'fastest particle seen {fastest:.3g} m/s')
    for i, s in enumerate(fig['subscribers']):
        if s is None:
            lines.append(f'  subscriber {i}: no result')
        else:
            lines.append(f"  subscriber {i} ({s['reliability']}): {s['received']} clouds, "
                         f"{s['rate_hz']:.1f} Hz, wrong size {s['bad_size']}, bad "
                         f"coordinates {s['non_finite']} of {s['checked']} checked")
    return '\n'.join(lines)


def orchestrate(a) -> int:
    """Start the processes, wait for them, print the report; 0 if all went well."""
    env = harness.ros_env(a.domain_id, harness.dds_profile(a.dds_profile,
                                                           use_environment=False))

    def start(role, *args):
        return harness.spawn('sm_ros.bench.soak_procs', [role, *args], env, stdin=True)
    limit = 3.0 * a.seconds + a.start_timeout + 120.0
    with tempfile.TemporaryDirectory(prefix='sm_ros_soak_') as tmp:
        scene = Path(tmp) / 'soak.yaml'
        expect = harness.box_scene(a.points, scene, a.damping, name=BODY,
                                   description='soak box')
        node_p = start('node', '--scene', str(scene), '--rate', str(a.rate), '--seconds',
                       str(a.seconds), '--lead', str(a.lead), '--subscribers',
                       str(a.subscribers), '--tail-timeout', str(limit))
        if harness.read_json_line(node_p, 'ready', a.start_timeout) is None:
            rc, _, err = harness.stop(node_p, 10.0)
            print(f'soak: sim_node did not start (exit {rc})\n{err}', file=sys.stderr)
            return 1
        driver_p = start('driver', '--seconds', str(limit), '--points', str(a.points),
                         '--forces', str(a.forces), '--param-rate', str(a.param_rate))
        sub_ps = [start('sub', '--seconds', str(limit), '--index', str(i), '--expect',
                        str(expect)) for i in range(a.subscribers)]
        window = harness.read_json_line(node_p, 'window', limit)
        outs = {'driver': harness.stop(driver_p, 60.0)}
        for i, p in enumerate(sub_ps):
            outs[f'sub{i}'] = harness.stop(p, 30.0)
        outs['node'] = harness.stop(node_p, 60.0)
    crashed = {k: (rc, err) for k, (rc, res, err) in outs.items() if rc != 0 or res is None}
    if window is None:
        crashed.setdefault('node', (outs['node'][0], outs['node'][2]))
        print('soak: sim_node crashed or gave no result:\n' + outs['node'][2],
              file=sys.stderr)
        return 1
    node_res = dict(window['window'])
    final = outs['node'][1] or {}
    node_res.update({k: final.get(k) for k in ('params_accepted', 'params_applied',
                                               'params_superseded', 'params_mismatch')})
    node_res['finite'] = final.get('finite', False)
    fig = summarise(node_res, outs['driver'][1],
                    [outs[f'sub{i}'][1] for i in range(a.subscribers)], a)
    fig['node_all_run'] = {k: final.get(k) for k in ('refused_all_run', 'received_all_run',
                                                     'last_refusal', 'com_end',
                                                     'com_trace')}
    fig['crashed'] = {k: {'exit': rc, 'stderr_tail': err[-500:]}
                      for k, (rc, err) in crashed.items()}
    print(report(fig))
    if crashed:
        print(f"  CRASHED: {', '.join(crashed)}", file=sys.stderr)
    if a.json:
        Path(a.json).write_text(json.dumps(fig, indent=1, default=str) + '\n')
    good, reasons = verdict(fig, a.max_dropped)
    for reason in reasons:
        print(f'  FAILED: {reason}', file=sys.stderr)
    return 0 if good else 1


def verdict(fig: Dict[str, Any], max_dropped: float) -> tuple:
    """
    Return (passed, reasons): crashes, a non-finite state, accepted parameters not applied,
    and more than ``max_dropped`` (a fraction) of the expected ticks dropped.
    """
    reasons = []
    if fig.get('crashed'):
        reasons.append(f"crashed: {', '.join(fig['crashed'])}")
    if not fig.get('state_finite'):
        reasons.append('the state went non-finite')
    if not fig.get('every_accepted_parameter_applied'):
        reasons.append('an accepted parameter change was not applied')
    expected = fig.get('ticks_expected') or 0
    dropped = fig.get('dropped_ticks') or 0
    if expected and dropped > max_dropped * expected:
        reasons.append(f'{dropped} of {expected} ticks dropped ({100.0 * dropped / expected:.1f} '
                       f'% > {100.0 * max_dropped:g} %): '
                       f"{fig.get('rate_hz_achieved', 0.0):.1f} of "
                       f"{fig.get('rate_hz_target', 0.0):g} Hz held")
    return not reasons, reasons


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog='python -m sm_ros.bench.soak',
                                description=__doc__.split('\n\n')[0].strip())
    p.add_argument('--seconds', type=float, default=60.0, help='measured time (s)')
    p.add_argument('--points', type=int, default=100_000, help='particles of the box')
    p.add_argument('--rate', type=float, default=60.0, help='node tick rate (Hz)')
    p.add_argument('--forces', type=float, default=1000.0, help='force messages per second')
    p.add_argument('--param-rate', type=float, default=50.0,
                   help='parameter changes per second')
    p.add_argument('--subscribers', type=int, default=2, help='cloud subscriber processes')
    p.add_argument('--damping', type=float, default=0.05,
                   help='damping of the box, as in the bundled scenes')
    p.add_argument('--lead', type=float, default=3.0,
                   help='seconds the node runs before measuring (the others connect)')
    p.add_argument('--start-timeout', type=float, default=180.0,
                   help='seconds allowed for the node to start (cold Numba cache)')
    p.add_argument('--domain-id', type=int, default=None, help='ROS_DOMAIN_ID (random)')
    p.add_argument('--dds-profile', default=None,
                   help="Fast DDS profile (default config/fastdds_shm.xml; '' for none)")
    p.add_argument('--max-dropped', type=float, default=0.01,
                   help='fraction of the expected ticks that may be dropped before the '
                        'soak fails (0.01; 1 accepts any rate)')
    p.add_argument('--json', default=None, help='write the figures to this file')
    return p


def main(argv: Optional[List[str]] = None) -> int:
    """Entry point (also ``python -m sm_ros.bench soak``); returns the exit status."""
    argv = list(sys.argv[1:] if argv is None else argv)
    a = _parser().parse_args(argv)
    a.argv = argv
    return orchestrate(a)


if __name__ == '__main__':
    sys.exit(main())
