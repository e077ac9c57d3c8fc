"""
What the node pays per tick beside the steps, side by side in one process (issue 11, item 3).

Builds a SimNode on one box of ``--points`` particles (linear, ``--clusters`` cubes per
axis, damping 0.05) and times, round-robin over ``--rounds`` rounds (medians):

- ``tick minus its steps``: a whole ``SimNode.tick`` (2 steps of the world, the live
  error estimate off) less its steps as ``Simulation.stats`` times them, nobody subscribed:
  the node's own overhead;
- the non-finite check body by body (``Body.is_finite``, before) against one compiled
  call over every body (``sm_ros.nonfinite``, now), and one ``get_subscription_count``;

- ``publish, nobody subscribed``: the tick's publishing when no ROS subscriber, Foxglove
  client or recorder takes anything (what every tick costs a node nobody watches);
- ``publish, points + poses subscribed``: the same with a subscriber on both in this
  process (cloud fill + serialisation + poses);
- ``publish, a Foxglove client on /points``: only the live view takes the cloud (fill +
  one join of header and cloud bytes; the SDK sends it from its own thread);
- ``poses: one pass + extract_rotation`` against ``poses: Body.com() + Body.rotation()``
  (the NumPy einsum the node used before);
- ``momentum: one sum`` (what a tick paid twice before; now once per conservative run and
  once per diagnostics report).

    .venv/bin/python tools/node_overhead.py --points 100000 --clusters 2
"""

import argparse
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path


def main(argv=None) -> int:
    """Run the measurement; print a markdown table."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--points', type=int, default=100_000)
    ap.add_argument('--clusters', type=int, default=2)
    ap.add_argument('--rounds', type=int, default=30)
    args = ap.parse_args(argv)
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
    import rclpy
    from rclpy.parameter import Parameter
    from geometry_msgs.msg import PoseArray
    from sensor_msgs.msg import PointCloud2
    from sm_ros.bench import common as bc, harness
    from sm_ros.node import SimNode
    from sm_ros.nonfinite import NonFiniteCheck
    from sm_ros.stats import MomentumDrift

    rclpy.init()
    with tempfile.TemporaryDirectory() as d:
        scene = Path(d) / 'box.yaml'
        n = bc.lattice_side(args.points) ** 3
        harness.box_scene(n, scene, 0.05)
        node = SimNode(paused=True, parameter_overrides=[
            Parameter('scene', value=str(scene)), Parameter('clusters', value=args.clusters),
            Parameter('error_estimate.rate', value=0.0)])
    out = node.outputs
    body = node.world.bodies[0]
    for _ in range(3):
        node.tick()
    probe = rclpy.create_node('overhead_probe')
    subs = []

    def subscribe():
        subs.append(probe.create_subscription(PointCloud2, 'points', lambda m: None, 5))
        subs.append(probe.create_subscription(PoseArray, 'poses', lambda m: None, 5))
        deadline = time.monotonic() + 10
        while (out.pub_points.get_subscription_count() == 0
               or out.pub_poses.get_subscription_count() == 0):
            if time.monotonic() > deadline:
                raise RuntimeError('the subscriptions were not matched')
            rclpy.spin_once(probe, timeout_sec=0.01)

    drift = MomentumDrift()
    sim = node.sim
    bodies = node.world.bodies
    check = NonFiniteCheck()

    def tick_overhead():
        # a whole tick (2 steps, checks, publishing) minus its steps as the stats time them
        steps = sim.stats.step_s_sum
        t = time.perf_counter()
        node.tick()
        return time.perf_counter() - t - (sim.stats.step_s_sum - steps)
    cases = {
        'tick minus its steps, nobody subscribed': tick_overhead,
        'non-finite check: Body.is_finite body by body (before)':
            lambda: [b for b in bodies if not b.is_finite()],
        'non-finite check: one compiled call (sm_ros.nonfinite, now)':
            lambda: check.bad_bodies(bodies),
        'get_subscription_count (one publisher)': out.pub_points.get_subscription_count,
        'publish, nobody subscribed': out.publish,
        'poses: one pass + extract_rotation': out.body_poses,
        'poses: Body.com() + Body.rotation()': lambda: (body.com(), body.rotation()),
        'momentum: one sum': lambda: drift.measure(node.world),
    }
    times = {k: [] for k in cases}
    for _ in range(args.rounds):
        for name, fn in cases.items():
            t = time.perf_counter()
            r = fn()
            times[name].append(r if fn is tick_overhead else time.perf_counter() - t)
    try:
        times.update(_with_foxglove(node, out, args.rounds))
    except ImportError as exc:
        print(f'(no Foxglove row: {exc})', file=sys.stderr)
    subscribe()
    times['publish, points + poses subscribed'] = []
    for _ in range(args.rounds):
        t = time.perf_counter()
        out.publish()
        times['publish, points + poses subscribed'].append(time.perf_counter() - t)
        rclpy.spin_once(probe, timeout_sec=0)
    print(f'{node.num_points} points, {body.num_clusters} clusters; {args.rounds} rounds, '
          f'load average {os.getloadavg()[0]:.1f}\n')
    print('| what | median ms | best ms |\n| --- | --- | --- |')
    for name, ts in times.items():
        print(f'| {name} | {1e3 * statistics.median(ts):.3f} | {1e3 * min(ts):.3f} |')
    node.destroy_node()
    probe.destroy_node()
    rclpy.try_shutdown()
    return 0


def _with_foxglove(node, out, rounds):
    """Time publishing with only a Foxglove client on /points (a WebSocket client here)."""
    import json
    import socket
    from websockets.sync.client import connect
    from sm_ros.live import FoxgloveView
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        port = s.getsockname()[1]
    out.live = FoxgloveView(port=port)
    got = []
    with connect(out.live.url, subprotocols=['foxglove.sdk.v1'], max_size=None) as ws:
        channels = {}
        while '/points' not in channels:
            msg = json.loads(ws.recv(timeout=5))
            if msg['op'] == 'advertise':
                channels.update({c['topic']: c['id'] for c in msg['channels']})
        ws.send(json.dumps({'op': 'subscribe',
                            'subscriptions': [{'id': 1, 'channelId': channels['/points']}]}))
        deadline = time.monotonic() + 5
        while not out.live.wants_cloud() and time.monotonic() < deadline:
            time.sleep(0.01)
        ts = []
        for _ in range(rounds):
            t = time.perf_counter()
            out.publish()
            ts.append(time.perf_counter() - t)
            got.append(len(ws.recv(timeout=5)))
    out.live.close()
    out.live = None
    return {f'publish, a Foxglove client on /points ({len(got)} clouds of '
            f'{max(got) / 2**20:.1f} MiB received)': ts}


if __name__ == '__main__':
    sys.exit(main())
