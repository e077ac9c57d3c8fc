"""
The processes of the soak test (``sm_ros.bench.soak`` starts them; one JSON line each).

``python -m sm_ros.bench.soak_procs node|driver|sub ...``: sim_node with its measurements,
the driver (forces, parameter changes, grab and release), or one cloud subscriber. Each
runs until the parent writes 'stop' to its stdin (or a safety time limit passes) and then
prints its record.
"""

import argparse
import json
import math
import random
import sys
import time
from typing import Any, Dict, List, Optional

from . import harness

BODY = 'box'
GRIPPER = 'soak_hand'


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

    node, ex = harness.start_sim_node({'scene': a.scene, 'rate': float(a.rate),
                                       'diagnostics_rate': 1.0})
    rec = {'tick': [], 'start': [], 'accepted': 0, 'applied': 0, 'superseded': 0,
           'mismatch': []}
    measuring = [False]
    latest: Dict[str, Any] = {}

    trace = []

    def record(start, seconds):
        if measuring[0]:
            rec['tick'].append(seconds)
            rec['start'].append(start)
        if len(rec['tick']) % 60 == 1 and node.world.bodies:     # where the box is, ~1 Hz
            b = node.world.bodies[0]
            trace.append([round(time.monotonic(), 3)] + [round(float(c), 4) for c in b.com()]
                         + [round(float(np.abs(b.v).max()), 4)])
    harness.time_ticks(node, record)

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

    print(json.dumps({'ready': True, 'points': node.num_points}), flush=True)
    deadline = time.monotonic() + a.connect_timeout
    while time.monotonic() < deadline and not (
            node.count_publishers('force') > 0
            and node.pub_points.get_subscription_count() >= a.subscribers):
        ex.spin_once(timeout_sec=0.01)
    lead_end = time.monotonic() + a.lead
    while time.monotonic() < lead_end:
        ex.spin_once(timeout_sec=0.01)
    rss_start = harness.rss_bytes()
    received_start = dict(received)
    refused_start = dict(node.refused)
    measuring[0] = True
    t0 = time.monotonic()
    t_end = t0 + a.seconds
    while time.monotonic() < t_end:
        ex.spin_once(timeout_sec=0.01)
    elapsed = time.monotonic() - t0
    measuring[0] = False
    rss_end = harness.rss_bytes()
    refused = {k: v - refused_start.get(k, 0) for k, v in node.refused.items()
               if v - refused_start.get(k, 0)}
    window = {'points': node.num_points, 'rate_hz_target': a.rate, 'elapsed_s': elapsed,
              'ticks': len(rec['tick']), 'tick_s': rec['tick'], 'tick_start_s': rec['start'],
              'rss_start_bytes': rss_start, 'rss_end_bytes': rss_end, 'refused': refused,
              'received': {k: v - received_start.get(k, 0) for k, v in received.items()}}
    print(json.dumps({'window': window}), flush=True)
    # the others finish against a live node (answers to the last parameter requests)
    deadline = time.monotonic() + a.tail_timeout
    while time.monotonic() < deadline and not harness.stop_requested():
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
    while time.monotonic() < t_end and not harness.stop_requested():
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
    from sm_ros.cloud import read_xyz

    stats = {'received': 0, 'bad_size': 0, 'non_finite': 0, 'checked': 0,
             'reliability': 'best_effort' if a.index % 2 else 'reliable', 'first_s': None,
             'last_s': None}

    def on_cloud(msg, _wall):
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
    # a safety limit of a.seconds: 'stop' on stdin ends it
    harness.spin_points(on_cloud, a.seconds, reliable=not a.index % 2,
                        name=f'soak_sub_{a.index}', until=harness.stop_requested)
    span = (stats['last_s'] - stats['first_s']) if stats['received'] > 1 else 0.0
    stats['rate_hz'] = (stats['received'] - 1) / span if span > 0 else 0.0
    del stats['first_s'], stats['last_s']
    return stats


def main(argv: Optional[List[str]] = None) -> int:
    """Run one role and print its record as one JSON line."""
    p = argparse.ArgumentParser(prog='python -m sm_ros.bench.soak_procs')
    p.add_argument('role', choices=('node', 'driver', 'sub'))
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
    a = p.parse_args(argv)
    fn = {'node': run_node, 'driver': run_driver, 'sub': run_sub}[a.role]
    print(json.dumps(fn(a), default=str), flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
