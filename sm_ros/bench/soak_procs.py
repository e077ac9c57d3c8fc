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
    trace = []

    def record(start, seconds):
        if measuring[0]:
            rec['tick'].append(seconds)
            rec['start'].append(start)
        if len(rec['tick']) % 60 == 1 and node.world.bodies:     # where the box is, ~1 Hz
            body = node.world.bodies[0]
            trace.append([round(time.monotonic(), 3)] + [round(float(c), 4) for c in body.com()]
                         + [round(float(np.abs(body.v).max()), 4)])
    harness.time_ticks(node, record)
    apply_pending = _watch_parameters(node, rec)
    received = _count_received(node)
    print(json.dumps({'ready': True, 'points': node.num_points}), flush=True)
    deadline = time.monotonic() + a.connect_timeout
    while time.monotonic() < deadline and not (
            node.count_publishers('force') > 0
            and node.pub_points.get_subscription_count() >= a.subscribers):
        ex.spin_once(timeout_sec=0.01)
    harness.spin_for(ex, a.lead)
    print(json.dumps({'window': _measure_window(node, ex, a, rec, measuring, received)}),
          flush=True)
    # the others finish against a live node (answers to the last parameter requests)
    deadline = time.monotonic() + a.tail_timeout
    while time.monotonic() < deadline and not harness.stop_requested():
        ex.spin_once(timeout_sec=0.01)
    apply_pending()        # anything accepted in the last moments, then every change checked
    out = {'params_accepted': rec['accepted'], 'params_applied': rec['applied'],
           'params_superseded': rec['superseded'], 'params_mismatch': rec['mismatch'],
           'refused_all_run': dict(node.refused), 'received_all_run': received,
           'last_refusal': dict(node.last_refusal),
           'com_end': [[body.name] + [round(float(c), 4) for c in body.com()]
                       for body in node.world.bodies], 'com_trace': trace,
           'finite': all(body.is_finite() for body in node.world.bodies)}
    node.destroy_node()
    rclpy.try_shutdown()
    return out


def _watch_parameters(node, rec: Dict[str, Any]):
    """Count the parameter changes the node accepts, and after each ``apply_pending``
    whether they show in the node and the world; returns the wrapped ``apply_pending``."""
    latest: Dict[str, Any] = {}
    set0 = node.parameters_set_callback

    def parameters_set(params):
        set0(params)
        for param in params:
            if param.name in node._p:
                if param.name in latest:
                    rec['superseded'] += 1          # replaced before a tick applied it
                latest[param.name] = node._pending.get(param.name, param.value)
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
            if node._p.get(name) == value and _body_field_ok(node, name, value):
                rec['applied'] += 1
            else:
                rec['mismatch'].append([name, repr(value), repr(node._p.get(name))])
    node.sim.apply_pending = apply_pending
    return apply_pending


def _count_received(node) -> Dict[str, int]:
    """{topic: messages received}, counted by wrapping every subscription's callback."""
    received: Dict[str, int] = {}
    for sub in node.subscriptions:
        topic = sub.topic_name.rsplit('/', 1)[-1]

        def counted(msg, callback=sub.callback, topic=topic):
            received[topic] = received.get(topic, 0) + 1
            callback(msg)
        sub.callback = counted
    return received


def _measure_window(node, ex, a, rec, measuring, received) -> Dict[str, Any]:
    """Spin ``a.seconds`` with the ticks recorded; the window's figures."""
    rss_start = harness.rss_bytes()
    received_start = dict(received)
    refused_start = dict(node.refused)
    measuring[0] = True
    elapsed = harness.spin_for(ex, a.seconds)
    measuring[0] = False
    rss_end = harness.rss_bytes()
    refused = {k: v - refused_start.get(k, 0) for k, v in node.refused.items()
               if v - refused_start.get(k, 0)}
    return {'points': node.num_points, 'rate_hz_target': a.rate, 'elapsed_s': elapsed,
            'ticks': len(rec['tick']), 'tick_s': rec['tick'], 'tick_start_s': rec['start'],
            'rss_start_bytes': rss_start, 'rss_end_bytes': rss_end, 'refused': refused,
            'received': {k: v - received_start.get(k, 0) for k, v in received.items()}}


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
    rclpy.init()
    driver = _Driver(a)
    driver.connect()
    t0 = time.monotonic()
    t_end = t0 + a.seconds                             # a safety limit: 'stop' ends it
    while time.monotonic() < t_end and not harness.stop_requested():
        now = time.monotonic()
        driver.send_forces(now)
        driver.change_parameter(now)
        driver.move_gripper(now, t0)
        driver.collect_answers(check_expected=True)
        driver.spin(max(0.0, min(driver.next_force, driver.next_param, driver.next_grab)
                        - time.monotonic()))
    stats = driver.finish()
    stats['elapsed_s'] = time.monotonic() - t0
    driver.node.destroy_node()
    rclpy.try_shutdown()
    return stats


class _Driver:
    """The driver's node, publishers, clients and counts (``run_driver``)."""

    def __init__(self, a):
        from geometry_msgs.msg import PoseArray, PoseStamped, WrenchStamped
        from rcl_interfaces.srv import GetParameters, SetParameters
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.node import Node
        from std_msgs.msg import String
        self.args = a
        self.node = Node('soak_driver')
        self.pub_force = self.node.create_publisher(WrenchStamped, 'force', 100)
        self.pub_grab = self.node.create_publisher(PoseStamped, 'grab', 10)
        self.pub_release = self.node.create_publisher(String, 'release', 10)
        self.set_client = self.node.create_client(SetParameters,
                                                  f'/{a.node_name}/set_parameters')
        self.get_client = self.node.create_client(GetParameters,
                                                  f'/{a.node_name}/get_parameters')
        self.com = None                                 # the box's centre, from 'poses'
        self.node.create_subscription(PoseArray, 'poses', self._on_poses, 10)
        self.executor = SingleThreadedExecutor()
        self.executor.add_node(self.node)
        self.stats = {'forces_sent': 0, 'forces_bad_sent': 0, 'params_sent': 0,
                      'params_accepted': 0, 'params_refused': 0, 'params_unexpected': [],
                      'params_unanswered': 0, 'grabs_sent': 0, 'releases_sent': 0}
        self.last_accepted: Dict[str, Any] = {}
        self.pending = []
        self.rng = random.Random(7)
        self.next_force = self.next_param = self.next_grab = 0.0
        self.force_count = self.param_count = 0
        self.holding = False
        self.grab_at = (0.0, 0.0, 0.0)
        self.last_release = 0.0

    def _on_poses(self, msg):
        if msg.poses:
            position = msg.poses[0].position
            self.com = (position.x, position.y, position.z)

    def spin(self, timeout: float):
        """Wait for the next event, then take what else is ready (responses, poses)."""
        self.executor.spin_once(timeout_sec=timeout)
        for _ in range(4):
            self.executor.spin_once(timeout_sec=0.0)

    def connect(self):
        """Wait for sim_node's parameter service and force subscription."""
        deadline = time.monotonic() + self.args.connect_timeout
        while not (self.set_client.service_is_ready()
                   and self.pub_force.get_subscription_count() > 0):
            if time.monotonic() > deadline:
                raise RuntimeError('sim_node did not show up')
            self.executor.spin_once(timeout_sec=0.05)
        now = time.monotonic()
        self.next_force = self.next_param = self.next_grab = self.last_release = now

    def send_forces(self, now: float):
        """The forces due by ``now``, in bursts of 1 ms slots (every 50th bad)."""
        from geometry_msgs.msg import WrenchStamped
        while self.next_force <= now:
            msg = WrenchStamped()
            self.force_count += 1
            count, rng = self.force_count, self.rng
            if count % 100 == 0:
                msg.header.frame_id = BODY
                msg.wrench.force.x = float('nan')
                self.stats['forces_bad_sent'] += 1
            elif count % 100 == 50:
                msg.header.frame_id = 'no_such_body'
                msg.wrench.force.z = 1.0
                self.stats['forces_bad_sent'] += 1
            else:
                msg.header.frame_id = BODY if count % 2 else ''
                msg.wrench.force.x = rng.uniform(-2.0, 2.0)
                msg.wrench.force.y = rng.uniform(-2.0, 2.0)
                msg.wrench.force.z = rng.uniform(0.0, 5.0)
                msg.wrench.torque.z = rng.uniform(-0.01, 0.01)
            self.pub_force.publish(msg)
            self.stats['forces_sent'] += 1
            self.next_force += 1.0 / self.args.forces

    def change_parameter(self, now: float):
        """One parameter change when one is due."""
        from rcl_interfaces.srv import SetParameters
        from rclpy.parameter import Parameter
        if self.next_param > now:
            return
        name, value, good = _param_change(self.param_count, self.rng)
        self.param_count += 1
        req = SetParameters.Request()
        req.parameters = [Parameter(name, value=value).to_parameter_msg()]
        self.pending.append((self.set_client.call_async(req), name, value, good))
        self.stats['params_sent'] += 1
        self.next_param += 1.0 / self.args.param_rate

    def move_gripper(self, now: float, t0: float):
        """The gripper at 20 Hz: grab where the box is, circle, release after 1 s."""
        from geometry_msgs.msg import PoseStamped
        from std_msgs.msg import String
        if self.next_grab > now:
            return
        if self.holding and now - self.last_release >= 1.0:
            self.pub_release.publish(String(data=GRIPPER))
            self.stats['releases_sent'] += 1
            self.holding = False
            self.last_release = now
        elif self.com is not None:
            if not self.holding:                          # grab where the box is now
                self.grab_at = self.com
            phase = 2.0 * math.pi * (now - t0)
            at, holding = self.grab_at, self.holding
            pose = PoseStamped()
            pose.header.frame_id = GRIPPER
            pose.pose.position.x = at[0] + (0.01 * math.cos(phase) if holding else 0)
            pose.pose.position.y = at[1] + (0.01 * math.sin(phase) if holding else 0)
            pose.pose.position.z = at[2] + (0.02 if holding else 0.0)
            pose.pose.orientation.w = 1.0
            self.pub_grab.publish(pose)
            self.stats['grabs_sent'] += 1
            if not holding:
                self.holding = True
                self.last_release = now
        self.next_grab += 0.05

    def collect_answers(self, check_expected: bool):
        """Count the answered parameter changes; remember the accepted values."""
        for item in [p for p in self.pending if p[0].done()]:
            self.pending.remove(item)
            future, name, value, good = item
            accepted = bool(future.result().results[0].successful)
            self.stats['params_accepted' if accepted else 'params_refused'] += 1
            if accepted:
                self.last_accepted[name] = value
            if check_expected and accepted != good:
                self.stats['params_unexpected'].append([name, repr(value), accepted])

    def finish(self) -> Dict[str, Any]:
        """Wait for the last answers; compare the node's parameters with the last
        accepted value of each; return the counts."""
        from rcl_interfaces.srv import GetParameters
        from rclpy.parameter import parameter_value_to_python
        wait_end = time.monotonic() + 15.0
        while self.pending and time.monotonic() < wait_end:
            self.executor.spin_once(timeout_sec=0.05)
            self.collect_answers(check_expected=False)
        self.stats['params_unanswered'] = len(self.pending)
        req = GetParameters.Request()
        req.names = sorted(self.last_accepted)
        future = self.get_client.call_async(req)
        self.executor.spin_until_future_complete(future, timeout_sec=5.0)
        final_ok = []
        if future.done():
            for name, value in zip(req.names, future.result().values):
                got = parameter_value_to_python(value)
                got = [float(c) for c in got] \
                    if not isinstance(got, (str, bool, int, float)) else got
                final_ok.append([name, got == self.last_accepted[name]])
        self.stats['final_values_match'] = final_ok
        return self.stats


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
