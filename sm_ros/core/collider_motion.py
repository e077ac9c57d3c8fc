"""Per-step poses of the collider pass's colliders: one compiled call for all of them.

Walking the colliders in Python (a slerp, a rotation matrix and a few small NumPy arrays
per moving collider) would cost more than the whole step of a small scene.
``advance_poses`` (compiled, in ``kinematic.py`` beside the row layout it writes, so that
Numba's cache sees an edit of either) does the same arithmetic for every collider in one
loop over plain arrays; ``advance_reference`` here is its plain-Python twin (per-collider
code on the same arrays) that the tests compare it against.

State (owned by ``ColliderSet``): ``kinematic.ColliderMotion`` (modes, poses, commanded
moves, the moves that ended), ``kinematic.Keyframes`` (every scripted path's keyframes,
concatenated) and ``rows`` (nc, kinematic.ROW), where the pose, rotation matrix and
velocities go.
"""

import numpy as np

from . import kinematic as KC
from .kinematic import (IDLE, M_ANGLE, M_AXIS, M_DUR, M_EL, M_P0, M_P1, M_Q0,  # noqa: F401
                        M_Q1, M_VEL, MOVE, MV, PATH, ColliderMotion, Keyframes,
                        advance_poses)
from .quaternion import axis_angle_quat, quat_matrix, quat_mul, rotation_between


def write_pose(rows, c, motion, vel, ang):
    """Row c of ``rows``: the pose of collider c in ``motion``, velocities ``vel``, ``ang``."""
    row = rows[c]
    row[KC.C_POS:KC.C_POS + 3] = motion.pos[c]
    row[KC.C_ROT:KC.C_ROT + 9] = quat_matrix(motion.quat[c]).reshape(-1)
    row[KC.C_VEL:KC.C_VEL + 3] = vel
    row[KC.C_ANG:KC.C_ANG + 3] = ang


def _path_step(c, motion, keys, rows, h, t):
    """Collider c one step along its keyframes (``kinematic._advance_path``)."""
    first, stop = keys.offset[c], keys.offset[c + 1]
    times = keys.time[first:stop]
    if t >= times[-1]:
        motion.mode[c] = IDLE
        write_pose(rows, c, motion, np.zeros(3), np.zeros(3))
        return
    later = t + h
    if later >= times[-1]:
        pos, quat = keys.pos[stop - 1].copy(), keys.quat[stop - 1].copy()
    else:
        k = int(np.searchsorted(times, later, side='right')) - 1 + first
        s = (later - keys.time[k]) / (keys.time[k + 1] - keys.time[k])
        pos = keys.pos[k] + (keys.pos[k + 1] - keys.pos[k]) * s
        quat = quat_mul(axis_angle_quat(keys.segment[k, :3], keys.segment[k, 3] * s),
                        keys.quat[k])
    vel = (pos - motion.pos[c]) / h
    axis, angle = rotation_between(motion.quat[c], quat)
    motion.pos[c], motion.quat[c] = pos, quat
    write_pose(rows, c, motion, vel, axis * (angle / h))


def _move_step(c, motion, rows, h):
    """Collider c one step of its commanded move; 1 when the move ended in it."""
    move = motion.moves[c]
    duration, elapsed = move[M_DUR], move[M_EL] + h
    ended = 0
    if elapsed >= duration * (1.0 - 1e-9):
        motion.pos[c], motion.quat[c] = move[M_P1:M_P1 + 3], move[M_Q1:M_Q1 + 4]
        motion.mode[c], motion.done[c] = IDLE, 1
        ended = 1
    else:
        s = elapsed / duration
        motion.pos[c] = move[M_P0:M_P0 + 3] + (move[M_P1:M_P1 + 3] - move[M_P0:M_P0 + 3]) * s
        motion.quat[c] = quat_mul(axis_angle_quat(move[M_AXIS:M_AXIS + 3], move[M_ANGLE] * s),
                                  move[M_Q0:M_Q0 + 4])
        move[M_EL] = elapsed
    write_pose(rows, c, motion, move[M_VEL:M_VEL + 3],
           move[M_AXIS:M_AXIS + 3] * (move[M_ANGLE] / duration))
    return ended


def advance_reference(motion: ColliderMotion, keys: Keyframes, rows, h, t):
    """Plain-Python twin of ``advance_poses`` (with NumPy quaternion helpers; same
    arguments and result)."""
    ended = 0
    for c in range(len(motion.mode)):
        if motion.mode[c] == PATH:
            _path_step(c, motion, keys, rows, h, t)
        elif motion.mode[c] == MOVE:
            ended += _move_step(c, motion, rows, h)
        elif rows[c, KC.C_VEL:KC.C_ANG + 3].any():
            write_pose(rows, c, motion, np.zeros(3), np.zeros(3))
    return ended
