"""
The live error estimate (``sm_ros.error_estimate``) measured: ``python -m sm_ros.bench
accuracy --estimate-only`` (or ``--estimate`` after the sweep).

- ``estimate_accuracy``: on the accuracy scenes at 1/120 and 1/240 s, eight estimates
  along T s against the scene's true error (the sweep's error: the largest RMS position
  error over T); the mean ratio and the worst single one;
- ``estimate_timing``: one estimate's milliseconds against one step's, and the bytes a
  save copies, on the default scene and in ``paper_384``'s pour;
- ``estimate_cost``: bundled scenes ticked in real time (the node's rate, a tick waits for
  its period) with the estimate at its default rate: the estimate's seconds as a fraction
  of the ticks' step seconds, the oldest estimate seen (``error_estimate_age_s``) against
  2 / rate, the estimates made, the milliseconds of each and the megabytes a save copies,
  and the ticks that overran their period.
"""

import math
import time
from typing import Any, Dict, List

import numpy as np

from . import common as bc

#: Scenes whose estimate cost and age are measured (``--estimate-seconds`` of ticks each)
#: and the rate (None: the default): ``paper_384`` at 2 Hz too, so that estimates fall in
#: its pour (at the default rate the first is due when the heap may be asleep already).
COST_SCENES = (('default', None), ('paper_384', None), ('paper_384', 2.0))


def run(args, out) -> Dict[str, Any]:
    """The live error estimate's tables of ``python -m sm_ros.bench accuracy --estimate``
    (or ``--estimate-only``): its accuracy, timing and cost; nothing without those."""
    if not (getattr(args, 'estimate_only', False) or getattr(args, 'estimate', False)):
        return {}
    from . import accuracy as acc
    with bc.one_numba_thread():               # solver time on one thread
        return {'estimate_accuracy': estimate_accuracy(
                    list(acc.ESTIMATE_SCENES), args.accuracy_points, args.duration, out),
                'estimate_timing': estimate_timing(out),
                'estimate_cost': estimate_cost(args.estimate_seconds, out)}


def ratios(scene, h: float, duration: float, every_s: float = 0.25) -> Dict[str, Any]:
    """Estimates every ``every_s`` s along a run of ``scene`` (``accuracy.Scene``) against
    its true error over ``duration`` s."""
    from sm_ros import error_estimate as EE
    from sm_ros.core.snapshot import Snapshot
    from . import accuracy as acc
    world, body, driver = scene.build(dict(scene.nominal))
    n = int(round(duration / h))
    every = int(round((1.0 / acc.SAMPLE_RATE) / h))
    at = int(round(every_s / h))
    snap, xs, est = Snapshot(), [], []
    for i in range(n):
        if driver is not None:
            driver(world, body, (i + 1) * h)
        if i % at == 0:
            est.append(EE.estimate(world, h, snap)['error_m'])
        world.step(h)
        if (i + 1) % every == 0:
            xs.append(np.array(body.x))
    xs = np.array(xs)
    t = (np.arange(len(xs)) + 1) * every * h
    truth = (acc.exact_samples(scene, t) if scene.exact is not None
             else acc.simulate(scene, scene.nominal, h / 16.0, duration)['x'])
    true = acc.max_rms(xs, truth)
    r = np.array(est) / true
    return {'true_m': true, 'mean_m': float(np.mean(est)), 'mean_ratio': float(r.mean()),
            'worst_ratio': float(r[np.argmax(np.maximum(r, 1.0 / r))]), 'n': len(est),
            'ratios': r}


def estimate_accuracy(names: List[str], points: int, duration: float, out) -> List[dict]:
    """The table of estimate against true error for the accuracy scenes ``names``."""
    from . import accuracy as acc
    scenes = acc.make_scenes(points)
    t = bc.Table('estimate_accuracy', ['scene', 'dt_ms', 'true_err_m', 'estimate_mean_m',
                                       'mean_ratio', 'worst_ratio', 'estimates'],
                 f'Live error estimate against the true error over T = {duration:g} s '
                 '(ratio: estimate / true; worst: the single estimate farthest off)')
    for name in names:
        for rate in (120.0, 240.0):
            res = ratios(scenes[name], 1.0 / rate, duration)
            t.add(scene=name, dt_ms=1e3 / rate, true_err_m=res['true_m'],
                  estimate_mean_m=res['mean_m'], mean_ratio=res['mean_ratio'],
                  worst_ratio=res['worst_ratio'], estimates=res['n'])
            bc.log(f'[estimate] {name} 1/{rate:g} s: true {res["true_m"]:.3g} m, mean '
                   f'ratio {res["mean_ratio"]:.2f}, worst {res["worst_ratio"]:.2f}')
    t.write(out)
    return t.rows


#: Scenes whose estimates are timed against their steps, and the steps before the first.
TIMING_SCENES = (('default', 40), ('paper_384', 120))


def timing_run(scene: str, lead: int, count: int = 12) -> Dict[str, Any]:
    """From step ``lead`` of ``scene``, ``count`` estimates (``error_estimate.estimate``),
    one every 12 steps: the median milliseconds of an estimate and of a step, and the
    megabytes a save copies."""
    from sm_ros import error_estimate as EE
    from sm_ros.core.snapshot import Snapshot
    from sm_ros.sim import Simulation
    sim = Simulation({'scene': scene, 'error_estimate.rate': 0.0})
    world, h = sim.world, float(sim.params['dt'])
    for _ in range(lead):
        world.step(h)
    snap, est, steps = Snapshot(), [], []
    for _ in range(count):
        t0 = time.perf_counter()
        EE.estimate(world, h, snap)
        est.append(time.perf_counter() - t0)
        for _ in range(12):
            t0 = time.perf_counter()
            world.step(h)
            steps.append(time.perf_counter() - t0)
    ms, step_ms = 1e3 * float(np.median(est)), 1e3 * float(np.median(steps))
    return {'scene': scene, 'from_step': lead, 'estimate_ms': ms, 'step_ms': step_ms,
            'steps_worth': ms / step_ms, 'saved_mb': snap.nbytes / 1e6}


def estimate_timing(out) -> List[dict]:
    """The table of an estimate's milliseconds against a step's on ``TIMING_SCENES``."""
    t = bc.Table('estimate_timing', ['scene', 'from_step', 'estimate_ms', 'step_ms',
                                     'steps_worth', 'saved_mb'],
                 'One live error estimate (three steps, a save, two loads) against one '
                 'step: medians of 12 estimates one every 12 steps, and the megabytes a '
                 'save copies')
    for scene, lead in TIMING_SCENES:
        res = timing_run(scene, lead)
        t.add(**res)
        bc.log(f'[estimate] {scene}: {res["estimate_ms"]:.2f} ms an estimate, '
               f'{res["steps_worth"]:.1f} steps, {res["saved_mb"]:.2f} MB saved')
    t.write(out)
    return t.rows


def cost_run(scene: str, seconds: float, rate=None) -> Dict[str, Any]:
    """Tick ``scene`` in real time for ``seconds`` with estimates at ``rate`` Hz (None:
    the default); the estimate's cost and age."""
    from sm_ros.sim import Simulation
    sim = Simulation({'scene': scene} if rate is None else
                     {'scene': scene, 'error_estimate.rate': float(rate)})
    rate = float(sim.params['error_estimate.rate'])
    period = 1.0 / float(sim.params['rate'])
    ages, t_end, done, saved = [], time.monotonic() + seconds, set(), 0
    next_tick = time.monotonic()
    while time.monotonic() < t_end:
        sim.tick()
        age = sim.status_values()['error_estimate_age_s']
        ages.append(-1.0 if age is None else age)
        est = sim._estimates
        if est.result is not None and est.result.get('steps'):
            done.add(est.result_at)
        saved = max([saved] + [snap.nbytes for snap in est.snapshots])
        next_tick += period
        time.sleep(max(0.0, next_tick - time.monotonic()))
    st = sim.stats
    late = ages[int(len(ages) * 0.1):]
    return {'scene': scene, 'ticks': st.ticks, 'step_s': st.step_s_sum,
            'estimate_s': st.estimate_s_sum,
            'fraction': st.estimate_s_sum / st.step_s_sum if st.step_s_sum else 0.0,
            'age_max_s': max(late) if late else -1.0,
            'age_limit_s': 2.0 / rate if rate > 0.0 else math.inf,
            'overruns': st.overruns_total, 'rate_hz': rate, 'estimates': len(done),
            'ms_per_estimate': 1e3 * st.estimate_s_sum / max(len(done), 1),
            'saved_mb': saved / 1e6}


def estimate_cost(seconds: float, out) -> List[dict]:
    """The table of the estimate's cost and age on ``COST_SCENES``."""
    t = bc.Table('estimate_cost', ['scene', 'rate_hz', 'ticks', 'step_s', 'estimate_s',
                                   'fraction', 'estimates', 'ms_per_estimate', 'saved_mb',
                                   'age_max_s', 'age_limit_s', 'overruns'],
                 f'Live error estimate at its default rate, {seconds:g} s of real-time '
                 "ticks: its seconds as a fraction of the steps' seconds, the estimates "
                 'made (not counting those of a world asleep) and the seconds of each, the '
                 'megabytes a save copies, the oldest estimate seen (after the first 10 % '
                 'of the ticks) and the limit 2 / rate')
    for scene, rate in COST_SCENES:
        res = cost_run(scene, seconds, rate)
        t.add(**res)
        bc.log(f'[estimate] {scene} at {res["rate_hz"]:g} Hz: {100 * res["fraction"]:.1f} % '
               'of the step time, '
               f'{res["ms_per_estimate"]:.1f} ms an estimate, {res["saved_mb"]:.2f} MB saved, '
               f'oldest {res["age_max_s"]:.2f} s (limit {res["age_limit_s"]:g} s), '
               f'{res["overruns"]} overruns')
    t.write(out)
    return t.rows
