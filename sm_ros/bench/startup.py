"""
``python -m sm_ros.bench startup``: how long a user waits for the first cloud.

Three figures, each from a separate process:

- **cold**: ``sim_node`` on an empty Numba cache (``NUMBA_CACHE_DIR`` pointed at a new
  temporary folder, which Numba honours): seconds from the process start to the first
  PointCloud2 on ``/points`` seen by a subscriber in this process (the scene at rest,
  published while the solver compiles) and to the first simulated one (stamped after
  time 0: the node compiled what its scene needs; then it starts the background warm-up
  of the rest);
- **full warm-up**: ``python -m sm_ros.warmup`` on another empty cache: every kernel
  (what ``make test`` and ``ros2 run sm_ros warmup`` do);
- **warm**: ``sim_node`` again on the cache the full warm-up filled (``--runs`` times).

Each node runs in a DDS domain of its own and is stopped with SIGINT after its first cloud.
``--warm-only`` measures only the warm start on the environment's own cache (the smoke test
does that), ``--cold-only`` only the cold one. Arguments after ``--`` go to ``sim_node``, e.g.
``python -m sm_ros.bench startup -- --ros-args -p scene:=many``.
"""

import argparse
import json
import os
from pathlib import Path
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from typing import Dict, List, Optional, Tuple

ROOT = str(Path(__file__).resolve().parent.parent.parent)


def _env(cache: Optional[str]) -> Dict[str, str]:
    """This environment with this package first on the path, a DDS domain of its own and,
    when given, the Numba cache folder. The discovery range stays the user's, as in the
    probe's own participant: with ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` a subscriber
    that was there first often sees a new node only at its next announcement, up to 3 s
    later (doc/running.md)."""
    env = dict(os.environ, ROS_DOMAIN_ID=str(random.Random().randint(100, 200)))
    env['PYTHONPATH'] = os.pathsep.join(p for p in (ROOT, env.get('PYTHONPATH')) if p)
    if cache is not None:
        env['NUMBA_CACHE_DIR'] = cache
    return env


def _cpu_seconds(pid: int) -> float:
    """CPU seconds (user + system) process ``pid`` has used so far (Linux; nan elsewhere).
    On a loaded machine the wall time of a compile grows with the load, its CPU time not:
    on an idle one the two are about equal (compiling takes one core)."""
    try:
        with open(f'/proc/{pid}/stat') as f:
            fields = f.read().rsplit(')', 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')
    except (OSError, ValueError, IndexError):
        return float('nan')


def first_cloud_seconds(cmd: List[str], env: Dict[str, str], timeout: float
                        ) -> Tuple[float, float, float, int, str]:
    """Start ``cmd``; return (seconds to the first PointCloud2 on /points, to the first
    one stamped after simulation time 0 (a simulated one; on a cold cache the scene at
    rest comes first), nan if none; the CPU seconds the node had used at the simulated
    one, the exit code after SIGINT, the end of its stderr)."""
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.qos import QoSProfile
    from sensor_msgs.msg import PointCloud2
    ctx = Context()
    rclpy.init(context=ctx, domain_id=int(env['ROS_DOMAIN_ID']))
    node = Node('startup_probe', context=ctx)
    executor = SingleThreadedExecutor(context=ctx)
    executor.add_node(node)
    got, moved = [], []

    def on_cloud(msg):
        got.append(time.monotonic())
        if msg.header.stamp.sec or msg.header.stamp.nanosec:
            moved.append(got[-1])
    node.create_subscription(PointCloud2, '/points', on_cloud, QoSProfile(depth=1))
    err = tempfile.TemporaryFile()
    t0 = time.monotonic()
    proc = subprocess.Popen(cmd, env=env, stdin=subprocess.DEVNULL,
                            stdout=subprocess.DEVNULL, stderr=err, start_new_session=True)
    try:
        while not moved and time.monotonic() - t0 < timeout and proc.poll() is None:
            executor.spin_once(timeout_sec=0.01)
        first = got[0] - t0 if got else float('nan')
        elapsed = moved[0] - t0 if moved else float('nan')
        cpu = _cpu_seconds(proc.pid) if moved else float('nan')
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)       # with its background warm-up
            proc.wait()
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=ctx)
        err.seek(0)
        tail = err.read().decode(errors='replace')[-2000:]
        err.close()
    return first, elapsed, cpu, proc.returncode, tail


def warmup_seconds(env: Dict[str, str], timeout: float) -> Tuple[float, float, int]:
    """Run ``python -m sm_ros.warmup``; return (wall seconds, CPU seconds of it and its
    second process, exit code); (nan, nan, -9) when it ran past ``timeout`` (then both
    are killed)."""
    t0 = time.monotonic()
    proc = subprocess.Popen([sys.executable, '-m', 'sm_ros.warmup'], env=env,
                            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, start_new_session=True)
    while proc.returncode is None:
        done, status, usage = os.wait4(proc.pid, os.WNOHANG)
        if done:
            proc.returncode = os.waitstatus_to_exitcode(status)
            return (time.monotonic() - t0, usage.ru_utime + usage.ru_stime,
                    proc.returncode)
        if time.monotonic() - t0 > timeout:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
            return float('nan'), float('nan'), -9
        time.sleep(0.1)
    return time.monotonic() - t0, float('nan'), proc.returncode


def _node(env: Dict[str, str], args, label: str, results: Dict) -> None:
    cmd = [sys.executable, '-m', 'sm_ros.node', *args.node_args]
    first, seconds, cpu, code, tail = first_cloud_seconds(cmd, env, args.timeout)
    results.setdefault(f'{label} first cloud', []).append(first)
    results.setdefault(label, []).append(seconds)
    results.setdefault(f'{label} cpu', []).append(cpu)
    print(f'{label}: first cloud after {first:.2f} s, first simulated cloud after '
          f'{seconds:.2f} s (exit code {code}; the node had used {cpu:.1f} CPU s)', flush=True)
    if seconds != seconds:
        sys.stderr.write(tail)


def run(args) -> Dict:
    """Measure what ``args`` asks for; return {label: [seconds, ...]}."""
    results: Dict = {}
    if args.warm_only:
        for _ in range(args.runs):
            _node(_env(None), args, 'warm', results)
        return results
    cold = tempfile.mkdtemp(prefix='sm_ros_numba_cold_')
    full = tempfile.mkdtemp(prefix='sm_ros_numba_full_')
    try:
        _node(_env(cold), args, 'cold', results)
        if args.cold_only:
            return results
        seconds, cpu, code = warmup_seconds(_env(full), args.timeout)
        results['full warm-up'] = [seconds]
        results['full warm-up cpu'] = [cpu]
        print(f'full warm-up: {seconds:.1f} s (exit code {code}; {cpu:.1f} CPU s in its two '
              'processes)', flush=True)
        for _ in range(args.runs):
            _node(_env(full), args, 'warm', results)
    finally:
        shutil.rmtree(cold, ignore_errors=True)
        shutil.rmtree(full, ignore_errors=True)
    return results


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The options of ``python -m sm_ros.bench startup``."""
    p.add_argument('--runs', type=int, default=2, help='warm runs (default 2)')
    p.add_argument('--timeout', type=float, default=600.0, help='seconds per run')
    p.add_argument('--warm-only', action='store_true',
                   help="only warm starts, on this environment's Numba cache")
    p.add_argument('--cold-only', action='store_true',
                   help='only the cold start (no full warm-up, no warm starts)')
    p.add_argument('--out', default=None, help='also write startup.json into this folder')
    p.add_argument('node_args', nargs='*', help='arguments for sim_node (after --)')


def main(argv: Optional[List[str]] = None) -> int:
    """Entry point; exit status 1 when a run saw no cloud."""
    p = argparse.ArgumentParser(prog='python -m sm_ros.bench startup',
                                description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    add_arguments(p)
    args = p.parse_args(argv)
    from .common import machine_info
    m = machine_info()
    print(f"machine: {m['cpu']}, {m['cpus']} CPUs, Numba {m['numba']}, load average "
          f"{m.get('loadavg_1min', '?')}", flush=True)
    results = run(args)
    if args.out:
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        (out / 'startup.json').write_text(json.dumps(
            {'command': 'python -m sm_ros.bench startup ' + ' '.join(argv or sys.argv[1:]),
             'machine': m, 'seconds': results}, indent=1, default=str))
    return 0 if all(s == s for k, v in results.items() if 'cpu' not in k for s in v) else 1
