"""
A live estimate of the position error of the running configuration (step doubling; no ROS).

A user tuning ``dt``, ``substeps`` or ``clusters`` should see the error they pay for, not
only the time. :func:`estimate` copies the world twice and advances one copy ``2 n``
steps of h and the other ``4 n`` steps of h/2 (n covers at least one tick and
``WINDOW_S`` of simulated time). With the difference of the two after n and after 2 n
coarse steps, d1 and d2:

* the part that does not grow with time (a rigid body's in-step distortion, the sag of a
  resting body, which differs with the step) is ``offset = RMS(d1)``;
* the part that grows is ``rate = RMS(d2 - d1) / (n h)``: metres per simulated second;
* Richardson: the coarse solution's error is the difference / (1 - 2^-p) with p the
  measured order of the method (``ORDER`` = 1: the order the accuracy benchmark measures
  for bodies under gravity and on the ground; rigid spin converges at 2);
* the estimate is the error after ``HORIZON_S`` (2 s, the accuracy benchmark's horizon):
  ``(offset + rate * HORIZON_S) / (1 - 2^-p)`` (RMS over the particles, metres).

Measured against the accuracy scenes (``test/test_physics.py``, doc/benchmarks.md): it
tracks the true error of free and pinned bodies (rigid spin, ballistic, cantilever) within
a factor of 3 and overestimates bodies sliding on the ground or squeezed (contact and
friction forget part of the error the extrapolation counts): an upper estimate there.
"""

import copy
import math
import time
from typing import Any, Dict

import numpy as np

#: Order p of the method used for the Richardson factor 1 / (1 - 2^-p).
ORDER = 1.0
#: Simulated time over which the estimate is stated (s).
HORIZON_S = 2.0
#: Least simulated time of the window n h (s): shorter windows take a rigid body's
#: in-step distortion for growth.
WINDOW_S = 0.05


def window_steps(dt: float, substeps: int = 1) -> int:
    """Coarse steps n of the window: at least one tick and ``WINDOW_S``."""
    return max(int(substeps), int(math.ceil(WINDOW_S / dt - 1e-9)))


def _positions(world) -> np.ndarray:
    return np.concatenate([np.asarray(b.x) for b in world.bodies]) if world.bodies else \
        np.zeros((0, 3))


def estimate(world, dt: float, substeps: int = 1, order: float = ORDER,
             horizon: float = HORIZON_S) -> Dict[str, Any]:
    """Step-double copies of ``world`` (left untouched); return the error estimate.

    Keys: ``error_m`` (estimated RMS position error after ``horizon`` s), ``offset_m``,
    ``rate_m_per_s``, ``steps`` (n), ``cost_s`` (wall time of the estimate).
    """
    t0 = time.perf_counter()
    n = window_steps(dt, substeps)
    coarse = copy.deepcopy(world)
    fine = copy.deepcopy(world)
    diffs = []
    for j in range(2 * n):
        coarse.step(dt)
        fine.step(0.5 * dt)
        fine.step(0.5 * dt)
        if j + 1 in (n, 2 * n):
            diffs.append(_positions(coarse) - _positions(fine))
    npts = max(len(diffs[0]), 1)
    r1, r2 = (math.sqrt(float((d * d).sum()) / npts) for d in diffs)
    offset = max(r1, r2)
    rate = max(0.0, r2 - r1) / (n * dt)
    factor = 1.0 / (1.0 - 2.0 ** -order)
    err = factor * (offset + rate * horizon)
    if not math.isfinite(err):
        err = float('inf')
    return {'error_m': err, 'offset_m': factor * offset, 'rate_m_per_s': factor * rate,
            'steps': n, 'cost_s': time.perf_counter() - t0}
