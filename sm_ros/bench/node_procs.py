"""
The two processes of the node benchmark (run by ``node_bench``; one JSON line each).

``python -m sm_ros.bench.node_procs node --scene S --rate R --seconds T``
    runs sim_node in this process and records, per tick, the time of the step(s), of the
    cloud build (``CloudBuffer.fill``), of the publish call, and the wall time at which
    each cloud was handed to rclpy (keyed by its stamp).
``python -m sm_ros.bench.node_procs sub --seconds T``
    subscribes to ``points`` and records each message's stamp and wall receive time.
"""

import argparse
import json
import sys
import time


def _node(a) -> dict:
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter import Parameter
    from sm_ros.node import SimNode

    rclpy.init()
    overrides = [Parameter('scene', value=a.scene), Parameter('rate', value=float(a.rate)),
                 Parameter('dt', value=1.0 / (a.rate * a.substeps)),
                 Parameter('substeps', value=int(a.substeps)),
                 Parameter('mode', value=a.mode), Parameter('clusters', value=int(a.clusters))]
    node = SimNode(parameter_overrides=overrides, namespace=a.namespace or None)
    rec = {'step': [], 'fill': [], 'publish': [], 'tick': [], 'sent': {}}
    measuring = [False]

    tick0 = node.tick

    def tick():
        t = time.perf_counter()
        tick0()
        if measuring[0]:
            rec['tick'].append(time.perf_counter() - t)
    node.tick = tick

    def wrap_world():
        step0 = node.world.step

        def step(dt):
            t = time.perf_counter()
            step0(dt)
            if measuring[0]:
                rec['step'].append(time.perf_counter() - t)
        node.world.step = step
    wrap_world()

    fill0 = node.cloud.fill

    def fill(blocks, stamp):
        t = time.perf_counter()
        msg = fill0(blocks, stamp)
        if measuring[0]:
            rec['fill'].append(time.perf_counter() - t)
        return msg
    node.cloud.fill = fill

    pub0 = node.pub_points.publish

    def publish(msg):
        t = time.perf_counter()
        key = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        rec['sent'][key] = time.time()
        pub0(msg)
        if measuring[0]:
            rec['publish'].append(time.perf_counter() - t)
    node.pub_points.publish = publish

    ex = SingleThreadedExecutor()
    ex.add_node(node)
    t_end_warm = time.monotonic() + a.warmup
    while time.monotonic() < t_end_warm:
        ex.spin_once(timeout_sec=0.05)
    measuring[0] = True
    t0 = time.monotonic()
    t_end = t0 + a.seconds
    while time.monotonic() < t_end:
        ex.spin_once(timeout_sec=0.05)
    elapsed = time.monotonic() - t0
    ticks = len(rec['tick'])
    out = {'points': node.num_points, 'rate_target': a.rate, 'substeps': a.substeps,
           'elapsed_s': elapsed, 'ticks': ticks,
           'step_s': rec['step'], 'fill_s': rec['fill'], 'publish_s': rec['publish'],
           'tick_s': rec['tick'], 'sent': {str(k): v for k, v in rec['sent'].items()}}
    node.destroy_node()
    rclpy.try_shutdown()
    return out


def _sub(a) -> dict:
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import PointCloud2

    rclpy.init()
    node = Node('bench_points_sub', namespace=a.namespace or None)
    got = []

    def cb(msg):
        got.append((msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec,
                    time.time(), msg.width * msg.height))
    node.create_subscription(PointCloud2, 'points', cb,
                             QoSProfile(depth=5, reliability=ReliabilityPolicy.RELIABLE))
    ex = SingleThreadedExecutor()
    ex.add_node(node)
    t_end = time.monotonic() + a.seconds
    while time.monotonic() < t_end:
        ex.spin_once(timeout_sec=0.05)
    node.destroy_node()
    rclpy.try_shutdown()
    return {'received': [[str(s), t, n] for s, t, n in got]}


def main(argv=None) -> int:
    """Run one of the two processes; print its JSON on one line."""
    p = argparse.ArgumentParser(prog='python -m sm_ros.bench.node_procs')
    p.add_argument('role', choices=('node', 'sub'))
    p.add_argument('--scene', default='')
    p.add_argument('--rate', type=float, default=60.0)
    p.add_argument('--substeps', type=int, default=1)
    p.add_argument('--mode', default='linear')
    p.add_argument('--clusters', type=int, default=1)
    p.add_argument('--seconds', type=float, default=3.0)
    p.add_argument('--warmup', type=float, default=1.0)
    p.add_argument('--namespace', default='', help='namespace of the node / subscriber')
    a = p.parse_args(argv)
    res = _node(a) if a.role == 'node' else _sub(a)
    sys.stdout.write(json.dumps(res) + '\n')
    return 0


if __name__ == '__main__':
    sys.exit(main())
