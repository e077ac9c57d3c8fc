r"""
Measure how PointCloud2 messages of sm_ros's layout cross a process boundary.

A publisher (this process) sends clouds of ``--points`` points at ``--rate`` for
``--seconds``; a subscriber in a second process (reliable, then best effort) counts them
and measures the latency from the header stamp to its callback. Run it with and without the
Fast DDS profile to see what the profile changes::

    .venv/bin/python tools/cloud_transport.py --points 100000 --rate 60
    .venv/bin/python tools/cloud_transport.py --points 100000 --rate 60 \\
        --profile config/fastdds_shm.xml
"""

import argparse
import json
import os
import random
import subprocess
import sys
import time

import numpy as np


def _init(name):
    import rclpy
    from rclpy.node import Node
    rclpy.init()
    return rclpy, Node(name)


def subscriber(seconds: float, reliability: str) -> None:
    """Count clouds and latencies for ``seconds``; print one JSON line."""
    rclpy, node = _init('transport_sub')
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import PointCloud2
    lat = []
    policy = (ReliabilityPolicy.RELIABLE if reliability == 'reliable'
              else ReliabilityPolicy.BEST_EFFORT)

    def callback(msg):
        lat.append(time.time() - (msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec))
    node.create_subscription(PointCloud2, 'points', callback,
                             QoSProfile(depth=5, reliability=policy))
    print('ready', flush=True)
    end = time.time() + seconds
    while time.time() < end:
        rclpy.spin_once(node, timeout_sec=0.05)
    ms = 1e3 * np.array(lat) if lat else np.zeros(1)
    print(json.dumps({'received': len(lat), 'median_ms': float(np.median(ms)),
                      'p95_ms': float(np.percentile(ms, 95))}), flush=True)
    node.destroy_node()
    rclpy.shutdown()


def publisher(points: int, rate: float, seconds: float) -> dict:
    """Publish clouds at ``rate`` for ``seconds``; return the count and publish times."""
    rclpy, node = _init('transport_pub')
    from builtin_interfaces.msg import Time
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import PointCloud2
    from sm_ros.cloud import CloudBuffer
    pub = node.create_publisher(PointCloud2, 'points',
                                QoSProfile(depth=5, reliability=ReliabilityPolicy.RELIABLE))
    buf = CloudBuffer()
    x = np.random.default_rng(0).random((points, 3))
    deadline = time.time() + 30
    while pub.get_subscription_count() < 1 and time.time() < deadline:
        rclpy.spin_once(node, timeout_sec=0.05)
    time.sleep(0.5)                 # let the readers' matching settle on both sides
    sent, pub_s = 0, []
    end = time.time() + seconds
    while time.time() < end:
        t = time.time()
        msg = buf.fill([x], Time(sec=int(t), nanosec=int((t % 1.0) * 1e9)))
        s = time.perf_counter()
        pub.publish(msg)
        pub_s.append(time.perf_counter() - s)
        sent += 1
        wait = 1.0 / rate - (time.time() - t)
        if wait > 0:
            time.sleep(wait)
    node.destroy_node()
    rclpy.shutdown()
    return {'sent': sent, 'publish_ms_mean': 1e3 * float(np.mean(pub_s))}


def main(argv=None) -> int:
    """Run one measurement and print a Markdown table row per subscriber."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument('--points', type=int, default=100_000)
    parser.add_argument('--rate', type=float, default=60.0)
    parser.add_argument('--seconds', type=float, default=5.0)
    parser.add_argument('--profile', default=None, help='FASTRTPS_DEFAULT_PROFILES_FILE')
    parser.add_argument('--reliability', choices=('reliable', 'best_effort', 'both'),
                        default='both', help='subscriber QoS (both: one after the other)')
    parser.add_argument('--role', choices=('sub',), help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.role == 'sub':
        subscriber(args.seconds, args.reliability)
        return 0
    env = dict(os.environ, ROS_DOMAIN_ID=str(random.randint(100, 200)),
               ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST', RMW_IMPLEMENTATION='rmw_fastrtps_cpp')
    env.pop('FASTRTPS_DEFAULT_PROFILES_FILE', None)
    if args.profile:
        env['FASTRTPS_DEFAULT_PROFILES_FILE'] = os.path.abspath(args.profile)
    os.environ.clear()
    os.environ.update(env)
    profile = os.path.basename(args.profile) if args.profile else 'defaults'
    kinds = ('reliable', 'best_effort') if args.reliability == 'both' else (args.reliability,)
    for rel in kinds:
        proc = subprocess.Popen(
            [sys.executable, __file__, '--role', 'sub', '--reliability', rel,
             '--seconds', str(args.seconds + 6.0)],
            env=env, stdout=subprocess.PIPE, text=True)
        proc.stdout.readline()
        result = publisher(args.points, args.rate, args.seconds)
        out = json.loads(proc.communicate(timeout=60)[0].strip().splitlines()[-1])
        print(f'| {args.points:,} | {args.rate:g} | {profile} | {rel} | '
              f"{out['received']}/{result['sent']} | {out['median_ms']:.1f} | "
              f"{out['p95_ms']:.1f} | {result['publish_ms_mean']:.1f} |", flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
