"""Compiled kernels of the contact pass that are neither the pair list
(``contact_build.py``) nor the solve (``contact_solve.py``, ``contact_sweeps.py``):
the count of particles fast enough to tunnel, and the median neighbour distance of a
body's default contact radius.

Tunnelling: a pair is seen only where it is within 1.2 contact distances at the end of a
step, so particles approaching faster than about ``r / h`` (r = contact radius, h = step)
may cross a layer one particle thick between two steps; ``Contact.fast_particles`` counts
the particles moving faster than that.
"""

import numpy as np
from numba import njit

from .kernels.jit import JIT


@njit(**JIT)
def count_fast(V, R, B, act, h, fast):
    """fast[b] = particles of colliding body b moving more than their radius per step."""
    fast[:] = 0
    for i in range(V.shape[1]):
        b = B[i]
        if not act[b]:
            continue
        s2 = V[0, i] * V[0, i] + V[1, i] * V[1, i] + V[2, i] * V[2, i]
        lim = R[i] / h
        if s2 > lim * lim:
            fast[b] += 1


@njit(**JIT)
def median_nn_distance(x, step):
    """Median nearest-neighbour distance of the points x[::step] among all of x (N, 3)."""
    n = x.shape[0]
    ns = (n + step - 1) // step
    best = np.empty(ns)
    for a in range(ns):
        i = a * step
        b2 = np.inf
        for j in range(n):
            if j == i:
                continue
            dx = x[j, 0] - x[i, 0]
            dy = x[j, 1] - x[i, 1]
            dz = x[j, 2] - x[i, 2]
            d2 = dx * dx + dy * dy + dz * dz
            if d2 > 0.0 and d2 < b2:
                b2 = d2
        best[a] = b2
    best.sort()
    return np.sqrt(best[ns // 2])


@njit(**JIT)
def neighbour_directions(x, reach):
    """Per point of x (n, 3), the sum of the unit directions to its neighbours within
    ``reach`` (n, 3): a sweep along x over the points sorted by it."""
    n = x.shape[0]
    order = np.argsort(x[:, 0])
    acc = np.zeros((n, 3))
    r2 = reach * reach
    for a in range(n):
        i = order[a]
        for b in range(a + 1, n):
            j = order[b]
            dx = x[j, 0] - x[i, 0]
            if dx > reach:
                break
            dy = x[j, 1] - x[i, 1]
            dz = x[j, 2] - x[i, 2]
            d2 = dx * dx + dy * dy + dz * dz
            if d2 > r2 or not d2 > 0.0:
                continue
            d = np.sqrt(d2)
            acc[i, 0] += dx / d
            acc[i, 1] += dy / d
            acc[i, 2] += dz / d
            acc[j, 0] -= dx / d
            acc[j, 1] -= dy / d
            acc[j, 2] -= dz / d
    return acc
