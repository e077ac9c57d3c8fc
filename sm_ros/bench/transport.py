r"""
``python -m sm_ros.bench transport``: how clouds of sm_ros's layout cross a process boundary.

This process publishes PointCloud2 messages of ``--points`` points (built by
``sm_ros.cloud.CloudBuffer``, as the node builds them) at ``--rate`` for ``--seconds``; a
subscriber in a second process (reliable, then best effort) counts them and measures the
latency from the header stamp to its callback. Both processes run in a ROS domain of their
own with discovery on this host. Run it with and without the Fast DDS profile to see what
the profile changes::

    python -m sm_ros.bench transport --points 100000 --rate 60 --profile ''
    python -m sm_ros.bench transport --points 100000 --rate 60 --profile config/fastdds_shm.xml

Prints one markdown row per subscriber: points, rate, profile, reliability, clouds received
of those sent, latency median and 95th percentile (ms), mean publish call (ms).
"""

import argparse
import json
import sys
import time
from typing import Any, Dict, List, Optional

import numpy as np

from . import harness

HEADER = ('| points | rate (Hz) | profile | subscriber | received/sent | latency median (ms) '
          '| p95 (ms) | publish (ms) |\n| --- | --- | --- | --- | --- | --- | --- | --- |')


def add_arguments(parser: argparse.ArgumentParser):
    """Add the flags of the ``transport`` subcommand."""
    parser.add_argument('--points', type=int, default=100_000)
    parser.add_argument('--rate', type=float, default=60.0)
    parser.add_argument('--seconds', type=float, default=5.0)
    parser.add_argument('--profile', default='',
                        help="Fast DDS profile file ('': the DDS defaults, as in the examples)")
    parser.add_argument('--reliability', choices=('reliable', 'best_effort', 'both'),
                        default='both', help='subscriber QoS (both: one after the other)')
    parser.add_argument('--role', choices=('sub',), help=argparse.SUPPRESS)


def _init(name: str):
    import rclpy
    from rclpy.node import Node
    rclpy.init()
    return rclpy, Node(name)


def subscriber(seconds: float, reliability: str) -> Dict[str, Any]:
    """Count clouds and their latencies for ``seconds``; return the figures."""
    rclpy, node = _init('transport_sub')
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import PointCloud2
    lat: List[float] = []
    policy = (ReliabilityPolicy.RELIABLE if reliability == 'reliable'
              else ReliabilityPolicy.BEST_EFFORT)

    def cloud_callback(msg):
        lat.append(time.time() - (msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec))
    node.create_subscription(PointCloud2, 'points', cloud_callback,
                             QoSProfile(depth=5, reliability=policy))
    print(json.dumps({'ready': True}), flush=True)
    end = time.time() + seconds
    while time.time() < end and not harness.stop_requested():
        rclpy.spin_once(node, timeout_sec=0.05)
    end = time.time() + 0.5                     # the clouds still on their way
    while time.time() < end:
        rclpy.spin_once(node, timeout_sec=0.05)
    node.destroy_node()
    rclpy.try_shutdown()
    lat_ms = 1e3 * np.array(lat) if lat else np.full(1, np.nan)
    return {'received': len(lat), 'median_ms': float(np.median(lat_ms)),
            'p95_ms': float(np.percentile(lat_ms, 95))}


def publisher(points: int, rate: float, seconds: float) -> Dict[str, Any]:
    """Publish clouds at ``rate`` for ``seconds``; return the count and publish time."""
    rclpy, node = _init('transport_pub')
    from builtin_interfaces.msg import Time
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import PointCloud2
    from sm_ros.cloud import CloudBuffer
    pub = node.create_publisher(PointCloud2, 'points',
                                QoSProfile(depth=5, reliability=ReliabilityPolicy.RELIABLE))
    buf = CloudBuffer()
    xyz = np.random.default_rng(0).random((points, 3))
    deadline = time.time() + 30
    while pub.get_subscription_count() < 1 and time.time() < deadline:
        rclpy.spin_once(node, timeout_sec=0.05)
    time.sleep(0.5)                 # let the readers' matching settle on both sides
    sent, pub_s = 0, []
    end = time.time() + seconds
    while time.time() < end:
        now = time.time()
        msg = buf.fill([xyz], Time(sec=int(now), nanosec=int((now % 1.0) * 1e9)))
        start = time.perf_counter()
        pub.publish(msg)
        pub_s.append(time.perf_counter() - start)
        sent += 1
        wait = 1.0 / rate - (time.time() - now)
        if wait > 0:
            time.sleep(wait)
    node.destroy_node()
    rclpy.try_shutdown()
    return {'sent': sent, 'publish_ms_mean': 1e3 * float(np.mean(pub_s)) if pub_s else 0.0}


def measure(points: int, rate: float, seconds: float, profile: str,
            reliability: str) -> Dict[str, Any]:
    """One subscriber process of QoS ``reliability`` against this process's publisher."""
    import os
    env = harness.ros_env(profile=os.path.abspath(profile) if profile else None)
    env['RMW_IMPLEMENTATION'] = 'rmw_fastrtps_cpp'
    os.environ.clear()
    os.environ.update(env)                      # this process publishes in the same domain
    proc = harness.spawn('sm_ros.bench.transport',
                         ['--role', 'sub', '--reliability', reliability,
                          '--seconds', str(seconds + 60.0)], env, stdin=True)
    if harness.read_json_line(proc, 'ready', 60.0) is None:
        harness.stop(proc, 5.0)
        raise RuntimeError('the subscriber process did not start')
    sent = publisher(points, rate, seconds)
    _, got, err = harness.stop(proc, 60.0)
    if got is None:
        raise RuntimeError(f'the subscriber process reported nothing: {err[-300:]}')
    return {'points': points, 'rate': rate, 'profile': os.path.basename(profile) or 'defaults',
            'reliability': reliability, **got, **sent}


def row(res: Dict[str, Any]) -> str:
    """One markdown row of :data:`HEADER`."""
    return (f"| {res['points']:,} | {res['rate']:g} | {res['profile']} | {res['reliability']} "
            f"| {res['received']}/{res['sent']} | {res['median_ms']:.1f} | "
            f"{res['p95_ms']:.1f} | {res['publish_ms_mean']:.1f} |")


def main(argv: Optional[List[str]] = None) -> int:
    """Entry point of ``python -m sm_ros.bench transport``."""
    parser = argparse.ArgumentParser(prog='python -m sm_ros.bench transport', description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    add_arguments(parser)
    args = parser.parse_args(argv)
    if args.role == 'sub':
        print(json.dumps(subscriber(args.seconds, args.reliability)), flush=True)
        return 0
    kinds = ('reliable', 'best_effort') if args.reliability == 'both' else (args.reliability,)
    print(HEADER, flush=True)
    for reliability in kinds:
        print(row(measure(args.points, args.rate, args.seconds, args.profile, reliability)),
              flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
