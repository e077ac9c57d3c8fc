"""Particles that follow targets (grabbed and pinned: positions set after the pass,
velocity = displacement / h, their clusters' sums taken again) and the inertia tensor of
a body about its centre, for the turn limit."""

from numba import njit

from .goals import _qhat
from .integrate import _acc_lin, _acc_quad
from .jit import JIT
from .limits import _span


@njit(**JIT)
def gather_rows(src, idx, out):
    """out[p] = src[idx[p]] (used to remember kinematic particles' start positions)."""
    for p in range(idx.shape[0]):
        for j in range(3):
            out[p, j] = src[idx[p], j]


@njit(**JIT)
def apply_kinematic(quad, particles, rest, part, targets, h):
    """Kinematic particles land exactly on their targets with velocity (target - prev)/h
    (``targets``: the particles, their targets and their positions before the step;
    ``particles``, ``rest``: ``integrate.BodyParticles``, ``integrate.ClusterRest``).

    The accumulators for the next step already hold these particles' integrated
    positions: their contribution is swapped for the one at the target.
    """
    x, v, x0, mass = particles.x, particles.v, particles.x0, particles.mass
    ptr, cluster_ids, rest_lin, rest_off = rest.ptr, rest.cluster_ids, rest.rest_lin, rest.rest_off
    idx, tgt, prev = targets
    single = ptr.shape[0] == 0
    for p in range(idx.shape[0]):
        i = idx[p]
        a0, a1, a2 = x0[i, 0], x0[i, 1], x0[i, 2]
        j0, j1, w = _span(i, single, ptr, mass)
        for j in range(j0, j1):
            k = 0 if single else cluster_ids[j]
            q0, q1, q2 = _qhat(rest_lin=rest_lin, rest_off=rest_off, k=k, a0=a0, a1=a1, a2=a2)
            d0 = tgt[p, 0] - x[i, 0]
            d1 = tgt[p, 1] - x[i, 1]
            d2 = tgt[p, 2] - x[i, 2]
            if quad:
                _acc_quad(row=part[0, k], w=w, d0=d0, d1=d1, d2=d2, q0=q0, q1=q1, q2=q2)
            else:
                _acc_lin(row=part[0, k], w=w, d0=d0, d1=d1, d2=d2, q0=q0, q1=q1, q2=q2)
        for j in range(3):
            v[i, j] = (tgt[p, j] - prev[p, j]) / h
            x[i, j] = tgt[p, j]


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
