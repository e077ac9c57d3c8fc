"""The live error estimate: step doubling on the running world itself (no ROS).

From the state S the world takes one step of h and, from S again, two of h/2, and is put
back to S bit for bit (``sm_ros.core.snapshot``).  The RMS difference, Richardson-scaled
with order ``ORDER``, is a step's local error; a rigid-mode body counts the rigid motion of
its difference after two steps, halved (its shape match removes the rest before it adds
up).  ``error_m`` is the local error per second times ``HORIZON_S`` (doc/error_estimate.md)."""

import math
import time
from typing import Any, Dict, Optional

import numpy as np

from sm_ros.core.snapshot import Snapshot

#: Order p in the Richardson factor 1 / (1 - 2^-p): the accuracy benchmark's for bodies
ORDER = 1.0         # under gravity, in flight and on the ground
#: Simulated time over which the local error rate is stated (s).
HORIZON_S = 2.0
#: The pieces of an estimate: steps of h, then of h/2, then as many more of h/2.
PIECES = 3
#: Steps in each piece where a body is rigid-mode (one elsewhere).
PIECE_STEPS = 2


def positions(world) -> np.ndarray:
    """Every particle's position (N, 3), body after body, each in its storage order."""
    return np.concatenate([b._x for b in world.bodies]) if world.bodies else np.zeros((0, 3))


def rigid_part(x, d, starts) -> np.ndarray:
    """The rigid motion (translation and small turn about the centroid) closest to the
    displacements ``d`` of the points ``x`` (N, 3), per run of points from each of ``starts``."""
    count = np.diff(np.append(starts, len(x)))[:, None]
    run = np.repeat(np.arange(len(starts)), count[:, 0])
    centre, shift = np.add.reduceat(x, starts) / count, np.add.reduceat(d, starts) / count
    r, q = x - centre[run], d - shift[run]
    spread = np.add.reduceat(np.einsum('ij,ik->ijk', r, r), starts)
    inertia = np.trace(spread, axis1=1, axis2=2)[:, None, None] * np.eye(3) - spread
    torque = np.add.reduceat(np.cross(r, q), starts)
    turn = np.einsum('bij,bj->bi', np.linalg.pinv(inertia), torque)
    return shift[run] + np.cross(turn[run], r)


def step_difference(world, coarse, fine) -> np.ndarray:
    """Each particle's difference between h and h/2 over one step (N, 3), from the
    positions after each step of h (``coarse``) and each pair of h/2 (``fine``): the
    first, or for a rigid-mode body the rigid part of the second, halved."""
    d = fine[0] - coarse[0]
    rigid = np.array([b.params.mode == 'rigid' for b in world.bodies], dtype=bool)
    if len(coarse) > 1 and rigid.any():
        sizes = np.array([b.n for b in world.bodies], dtype=np.int64)
        mask = np.repeat(rigid, sizes)
        starts = np.concatenate(([0], np.cumsum(sizes[rigid])[:-1]))
        x, d2 = coarse[1][mask], fine[1][mask] - coarse[1][mask]
        finite = np.isfinite(x).all() and np.isfinite(d2).all()
        d[mask] = 0.5 * rigid_part(x, d2, starts) if finite else d2
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
    """One estimate in ``PIECES`` pieces (``run``): a step of h from the state S, then two
    of h/2 from S through the half way H.  S waits in the first snapshot, H in the second
    and, where ticks stepped the world between pieces (``touched``), the live state in the
    third.  ``result``: :func:`error_from`'s keys, ``cost_s`` and ``steps``."""

    def __init__(self, world, dt: float, snapshots):
        t0 = time.perf_counter()
        self.world, self.dt = world, float(dt)
        self.start, self.half, self.live = snapshots
        self.start.save(world)
        rigid = any(body.params.mode == 'rigid' for body in world.bodies)
        self.piece_steps = PIECE_STEPS if rigid else 1
        self.runs, self.touched, self.result = [], False, None
        self.cost_s = time.perf_counter() - t0

    @property
    def done_pieces(self) -> int:
        """The pieces run so far."""
        return len(self.runs)

    def run(self, pieces: int) -> float:
        """Do up to ``pieces`` more pieces; return the seconds spent."""
        t0, world = time.perf_counter(), self.world
        todo = range(len(self.runs), min(PIECES, len(self.runs) + max(int(pieces), 0)))
        if not todo:
            return 0.0
        if self.touched:
            self.live.save(world)
        holds = 'live' if self.touched else 'S'            # what the world holds now
        for k in todo:
            if holds != 'SSH'[k]:                          # from S, S, then H
                (self.half if k == 2 else self.start).load(world)
            after = []
            for _ in range(self.piece_steps):
                world.step(self.dt if k == 0 else 0.5 * self.dt)
                after.append(positions(world))
            self.runs.append(after)
            holds = 'CHF'[k]
        if holds == 'H':
            self.half.save(world)
        (self.live if self.touched else self.start).load(world)
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
        self._started, self._due, self._deadline = 0.0, -math.inf, math.inf
        self._snaps = (Snapshot(), Snapshot(), Snapshot())

    def snapshot_bytes(self) -> int:
        """Bytes of state a save copies (the largest snapshot)."""
        return max(snap.nbytes for snap in self._snaps)

    def age(self, now: float) -> Optional[float]:
        """Seconds since the state of the last estimate, or None before the first."""
        return None if self.result_at is None else now - self.result_at

    def drop(self) -> None:
        """Abandon the estimate in progress (the configuration changed); start anew."""
        self.running, self._due = None, -math.inf

    def after_tick(self) -> None:
        """The tick stepped the world: it no longer holds the running estimate's S."""
        if self.running is not None:
            self.running.touched = True

    def before_tick(self, world, dt: float, rate: float, now: float, room_s: float,
                    period: float, step_s: float) -> float:
        """Run what is due of an estimate before a tick; return the seconds spent.

        Due 1 / rate s after the state of the last, it runs as many pieces as fit in
        ``room_s`` (each ``piece_s``, or ``step_s`` before one was timed), and at least as
        many as leave one for each tick (``period`` s apart) still before the last estimate
        would be 2 / rate old.  A world asleep estimates 0, with nothing saved or stepped."""
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
                  PIECES - (est.done_pieces if est else 0) - later)
        if est is None and world.all_asleep:
            self._done({'local_m': 0.0, 'rate_m_s': 0.0, 'error_m': 0.0, 'cost_s': 0.0,
                        'steps': 0}, now)
        if est is None and (world.all_asleep or fit == 0):
            return 0.0
        t0 = time.perf_counter()
        if est is None:
            est = self.running = Estimate(world, float(dt), self._snaps)
            self._started = now
        first = est.done_pieces
        self.piece_s = est.run(fit) / max(est.done_pieces - first, 1) if fit else self.piece_s
        if est.result is not None:
            self._done(est.result, self._started)
        return time.perf_counter() - t0

    def _done(self, result, at: float) -> None:
        self.result, self.result_at, self.running, self._due = result, at, None, at
