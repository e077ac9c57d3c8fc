"""
Tick statistics (no ROS): timing figures of a diagnostics window, momentum drift, the
schedule of the live error estimate and the solver figures of the status.

``sm_ros.diagnostics`` turns them into the ``/diagnostics`` status; ``sm_ros.sim`` fills
them while it ticks.
"""

import math
from typing import Any, Callable, Dict, Iterable, List, Mapping, Optional, Tuple

import numpy as np

from sm_ros.error_estimate import ErrorEstimate, at_rest


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
                 exempt: float = 0.0) -> bool:
        """Record one tick; returns True when it overran ``period``.

        ``exempt`` seconds of it (the live error estimate) count in the tick times but not
        in the overrun test; they are summed apart too (``estimate_s_sum``).
        """
        self.ticks += 1
        self.tick_s_sum += seconds
        self.estimate_s_sum += exempt
        self.sim_s += sim_seconds
        if seconds > self.tick_s_max:
            self.tick_s_max = seconds
        if seconds - exempt > period:
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
        # Python floats, not a NumPy comparison: the first NumPy ufunc call after a step
        # pays 50-80 us at 100k points (its code and tables evicted by the step's passes)
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
            # sqrt of the row sums of squares: np.linalg.norm(v, axis=1) took 6 ms at 100k
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


#: The live error estimate's share of a tick: what is left of this share of the tick
#: period after the tick's own steps (``estimate_room``); a piece of its work that would
#: not fit waits for a tick with room, so a diagnostic does not cost the simulation its
#: rate.
ESTIMATE_ROOM = 0.75
#: A new estimate, due but waiting this long (s) for a tick with room for its copy,
#: starts anyway: a scene whose copy never fits still gets an estimate, one long tick at
#: most this often.
ESTIMATE_FORCE_S = 10.0
#: Before the first copy of the world is made, it is expected to cost this many of the
#: tick's steps (a deep copy and its first step: 20 steps of ``paper_384`` pouring, 70 of
#: the default scene, 15-46 for the other bundled scenes measured).
COPY_GUESS_STEPS = 40


def estimate_room(steps_s: float, rate: float) -> float:
    """Seconds the live error estimate may take in a tick whose steps took ``steps_s`` at
    ``rate`` Hz (``ESTIMATE_ROOM``; unbounded without a rate)."""
    return ESTIMATE_ROOM / rate - steps_s if rate > 0.0 else math.inf


class ErrorEstimateSchedule:
    """The live error estimate of a running simulation, one every 1 / rate s at most.

    Each estimate (``sm_ros.error_estimate.ErrorEstimate``) steps two copies of the world
    over a 0.5 s window (3 n world steps: n of h, 2 n of h/2) within a budget: every tick
    earns ``budget`` x ``substeps`` units of credit and the estimate does the pieces of
    work the credit covers: one world step of one copy (one unit) or the making of the
    second copy (``ErrorEstimate.COPY_UNITS``, about what a copy costs in steps). A tick
    thus adds at most max(ceil(``budget`` x ``substeps``), ``COPY_UNITS``) units; the unused
    credit carries over. The first copy is made when the estimate starts (a snapshot of
    the live world) on credit, which the next ticks pay back; the next estimate (after a
    finished or a dropped one) starts only once nothing is owed. With a small budget an
    estimate takes many ticks and comes less often than ``rate`` asks; ``age`` says how
    old the state the last one describes is. The node's budget is the parameter
    ``error_estimate.budget``.

    ``result`` is the last finished estimate (None before the first), ``running`` the one
    in progress or None, ``units`` the units of work done in the last ``advance``. The
    copies of the last estimate are kept (while estimates are on) and the next estimate
    writes the world's state into them (``ErrorEstimate``'s ``spares``).
    """

    def __init__(self):
        """No estimate yet; the first starts at the first tick."""
        self.result: Optional[Dict[str, Any]] = None
        self.running: Optional[Any] = None
        self._next = -math.inf
        self._credit = 0.0
        self._started = -math.inf       # clock time the running estimate's copies were made
        self.result_started = None      # the same, of ``result`` (None before the first)
        self.units = 0
        self._spares = {}               # the last estimate's copies, reused by the next
        #: seconds the last copy of the world took (None before the first)
        self.copy_s: Optional[float] = None
        self._waited = None             # clock time a due start first had no room

    def drop(self) -> None:
        """Abandon the estimate in progress (the configuration changed); start anew."""
        if self.running is not None:
            self._spares = self.running.spares()
            self.running = None
            self._next = -math.inf

    def expected_s(self, budget: float, substeps: int, step_s: float) -> float:
        """About how long this tick's piece of the estimate would take: making a copy (a
        new estimate's first, or the second: as long as the last copy took, or
        ``COPY_GUESS_STEPS`` steps of ``step_s`` before one was made), or ``budget`` x
        ``substeps`` units at what a unit of the running estimate last cost
        (``ErrorEstimate.unit_s``; before that is known, ``step_s``: a unit is one step
        of a copy of the world)."""
        est = self.running
        if est is None or est.next_units == ErrorEstimate.COPY_UNITS:
            return self.copy_s if self.copy_s is not None else COPY_GUESS_STEPS * step_s
        units = budget * max(int(substeps), 1)
        return units * (est.unit_s if est.unit_s is not None else step_s)

    def age(self, now: float) -> Optional[float]:
        """Seconds since the copies of the last finished estimate were made, or None."""
        return None if self.result_started is None else now - self.result_started

    def advance(self, world, dt: float, substeps: int, rate: float,
                clock: Callable[[], float], budget: Optional[float] = None,
                room_s: float = math.inf, step_s: float = 0.0) -> float:
        """Advance the estimate by a tick of ``world``; start one when due (``rate`` > 0:
        estimates per second) with ``budget`` x ``substeps`` units of work per tick (None:
        ``substeps`` coarse steps a tick, 3 units each, so the copies keep pace with the
        simulation and cost 3x its steps while a window runs).  ``room_s``: the seconds
        this tick leaves the estimate (``estimate_room``); a piece of work expected to
        take longer (``expected_s``, with ``step_s`` the tick's time a step) waits:
        nothing is done or earned, and the estimate goes on at the next tick with room (a
        new one that waited ``ESTIMATE_FORCE_S`` for room for its copy starts anyway).
        While every body of ``world`` sleeps (``World.all_asleep``) the estimate is
        ``error_estimate.at_rest`` (nothing copied).

        Returns the seconds spent this tick: they count in ``tick_ms_max`` /
        ``tick_ms_mean`` but not as an overrun.
        """
        self.units = 0
        if rate <= 0.0 or (budget is not None and budget <= 0.0) or not world.bodies:
            self.running = None
            self._spares = {}                    # off: the copies' memory goes
            return 0.0
        spent = 0.0
        now = clock()
        if world.all_asleep and (self.running is not None or now >= self._next):
            # every body sleeps: copies of the world would stand still (error 0), so
            # nothing is copied or stepped; one in progress (copies of a world that still
            # moved, each step of them as dear as an awake world's) gives way to this
            if self.running is not None:
                self._spares = self.running.spares()
                self.running = None
            self._next = now + 1.0 / rate
            self.result = at_rest(dt, substeps)
            self.result_started = self._started = now
            return 0.0
        if budget is None:
            self._credit = 0.0
        # a new estimate starts only once the copies of the last are paid for (a dropped
        # one's too), so parameter changes every tick cannot copy the world every tick
        starting = self.running is None and now >= self._next and self._credit >= 0.0
        if (starting or self.running is not None) and \
                self.expected_s(budget or 0.0, substeps, step_s) > room_s:
            if not starting:
                return 0.0                       # no room this tick: nothing done or earned
            if self._waited is None:
                self._waited = now
            if now - self._waited < ESTIMATE_FORCE_S:
                return 0.0
        if starting:
            self._waited = None
            self._next = now + 1.0 / rate
            self._started = now
            self.running = ErrorEstimate(world, dt, substeps, staged=budget is not None,
                                         spares=self._spares)
            self._spares = {}
            spent = self.copy_s = self.running.cost_s
            self.units = self.running.units
            if budget is not None:
                self._credit -= float(self.running.units)
        est = self.running
        if est is not None and (est.dt != dt or est.source is not world):
            self._spares = est.spares()
            est = self.running = None            # the step or the scene changed: start anew
            self._next = now
        if budget is not None and (est is not None or self._credit < 0.0):
            self._credit += budget * max(int(substeps), 1)
        if est is not None:
            before = est.units
            if budget is None:
                spent += est.advance(substeps)
            else:
                spent += est.work(self._credit)
                self._credit -= est.units - before
            self.units += est.units - before
            if est.done:
                self._spares = est.spares()
                self.result = est.result
                self.result_started = self._started
                self.running = None
        return spent


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
