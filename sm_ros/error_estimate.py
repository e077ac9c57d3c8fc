"""
A live estimate of the position error of the running configuration (step doubling; no ROS).

A user tuning ``dt``, ``substeps`` or ``clusters`` should see the error they pay for, not
only the time. An :class:`ErrorEstimate` copies the world twice and runs two short
trajectories side by side over a window of ``WINDOW_S`` simulated seconds: one copy
``n`` steps of h, the other ``2 n`` steps of h/2. After every coarse step k it records
the RMS (over the particles) distance d_k of the two copies. The estimate compares the
trajectories, not one local step, so whatever the dynamics do to a local error (grow it
linearly in a free flight, swing it in an oscillation, forget it on the ground, where
contact and friction pull both copies to the same rest) is measured, not assumed:

* D(t) = the largest d over the window up to t (the accuracy benchmark's error is a
  maximum over time);
* the measured growth exponent q = log2(D(W) / D(W/2)), clamped to [0, 1]: 1 for an
  error that grows linearly (ballistic flight, phase error of a spin), near 0 for one
  that contact keeps from growing;
* the error after ``HORIZON_S`` (2 s, the accuracy benchmark's horizon) is
  ``D(W) (HORIZON_S / W)^q``, Richardson-scaled by 1 / (1 - 2^-p) with p = ``ORDER`` = 1,
  the order the accuracy benchmark measures for bodies under gravity and on the ground
  (a rigid spin converges at 2: the estimate reads 0.9x its true error there).

Measured against the five scenes of ``sm_ros.bench.accuracy`` (``test/test_physics.py``;
mean of 4 estimates along 2 s, 125 particles): estimate / true error at 1/120 and 1/240 s:
rigid_spin 0.90, 0.91; ballistic 1.00, 1.00; soft_drop 1.50, 1.53; cantilever 0.78, 1.00;
plastic_press 2.03, 2.51. A single estimate can be 0.2-5x (an oscillation's phase).

Cost: the copies take 3 n world steps (n = ceil(W / h): n of h, 2 n of h/2) and two copies
of the world (each about 3 steps' worth). The node spreads them over its ticks
(:meth:`ErrorEstimate.work`, driven by ``sm_ros.stats.ErrorEstimateSchedule``) in units of
one world step of one copy, within a budget: each tick may add ``error_estimate.budget`` x
``substeps`` world steps of the copies (default 0.25: at 2 substeps one more step every
other tick), so the copies cost a bounded share of the simulation whatever the scene
(before the budget they ran ``substeps`` coarse steps a tick: 3x the tick's own steps,
which tripled the ticks of the 384-body paper scene). An estimate then takes
(3 n + 6) / (budget x substeps) ticks: 372 ticks, 6.2 s at 60 Hz with the default dt,
substeps and budget, longer where ticks are late; ``error_estimate.rate`` is the most
often one starts, and /diagnostics gives the age of the last (``error_estimate_age_s``).
Its value does not depend on the pace: the copies are independent of the live world once
made, and the same copies and steps give the same estimate.

The first estimate's copies are deep copies that keep the read-only flags of the world's
arrays (:func:`copy_world`): a plain ``copy.deepcopy`` made them writeable, which Numba
types differently, so the first step of every copy loaded a second set of compiled kernels
(2.4 s on the 384-body paper scene). Later estimates write the world's state into the last
estimate's copies instead (``sm_ros.world_sync.Twin``; the schedule keeps them): on
``paper_384`` a deep copy took 0.2 s and the copy's first step another 0.14 s to re-pack
its bodies, a sync about 16 ms (``world_sync``'s plan replayed in bulk) and no
re-packing; a copy of another make (bodies added or
rebuilt, buffers grown) is refused and deep-copied anew. The first copy is made when the
estimate starts (a snapshot of the live world); the second is made from the first, still
unstepped, as the first piece of work, so no tick pays for both.
"""

import copy
import math
import time
from typing import Any, Dict, Optional

import numpy as np

#: Order p of the method used for the Richardson factor 1 / (1 - 2^-p).
ORDER = 1.0
#: Simulated time over which the estimate is stated (s).
HORIZON_S = 2.0
#: Simulated time of the window W over which the two trajectories are compared (s).
#: Shorter windows take a rigid body's in-step distortion for the whole error (0.1 s reads
#: 0.3x the rigid spin's error) and catch a body in flight before it lands (0.25 s reads
#: 3.3x soft_drop's).
WINDOW_S = 0.5


def window_steps(dt: float, substeps: int = 1, window: float = WINDOW_S) -> int:
    """Coarse steps n of the window: at least one tick and ``window`` seconds."""
    return max(int(substeps), int(math.ceil(window / dt - 1e-9)))


def _positions(world) -> np.ndarray:
    return np.concatenate([np.asarray(b.x) for b in world.bodies]) if world.bodies else \
        np.zeros((0, 3))


def _rms(d: np.ndarray) -> float:
    return math.sqrt(float((d * d).sum()) / max(len(d), 1))


def extrapolate(d, window: float, order: float = ORDER, horizon: float = HORIZON_S
                ) -> Dict[str, float]:
    """The error estimate from the RMS differences ``d`` after each coarse step.

    Returns ``error_m`` (RMS position error after ``horizon`` s), ``window_m`` (the largest
    difference over the window, Richardson-scaled) and ``growth`` (the exponent q).
    """
    d = np.asarray(d, dtype=float)
    if d.size == 0:
        return {'error_m': 0.0, 'window_m': 0.0, 'growth': 0.0}
    if not np.all(d < np.finfo(np.float64).max):       # inf or nan: no estimate to give
        return {'error_m': float('inf'), 'window_m': float('inf'), 'growth': 1.0}
    peak = np.maximum.accumulate(d)
    late, early = float(peak[-1]), float(peak[max(len(d) // 2 - 1, 0)])
    q = 1.0 if early <= 0.0 < late else (
        0.0 if late <= 0.0 else min(1.0, max(0.0, math.log2(late / early))))
    factor = 1.0 / (1.0 - 2.0 ** -order)
    scale = max(horizon / window, 1.0) ** q
    return {'error_m': factor * late * scale, 'window_m': factor * late, 'growth': q}


def at_rest(dt: float, substeps: int = 1, order: float = ORDER, horizon: float = HORIZON_S,
            window: float = WINDOW_S) -> Dict[str, Any]:
    """The estimate of a world whose bodies all sleep (``World.all_asleep``): a step
    of such a world does nothing, so both copies would stand still and every difference
    be 0; the result of that window, with nothing copied or stepped (``units`` and
    ``cost_s`` 0)."""
    n = window_steps(dt, substeps, window)
    res = extrapolate([0.0] * n, n * dt, order, horizon)
    res.update(steps=n, units=0, cost_s=0.0)
    return res


def copy_world(world):
    """Return a deep copy of ``world`` whose arrays have the types of the world's.

    ``copy.deepcopy`` makes arrays writeable; Numba types a read-only array differently,
    so a copy's first step would load (or compile) a second specialisation of every kernel
    that reads one. A body keeps its own (the masses, the rest shape: ``Body.__setstate__``);
    this makes any other array read-only where the world's is (found through the deep
    copy's memo, which holds every object copied).
    """
    memo: Dict[int, Any] = {}
    twin = copy.deepcopy(world, memo)
    for original in memo.get(id(memo), ()):
        if isinstance(original, np.ndarray) and not original.flags.writeable:
            dup = memo.get(id(original))
            if isinstance(dup, np.ndarray) and dup is not original:
                dup.flags.writeable = False
    return twin


class ErrorEstimate:
    """Two copies of a world stepped at h and h/2 over a window, in slices.

    ``advance(k)`` runs at most k more coarse steps (and 2 k fine ones); ``work(units)``
    runs pieces of work: a world step of one copy (one unit) or, when ``staged``, the
    making of the fine copy from the coarse one, still unstepped (``COPY_UNITS``); the
    first piece. Once ``done``, ``result`` holds the estimate (:func:`extrapolate`'s keys
    plus ``steps``, n, ``cost_s``, the wall time of all slices, and ``units``, the units
    of work it took). ``units`` counts the units done so far.
    """

    #: Units of work the making of one copy counts as: a deep copy costs about three world
    #: steps (measured, copy against one step: paper_384 87 ms / 30 ms, many 11 / 4 ms).
    COPY_UNITS = 3

    def __init__(self, world, dt: float, substeps: int = 1, order: float = ORDER,
                 horizon: float = HORIZON_S, window: float = WINDOW_S, staged: bool = False,
                 spares: Optional[Dict[str, Any]] = None):
        t0 = time.perf_counter()
        self.dt, self.order, self.horizon = float(dt), order, horizon
        self.source = world                                  # the world it estimates
        self.n = window_steps(dt, substeps, window)
        #: the copies (``world_sync.Twin``) of the last estimate, to write this one's into
        self._spares = dict(spares or {})
        self._twins: Dict[str, Any] = {}
        self.coarse = self._copy('coarse', world)
        self.fine = None if staged else self._copy('fine', self.coarse)
        self.units = self.COPY_UNITS * (1 if staged else 2)
        self.d = []
        self._phase = 0         # the next unit: 0 coarse step, 1 and 2 the fine steps
        self.result: Optional[Dict[str, Any]] = None
        #: seconds a unit took in the last piece of work that did some (None before one)
        self.unit_s: Optional[float] = None
        self.cost_s = time.perf_counter() - t0

    def _copy(self, role: str, world):
        """A copy of ``world``: the last estimate's copy in this role with ``world``'s state
        written into it (``world_sync``: no allocation, its packed buffers and records
        kept), or a new deep copy where that is refused or there is none."""
        from sm_ros.world_sync import Twin
        twin = self._spares.pop(role, None)
        if twin is None or not twin.sync(world):
            twin = Twin(copy_world(world))
        self._twins[role] = twin
        return twin.world

    def spares(self) -> Dict[str, Any]:
        """The copies this estimate made (``world_sync.Twin`` by role), for the next one
        (``spares=``); their state is overwritten there."""
        return dict(self._twins)

    @property
    def done(self) -> bool:
        """Whether the window is complete (``result`` set)."""
        return self.result is not None

    @property
    def next_units(self) -> int:
        """The units the next piece of work counts (0 once done)."""
        if self.result is not None:
            return 0
        return self.COPY_UNITS if self.fine is None else 1

    def _unit(self) -> None:
        """Do the next unit: make the fine copy, or one step of one copy."""
        h = self.dt
        if self.fine is None:
            self.fine = self._copy('fine', self.coarse)
            self.units += self.COPY_UNITS
            return
        if self._phase == 0:
            self.coarse.step(h)
        else:
            self.fine.step(0.5 * h)
        self.units += 1
        self._phase = (self._phase + 1) % 3
        if self._phase == 0:
            self.d.append(_rms(_positions(self.coarse) - _positions(self.fine)))
            if len(self.d) >= self.n:
                self._finish()

    def _finish(self) -> None:
        self.coarse = self.fine = self.source = None    # the copies live on in spares()
        res = extrapolate(self.d, self.n * self.dt, self.order, self.horizon)
        res['steps'] = self.n
        res['units'] = self.units
        self.result = res

    def _timed(self, more) -> float:
        t0 = time.perf_counter()
        u0 = self.units
        while self.result is None and more():
            self._unit()
        spent = time.perf_counter() - t0
        self.cost_s += spent
        if self.units > u0:
            self.unit_s = spent / (self.units - u0)
        if self.result is not None:
            self.result['cost_s'] = self.cost_s
        return spent

    def advance(self, steps: int) -> float:
        """Run up to ``steps`` coarse steps of the window; return the seconds it took."""
        goal = len(self.d) + int(steps)
        return self._timed(lambda: len(self.d) < goal)

    def work(self, units: float) -> float:
        """Do the next pieces of work while they fit in ``units`` (a piece is done only
        when all of its units fit); return the seconds it took."""
        left = [float(units)]

        def more():
            cost = self.next_units
            if cost > left[0]:
                return False
            left[0] -= cost
            return True
        return self._timed(more)


def estimate(world, dt: float, substeps: int = 1, order: float = ORDER,
             horizon: float = HORIZON_S, window: float = WINDOW_S) -> Dict[str, Any]:
    """Step-double copies of ``world`` (left untouched) over a whole window at once.

    Keys: ``error_m`` (estimated RMS position error after ``horizon`` s), ``window_m``,
    ``growth``, ``steps`` (n), ``cost_s`` (wall time of the estimate).
    """
    est = ErrorEstimate(world, dt, substeps, order, horizon, window)
    est.advance(est.n)
    return est.result
