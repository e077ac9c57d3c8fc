"""Per-step poses of the collider pass's colliders: one compiled call for all of them.

``ColliderSet.advance`` used to walk its colliders in Python (a slerp, a rotation matrix and
a few small NumPy arrays per moving collider: 10-45 us each per step, more than the whole
step of a small scene).  ``advance_poses`` does the same arithmetic for every collider in
one compiled loop over plain arrays; ``advance_reference`` is its plain-Python twin (the
former per-collider code on the same arrays) that the tests compare it against.

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

import math

import numpy as np
from numba import njit

from . import kinematic as KC
from .kernels.jit import JIT

IDLE, MOVE, PATH = 0, 1, 2

# columns of a commanded move (mv)
M_P0 = 0            # start position (3)
M_Q0 = 3            # start quaternion (4)
M_P1 = 7            # target position (3)
M_Q1 = 10           # target quaternion (4)
M_DUR = 14          # duration (s)
M_EL = 15           # time elapsed (s)
M_VEL = 16          # linear velocity (3)
M_AXIS = 19         # rotation axis, world frame (3)
M_ANGLE = 22        # rotation angle over the whole move (rad)
MV = 23


@njit(**JIT)
def _axis_angle_mul(ax, ay, az, angle, q):
    """quat_mul(axis_angle_quat(axis, angle), q) as four floats."""
    s = math.sin(0.5 * angle)
    x, y, z, w = ax * s, ay * s, az * s, math.cos(0.5 * angle)
    bx, by, bz, bw = q[0], q[1], q[2], q[3]
    return (w * bx + x * bw + y * bz - z * by,
            w * by - x * bz + y * bw + z * bx,
            w * bz + x * by - y * bx + z * bw,
            w * bw - x * bx - y * by - z * bz)


@njit(**JIT)
def _rotation_between(q0, q1x, q1y, q1z, q1w):
    """(ax, ay, az, angle) of the world-frame rotation taking q0 to q1 (angle in [0, pi])."""
    ax, ay, az, aw = q1x, q1y, q1z, q1w
    bx, by, bz, bw = -q0[0], -q0[1], -q0[2], q0[3]
    dx = aw * bx + ax * bw + ay * bz - az * by
    dy = aw * by - ax * bz + ay * bw + az * bx
    dz = aw * bz + ax * by - ay * bx + az * bw
    dw = aw * bw - ax * bx - ay * by - az * bz
    if dw < 0.0:
        dx, dy, dz, dw = -dx, -dy, -dz, -dw
    s = math.sqrt(dx * dx + dy * dy + dz * dz)
    if s < 1e-15:
        return 0.0, 0.0, 1.0, 0.0
    return dx / s, dy / s, dz / s, 2.0 * math.atan2(s, dw)


@njit(**JIT)
def _write_pose(row, p, q, vx, vy, vz, wx, wy, wz):
    """Position, rotation matrix of unit quaternion q, linear and angular velocity."""
    row[KC.C_POS], row[KC.C_POS + 1], row[KC.C_POS + 2] = p[0], p[1], p[2]
    x, y, z, w = q[0], q[1], q[2], q[3]
    r = KC.C_ROT
    row[r] = 1 - 2 * (y * y + z * z)
    row[r + 1] = 2 * (x * y - z * w)
    row[r + 2] = 2 * (x * z + y * w)
    row[r + 3] = 2 * (x * y + z * w)
    row[r + 4] = 1 - 2 * (x * x + z * z)
    row[r + 5] = 2 * (y * z - x * w)
    row[r + 6] = 2 * (x * z - y * w)
    row[r + 7] = 2 * (y * z + x * w)
    row[r + 8] = 1 - 2 * (x * x + y * y)
    row[KC.C_VEL], row[KC.C_VEL + 1], row[KC.C_VEL + 2] = vx, vy, vz
    row[KC.C_ANG], row[KC.C_ANG + 1], row[KC.C_ANG + 2] = wx, wy, wz


@njit(**JIT)
def advance_poses(mode, pos, quat, mv, ktime, kpos, kquat, kseg, koff, rows, h, t, done):
    """Poses at the end of the next step (from world time ``t``, of ``h`` s) and the
    velocities during it, for every collider; returns how many commanded moves ended.

    One pass over the colliders (a few): each moving one costs a slerp, a rotation matrix
    and, on a path, a scan of its keyframes; a collider at rest only has its velocities
    zeroed once.
    """
    ended = 0
    for c in range(mode.shape[0]):
        row = rows[c]
        m = mode[c]
        if m == PATH:
            k0, k1 = koff[c], koff[c + 1]
            end = ktime[k1 - 1]
            if t >= end:                        # the path is over: at rest there
                mode[c] = IDLE
                _write_pose(row, pos[c], quat[c], 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
                continue
            tt = t + h
            if tt >= end:
                px, py, pz = kpos[k1 - 1, 0], kpos[k1 - 1, 1], kpos[k1 - 1, 2]
                qk = kquat[k1 - 1]
                qx, qy, qz, qw = qk[0], qk[1], qk[2], qk[3]
            else:
                k = k0
                while k + 1 < k1 and ktime[k + 1] <= tt:
                    k += 1
                s = (tt - ktime[k]) / (ktime[k + 1] - ktime[k])
                px = kpos[k, 0] + (kpos[k + 1, 0] - kpos[k, 0]) * s
                py = kpos[k, 1] + (kpos[k + 1, 1] - kpos[k, 1]) * s
                pz = kpos[k, 2] + (kpos[k + 1, 2] - kpos[k, 2]) * s
                qx, qy, qz, qw = _axis_angle_mul(kseg[k, 0], kseg[k, 1], kseg[k, 2],
                                                 kseg[k, 3] * s, kquat[k])
            vx, vy, vz = (px - pos[c, 0]) / h, (py - pos[c, 1]) / h, (pz - pos[c, 2]) / h
            ax, ay, az, angle = _rotation_between(quat[c], qx, qy, qz, qw)
            pos[c, 0], pos[c, 1], pos[c, 2] = px, py, pz
            quat[c, 0], quat[c, 1], quat[c, 2], quat[c, 3] = qx, qy, qz, qw
            w = angle / h
            _write_pose(row, pos[c], quat[c], vx, vy, vz, ax * w, ay * w, az * w)
        elif m == MOVE:
            mo = mv[c]
            d = mo[M_DUR]
            t_new = mo[M_EL] + h
            if t_new >= d * (1.0 - 1e-9):
                for i in range(3):
                    pos[c, i] = mo[M_P1 + i]
                for i in range(4):
                    quat[c, i] = mo[M_Q1 + i]
                mode[c] = IDLE
                done[c] = 1
                ended += 1
            else:
                s = t_new / d
                for i in range(3):
                    pos[c, i] = mo[M_P0 + i] + (mo[M_P1 + i] - mo[M_P0 + i]) * s
                qx, qy, qz, qw = _axis_angle_mul(mo[M_AXIS], mo[M_AXIS + 1], mo[M_AXIS + 2],
                                                 mo[M_ANGLE] * s, mo[M_Q0:M_Q0 + 4])
                quat[c, 0], quat[c, 1], quat[c, 2], quat[c, 3] = qx, qy, qz, qw
                mo[M_EL] = t_new
            w = mo[M_ANGLE] / d
            _write_pose(row, pos[c], quat[c], mo[M_VEL], mo[M_VEL + 1], mo[M_VEL + 2],
                        mo[M_AXIS] * w, mo[M_AXIS + 1] * w, mo[M_AXIS + 2] * w)
        else:
            moving = False
            for i in range(KC.C_VEL, KC.C_ANG + 3):
                if row[i] != 0.0:
                    moving = True
            if moving:
                _write_pose(row, pos[c], quat[c], 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    return ended


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
