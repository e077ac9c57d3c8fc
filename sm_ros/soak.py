"""
Soak test of sim_node (issue 6, endurance): the node under abuse for a bounded time.

``python -m sm_ros.soak --seconds 60`` (or ``python -m sm_ros.bench soak --seconds 60``)
runs, each in a process of its own, all on this host (``ROS_AUTOMATIC_DISCOVERY_RANGE=
LOCALHOST`` and a ROS domain of its own):

- ``node``: sim_node at ``--rate`` Hz on one box of ``--points`` particles resting on the
  ground (damping 0.05 as in the bundled scenes: undamped, the random alpha changes pump
  energy into it, parametric resonance of Eq. 13-14, and it flies off within a minute);
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
status is 0 when no process crashed and every accepted parameter was applied, else 1.
"""

import argparse
import json
import math
import os
from pathlib import Path
import random
import subprocess
import sys
import tempfile
import time
from typing import Any, Dict, List, Optional

SPACING = 0.01
BODY = 'box'
GRIPPER = 'soak_hand'


def _rss_bytes() -> int:
    """Resident set size of this process (psutil, else /proc)."""
    try:
        import psutil
        return int(psutil.Process().memory_info().rss)
    except ImportError:
        with open('/proc/self/statm') as f:
            return int(f.read().split()[1]) * os.sysconf('SC_PAGE_SIZE')


def stop_requested() -> bool:
    """Whether the orchestrator wrote 'stop' (or closed) this process's stdin."""
    import select
    try:
        if select.select([sys.stdin], [], [], 0)[0]:
            line = sys.stdin.readline()
            return line == '' or line.strip() == 'stop'
    except (OSError, ValueError):
        return True
    return False


def box_side(points: int) -> int:
    """Particles per edge of the cubic box of about ``points`` particles."""
    return max(2, int(round(points ** (1.0 / 3.0))))


def scene_yaml(points: int, path: Path, damping: float = 0.05) -> int:
    """Write the soak scene (one box on the ground); return its number of particles."""
    n = box_side(points)
    size = (n - 1) * SPACING
    path.write_text(
        'description: soak box\n'
        'bodies:\n'
        f'  - name: {BODY}\n'
        '    shape: box\n'
        f'    size: [{size:.6f}, {size:.6f}, {size:.6f}]\n'
        f'    spacing: {SPACING}\n'
        '    mass: 1.0\n'
        f'    damping: {damping}\n'
        f'    position: [0.0, 0.0, {size / 2 + 0.001:.6f}]\n')
    return n ** 3


# ----------------------------------------------------------------------------------------
# node process
# ----------------------------------------------------------------------------------------

def _body_field_ok(node, name: str, value: Any) -> bool:
    """Whether an applied parameter shows in the world (bodies, gravity, ground)."""
    import numpy as np
    from sm_ros.params import BODY_FIELDS
    world = node.world
    if name in BODY_FIELDS:
        return all(getattr(b.params, BODY_FIELDS[name]) == value for b in world.bodies)
    if name == 'gravity':
        return bool(np.array_equal(world.gravity, np.asarray(value, dtype=float)))
    if name == 'ground.friction':
        return world.ground is not None and world.ground.friction == value
    return True


def run_node(a) -> Dict[str, Any]:
    """Run sim_node; measure ticks, memory, refusals and parameter application."""
    import numpy as np
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter import Parameter
    from sm_ros.node import SimNode

    rclpy.init()
    overrides = [Parameter('scene', value=a.scene), Parameter('rate', value=float(a.rate)),
                 Parameter('diagnostics_rate', value=1.0)]
    node = SimNode(parameter_overrides=overrides)
    rec = {'tick': [], 'start': [], 'accepted': 0, 'applied': 0, 'superseded': 0,
           'mismatch': []}
    measuring = [False]
    latest: Dict[str, Any] = {}

    tick0 = node.tick

    trace = []

    def tick():
        t = time.perf_counter()
        tick0()
        if measuring[0]:
            rec['tick'].append(time.perf_counter() - t)
            rec['start'].append(t)
        if len(rec['tick']) % 60 == 1 and node.world.bodies:     # where the box is, ~1 Hz
            b = node.world.bodies[0]
            trace.append([round(time.monotonic(), 3)] + [round(float(c), 4) for c in b.com()]
                         + [round(float(np.abs(b.v).max()), 4)])
    node.tick = tick

    set0 = node.parameters_set_callback

    def parameters_set(params):
        set0(params)
        for p in params:
            if p.name in node._p:
                if p.name in latest:
                    rec['superseded'] += 1          # replaced before a tick applied it
                latest[p.name] = node._pending.get(p.name, p.value)
                rec['accepted'] += 1
    node.parameters_set_callback = parameters_set
    # rclpy holds the bound method it was given: register the wrapper in its place
    node._post_set_parameters_callbacks = [
        parameters_set if cb == set0 else cb for cb in node._post_set_parameters_callbacks]

    apply0 = node.sim.apply_pending

    def apply_pending():
        pending = dict(latest)
        latest.clear()
        apply0()
        for name, value in pending.items():
            ok = node._p.get(name) == value and _body_field_ok(node, name, value)
            if ok:
                rec['applied'] += 1
            else:
                rec['mismatch'].append([name, repr(value), repr(node._p.get(name))])
    node.sim.apply_pending = apply_pending

    received: Dict[str, int] = {}
    for sub in node.subscriptions:                  # count what arrives, per topic
        topic = sub.topic_name.rsplit('/', 1)[-1]

        def counted(msg, cb=sub.callback, topic=topic):
            received[topic] = received.get(topic, 0) + 1
            cb(msg)
        sub.callback = counted

    ex = SingleThreadedExecutor()
    ex.add_node(node)
    print(json.dumps({'ready': True, 'points': node.num_points}), flush=True)
    deadline = time.monotonic() + a.connect_timeout
    while time.monotonic() < deadline and not (
            node.count_publishers('force') > 0
            and node.pub_points.get_subscription_count() >= a.subscribers):
        ex.spin_once(timeout_sec=0.01)
    lead_end = time.monotonic() + a.lead
    while time.monotonic() < lead_end:
        ex.spin_once(timeout_sec=0.01)
    rss_start = _rss_bytes()
    received_start = dict(received)
    refused_start = dict(node.refused)
    measuring[0] = True
    t0 = time.monotonic()
    t_end = t0 + a.seconds
    while time.monotonic() < t_end:
        ex.spin_once(timeout_sec=0.01)
    elapsed = time.monotonic() - t0
    measuring[0] = False
    rss_end = _rss_bytes()
    refused = {k: v - refused_start.get(k, 0) for k, v in node.refused.items()
               if v - refused_start.get(k, 0)}
    window = {'points': node.num_points, 'rate_hz_target': a.rate, 'elapsed_s': elapsed,
              'ticks': len(rec['tick']), 'tick_s': rec['tick'], 'tick_start_s': rec['start'],
              'rss_start_bytes': rss_start, 'rss_end_bytes': rss_end, 'refused': refused,
              'received': {k: v - received_start.get(k, 0) for k, v in received.items()}}
    print(json.dumps({'window': window}), flush=True)
    # the others finish against a live node (answers to the last parameter requests)
    deadline = time.monotonic() + a.tail_timeout
    while time.monotonic() < deadline and not stop_requested():
        ex.spin_once(timeout_sec=0.01)
    apply_pending()        # anything accepted in the last moments, then every change checked
    out = {'params_accepted': rec['accepted'], 'params_applied': rec['applied'],
           'params_superseded': rec['superseded'], 'params_mismatch': rec['mismatch'],
           'refused_all_run': dict(node.refused), 'received_all_run': received,
           'last_refusal': dict(node.last_refusal),
           'com_end': [[b.name] + [round(float(c), 4) for c in b.com()]
                       for b in node.world.bodies], 'com_trace': trace,
           'finite': all(b.is_finite() for b in node.world.bodies)}
    node.destroy_node()
    rclpy.try_shutdown()
    return out


# ----------------------------------------------------------------------------------------
# driver process: forces, parameters, grab / release
# ----------------------------------------------------------------------------------------

PARAM_CYCLE = ('alpha', 'beta', 'gravity', 'ground.friction', 'plasticity.yield',
               'force_timeout')


def _param_change(k: int, rng: random.Random):
    """Return the k-th parameter change: (name, value, expected to be accepted)."""
    name = PARAM_CYCLE[k % len(PARAM_CYCLE)]
    if k % 10 == 9:                                      # out of range: must be refused
        bad = {'alpha': 1.5, 'beta': -0.5, 'gravity': [0.0, 0.0, float('nan')],
               'ground.friction': -1.0, 'plasticity.yield': -1.0, 'force_timeout': -2.0}
        return name, bad[name], False
    good = {'alpha': round(rng.uniform(0.2, 0.9), 6), 'beta': round(rng.uniform(0.0, 1.0), 6),
            'gravity': [0.0, 0.0, -round(rng.uniform(5.0, 15.0), 6)],
            'ground.friction': round(rng.uniform(0.1, 1.0), 6),
            'plasticity.yield': round(rng.uniform(0.0, 0.1), 6),
            'force_timeout': round(rng.uniform(0.0, 1.0), 6)}
    return name, good[name], True


def run_driver(a) -> Dict[str, Any]:
    """Send forces, parameter changes, grabs and releases until the time is up."""
    import rclpy
    from geometry_msgs.msg import PoseArray, PoseStamped, WrenchStamped
    from rcl_interfaces.srv import GetParameters, SetParameters
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.parameter import Parameter, parameter_value_to_python
    from std_msgs.msg import String

    rclpy.init()
    node = Node('soak_driver')
    pub_force = node.create_publisher(WrenchStamped, 'force', 100)
    pub_grab = node.create_publisher(PoseStamped, 'grab', 10)
    pub_release = node.create_publisher(String, 'release', 10)
    set_client = node.create_client(SetParameters, f'/{a.node_name}/set_parameters')
    get_client = node.create_client(GetParameters, f'/{a.node_name}/get_parameters')
    com = [None]                                         # the box's centre, from 'poses'

    def poses_cb(msg):
        if msg.poses:
            p = msg.poses[0].position
            com[0] = (p.x, p.y, p.z)
    node.create_subscription(PoseArray, 'poses', poses_cb, 10)
    ex = SingleThreadedExecutor()
    ex.add_node(node)
    stats = {'forces_sent': 0, 'forces_bad_sent': 0, 'params_sent': 0,
             'params_accepted': 0, 'params_refused': 0, 'params_unexpected': [],
             'params_unanswered': 0, 'grabs_sent': 0, 'releases_sent': 0}
    last_accepted: Dict[str, Any] = {}
    pending = []

    def collect_answers(check_expected: bool):
        """Count the answered parameter changes; remember the accepted values."""
        for item in [p for p in pending if p[0].done()]:
            pending.remove(item)
            future, name, value, good = item
            ok = bool(future.result().results[0].successful)
            stats['params_accepted' if ok else 'params_refused'] += 1
            if ok:
                last_accepted[name] = value
            if check_expected and ok != good:
                stats['params_unexpected'].append([name, repr(value), ok])
    deadline = time.monotonic() + a.connect_timeout
    while not (set_client.service_is_ready() and pub_force.get_subscription_count() > 0):
        if time.monotonic() > deadline:
            raise RuntimeError('sim_node did not show up')
        ex.spin_once(timeout_sec=0.05)

    rng = random.Random(7)
    t0 = time.monotonic()
    t_end = t0 + a.seconds                             # a safety limit: 'stop' ends it
    next_force = next_param = next_grab = t0
    k_param = 0
    k_force = 0
    holding = False
    grab_at = (0.0, 0.0, 0.0)
    last_release = t0
    while time.monotonic() < t_end and not stop_requested():
        now = time.monotonic()
        while next_force <= now:                         # forces, in bursts of 1 ms slots
            msg = WrenchStamped()
            k_force += 1
            if k_force % 100 == 0:
                msg.header.frame_id = BODY
                msg.wrench.force.x = float('nan')
                stats['forces_bad_sent'] += 1
            elif k_force % 100 == 50:
                msg.header.frame_id = 'no_such_body'
                msg.wrench.force.z = 1.0
                stats['forces_bad_sent'] += 1
            else:
                msg.header.frame_id = BODY if k_force % 2 else ''
                msg.wrench.force.x = rng.uniform(-2.0, 2.0)
                msg.wrench.force.y = rng.uniform(-2.0, 2.0)
                msg.wrench.force.z = rng.uniform(0.0, 5.0)
                msg.wrench.torque.z = rng.uniform(-0.01, 0.01)
            pub_force.publish(msg)
            stats['forces_sent'] += 1
            next_force += 1.0 / a.forces
        if next_param <= now:                            # one parameter change
            name, value, good = _param_change(k_param, rng)
            k_param += 1
            req = SetParameters.Request()
            req.parameters = [Parameter(name, value=value).to_parameter_msg()]
            pending.append((set_client.call_async(req), name, value, good))
            stats['params_sent'] += 1
            next_param += 1.0 / a.param_rate
        if next_grab <= now:                             # the gripper, 20 Hz
            if holding and now - last_release >= 1.0:
                pub_release.publish(String(data=GRIPPER))
                stats['releases_sent'] += 1
                holding = False
                last_release = now
            elif com[0] is not None:
                if not holding:                          # grab where the box is now
                    grab_at = com[0]
                phase = 2.0 * math.pi * (now - t0)
                pose = PoseStamped()
                pose.header.frame_id = GRIPPER
                pose.pose.position.x = grab_at[0] + (0.01 * math.cos(phase) if holding else 0)
                pose.pose.position.y = grab_at[1] + (0.01 * math.sin(phase) if holding else 0)
                pose.pose.position.z = grab_at[2] + (0.02 if holding else 0.0)
                pose.pose.orientation.w = 1.0
                pub_grab.publish(pose)
                stats['grabs_sent'] += 1
                if not holding:
                    holding = True
                    last_release = now
            next_grab += 0.05
        collect_answers(check_expected=True)
        ex.spin_once(timeout_sec=max(0.0, min(next_force, next_param, next_grab)
                                     - time.monotonic()))
        for _ in range(4):                 # take what else is ready (responses, poses)
            ex.spin_once(timeout_sec=0.0)
    wait_end = time.monotonic() + 15.0
    while pending and time.monotonic() < wait_end:
        ex.spin_once(timeout_sec=0.05)
        collect_answers(check_expected=False)
    stats['params_unanswered'] = len(pending)
    # the node's parameters now: the last accepted value of each
    req = GetParameters.Request()
    req.names = sorted(last_accepted)
    future = get_client.call_async(req)
    ex.spin_until_future_complete(future, timeout_sec=5.0)
    final_ok = []
    if future.done():
        for name, v in zip(req.names, future.result().values):
            got = parameter_value_to_python(v)
            got = [float(c) for c in got] if not isinstance(got, (str, bool, int, float)) \
                else got
            final_ok.append([name, got == last_accepted[name]])
    stats['final_values_match'] = final_ok
    stats['elapsed_s'] = time.monotonic() - t0
    node.destroy_node()
    rclpy.try_shutdown()
    return stats


# ----------------------------------------------------------------------------------------
# subscriber process
# ----------------------------------------------------------------------------------------

def run_sub(a) -> Dict[str, Any]:
    """Read the clouds; count them and check sizes and (a sample of) coordinates."""
    import numpy as np
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import PointCloud2
    from sm_ros.cloud import read_xyz

    rclpy.init()
    node = Node(f'soak_sub_{a.index}')
    reliability = ReliabilityPolicy.BEST_EFFORT if a.index % 2 else \
        ReliabilityPolicy.RELIABLE
    stats = {'received': 0, 'bad_size': 0, 'non_finite': 0, 'checked': 0,
             'reliability': 'best_effort' if a.index % 2 else 'reliable', 'first_s': None,
             'last_s': None}

    def cb(msg):
        now = time.monotonic()
        stats['received'] += 1
        stats['first_s'] = stats['first_s'] or now
        stats['last_s'] = now
        if msg.width * msg.height != a.expect:
            stats['bad_size'] += 1
        if stats['received'] % 30 == 1:
            stats['checked'] += 1
            try:
                xyz = read_xyz(msg)
                if xyz.shape[0] != a.expect or not np.isfinite(xyz).all():
                    stats['non_finite'] += 1
            except ValueError:
                stats['non_finite'] += 1
    node.create_subscription(PointCloud2, 'points', cb,
                             QoSProfile(depth=5, reliability=reliability))
    ex = SingleThreadedExecutor()
    ex.add_node(node)
    t_end = time.monotonic() + a.seconds                # a safety limit: 'stop' ends it
    while time.monotonic() < t_end and not stop_requested():
        ex.spin_once(timeout_sec=0.05)
    span = (stats['last_s'] - stats['first_s']) if stats['received'] > 1 else 0.0
    stats['rate_hz'] = (stats['received'] - 1) / span if span > 0 else 0.0
    del stats['first_s'], stats['last_s']
    node.destroy_node()
    rclpy.try_shutdown()
    return stats


# ----------------------------------------------------------------------------------------
# orchestration
# ----------------------------------------------------------------------------------------

def _env(domain: Optional[int], dds_profile: Optional[str]) -> Dict[str, str]:
    env = dict(os.environ)
    env['ROS_DOMAIN_ID'] = str(domain if domain is not None
                               else random.Random(os.getpid()).randint(101, 200))
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    env.pop('ROS_LOCALHOST_ONLY', None)           # deprecated in Jazzy, superseded above
    if dds_profile:
        env['RMW_IMPLEMENTATION'] = 'rmw_fastrtps_cpp'
        env['FASTRTPS_DEFAULT_PROFILES_FILE'] = dds_profile
    root = str(Path(__file__).resolve().parents[1])
    env['PYTHONPATH'] = root + os.pathsep + env.get('PYTHONPATH', '')
    return env


def _default_profile(flag: Optional[str]) -> Optional[str]:
    if flag == '':
        return None
    if flag:
        return str(Path(flag).resolve())
    cand = Path(__file__).resolve().parents[1] / 'config' / 'fastdds_shm.xml'
    return str(cand) if cand.is_file() else None


def _last_json(text: str) -> Optional[Dict[str, Any]]:
    lines = [ln for ln in text.splitlines() if ln.startswith('{')]
    for ln in reversed(lines):
        try:
            obj = json.loads(ln)
        except ValueError:
            continue
        if 'ready' not in obj:
            return obj
    return None


def _percentile(values: List[float], q: float) -> float:
    if not values:
        return float('nan')
    s = sorted(values)
    return s[min(len(s) - 1, int(round(q / 100.0 * (len(s) - 1))))]


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
        'command': 'python -m sm_ros.soak ' + ' '.join(a.argv),
        'points': node['points'], 'seconds': round(node['elapsed_s'], 3),
        'rate_hz_target': node['rate_hz_target'],
        'ticks': node['ticks'], 'ticks_expected': expected,
        'dropped_ticks': max(0, expected - node['ticks']),
        'skipped_periods': late,
        'rate_hz_achieved': node['ticks'] / node['elapsed_s'] if node['elapsed_s'] else 0.0,
        'tick_ms_worst': 1e3 * max(ticks) if ticks else float('nan'),
        'tick_ms_p99': 1e3 * _percentile(ticks, 99),
        'tick_ms_median': 1e3 * _percentile(ticks, 50),
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


def _read_json_line(proc, key: str, timeout: float) -> Optional[Dict[str, Any]]:
    """Read ``proc``'s stdout until a JSON line with ``key`` (None on EOF or timeout)."""
    import select
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if not select.select([proc.stdout], [], [], 0.5)[0]:
            if proc.poll() is not None:
                return None
            continue
        line = proc.stdout.readline()
        if not line:
            return None
        if line.startswith('{') and f'"{key}"' in line:
            try:
                return json.loads(line)
            except ValueError:
                continue
    return None


def _stop(proc, timeout: float):
    """Ask a child to finish; return (exit status, its last JSON, stderr tail)."""
    try:
        proc.stdin.write('stop\n')
        proc.stdin.flush()
    except (BrokenPipeError, OSError, ValueError):
        pass
    try:
        out, err = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, err = proc.communicate()
    return proc.returncode, _last_json(out or ''), (err or '')[-1500:]


def orchestrate(a) -> int:
    """Start the processes, wait for them, print the report; 0 if all went well."""
    py = [sys.executable, '-m', 'sm_ros.soak']
    env = _env(a.domain_id, _default_profile(a.dds_profile))
    pipes = {'env': env, 'stdin': subprocess.PIPE, 'stdout': subprocess.PIPE,
             'stderr': subprocess.PIPE, 'text': True}
    limit = 3.0 * a.seconds + a.start_timeout + 120.0
    with tempfile.TemporaryDirectory(prefix='sm_ros_soak_') as tmp:
        scene = Path(tmp) / 'soak.yaml'
        expect = scene_yaml(a.points, scene, a.damping)
        node_p = subprocess.Popen(
            py + ['_node', '--scene', str(scene), '--rate', str(a.rate), '--seconds',
                  str(a.seconds), '--lead', str(a.lead), '--subscribers', str(a.subscribers),
                  '--tail-timeout', str(limit)], **pipes)
        if _read_json_line(node_p, 'ready', a.start_timeout) is None:
            rc, _, err = _stop(node_p, 10.0)
            print(f'soak: sim_node did not start (exit {rc})\n{err}', file=sys.stderr)
            return 1
        driver_p = subprocess.Popen(
            py + ['_driver', '--seconds', str(limit), '--points', str(a.points),
                  '--forces', str(a.forces), '--param-rate', str(a.param_rate)], **pipes)
        sub_ps = [subprocess.Popen(
            py + ['_sub', '--seconds', str(limit), '--index', str(i), '--expect',
                  str(expect)], **pipes) for i in range(a.subscribers)]
        window = _read_json_line(node_p, 'window', limit)
        outs = {'driver': _stop(driver_p, 60.0)}
        for i, p in enumerate(sub_ps):
            outs[f'sub{i}'] = _stop(p, 30.0)
        outs['node'] = _stop(node_p, 60.0)
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
    good = not crashed and fig['every_accepted_parameter_applied'] and fig['state_finite']
    return 0 if good else 1


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog='python -m sm_ros.soak',
                                description=__doc__.split('\n\n')[0].strip())
    p.add_argument('--seconds', type=float, default=60.0, help='measured time (s)')
    p.add_argument('--points', type=int, default=100_000, help='particles of the box')
    p.add_argument('--rate', type=float, default=60.0, help='node tick rate (Hz)')
    p.add_argument('--forces', type=float, default=1000.0, help='force messages per second')
    p.add_argument('--param-rate', type=float, default=50.0,
                   help='parameter changes per second')
    p.add_argument('--subscribers', type=int, default=2, help='cloud subscriber processes')
    p.add_argument('--damping', type=float, default=0.05,
                   help='damping of the box, as in the bundled scenes (0: alpha changed at '
                        '50 Hz pumps energy into the undamped box until it flies off)')
    p.add_argument('--lead', type=float, default=3.0,
                   help='seconds the node runs before measuring (the others connect)')
    p.add_argument('--start-timeout', type=float, default=180.0,
                   help='seconds allowed for the node to start (cold Numba cache)')
    p.add_argument('--domain-id', type=int, default=None, help='ROS_DOMAIN_ID (random)')
    p.add_argument('--dds-profile', default=None,
                   help="Fast DDS profile (default config/fastdds_shm.xml; '' for none)")
    p.add_argument('--json', default=None, help='write the figures to this file')
    return p


def main(argv: Optional[List[str]] = None) -> int:
    """Entry point (also ``python -m sm_ros.bench soak``); returns the exit status."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] in (['_node'], ['_driver'], ['_sub']):
        role, rest = argv[0], argv[1:]
        p = argparse.ArgumentParser(prog=f'python -m sm_ros.soak {role}')
        p.add_argument('--seconds', type=float, required=True)
        p.add_argument('--scene', default='')
        p.add_argument('--rate', type=float, default=60.0)
        p.add_argument('--lead', type=float, default=3.0)
        p.add_argument('--points', type=int, default=100_000)
        p.add_argument('--forces', type=float, default=1000.0)
        p.add_argument('--param-rate', type=float, default=50.0)
        p.add_argument('--index', type=int, default=0)
        p.add_argument('--expect', type=int, default=0)
        p.add_argument('--node-name', default='sim_node')
        p.add_argument('--connect-timeout', type=float, default=60.0)
        p.add_argument('--subscribers', type=int, default=0)
        p.add_argument('--tail-timeout', type=float, default=600.0)
        a = p.parse_args(rest)
        fn = {'_node': run_node, '_driver': run_driver, '_sub': run_sub}[role]
        print(json.dumps(fn(a), default=str), flush=True)
        return 0
    a = _parser().parse_args(argv)
    a.argv = argv
    return orchestrate(a)


if __name__ == '__main__':
    sys.exit(main())
