"""Unit quaternions (x, y, z, w) in NumPy: the colliders' poses and their plain twins.

The compiled collider motion (``kinematic.advance_poses``) does the same arithmetic on
floats; these are what ``ColliderSet`` and ``collider_motion.advance_reference`` use.
"""

import math

import numpy as np


def quat_mul(a, b):
    """Hamilton product of quaternions (x, y, z, w)."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return np.array([aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw,
                     aw * bw - ax * bx - ay * by - az * bz])


def quat_matrix(q):
    """Rotation matrix (3, 3) of a unit quaternion (x, y, z, w); (..., 3, 3) of (..., 4)."""
    x, y, z, w = np.moveaxis(np.asarray(q, dtype=float), -1, 0)
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
        np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
        np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
    ], -2)


def rotation_between(q0, q1):
    """(axis, angle) of the world-frame rotation taking q0 to q1 (angle in [0, pi])."""
    dq = quat_mul(q1, np.array([-q0[0], -q0[1], -q0[2], q0[3]]))
    if dq[3] < 0.0:
        dq = -dq
    s = float(np.linalg.norm(dq[:3]))
    if s < 1e-15:
        return np.array([0.0, 0.0, 1.0]), 0.0
    return dq[:3] / s, 2.0 * math.atan2(s, dq[3])


def axis_angle_quat(axis, angle):
    """Quaternion (x, y, z, w) of a rotation by ``angle`` about the unit ``axis``."""
    s = math.sin(0.5 * angle)
    return np.array([axis[0] * s, axis[1] * s, axis[2] * s, math.cos(0.5 * angle)])
