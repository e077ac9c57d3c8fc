"""The live error estimate: step doubling on the running world itself (no ROS).

From the world's state S the estimate takes one step of h (the coarse answer C) and two of
h/2 (the fine answer F) with the world's own kernels, and puts the world back to S bit for
bit (``sm_ros.core.snapshot``) before the tick steps it.  With d = RMS over the particles
of |C - F| and the method's order p = ``ORDER`` (1: the accuracy benchmark measures 1 for
bodies under gravity, in flight and on the ground), Richardson's step doubling gives the
local error of the step, d / (1 - 2^-p); divided by h it is the local error per second of
simulated time, and ``error_m`` is that rate times ``HORIZON_S``: the RMS position error
the running dt would accumulate over 2 s of simulated time if every step's local error
added up (doc/error_estimate.md says where that holds and where it does not).

In the node (:class:`LiveEstimate`) an estimate starts every 1 / ``error_estimate.rate``
s.  Its three steps are pieces done before a tick's own steps, as many as fit in what the
last tick left of the period; a piece that does not fit waits, but an estimate still
running when the next is due does its remaining pieces in that tick, so the last estimate
is never older than 2 / rate.  While every body sleeps the estimate is 0 and nothing is
copied or stepped (a step of such a world moves nothing).
"""

import math
import time
from typing import Any, Dict, Optional

import numpy as np

from sm_ros.core.snapshot import Snapshot

#: Order p of the method used for the Richardson factor 1 / (1 - 2^-p).
ORDER = 1.0
#: Simulated time over which the local error rate is stated (s).
HORIZON_S = 2.0
#: The pieces of an estimate: one step of h, then two of h/2.
PIECES = 3


def positions(world) -> np.ndarray:
    """Every particle's position, body after body (N, 3)."""
    bodies = world.bodies
    return np.concatenate([b.x for b in bodies]) if bodies else np.zeros((0, 3))


def error_from(coarse: np.ndarray, fine: np.ndarray, dt: float, order: float = ORDER,
               horizon: float = HORIZON_S) -> Dict[str, float]:
    """The estimate from the positions after one step of ``dt`` and two of ``dt / 2``.

    Keys: ``local_m`` (the step's local error, Richardson-scaled), ``rate_m_s`` (per second
    of simulated time) and ``error_m`` (accumulated over ``horizon`` s); inf where the
    positions are not finite.
    """
    d = fine - coarse
    rms = math.sqrt(float(np.einsum('ij,ij->', d, d)) / max(len(d), 1))
    if not math.isfinite(rms):
        return {'local_m': math.inf, 'rate_m_s': math.inf, 'error_m': math.inf}
    local = rms / (1.0 - 2.0 ** -order)
    return {'local_m': local, 'rate_m_s': local / dt, 'error_m': local / dt * horizon}


def at_rest() -> Dict[str, Any]:
    """The estimate of a world whose bodies all sleep: no step moves it, so 0."""
    return {'local_m': 0.0, 'rate_m_s': 0.0, 'error_m': 0.0, 'cost_s': 0.0, 'steps': 0}


def estimate(world, dt: float, snapshot: Optional[Snapshot] = None) -> Dict[str, Any]:
    """Step-double ``world`` from its state now and leave it as it was (in one go)."""
    est = Estimate(world, dt, snapshot or Snapshot(), Snapshot())
    est.run(PIECES)
    return est.result


class Estimate:
    """One estimate of ``world`` at the step ``dt``, in ``PIECES`` pieces (``run``).

    The start state S is saved into ``start`` when made.  ``run(k)`` does the next k
    pieces with as few copies as it can: the world still at S (no tick since), one step
    of h, S back, two of h/2, S back; after a tick it puts the live state aside (into
    ``live``) first and back last.  Between two runs the fine trajectory's state waits in
    ``start``.  ``result`` is set once done (:func:`error_from`'s keys, ``cost_s`` the wall
    time of the saves and pieces, ``steps``).
    """

    def __init__(self, world, dt: float, start: Snapshot, live: Snapshot):
        t0 = time.perf_counter()
        self.world, self.dt = world, float(dt)
        self.start, self.live = start, live
        start.save(world)
        self.done_pieces = 0
        self.coarse: Optional[np.ndarray] = None
        self.result: Optional[Dict[str, Any]] = None
        self.touched = False            # a tick stepped the world since S was saved
        self.cost_s = time.perf_counter() - t0

    @property
    def done(self) -> bool:
        """Whether all pieces are done (``result`` set)."""
        return self.result is not None

    def run(self, pieces: int) -> float:
        """Do up to ``pieces`` more pieces; return the seconds it took."""
        t0 = time.perf_counter()
        world, first = self.world, self.done_pieces
        end = min(PIECES, first + max(int(pieces), 0))
        if end == first:
            return 0.0
        # where S will not be in ``start`` at the end, the live state waits in ``live``
        aside = self.touched or end == 2 or first == 2
        if aside:
            self.live.save(world)
        at = 'live' if self.touched else 'start'        # what the world holds now
        for k in range(first, end):
            if at != ('half' if k == 2 else 'start'):
                self.start.load(world)
            world.step(self.dt if k == 0 else 0.5 * self.dt)
            at = 'coarse' if k == 0 else ('half' if k == 1 else 'fine')
            if k == 0:
                self.coarse = positions(world)
            elif k == 2:
                self.result = dict(error_from(self.coarse, positions(world), self.dt),
                                   steps=PIECES)
        if end == 2:
            self.start.save(world)      # the fine trajectory's half way, for the last piece
        (self.live if aside else self.start).load(world)
        self.done_pieces = end
        spent = time.perf_counter() - t0
        self.cost_s += spent
        if self.result is not None:
            self.result['cost_s'] = self.cost_s
        return spent


class LiveEstimate:
    """The estimate of a running simulation, one every 1 / rate s (``before_tick``).

    ``result`` is the last finished estimate (None before the first), ``age(now)`` how old
    the state it describes is.  ``piece_s`` is what a piece last cost (its step and
    copies), against which the room a tick leaves is measured.
    """

    def __init__(self):
        self.result: Optional[Dict[str, Any]] = None
        self.result_at: Optional[float] = None
        self.running: Optional[Estimate] = None
        self.piece_s: Optional[float] = None
        self._started = 0.0
        self._next = -math.inf
        self._snaps = (Snapshot(), Snapshot())

    def age(self, now: float) -> Optional[float]:
        """Seconds since the state of the last estimate, or None before the first."""
        return None if self.result_at is None else now - self.result_at

    def drop(self) -> None:
        """Abandon the estimate in progress (the configuration changed); start anew."""
        self.running = None
        self._next = -math.inf

    def after_tick(self) -> None:
        """The tick stepped the world: the running estimate's S is no longer the world's."""
        if self.running is not None:
            self.running.touched = True

    def before_tick(self, world, dt: float, rate: float, now: float, room_s: float,
                    period: float, step_s: float) -> float:
        """Start an estimate when due and do the pieces that fit in ``room_s`` seconds
        (each as long as ``piece_s``, or ``step_s`` before one was timed: none before a
        step was), all that are
        left where the next estimate is due before the next tick (``period`` s away).
        Returns the seconds spent."""
        if rate <= 0.0 or not world.bodies:
            self.running, self.result, self.result_at = None, None, None
            return 0.0
        est = self.running
        if est is not None and (est.world is not world or est.dt != float(dt)):
            est = self.running = None            # another world or step: start anew
        spent = 0.0
        due = now + period >= self._next
        if due and est is not None:              # finish it before the next one is due
            spent += est.run(PIECES)
        if est is not None and est.done:
            self.result, self.result_at, est = est.result, self._started, None
            self.running = None
        if now >= self._next:
            nxt = self._next + 1.0 / rate       # on the grid, unless a whole period late
            self._next = nxt if nxt > now else now + 1.0 / rate
            self._started = now
            if world.all_asleep:                 # no step moves it: 0, nothing copied
                self.result, self.result_at = at_rest(), now
                return spent
            t0 = time.perf_counter()
            est = self.running = Estimate(world, float(dt), *self._snaps)
            spent += time.perf_counter() - t0
        if est is None:
            return spent
        cost = self.piece_s if self.piece_s is not None else step_s
        fit = int(max(room_s - spent, 0.0) // cost) if cost > 0.0 else 0
        if fit > 0:
            first = est.done_pieces
            took = est.run(fit)
            spent += took
            self.piece_s = took / max(est.done_pieces - first, 1)
        if est.done:
            self.result, self.result_at, self.running = est.result, self._started, None
        return spent
