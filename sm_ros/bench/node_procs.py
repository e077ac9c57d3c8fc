"""
The two processes of the node benchmark (run by ``node_bench``; one JSON line each).

``python -m sm_ros.bench.node_procs node --scene S --rate R --seconds T``
    runs sim_node in this process and records, per tick, the time of the step(s), of the
    cloud build (``CloudBuffer.fill``), of the publish call, of the live error estimate,
    the rest of the tick (``other``: the node's own overhead) and the wall time at which
    each cloud was handed to rclpy (keyed by its stamp).
``python -m sm_ros.bench.node_procs sub --seconds T``
    subscribes to ``points`` and records each message's stamp and wall receive time.
"""

import argparse
import json
import sys
import time

from . import harness


def _node(a) -> dict:
    """Run sim_node; time its ticks and their parts while measuring."""
    node, ex = harness.start_sim_node(
        {'scene': a.scene, 'rate': float(a.rate), 'dt': 1.0 / (a.rate * a.substeps),
         'substeps': int(a.substeps), 'mode': a.mode, 'clusters': int(a.clusters)},
        a.namespace)
    rec = {'step': [], 'fill': [], 'publish': [], 'tick': [], 'sent': {}, 'estimate': [],
           'other': []}
    measuring = [False]
    current = {'step': 0.0, 'fill': 0.0, 'publish': 0.0, 'estimate': 0.0}

    def tick_done(start, seconds):
        if measuring[0]:
            rec['tick'].append(seconds)
            rec['estimate'].append(current['estimate'])
            rec['other'].append(seconds - sum(current.values()))
        for k in current:
            current[k] = 0.0
    harness.time_ticks(node, tick_done)

    _time_steps(node, rec, current, measuring)
    _time_cloud(node, rec, current, measuring)
    harness.spin_for(ex, a.warmup, 0.05)
    measuring[0] = True
    elapsed = harness.spin_for(ex, a.seconds, 0.05)
    ticks = len(rec['tick'])
    out = {'points': node.num_points, 'rate_target': a.rate, 'substeps': a.substeps,
           'elapsed_s': elapsed, 'ticks': ticks,
           'step_s': rec['step'], 'fill_s': rec['fill'], 'publish_s': rec['publish'],
           'tick_s': rec['tick'], 'estimate_s': rec['estimate'], 'other_s': rec['other'],
           'sent': {str(k): v for k, v in rec['sent'].items()}}
    node.destroy_node()
    import rclpy
    rclpy.try_shutdown()
    return out


def _time_steps(node, rec, current, measuring):
    """Time the simulation's steps and the error estimate's share of each tick."""
    # the steps as the simulation times them (stats.add_step); wrapping world.step itself
    # would time the error estimate's steps of the world too
    stats = node.sim.stats
    add_step0 = stats.add_step

    def add_step(seconds):
        add_step0(seconds)
        current['step'] += seconds
        if measuring[0]:
            rec['step'].append(seconds)
    stats.add_step = add_step

    estimates = node.sim._estimates
    before_tick0 = estimates.before_tick

    def before_tick(*args, **kwargs):
        t = time.perf_counter()
        out = before_tick0(*args, **kwargs)
        current['estimate'] += time.perf_counter() - t
        return out
    estimates.before_tick = before_tick


def _time_cloud(node, rec, current, measuring):
    """Time the cloud's fill and its publishing; note when each cloud was sent."""
    fill0 = node.cloud.fill

    def fill(blocks, stamp):
        t = time.perf_counter()
        msg = fill0(blocks, stamp)
        s = time.perf_counter() - t
        current['fill'] += s
        if measuring[0]:
            rec['fill'].append(s)
        return msg
    node.cloud.fill = fill

    pub0 = node.pub_points.publish

    def publish(msg):
        t = time.perf_counter()
        key = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        rec['sent'][key] = time.time()
        pub0(msg)
        s = time.perf_counter() - t
        current['publish'] += s
        if measuring[0]:
            rec['publish'].append(s)
    node.pub_points.publish = publish


def _sub(a) -> dict:
    got = []

    def on_cloud(msg, now):
        got.append((msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec, now,
                    msg.width * msg.height))
    harness.spin_points(on_cloud, a.seconds, namespace=a.namespace, name='bench_points_sub')
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
