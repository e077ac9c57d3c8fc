"""The colliders of the collider pass: poses, motion of kinematic ones, wrenches.

``ColliderSet`` owns the rows that ``kinematic.collide_range`` reads, moves kinematic
colliders towards their targets substep by substep (position linearly, orientation by
slerp, at the constant linear and angular velocity that the move implies), and adds up the
impulses the bodies exert on each collider until they are taken as an average wrench.
"""

import math

import numpy as np

from . import kinematic as KC
from .params import KIND_BOX, KIND_CAPSULE, QUAT_TOLERANCE

_IDENTITY = np.array([0.0, 0.0, 0.0, 1.0])


def quat_mul(a, b):
    """Hamilton product of quaternions (x, y, z, w)."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return np.array([aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw,
                     aw * bw - ax * bx - ay * by - az * bz])


def quat_matrix(q):
    """Rotation matrix of a unit quaternion (x, y, z, w)."""
    x, y, z, w = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


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


def check_pose(name, position, orientation):
    """Validated (position (3,), unit quaternion (4,)) or ValueError with the reason."""
    p = np.asarray(position, dtype=float).reshape(-1)
    if p.shape != (3,) or not np.all(np.isfinite(p)):
        raise ValueError(f'collider {name!r}: position must be 3 finite numbers, '
                         f'got {position!r}')
    q = np.asarray(orientation, dtype=float).reshape(-1)
    if q.shape != (4,) or not np.all(np.isfinite(q)):
        raise ValueError(f'collider {name!r}: orientation must be a quaternion of 4 finite '
                         f'numbers (x, y, z, w), got {orientation!r}')
    n = float(np.linalg.norm(q))
    if n == 0.0:
        raise ValueError(f'collider {name!r}: orientation is a zero quaternion')
    if abs(n - 1.0) > QUAT_TOLERANCE:
        raise ValueError(f'collider {name!r}: orientation must be a unit quaternion, '
                         f'its norm is {n:.6g}')
    return p, q / n


class ColliderSet:
    """The collider-pass colliders of a world (boxes, spheres, capsules; see params)."""

    def __init__(self, colliders):
        """Take validated Box / Sphere / Capsule instances (names unique)."""
        self.items = tuple(colliders)
        nc = len(self.items)
        self.rows = np.zeros((nc, KC.ROW))
        self.index = {}
        self.kind = []
        self.pos0 = np.zeros((nc, 3))
        self.quat0 = np.tile(_IDENTITY, (nc, 1))
        for c, item in enumerate(self.items):
            kind, centre, quat, dims = item.shape()
            if item.name is not None:
                self.index[item.name] = c
            self.pos0[c] = centre
            self.quat0[c] = quat
            row = self.rows[c]
            row[KC.C_KIND] = kind
            row[KC.C_DIM:KC.C_DIM + 3] = dims
            row[KC.C_MU] = float(item.friction)
            row[KC.C_E] = float(item.restitution)
            if kind == KIND_BOX:
                bound = float(np.linalg.norm(dims))
            elif kind == KIND_CAPSULE:
                bound = dims[0] + dims[1]
            else:
                bound = dims[0]
            # a little slack: the bound only skips particles that cannot touch
            row[KC.C_BOUND] = bound * (1.0 + 1e-9) + 1e-12
        # scripted paths: keyframe times (from 0), positions, quaternions
        self.paths = {}
        from .params import _path
        for c, item in enumerate(self.items):
            frames = _path('collider', item)
            if frames:
                times = np.array([0.0] + [f[0] for f in frames])
                pos = [self.pos0[c]]
                quats = [self.quat0[c]]
                for _, p, q in frames:
                    pos.append(p)
                    quats.append(quats[-1] if q is None else q)
                self.paths[c] = (times, np.array(pos), np.array(quats))
        self.imp = np.zeros((nc, 6))
        self.imp_time = 0.0
        self.reset()

    def __len__(self):
        return len(self.items)

    def reset(self):
        """Initial poses, no motion, no accumulated impulses."""
        self.pos = self.pos0.copy()
        self.quat = self.quat0.copy()
        # per collider: None or (start pos, start quat, target pos, target quat, duration,
        # elapsed, linear velocity, axis, angle)
        self.motion = [None] * len(self.items)
        self.playing = set(self.paths)
        for c in range(len(self.items)):
            self._write_pose(c, np.zeros(3), np.zeros(3))
        self.imp[:] = 0.0
        self.imp_time = 0.0

    def _write_pose(self, c, vel, ang):
        row = self.rows[c]
        row[KC.C_POS:KC.C_POS + 3] = self.pos[c]
        row[KC.C_ROT:KC.C_ROT + 9] = quat_matrix(self.quat[c]).reshape(-1)
        row[KC.C_VEL:KC.C_VEL + 3] = vel
        row[KC.C_ANG:KC.C_ANG + 3] = ang

    # ------------------------------------------------------------------ motion
    def lookup(self, name):
        """Index of the collider called ``name`` (ValueError naming the known ones)."""
        if not isinstance(name, str) or name not in self.index:
            known = ', '.join(sorted(self.index)) or 'none'
            raise ValueError(f'unknown collider {name!r} (named colliders: {known})')
        return self.index[name]

    def move(self, name, position, orientation, duration):
        """Move kinematic collider ``name`` to the pose over ``duration`` s of steps
        (0: jump there now, at rest).  Raises ValueError and changes nothing on bad input.
        """
        c = self.lookup(name)
        if not self.items[c].kinematic:
            raise ValueError(f'collider {name!r} is static (declare it kinematic to move it)')
        p, q = check_pose(name, position, orientation)
        try:
            d = float(duration)
        except (TypeError, ValueError):
            raise ValueError(f'duration must be a number, got {duration!r}') from None
        if not (math.isfinite(d) and d >= 0.0):
            raise ValueError(f'duration must be finite and >= 0, got {duration!r}')
        self.playing.discard(c)           # a commanded move ends the scripted path
        if d == 0.0:
            self.pos[c] = p
            self.quat[c] = q
            self.motion[c] = None
            self._write_pose(c, np.zeros(3), np.zeros(3))
            return
        axis, angle = rotation_between(self.quat[c], q)
        self.motion[c] = (self.pos[c].copy(), self.quat[c].copy(), p, q, d, 0.0,
                          (p - self.pos[c]) / d, axis, angle)

    def path_pose(self, c, t):
        """Pose of collider ``c``'s scripted path at time ``t`` (s)."""
        times, pos, quats = self.paths[c]
        if t >= times[-1]:
            return pos[-1].copy(), quats[-1].copy()
        k = int(np.searchsorted(times, t, side='right')) - 1
        s = (t - times[k]) / (times[k + 1] - times[k])
        axis, angle = rotation_between(quats[k], quats[k + 1])
        return (pos[k] + (pos[k + 1] - pos[k]) * s,
                quat_mul(axis_angle_quat(axis, angle * s), quats[k]))

    def advance(self, h, t=0.0):
        """Poses at the end of the next step (from time ``t``, of ``h`` s) and the
        velocities during it."""
        for c, mo in enumerate(self.motion):
            if c in self.playing:
                if t >= self.paths[c][0][-1]:          # the path is over: at rest there
                    self.playing.discard(c)
                    self._write_pose(c, np.zeros(3), np.zeros(3))
                    continue
                p, q = self.path_pose(c, t + h)
                vel = (p - self.pos[c]) / h
                axis, angle = rotation_between(self.quat[c], q)
                self.pos[c] = p
                self.quat[c] = q
                self._write_pose(c, vel, axis * (angle / h))
                continue
            if mo is None:
                if self.rows[c, KC.C_VEL:KC.C_ANG + 3].any():
                    self._write_pose(c, np.zeros(3), np.zeros(3))
                continue
            p0, q0, p1, q1, d, t, vel, axis, angle = mo
            t_new = t + h
            if t_new >= d * (1.0 - 1e-9):
                self.pos[c] = p1
                self.quat[c] = q1
                self.motion[c] = None
            else:
                s = t_new / d
                self.pos[c] = p0 + (p1 - p0) * s
                self.quat[c] = quat_mul(axis_angle_quat(axis, angle * s), q0)
                self.motion[c] = (p0, q0, p1, q1, d, t_new, vel, axis, angle)
            self._write_pose(c, vel, axis * (angle / d))

    # ------------------------------------------------------------------ contact
    def collide(self, X, V, w, bid, start, end, h, thresh, stats, touched):
        """Run the pass over particles start..end of (3, N) state after a step of h s
        (see ``kinematic.collide_range``)."""
        KC.collide_range(X, V, w, bid, start, end, self.rows, h, thresh, self.imp, stats,
                         touched)

    def wrench(self, c):
        """(force, torque) on collider ``c`` averaged over the accumulated time."""
        if self.imp_time <= 0.0:
            return np.zeros(3), np.zeros(3)
        return self.imp[c, :3] / self.imp_time, self.imp[c, 3:] / self.imp_time

    def take(self):
        """{name: (force, torque)} averaged since the last take; starts a new window."""
        out = {name: self.wrench(c) for name, c in self.index.items()}
        self.imp[:] = 0.0
        self.imp_time = 0.0
        return out
