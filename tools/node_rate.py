"""
The node's rate as users see it: ``sim_node`` on a scene in its own process, and this
process as the other end (a ``/diagnostics`` subscriber and, unless ``--no-cloud``, a
``points`` subscriber, as a viewer would be).  Prints each ``/diagnostics`` message (2 Hz):
seconds since the start, ``rate_achieved_hz``, ``tick_ms_mean``, ``step_ms_mean``, the live
error estimate's share, the bodies asleep and the clouds received; then the lowest rate
and the median tick over the windows after the first.  Needs the ROS wheels (``make
venv``).  With ``--shm`` both processes use the repository's Fast DDS profile
(``config/fastdds_shm.xml``, README "Large clouds across processes").

    .venv/bin/python tools/node_rate.py --scene paper_384 --seconds 24 --shm
    .venv/bin/python tools/node_rate.py --scene paper_384 --seconds 45 --shm \
        --param contact.sleep:=false          # bodies never sleep: estimates keep starting
"""

import argparse
import os
import pathlib
import statistics
import subprocess
import sys
import time


def main():
    """Start the node, watch it for ``--seconds``, print the figures."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--scene', default='paper_384')
    ap.add_argument('--seconds', type=float, default=24.0)
    ap.add_argument('--no-cloud', action='store_true', help='no points subscriber')
    ap.add_argument('--shm', action='store_true', help='the Fast DDS shared-memory profile')
    ap.add_argument('--param', action='append', default=[], metavar='NAME:=VALUE',
                    help="a node parameter more (repeatable), e.g. 'contact.sleep:=false'")
    a = ap.parse_args()
    env = dict(os.environ)
    if a.shm:
        env['FASTRTPS_DEFAULT_PROFILES_FILE'] = str(
            pathlib.Path(__file__).resolve().parent.parent / 'config' / 'fastdds_shm.xml')
        os.environ.update(env)                 # before rclpy starts in this process too
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.node import Node
    from sensor_msgs.msg import PointCloud2
    node_exe = pathlib.Path(sys.executable).with_name('sim_node')
    proc = subprocess.Popen([str(node_exe), '--ros-args', '-p', f'scene:={a.scene}',
                             '-p', 'foxglove.port:=0', '-p', 'diagnostics_rate:=2.0']
                            + [x for p in a.param for x in ('-p', p)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env)
    rclpy.init()
    n = Node('node_rate_watch')
    t0 = time.monotonic()
    clouds = [0]
    rows = []

    def on_diag(msg):
        for st in msg.status:
            kv = {k.key: k.value for k in st.values}
            if 'rate_achieved_hz' not in kv:
                continue
            row = (time.monotonic() - t0, float(kv['rate_achieved_hz']),
                   float(kv['tick_ms_mean']), float(kv['step_ms_mean']),
                   float(kv.get('error_estimate_ms_mean') or 0.0), kv.get('bodies_asleep'),
                   clouds[0])
            rows.append(row)
            clouds[0] = 0
            print('%6.1f s  rate %5.1f Hz  tick %6.2f ms  step %6.2f ms  estimate %5.2f ms  '
                  'asleep %s  clouds %d' % row, flush=True)

    def on_cloud(_msg):
        clouds[0] += 1

    n.create_subscription(DiagnosticArray, '/diagnostics', on_diag, 10)
    if not a.no_cloud:
        n.create_subscription(PointCloud2, 'points', on_cloud, 5)
    end = time.monotonic() + a.seconds
    try:
        while time.monotonic() < end and proc.poll() is None:
            rclpy.spin_once(n, timeout_sec=0.1)
    finally:
        proc.terminate()
        proc.wait()
        n.destroy_node()
        rclpy.shutdown()
    later = rows[1:]
    if later:
        print(f'{a.scene}: lowest rate {min(r[1] for r in later):.1f} Hz, median tick '
              f'{statistics.median(r[2] for r in later):.2f} ms over {len(later)} windows '
              f'after the first ({"no cloud subscriber" if a.no_cloud else "one cloud subscriber"}'
              f'{", shm profile" if a.shm else ""}{"".join(", " + p for p in a.param)})')


if __name__ == '__main__':
    main()
