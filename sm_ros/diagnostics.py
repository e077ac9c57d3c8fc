"""
Timing and error figures of the node, and the DiagnosticArray that reports them.

diagnostic_updater is not on PyPI; doc/interface.md fixes the keys, so a small accumulator
(``sm_ros.stats.TickStats``, no ROS) and one function that builds the status are enough.
Values are plain decimal strings; the level is compared as
``DiagnosticStatus.OK/WARN/ERROR`` (bytes).
"""

from dataclasses import dataclass
from typing import Dict, Optional

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from sm_ros.stats import TickStats

HARDWARE_ID = 'sm_ros'

#: Every key of the solver status, in the order it is published (interface.md, plus the
#: sm_ros extras from momentum_drift_measured on). A tick's time splits into the steps
#: (step_ms_mean x substeps), publishing (publish_ms_mean: building and sending what is
#: consumed), the live error estimate's share (error_estimate_ms_mean) and the rest
#: (other_ms_mean: parameter changes, checks, momentum).
KEYS = ('points', 'bodies', 'clusters', 'mode', 'step_ms_mean', 'step_ms_max',
        'publish_ms_mean', 'tick_ms_max', 'rate_target_hz', 'rate_achieved_hz',
        'real_time_factor', 'overruns', 'shape_error_rms_m', 'momentum_drift',
        'momentum_drift_measured', 'nonfinite_resets', 'refused_messages', 'tick_ms_mean',
        'other_ms_mean', 'recording', 'recorder_messages', 'recorder_dropped', 'contacts',
        'contact_fast_particles', 'bodies_asleep', 'speed_limited', 'turn_limited',
        'error_estimate_m', 'error_estimate_ms', 'error_estimate_age_s', 'error_estimate_ms_mean')


def fmt(value: float) -> str:
    """Format a number as a plain decimal string (no exponent, no 'nan')."""
    value = float(value)
    if value != value or value in (float('inf'), float('-inf')):
        return '0'
    text = f'{value:.6f}'.rstrip('0').rstrip('.')
    return text if text not in ('', '-0') else '0'


@dataclass
class SolverFigures:
    """The figures of the solver status beside the tick statistics: the world's
    (``Simulation.status_values``), the node's and the recorder's
    (``Outputs.recorder_status``).

    ``recording`` is the folder being recorded into ('' when not recording);
    ``recorder_*`` count over the recording, ``recorder_dropped_window`` over the window.
    ``error_estimate_age_s``: seconds since the state of the last error estimate (None:
    no estimate yet, published as -1).
    """

    points: int
    bodies: int
    clusters: int
    mode: str
    rate_target_hz: float
    shape_error_rms_m: float
    momentum_drift: Optional[float]
    refused_messages: int
    paused: bool = False
    recording: str = ''
    recorder_messages: int = 0
    recorder_dropped: int = 0
    recorder_dropped_window: int = 0
    speed_limited: int = 0
    turn_limited: int = 0
    error_estimate_m: float = 0.0
    error_estimate_ms: float = 0.0
    error_estimate_age_s: Optional[float] = None


def _per_tick_ms(stats: TickStats, total_s: float) -> float:
    return 1e3 * total_s / stats.ticks if stats.ticks else 0.0


def _values(stats: TickStats, span: float, fig: SolverFigures) -> Dict[str, str]:
    """Every key of ``KEYS`` as its published string."""
    tick_ms = _per_tick_ms(stats, stats.tick_s_sum)
    step_ms = _per_tick_ms(stats, stats.step_s_sum)
    publish_ms = _per_tick_ms(stats, stats.publish_s_sum)
    estimate_ms = _per_tick_ms(stats, getattr(stats, 'estimate_s_sum', 0.0))
    return {
        'points': str(int(fig.points)),
        'bodies': str(int(fig.bodies)),
        'clusters': str(int(fig.clusters)),
        'mode': fig.mode,
        'step_ms_mean': fmt(1e3 * stats.step_s_sum / stats.steps if stats.steps else 0.0),
        'step_ms_max': fmt(1e3 * stats.step_s_max),
        'publish_ms_mean': fmt(
            1e3 * stats.publish_s_sum / stats.publishes if stats.publishes else 0.0),
        'tick_ms_max': fmt(1e3 * stats.tick_s_max),
        'rate_target_hz': fmt(fig.rate_target_hz),
        'rate_achieved_hz': fmt(stats.ticks / span),
        'real_time_factor': fmt(stats.sim_s / span),
        'overruns': str(stats.overruns_total),
        'shape_error_rms_m': fmt(fig.shape_error_rms_m),
        'momentum_drift': fmt(fig.momentum_drift or 0.0),
        'momentum_drift_measured': 'true' if fig.momentum_drift is not None else 'false',
        'nonfinite_resets': str(stats.nonfinite_total),
        'refused_messages': str(int(fig.refused_messages)),
        'tick_ms_mean': fmt(tick_ms),
        'other_ms_mean': fmt(max(0.0, tick_ms - step_ms - publish_ms - estimate_ms)),
        'recording': fig.recording,
        'recorder_messages': str(int(fig.recorder_messages)),
        'recorder_dropped': str(int(fig.recorder_dropped)),
        'contacts': str(int(getattr(stats, 'contacts', 0))),
        'contact_fast_particles': str(int(getattr(stats, 'contact_fast_max', 0))),
        'bodies_asleep': str(int(getattr(stats, 'asleep', 0))),
        'speed_limited': str(int(fig.speed_limited)),
        'turn_limited': str(int(fig.turn_limited)),
        'error_estimate_m': fmt(fig.error_estimate_m),
        'error_estimate_ms': fmt(fig.error_estimate_ms),
        'error_estimate_age_s': '-1' if fig.error_estimate_age_s is None
        else fmt(fig.error_estimate_age_s),
        'error_estimate_ms_mean': fmt(estimate_ms),
    }


def solver_status(node_name: str, stats: TickStats, now: float,
                  figures: SolverFigures) -> DiagnosticStatus:
    """
    Build the '<node name>: solver' status for the window that ends at ``now``.

    Level: ERROR when a body went non-finite in the window, else WARN when ticks overran
    or the recorder dropped messages in the window, else OK.
    """
    values = _values(stats, max(now - stats.window_start, 1e-9), figures)
    status = DiagnosticStatus()
    status.name = f'{node_name}: solver'
    status.hardware_id = HARDWARE_ID
    if stats.nonfinite:
        status.level = DiagnosticStatus.ERROR
        names = ', '.join(f"'{body}'" for body in dict.fromkeys(stats.nonfinite))
        status.message = f'body {names} went non-finite and was reset'
    elif stats.overruns:
        status.level = DiagnosticStatus.WARN
        status.message = (f'{stats.overruns} of {stats.ticks} ticks overran the period '
                          f'of {fmt(1e3 / figures.rate_target_hz)} ms')
    elif figures.recorder_dropped_window:
        status.level = DiagnosticStatus.WARN
        status.message = (f'the recorder dropped {int(figures.recorder_dropped_window)} '
                          'messages (the disk did not keep up)')
    else:
        status.level = DiagnosticStatus.OK
        status.message = 'paused' if figures.paused else 'running'
    status.values = [KeyValue(key=key, value=values[key]) for key in KEYS]
    return status


def contact_status(node_name: str, per_body) -> DiagnosticStatus:
    """
    Build the '<node name>: contacts' status from per-body contact figures.

    ``per_body`` is ``{body: (contacts, deepest m)}`` of the last step
    (``World.contact_stats``); keys ``<body>.contacts`` (particle-collider contacts of the
    collider pass plus body-body pairs) and ``<body>.penetration_max_m``, for the bodies
    in contact only.
    """
    status = DiagnosticStatus()
    status.name = f'{node_name}: contacts'
    status.hardware_id = HARDWARE_ID
    status.level = DiagnosticStatus.OK
    total = sum(int(count) for count, _ in per_body.values())
    status.message = f'{total} contacts'
    values = []
    for name, (count, depth) in per_body.items():
        if not count:
            continue                  # only the bodies in contact (a bin of 384 bodies)
        values.append(KeyValue(key=f'{name}.contacts', value=str(int(count))))
        values.append(KeyValue(key=f'{name}.penetration_max_m', value=fmt(depth)))
    status.values = values
    return status


def diagnostic_array(status, stamp) -> DiagnosticArray:
    """Wrap one status (or a list of them) in a DiagnosticArray stamped ``stamp``."""
    msg = DiagnosticArray()
    msg.header.stamp = stamp
    msg.status = list(status) if isinstance(status, (list, tuple)) else [status]
    return msg
