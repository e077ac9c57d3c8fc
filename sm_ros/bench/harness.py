"""
The process harness of the node benchmark and the soak test.

Both run sim_node in one process and subscribers (and, for the soak, a driver) in others,
all on this host and in a ROS domain of their own. This module holds what they share:

- the parent side: the scene of one box on the ground (:func:`box_scene`), the environment
  of the child processes (:func:`ros_env`, :func:`dds_profile`), starting a child
  (:func:`spawn`), reading its JSON lines (:func:`read_json_line`, :func:`last_json`) and
  stopping it (:func:`stop`);
- the child side: sim_node in this process with its executor (:func:`start_sim_node`), a
  hook around its ticks (:func:`time_ticks`), a subscriber to ``points``
  (:func:`spin_points`), and whether the parent asked to stop (:func:`stop_requested`).

A child prints one JSON object per line on stdout; the parent reads them.
"""

import json
import os
from pathlib import Path
import random
import select
import subprocess
import sys
import time
from typing import Any, Callable, Dict, List, Optional, Sequence, Tuple

ROOT = Path(__file__).resolve().parents[2]
SPACING = 0.01                       # m, the box's particle spacing


# ----------------------------------------------------------------------------------------
# parent side
# ----------------------------------------------------------------------------------------

def box_side(points: int) -> int:
    """Return the particles per edge of a cubic box of about ``points`` particles."""
    return max(2, int(round(points ** (1.0 / 3.0))))


def box_scene(points: int, path: Path, damping: float = 0.0, name: str = 'box',
              description: str = 'benchmark box') -> int:
    """Write a scene of one box resting on the ground; return its number of particles."""
    n = box_side(points)
    size = (n - 1) * SPACING
    path.write_text(
        f'description: {description}\n'
        'bodies:\n'
        f'  - name: {name}\n'
        '    shape: box\n'
        f'    size: [{size:.6f}, {size:.6f}, {size:.6f}]\n'
        f'    spacing: {SPACING}\n'
        '    mass: 1.0\n'
        f'    damping: {float(damping)}\n'
        f'    position: [0.0, 0.0, {size / 2 + 0.001:.6f}]\n')
    return n ** 3


def dds_profile(flag: Optional[str], use_environment: bool = True) -> Optional[str]:
    """
    Return the Fast DDS profile file to use, or None for the DDS defaults.

    ``flag`` '' means none; a path means that file; None means
    $FASTRTPS_DEFAULT_PROFILES_FILE (if ``use_environment``) or the repository's
    config/fastdds_shm.xml, as the README recommends for large clouds.
    """
    if flag == '':
        return None
    if flag:
        return str(Path(flag).resolve())
    if use_environment and os.environ.get('FASTRTPS_DEFAULT_PROFILES_FILE'):
        return os.environ['FASTRTPS_DEFAULT_PROFILES_FILE']
    cand = ROOT / 'config' / 'fastdds_shm.xml'
    return str(cand) if cand.is_file() else None


def ros_env(domain: Optional[int] = None, profile: Optional[str] = None) -> Dict[str, str]:
    """
    Return the environment of the child processes.

    Discovery stays on this host; the ROS domain is ``domain`` (or $ROS_DOMAIN_ID, or a
    random one in 101..200); this repository comes first on PYTHONPATH.
    """
    env = dict(os.environ)
    if domain is not None:
        env['ROS_DOMAIN_ID'] = str(domain)
    else:
        env.setdefault('ROS_DOMAIN_ID', str(random.randint(101, 200)))
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    env.pop('ROS_LOCALHOST_ONLY', None)           # deprecated in Jazzy, superseded above
    if profile:
        env['RMW_IMPLEMENTATION'] = 'rmw_fastrtps_cpp'
        env['FASTRTPS_DEFAULT_PROFILES_FILE'] = profile
    else:
        env.pop('FASTRTPS_DEFAULT_PROFILES_FILE', None)
    env['PYTHONPATH'] = str(ROOT) + os.pathsep + env.get('PYTHONPATH', '')
    return env


def spawn(module: str, args: Sequence[str], env: Dict[str, str],
          stdin: bool = False) -> subprocess.Popen:
    """Start ``python -m module args`` with text pipes (stdin too when ``stdin``)."""
    return subprocess.Popen([sys.executable, '-m', module, *args], env=env,
                            stdin=subprocess.PIPE if stdin else None, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)


def last_json(text: str, skip: Sequence[str] = ('ready',)) -> Optional[Dict[str, Any]]:
    """Return the last JSON object line of ``text`` that has none of the keys ``skip``."""
    for line in reversed([ln for ln in text.splitlines() if ln.startswith('{')]):
        try:
            obj = json.loads(line)
        except ValueError:
            continue
        if not any(k in obj for k in skip):
            return obj
    return None


def read_json_line(proc: subprocess.Popen, key: str, timeout: float
                   ) -> Optional[Dict[str, Any]]:
    """Read ``proc``'s stdout until a JSON line with ``key`` (None on EOF or timeout)."""
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


def stop(proc: subprocess.Popen, timeout: float
         ) -> Tuple[Optional[int], Optional[Dict[str, Any]], str]:
    """Ask a child to finish ('stop' on stdin); return (exit status, last JSON, stderr)."""
    if proc.stdin is not None:
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
    return proc.returncode, last_json(out or ''), (err or '')[-1500:]


# ----------------------------------------------------------------------------------------
# child side
# ----------------------------------------------------------------------------------------

def stop_requested() -> bool:
    """Whether the parent wrote 'stop' to (or closed) this process's stdin."""
    try:
        if select.select([sys.stdin], [], [], 0)[0]:
            line = sys.stdin.readline()
            return line == '' or line.strip() == 'stop'
    except (OSError, ValueError):
        return True
    return False


def start_sim_node(params: Dict[str, Any], namespace: str = ''):
    """Initialise rclpy and start a SimNode with ``params``; return (node, executor)."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter import Parameter
    from sm_ros.node import SimNode

    rclpy.init()
    node = SimNode(parameter_overrides=[Parameter(k, value=v) for k, v in params.items()],
                   namespace=namespace or None)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    return node, executor


def time_ticks(node, record: Callable[[float, float], None]) -> None:
    """Wrap ``node.tick`` so that ``record(start, seconds)`` follows every tick."""
    tick0 = node.tick

    def tick():
        t = time.perf_counter()
        tick0()
        record(t, time.perf_counter() - t)
    node.tick = tick


def spin_for(executor, seconds: float, step: float = 0.01) -> float:
    """Spin ``executor`` for ``seconds`` (waits of at most ``step`` s); the time it took."""
    start = time.monotonic()
    end = start + seconds
    while time.monotonic() < end:
        executor.spin_once(timeout_sec=step)
    return time.monotonic() - start


def spin_points(on_cloud: Callable[[Any, float], None], seconds: float, *,
                namespace: str = '', reliable: bool = True, name: str = 'points_sub',
                until: Callable[[], bool] = lambda: False) -> None:
    """
    Subscribe to ``points``; call ``on_cloud(msg, wall time)`` for each cloud.

    Spins until ``seconds`` have passed, ``until()`` is true or SIGTERM arrives (then it
    returns normally, so the caller still reports); initialises and shuts down rclpy itself.
    """
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import PointCloud2

    rclpy.init()
    node = Node(name, namespace=namespace or None)
    reliability = ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT
    node.create_subscription(PointCloud2, 'points', lambda msg: on_cloud(msg, time.time()),
                             QoSProfile(depth=5, reliability=reliability))
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    stop = []
    import signal
    signal.signal(signal.SIGTERM, lambda *_: stop.append(1))   # the bench is done: report
    t_end = time.monotonic() + seconds
    while time.monotonic() < t_end and not until() and not stop:
        executor.spin_once(timeout_sec=0.05)
    node.destroy_node()
    rclpy.try_shutdown()


def rss_bytes() -> int:
    """Return the resident set size of this process (psutil, else /proc)."""
    try:
        import psutil
        return int(psutil.Process().memory_info().rss)
    except ImportError:
        with open('/proc/self/statm') as f:
            return int(f.read().split()[1]) * os.sysconf('SC_PAGE_SIZE')


def percentile(values: List[float], q: float) -> float:
    """Return the q-th percentile (nearest rank) of ``values``; NaN for none."""
    if not values:
        return float('nan')
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(round(q / 100.0 * (len(ordered) - 1))))]
