"""
Tick statistics (no ROS): timing figures of a diagnostics window, momentum drift and the
solver figures of the status.

``sm_ros.diagnostics`` turns them into the ``/diagnostics`` status; ``sm_ros.sim`` fills
them while it ticks.
"""

import math
from typing import Any, Dict, Iterable, List, Mapping, Optional, Tuple

import numpy as np


class TickStats:
    """
    Timing figures accumulated between two diagnostics reports.

    ``step_ms`` is one ``world.step(dt)`` (one substep); ``tick_ms`` is a whole tick
    (pending changes, substeps, checks, the live error estimate's share and publishing);
    ``publish_ms`` is building and publishing the messages of one tick; ``estimate_s_sum``
    the error estimate's seconds in the window's ticks.
    """

    def __init__(self, now: float):
        """Start an empty window at steady time ``now`` (seconds)."""
        self.overruns_total = 0
        self.nonfinite_total = 0
        self.reset_window(now)

    def reset_window(self, now: float) -> None:
        """Forget the window's figures (not the totals) and start a new window at ``now``."""
        self.window_start = now
        self.ticks = 0
        self.steps = 0
        self.step_s_sum = 0.0
        self.step_s_max = 0.0
        self.publish_s_sum = 0.0
        self.publishes = 0
        self.tick_s_max = 0.0
        self.tick_s_sum = 0.0
        self.estimate_s_sum = 0.0
        self.sim_s = 0.0
        self.overruns = 0
        self.nonfinite: List[str] = []
        self.contacts = 0
        self.contact_fast_max = 0
        self.asleep = 0

    def add_step(self, seconds: float) -> None:
        """Record one world.step."""
        self.steps += 1
        self.step_s_sum += seconds
        if seconds > self.step_s_max:
            self.step_s_max = seconds

    def add_publish(self, seconds: float) -> None:
        """Record the publishing of one tick."""
        self.publishes += 1
        self.publish_s_sum += seconds

    def add_tick(self, seconds: float, sim_seconds: float, period: float,
                 estimate_s: float = 0.0) -> bool:
        """Record one tick; returns True when it overran ``period``.

        ``estimate_s`` seconds of it (the live error estimate's pieces) are summed apart
        too (``estimate_s_sum``).
        """
        self.ticks += 1
        self.tick_s_sum += seconds
        self.estimate_s_sum += estimate_s
        self.sim_s += sim_seconds
        if seconds > self.tick_s_max:
            self.tick_s_max = seconds
        if seconds > period:
            self.overruns += 1
            self.overruns_total += 1
            return True
        return False

    def add_contact(self, pairs: int, fast: int) -> None:
        """Record a tick's touching particle pairs and fast particles (sm_ros.core.contact).

        ``fast``: particles that moved more than their contact radius in the tick's last
        step (the window keeps the largest count), which can tunnel through a thin layer.
        """
        self.contacts = int(pairs)
        if fast > self.contact_fast_max:
            self.contact_fast_max = int(fast)

    def add_nonfinite(self, names: Iterable[str]) -> None:
        """Record bodies that went non-finite and were reset."""
        names = list(names)
        self.nonfinite.extend(names)
        self.nonfinite_total += len(names)


class MomentumDrift:
    """
    Relative change of the total linear momentum over ticks in which no external force acts.

    ``drift`` is None until such a tick was measured; ``forget()`` starts over (a new
    world, a reset, a tick with an external force or a non-finite body).

    The momentum is summed when it is needed, not every tick: once when a run of
    conservative ticks starts (the reference) and when ``drift`` is read (the node reads
    it for /diagnostics, once a second by default). ``world`` is a function returning the
    current world; without it ``track`` sums at every tick, as before.
    """

    def __init__(self, world=None):
        """Start with nothing measured; ``world()`` returns the world ``drift`` measures."""
        self.reference: Optional[Tuple[np.ndarray, float]] = None
        self._drift = 0.0
        self._world = world
        self._stale = False
        self.sums = 0       # how many times the momentum was summed (tests, benchmarks)

    @property
    def drift(self) -> Optional[float]:
        """Return |p - p_ref| / (sum of m |v|), or None when nothing was measured."""
        if self.reference is None:
            return None
        if self._stale and self._world is not None:
            self._update(self._world())
        return self._drift

    def forget(self) -> None:
        """Drop the reference momentum."""
        self.reference = None
        self._stale = False

    @staticmethod
    def conservative(world, held: bool) -> bool:
        """
        Return whether no external force acts on ``world`` this tick.

        ``held``: a force or a gripper acts. Gravity, colliders, pins and bodies touching
        the ground count as external forces too.
        """
        # Python floats, not a NumPy comparison: the first NumPy ufunc call after a step is
        # slow (its code and tables evicted by the step's passes)
        if held or any(g != 0.0 for g in world.gravity.tolist()):
            return False
        if world.boxes or world.spheres or getattr(world, 'capsules', ()):
            return False
        if any(len(b.pinned) for b in world.bodies):
            return False                                  # pins hold bodies in place
        if world.ground is not None:
            height = world.ground.height
            for b in world.bodies:
                if b.n and float(b.x[:, 2].min()) <= height + 1e-6:
                    return False
        return True

    def measure(self, world) -> Tuple[np.ndarray, float]:
        """Return the total momentum and its scale (sum of m |v|)."""
        self.sums += 1
        p = np.zeros(3)
        scale = 0.0
        for b in world.bodies:
            p += b.momentum()
            v = b.v
            # sqrt of the row sums of squares: faster than np.linalg.norm(v, axis=1)
            scale += float(np.dot(b.m, np.sqrt(np.einsum('ij,ij->i', v, v))))
        return p, scale

    def needs_reference(self) -> bool:
        """Return True when the next conservative tick must measure its start."""
        return self.reference is None

    def track(self, world, before: Optional[Tuple[np.ndarray, float]]) -> None:
        """After a conservative tick that started with ``before`` (None: the reference is
        already there): the drift is measured now, or on reading ``drift``."""
        if self.reference is None:
            self.reference = before
        if self._world is not None:
            self._stale = True
        else:
            self._update(world)

    def _update(self, world) -> None:
        p_ref, s_ref = self.reference
        p_now, s_now = self.measure(world)
        denom = max(s_ref, s_now, 1e-300)
        self._drift = float(np.linalg.norm(p_now - p_ref)) / denom \
            if denom > 1e-300 else 0.0
        self._stale = False


def solver_figures(world, values: Mapping[str, Any], momentum: MomentumDrift,
                   estimate: Optional[Dict[str, Any]], estimate_age: Optional[float] = None
                   ) -> Dict[str, Any]:
    """The figures of the solver status (``sm_ros.diagnostics.solver_status``) of a world
    run with node parameter ``values``, its momentum drift and last error estimate (made
    from the state of ``estimate_age`` seconds ago)."""
    bodies = world.bodies
    n = int(sum(b.n for b in bodies))
    err2 = sum(b.n * float(b.shape_error_rms()) ** 2 for b in bodies)
    modes = sorted({b.params.mode for b in bodies}) or [values['mode']]
    return dict(points=n, bodies=len(bodies),
                clusters=sum(int(b.num_clusters) for b in bodies), mode=','.join(modes),
                rate_target_hz=values['rate'],
                shape_error_rms_m=math.sqrt(err2 / n) if n else 0.0,
                momentum_drift=momentum.drift,
                speed_limited=sum(b.limit_counts[0] for b in bodies),
                turn_limited=sum(b.limit_counts[1] for b in bodies),
                error_estimate_m=estimate['error_m'] if estimate else 0.0,
                error_estimate_ms=1e3 * estimate['cost_s'] if estimate else 0.0,
                error_estimate_age_s=estimate_age if estimate else None)
