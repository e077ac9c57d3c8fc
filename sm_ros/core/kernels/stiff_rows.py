"""A stiff contact's rows for the impulse sweeps (``stiff_solve``): its three directions
(normal, two tangents) with what an impulse along each does to its bodies, taken once a
step, so a visit is a few dot products (Box2D's precomputed contact constraints).

``jacobians`` returns (count, 3, ``J_ROW``): per direction d, d itself, the lever arms'
moments r_a x d and r_b x d, what a unit impulse does to each body's spin (I^-1 r x d),
the effective mass along d, and the collider's surface speed along d (0 for a body pair).
Body b < 0 is a collider: infinitely heavy, moving at that surface speed.
"""

import numpy as np
from numba import njit

from .jit import JIT, JIT_NO_REFCOUNT
from .stiff_contacts import (F_INV, F_SPIN, F_VEL, K_A, K_B, K_GRIP, K_MU, K_N, K_RA, K_RB,
                             K_SURF, K_TARGET, _tangents)

#: Columns of a direction's row: d, r_a x d, I_a^-1 (r_a x d), r_b x d, I_b^-1 (r_b x d),
#: the effective mass, the surface speed along d.
J_D, J_CA, J_IA, J_CB, J_IB, J_MASS, J_SURF = 0, 3, 6, 9, 12, 15, 16
J_ROW = 17


@njit(**JIT)
def _side(j, inv_inertia, b, r, at_c, at_i, frames):
    """Fill one body's moment and spin response for direction j[J_D:J_D+3]; returns its
    share of the inverse effective mass."""
    d = j[J_D:J_D + 3]
    j[at_c] = r[1] * d[2] - r[2] * d[1]
    j[at_c + 1] = r[2] * d[0] - r[0] * d[2]
    j[at_c + 2] = r[0] * d[1] - r[1] * d[0]
    if b < 0:
        j[at_i:at_i + 3] = 0.0
        return 0.0
    inv = frames[b, F_INV]
    for i in range(3):
        j[at_i + i] = (inv_inertia[b, i, 0] * j[at_c] + inv_inertia[b, i, 1] * j[at_c + 1]
                       + inv_inertia[b, i, 2] * j[at_c + 2])
        inv += j[at_c + i] * j[at_i + i]
    return inv


@njit(**JIT)
def jacobians(frames, inv_inertia, rows):
    """The directions of every contact row (module docstring)."""
    jac = np.zeros((rows.shape[0], 3, J_ROW))
    for k in range(rows.shape[0]):
        row = rows[k]
        a, b = int(row[K_A]), int(row[K_B])
        n = row[K_N:K_N + 3]
        t1x, t1y, t1z, t2x, t2y, t2z = _tangents(n[0], n[1], n[2])
        jac[k, 0, J_D:J_D + 3] = n
        jac[k, 1, J_D], jac[k, 1, J_D + 1], jac[k, 1, J_D + 2] = t1x, t1y, t1z
        jac[k, 2, J_D], jac[k, 2, J_D + 1], jac[k, 2, J_D + 2] = t2x, t2y, t2z
        for e in range(3):
            j = jac[k, e]
            inv = (_side(j, inv_inertia, a, row[K_RA:K_RA + 3], J_CA, J_IA, frames)
                   + _side(j, inv_inertia, b, row[K_RB:K_RB + 3], J_CB, J_IB, frames))
            j[J_MASS] = 1.0 / inv if inv > 0.0 else 0.0
            if b < 0:
                j[J_SURF] = (j[J_D] * row[K_SURF] + j[J_D + 1] * row[K_SURF + 1]
                             + j[J_D + 2] * row[K_SURF + 2])
    return jac


@njit(**JIT_NO_REFCOUNT)
def speed_along(frames, j, a, b, surface):
    """The speed of a's contact point relative to b's (or the collider's surface, when
    ``surface``) along the direction of row j."""
    s = 0.0
    for i in range(3):
        s += j[J_D + i] * frames[a, F_VEL + i] + j[J_CA + i] * frames[a, F_SPIN + i]
    if b >= 0:
        for i in range(3):
            s -= j[J_D + i] * frames[b, F_VEL + i] + j[J_CB + i] * frames[b, F_SPIN + i]
    elif surface:
        s -= j[J_SURF]
    return s


@njit(**JIT_NO_REFCOUNT)
def apply(frames, j, a, b, lam):
    """Impulse ``lam`` along the direction of row j: + on a, - on b."""
    wa = frames[a, F_INV] * lam
    for i in range(3):
        frames[a, F_VEL + i] += wa * j[J_D + i]
        frames[a, F_SPIN + i] += lam * j[J_IA + i]
    if b >= 0:
        wb = frames[b, F_INV] * lam
        for i in range(3):
            frames[b, F_VEL + i] -= wb * j[J_D + i]
            frames[b, F_SPIN + i] -= lam * j[J_IB + i]


@njit(**JIT_NO_REFCOUNT)
def visit(frames, jac, row, acc):
    """One visit of a contact: its normal impulse towards its target speed, accumulated
    and never pulling, then its friction, held within mu times the normal impulse so far
    and the position solve's (``K_GRIP``: a finger pressed into a body holds it).  Returns
    the largest speed change it made."""
    a, b = int(row[K_A]), int(row[K_B])
    jn = jac[0]
    lam = jn[J_MASS] * (row[K_TARGET] - speed_along(frames, jn, a, b, True))
    lam = max(acc[0] + lam, 0.0) - acc[0]
    acc[0] += lam
    apply(frames, jn, a, b, lam)
    f1 = acc[1] - jac[1, J_MASS] * speed_along(frames, jac[1], a, b, True)
    f2 = acc[2] - jac[2, J_MASS] * speed_along(frames, jac[2], a, b, True)
    cap = row[K_MU] * (acc[0] + row[K_GRIP])
    size = np.sqrt(f1 * f1 + f2 * f2)
    if size > cap:
        f1, f2 = f1 * cap / size, f2 * cap / size
    d1, d2 = f1 - acc[1], f2 - acc[2]
    acc[1], acc[2] = f1, f2
    apply(frames, jac[1], a, b, d1)
    apply(frames, jac[2], a, b, d2)
    change = 0.0
    for e, amount in ((0, lam), (1, d1), (2, d2)):
        if jac[e, J_MASS] > 0.0:
            change = max(change, abs(amount) / jac[e, J_MASS])
    return change


@njit(**JIT_NO_REFCOUNT)
def push_visit(frames, jn, row, acc, target):
    """One visit of the position solve: the normal push towards ``target`` (a speed that,
    for one step, removes part of the overlap), accumulated and never pulling; colliders
    are not pushed.  Returns the speed change."""
    a, b = int(row[K_A]), int(row[K_B])
    lam = jn[J_MASS] * (target - speed_along(frames, jn, a, b, False))
    lam = max(acc + lam, 0.0) - acc
    apply(frames, jn, a, b, lam)
    return lam
