"""
Measure sim_node's start-up time: from process start to the first cloud on ``points``.

Usage (from the repository root, with the environment of ``make run``)::

    .venv/bin/python tools/startup_time.py --runs 3          # cold once, then warm
    .venv/bin/python tools/startup_time.py --runs 3 -- --ros-args -p scene:=many

The first run uses an empty Numba cache directory (cold: every kernel is compiled); the
next runs reuse it (warm: kernels are loaded from the cache). Each run starts
``sim_node`` as a separate process in a DDS domain of its own and stops it with SIGINT.
"""

import argparse
import os
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import time


def first_cloud_seconds(cmd, env, timeout):
    """Start ``cmd``; return (seconds to the first PointCloud2 on /points, exit code)."""
    import rclpy
    from rclpy.context import Context
    from rclpy.node import Node
    from rclpy.qos import QoSProfile
    from sensor_msgs.msg import PointCloud2
    ctx = Context()
    rclpy.init(context=ctx, domain_id=int(env['ROS_DOMAIN_ID']))
    node = Node('startup_probe', context=ctx)
    got = []
    node.create_subscription(PointCloud2, '/points', lambda m: got.append(time.monotonic()),
                             QoSProfile(depth=1))
    t0 = time.monotonic()
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True)
    try:
        while not got and time.monotonic() - t0 < timeout and proc.poll() is None:
            _spin_once(node, ctx)
        elapsed = got[0] - t0 if got else float('nan')
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
        try:
            _, err = proc.communicate(timeout=20)
        except subprocess.TimeoutExpired:
            proc.kill()
            _, err = proc.communicate()
        node.destroy_node()
        rclpy.try_shutdown(context=ctx)
    if not got:
        sys.stderr.write(err)
    return elapsed, proc.returncode


def _spin_once(node, ctx):
    from rclpy.executors import SingleThreadedExecutor
    ex = getattr(node, '_probe_executor', None)
    if ex is None:
        ex = SingleThreadedExecutor(context=ctx)
        ex.add_node(node)
        node._probe_executor = ex
    ex.spin_once(timeout_sec=0.01)


def main(argv=None):
    """Run the measurement and print one line per run."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument('--runs', type=int, default=3, help='runs (the first one cold)')
    parser.add_argument('--timeout', type=float, default=300.0)
    parser.add_argument('--cache-dir', default=None,
                        help='Numba cache directory to use (default: a new empty one)')
    parser.add_argument('node_args', nargs='*', help='arguments for sim_node (after --)')
    args = parser.parse_args(argv)
    exe = os.path.join(os.path.dirname(sys.executable), 'sim_node')
    cmd = [exe if os.path.exists(exe) else 'sim_node'] + args.node_args
    cache = args.cache_dir or tempfile.mkdtemp(prefix='sm_ros_numba_')
    env = dict(os.environ, NUMBA_CACHE_DIR=cache,
               ROS_DOMAIN_ID=str(random.Random().randint(100, 200)),
               ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    results = []
    try:
        for i in range(args.runs):
            label = 'cold' if i == 0 and not args.cache_dir else 'warm'
            seconds, code = first_cloud_seconds(cmd, env, args.timeout)
            results.append((label, seconds))
            print(f'run {i + 1} ({label} Numba cache): first cloud after {seconds:.2f} s '
                  f'(exit code {code})', flush=True)
    finally:
        if not args.cache_dir:
            shutil.rmtree(cache, ignore_errors=True)
    return 0 if all(s == s for _, s in results) else 1


if __name__ == '__main__':
    sys.exit(main())
