"""Particles that follow targets (grabbed and pinned: positions set after the pass,
velocity = displacement / h, their clusters' sums taken again) and what a body's force and
torque do to a step (the torque through the inertia tensor about the body's centre)."""

import numpy as np
from numba import njit

from .jit import JIT_NO_REFCOUNT
from .linalg import pinv_sym


@njit(**JIT_NO_REFCOUNT)
def gather_rows(src, idx, out):
    """out[p] = src[idx[p]] (used to remember kinematic particles' start positions)."""
    for p in range(idx.shape[0]):
        for j in range(3):
            out[p, j] = src[idx[p], j]


@njit(**JIT_NO_REFCOUNT)
def inertia(x, mass, com, out):
    """Inertia tensor about ``com``: sum m (|r|^2 I - r r^T)."""
    for i in range(3):
        for j in range(3):
            out[i, j] = 0.0
    for i in range(x.shape[0]):
        r0 = x[i, 0] - com[0]
        r1 = x[i, 1] - com[1]
        r2 = x[i, 2] - com[2]
        w = mass[i]
        rr = r0 * r0 + r1 * r1 + r2 * r2
        out[0, 0] += w * (rr - r0 * r0)
        out[1, 1] += w * (rr - r1 * r1)
        out[2, 2] += w * (rr - r2 * r2)
        out[0, 1] -= w * r0 * r1
        out[0, 2] -= w * r0 * r2
        out[1, 2] -= w * r1 * r2
    out[1, 0] = out[0, 1]
    out[2, 0] = out[0, 2]
    out[2, 1] = out[1, 2]


@njit(**JIT_NO_REFCOUNT)
def wrench_accelerations(wrench, gravity, clusters, particles, turn, out, scratch):
    """The step's acceleration ``out[0]`` (the force over the mass ``wrench[0]``, plus
    gravity) and angular acceleration ``out[1]`` about the centre of mass ``out[2]`` (the
    torque ``wrench[1]`` through the inverse inertia; zero without a torque), at most
    max_turn / h of spin added in one step (``turn`` = (h, max_turn); beyond that the step
    cannot represent the turn).  ``clusters`` = (wsum, ref): the centre of mass from the
    clusters' masses and centres; ``particles`` = (x, mass); ``scratch`` = (inertia,
    its inverse, two 3 x 3).  Returns 1 where the spin was capped, else 0."""
    facc, torque = wrench
    acc, ang, com = out
    for i in range(3):
        acc[i] = facc[i] + gravity[i]
        ang[i] = 0.0
    if torque[0] == 0.0 and torque[1] == 0.0 and torque[2] == 0.0:
        return 0
    wsum, ref = clusters
    total = 0.0
    for i in range(3):
        com[i] = 0.0
    for k in range(wsum.shape[0]):
        total += wsum[k]
        for i in range(3):
            com[i] += wsum[k] * ref[k, i]
    for i in range(3):
        com[i] /= total
    tensor, tensor_inv, wa, wv = scratch
    inertia(particles[0], particles[1], com, tensor)
    pinv_sym(mat=tensor, out=tensor_inv, wa=wa, wv=wv, rcond=1e-12)
    for i in range(3):
        ang[i] = (tensor_inv[i, 0] * torque[0] + tensor_inv[i, 1] * torque[1]
                  + tensor_inv[i, 2] * torque[2])
    h, max_turn = turn
    a_norm = np.sqrt(ang[0] * ang[0] + ang[1] * ang[1] + ang[2] * ang[2])
    if max_turn > 0.0 and a_norm * h * h > max_turn:
        for i in range(3):
            ang[i] *= max_turn / (a_norm * h * h)
        return 1
    return 0
