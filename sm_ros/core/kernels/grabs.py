"""Particles that follow targets (grabbed and pinned: positions set after the pass,
velocity = displacement / h, their clusters' sums taken again) and the inertia tensor of
a body about its centre, for the turn limit."""

from numba import njit

from .jit import JIT


@njit(**JIT)
def gather_rows(src, idx, out):
    """out[p] = src[idx[p]] (used to remember kinematic particles' start positions)."""
    for p in range(idx.shape[0]):
        for j in range(3):
            out[p, j] = src[idx[p], j]


@njit(**JIT)
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
