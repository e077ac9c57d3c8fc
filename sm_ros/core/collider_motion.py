"""Per-step poses of the collider pass's colliders: one compiled call for all of them.

Walking the colliders in Python (a slerp, a rotation matrix and a few small NumPy arrays
per moving collider) would cost more than the whole step of a small scene.
``advance_poses`` (compiled, in ``kinematic.py`` beside the row
layout it writes, so that Numba's cache sees an edit of either) does the same arithmetic
for every collider in one loop over plain arrays; ``advance_reference`` here is its
plain-Python twin (per-collider code on the same arrays) that the tests compare
it against.

State (owned by ``ColliderSet``; ``nc`` colliders):

- ``mode`` (nc,) int64: ``IDLE`` (at rest), ``MOVE`` (a commanded move in progress) or
  ``PATH`` (playing its scripted keyframes);
- ``pos`` (nc, 3), ``quat`` (nc, 4): current poses (x, y, z, w);
- ``mv`` (nc, MV) float: a commanded move, columns named ``M_*`` below;
- keyframes of every path, concatenated: ``ktime`` (K,), ``kpos`` (K, 3), ``kquat`` (K, 4)
  and ``kseg`` (K, 4) (axis and angle from keyframe k to k + 1, the last of each path
  unused); collider c's keyframes are ``koff[c]:koff[c + 1]`` (none without a path);
- ``rows`` (nc, kinematic.ROW): where the pose, rotation matrix and velocities go;
- ``done`` (nc,) int64: set to 1 where a commanded move ended in this call.
"""

import numpy as np

from . import kinematic as KC
from .kinematic import (IDLE, M_ANGLE, M_AXIS, M_DUR, M_EL, M_P0, M_P1, M_Q0,  # noqa: F401
                        M_Q1, M_VEL, MOVE, MV, PATH, advance_poses)


def advance_reference(mode, pos, quat, mv, ktime, kpos, kquat, kseg, koff, rows, h, t,
                      done):
    """Plain-Python twin of ``advance_poses`` (the former per-collider code of
    ``ColliderSet.advance``, with NumPy quaternion helpers; same arguments and result)."""
    from .colliders import axis_angle_quat, quat_matrix, quat_mul, rotation_between

    def write(c, vel, ang):
        row = rows[c]
        row[KC.C_POS:KC.C_POS + 3] = pos[c]
        row[KC.C_ROT:KC.C_ROT + 9] = quat_matrix(quat[c]).reshape(-1)
        row[KC.C_VEL:KC.C_VEL + 3] = vel
        row[KC.C_ANG:KC.C_ANG + 3] = ang

    ended = 0
    zero = np.zeros(3)
    for c in range(len(mode)):
        if mode[c] == PATH:
            times = ktime[koff[c]:koff[c + 1]]
            if t >= times[-1]:
                mode[c] = IDLE
                write(c, zero, zero)
                continue
            tt = t + h
            if tt >= times[-1]:
                p, q = kpos[koff[c + 1] - 1].copy(), kquat[koff[c + 1] - 1].copy()
            else:
                k = int(np.searchsorted(times, tt, side='right')) - 1 + koff[c]
                s = (tt - ktime[k]) / (ktime[k + 1] - ktime[k])
                p = kpos[k] + (kpos[k + 1] - kpos[k]) * s
                q = quat_mul(axis_angle_quat(kseg[k, :3], kseg[k, 3] * s), kquat[k])
            vel = (p - pos[c]) / h
            axis, angle = rotation_between(quat[c], q)
            pos[c], quat[c] = p, q
            write(c, vel, axis * (angle / h))
        elif mode[c] == MOVE:
            mo = mv[c]
            d, t_new = mo[M_DUR], mo[M_EL] + h
            if t_new >= d * (1.0 - 1e-9):
                pos[c], quat[c] = mo[M_P1:M_P1 + 3], mo[M_Q1:M_Q1 + 4]
                mode[c], done[c] = IDLE, 1
                ended += 1
            else:
                s = t_new / d
                pos[c] = mo[M_P0:M_P0 + 3] + (mo[M_P1:M_P1 + 3] - mo[M_P0:M_P0 + 3]) * s
                quat[c] = quat_mul(axis_angle_quat(mo[M_AXIS:M_AXIS + 3], mo[M_ANGLE] * s),
                                   mo[M_Q0:M_Q0 + 4])
                mo[M_EL] = t_new
            write(c, mo[M_VEL:M_VEL + 3], mo[M_AXIS:M_AXIS + 3] * (mo[M_ANGLE] / d))
        elif rows[c, KC.C_VEL:KC.C_ANG + 3].any():
            write(c, zero, zero)
    return ended
