"""The live error estimate: step doubling on the running world itself (no ROS).

From the state S the world takes a step of h and, from S again, two of h/2, and is put back
to S bit for bit (``sm_ros.core.snapshot``). The RMS difference, Richardson-scaled, is a
step's local error, and ``error_m`` that per second times ``HORIZON_S``: what the running
step adds up to over that time (doc/error_estimate.md)."""

import math
import time
from typing import Any, Dict, Optional

import numpy as np

from sm_ros.core.param_energy import motion
from sm_ros.core.snapshot import Snapshot

#: Order p in the Richardson factor 1 / (1 - 2^-p): the accuracy benchmark's for bodies
ORDER = 1.0         # under gravity, in flight and on the ground
#: Simulated time over which the local error rate is stated (s).
HORIZON_S = 2.0
#: The pieces of an estimate: steps of h from S, of h/2 from S, as many more from there.
PIECES = 3
#: Steps in each piece where a body is rigid-mode (one elsewhere).
PIECE_STEPS = 2


def step_difference(world, coarse, fine) -> np.ndarray:
    """Each particle's difference between h and h/2 over one step (N, 3) from the positions
    after each step of h (``coarse``) and each pair of h/2 (``fine``): the first, or for a
    rigid-mode body the rigid motion closest to the second (``param_energy.motion``), halved."""
    d, end = fine[0] - coarse[0], 0
    for body in world.bodies:
        run, end = slice(end, end + body.n), end + body.n
        if body.params.mode == 'rigid' and len(coarse) > 1:
            x, d2 = coarse[1][run], fine[1][run] - coarse[1][run]
            if np.isfinite(x).all() and np.isfinite(d2).all():
                centre, shift, turn, _ = motion(x, d2, body._m)
                d2 = shift + np.cross(turn, x - centre)
            d[run] = 0.5 * d2
    return d


def error_from(d, dt: float, order: float = ORDER, horizon: float = HORIZON_S) -> Dict[str, float]:
    """``local_m`` (a step's local error, Richardson-scaled), ``rate_m_s`` (per second) and
    ``error_m`` (over ``horizon`` s) from the particles' differences ``d`` between one step
    of ``dt`` and two of ``dt / 2``; inf where they are not finite."""
    d = np.asarray(d)
    rms = math.sqrt(float(np.einsum('ij,ij->', d, d)) / max(len(d), 1))
    local = rms / (1.0 - 2.0 ** -order) if math.isfinite(rms) else math.inf
    return {'local_m': local, 'rate_m_s': local / dt, 'error_m': local / dt * horizon}


def estimate(world, dt: float, snapshot: Optional[Snapshot] = None) -> Dict[str, Any]:
    """Step-double ``world`` from its state now, in one go, and leave it as it was."""
    (est := Estimate(world, dt, (snapshot or Snapshot(), Snapshot(), Snapshot()))).run(PIECES)
    return est.result


class Estimate:
    """One estimate in ``PIECES`` pieces (``run``): the first snapshot holds S, the second
    the half way H of the h/2 steps, the third the live state the ticks moved the world on
    to while later pieces run. ``result``: :func:`error_from`'s keys, ``cost_s``, ``steps``."""

    def __init__(self, world, dt: float, snapshots):
        t0 = time.perf_counter()
        self.world, self.dt = world, float(dt)
        self.start, self.half, self.live = snapshots
        self.start.save(world)
        rigid = any(body.params.mode == 'rigid' for body in world.bodies)
        self.piece_steps = PIECE_STEPS if rigid else 1
        self.runs, self.result = [], None
        self.cost_s = time.perf_counter() - t0

    def run(self, pieces: int) -> float:
        """Do up to ``pieces`` more pieces; return the seconds spent."""
        t0, world, done = time.perf_counter(), self.world, len(self.runs)
        todo = range(done, min(PIECES, done + max(int(pieces), 0)))
        if not todo:
            return 0.0
        if done:                                           # ticks moved the world on
            self.live.save(world)
        holds = 'live' if done else 'S'                    # what the world holds now
        for k in todo:
            if holds != 'SSH'[k]:                          # from S, S, then H
                (self.half if k == 2 else self.start).load(world)
            self.runs.append([])
            for _ in range(self.piece_steps):
                world.step(self.dt if k == 0 else 0.5 * self.dt)
                self.runs[-1].append(np.concatenate([b._x for b in world.bodies]))
            holds = 'CHF'[k]
        if holds == 'H':
            self.half.save(world)
        (self.live if done else self.start).load(world)
        self.cost_s += time.perf_counter() - t0
        if len(self.runs) == PIECES:
            coarse, half, fine = self.runs                 # the fine run's every second half
            self.result = error_from(step_difference(world, coarse, (half + fine)[1::2]),
                                     self.dt)
            self.result.update(cost_s=self.cost_s, steps=PIECES * self.piece_steps)
        return time.perf_counter() - t0


class LiveEstimate:
    """A running simulation's estimate: ``result`` (the last), ``age(now)``, ``piece_s``."""

    def __init__(self):
        self.result = self.result_at = self.running = self.piece_s = None
        self._due, self._deadline = -math.inf, math.inf
        self.snapshots = (Snapshot(), Snapshot(), Snapshot())

    def age(self, now: float) -> Optional[float]:
        """Seconds since the state of the last estimate, or None before the first."""
        return None if self.result_at is None else now - self.result_at

    def drop(self) -> None:
        """Abandon the estimate in progress (the configuration changed); start anew."""
        self.running, self._due = None, -math.inf

    def before_tick(self, world, dt: float, rate: float, now: float, room_s: float,
                    period: float, step_s: float) -> float:
        """Run what is due of an estimate before a tick; return the seconds spent.

        Due 1 / rate s after the state of the last, it runs as many pieces as fit in
        ``room_s`` (each ``piece_s``, or ``step_s`` before one was timed), and at least as
        many as leave one for each tick (``period`` s apart) still before the last estimate
        would be 2 / rate old. A world asleep estimates 0, with nothing saved or stepped."""
        if rate <= 0.0 or not world.bodies:
            self.__init__()                      # off: forgotten, the snapshots too
            return 0.0
        if self.result_at is not None and self._due > -math.inf:     # follows the rate
            self._due, self._deadline = (self.result_at + k / rate for k in (1.0, 2.0))
        est = self.running
        if est is not None and (est.world is not world or est.dt != float(dt)):
            est = self.running = None            # another world or step: start anew
        if est is None and now < self._due:
            return 0.0
        self._deadline = min(self._deadline, now + 1.0 / rate)
        later = max(math.ceil((self._deadline - now) / period - 1e-6) - 1, 0)  # ticks in time
        cost = self.piece_s or step_s
        fit = max(int(max(room_s, 0.0) // cost) if cost > 0.0 else 0,
                  PIECES - (len(est.runs) if est else 0) - later)
        if est is None and world.all_asleep:
            self._done(dict(local_m=0.0, rate_m_s=0.0, error_m=0.0, cost_s=0.0, steps=0), now)
        if est is None and (world.all_asleep or fit == 0):
            return 0.0
        t0 = time.perf_counter()
        if est is None:
            est = self.running = Estimate(world, float(dt), self.snapshots)
            est.started = now
        first = len(est.runs)
        self.piece_s = est.run(fit) / max(len(est.runs) - first, 1) if fit else self.piece_s
        if est.result is not None:
            self._done(est.result, est.started)
        return time.perf_counter() - t0

    def _done(self, result, at: float) -> None:
        self.result, self.result_at, self.running, self._due = result, at, None, at
