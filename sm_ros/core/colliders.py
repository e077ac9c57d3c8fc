"""The colliders of the collider pass: poses, motion of kinematic ones, wrenches.

``ColliderSet`` owns the rows that ``kinematic.collide_range`` reads, moves kinematic
colliders towards their targets substep by substep (position linearly, orientation by
slerp, at the constant linear and angular velocity that the move implies), and adds up the
impulses the bodies exert on each collider until they are taken as an average wrench.
"""

import math

import numpy as np

from . import collider_motion as CM
from . import kinematic as KC
from .params import _path, KIND_BOX, KIND_CAPSULE, QUAT_TOLERANCE
from .quaternion import axis_angle_quat, quat_matrix, quat_mul, rotation_between  # noqa: F401

_IDENTITY = np.array([0.0, 0.0, 0.0, 1.0])


def check_pose(name, position, orientation):
    """Validated (position (3,), unit quaternion (4,)) or ValueError with the reason."""
    pos = np.asarray(position, dtype=float).reshape(-1)
    if pos.shape != (3,) or not np.all(np.isfinite(pos)):
        raise ValueError(f'collider {name!r}: position must be 3 finite numbers, '
                         f'got {position!r}')
    quat = np.asarray(orientation, dtype=float).reshape(-1)
    if quat.shape != (4,) or not np.all(np.isfinite(quat)):
        raise ValueError(f'collider {name!r}: orientation must be a quaternion of 4 finite '
                         f'numbers (x, y, z, w), got {orientation!r}')
    norm = float(np.linalg.norm(quat))
    if norm == 0.0:
        raise ValueError(f'collider {name!r}: orientation is a zero quaternion')
    if abs(norm - 1.0) > QUAT_TOLERANCE:
        raise ValueError(f'collider {name!r}: orientation must be a unit quaternion, '
                         f'its norm is {norm:.6g}')
    return pos, quat / norm


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
        # scripted paths: per collider (times, positions, quaternions), and all of them
        # concatenated for the compiled motion (collider_motion.py)
        self.paths, self.keys = _keyframes(self.items, self.pos0, self.quat0)
        self.mode = np.zeros(nc, dtype=np.int64)
        self.pos = np.zeros((nc, 3))
        self.quat = np.zeros((nc, 4))
        self.moves = np.zeros((nc, CM.MV))
        self.done = np.zeros(nc, dtype=np.int64)
        self.imp = np.zeros((nc, 6))
        self.imp_time = 0.0
        self.reset()

    def step_state(self) -> tuple:
        """What a step changes and a later step reads (``snapshot``): poses, motion, the
        rows the pass reads, the accumulated impulses and their time."""
        return ('pos', 'quat', 'mode', 'moves', 'motion', 'rows', 'imp', 'imp_time')

    def __len__(self):
        return len(self.items)

    def reset(self):
        """Initial poses, no motion, no accumulated impulses."""
        self.pos[:] = self.pos0
        self.quat[:] = self.quat0
        # per collider: None or the commanded move in progress, (start pos, start quat,
        # target pos, target quat, duration, linear velocity, axis, angle) as commanded;
        # its progress lives in ``moves`` (collider_motion.py)
        self.motion = [None] * len(self.items)
        self.mode[:] = CM.IDLE
        for c in self.paths:
            self.mode[c] = CM.PATH
        self.moves[:] = 0.0
        for c in range(len(self.items)):
            self._write_pose(c, np.zeros(3), np.zeros(3))
        self.imp[:] = 0.0
        self.imp_time = 0.0

    def _write_pose(self, c, vel, ang):
        CM.write_pose(self.rows, c, self.motion_arrays(), vel, ang)

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
        pos, quat = check_pose(name, position, orientation)
        try:
            seconds = float(duration)
        except (TypeError, ValueError):
            raise ValueError(f'duration must be a number, got {duration!r}') from None
        if not (math.isfinite(seconds) and seconds >= 0.0):
            raise ValueError(f'duration must be finite and >= 0, got {duration!r}')
        if seconds == 0.0:
            self.mode[c] = CM.IDLE        # a commanded move ends the scripted path
            self.pos[c] = pos
            self.quat[c] = quat
            self.motion[c] = None
            self._write_pose(c, np.zeros(3), np.zeros(3))
            return
        axis, angle = rotation_between(self.quat[c], quat)
        vel = (pos - self.pos[c]) / seconds
        self.motion[c] = (self.pos[c].copy(), self.quat[c].copy(), pos, quat, seconds, vel,
                          axis, angle)
        row = self.moves[c]
        row[CM.M_P0:CM.M_P0 + 3] = self.pos[c]
        row[CM.M_Q0:CM.M_Q0 + 4] = self.quat[c]
        row[CM.M_P1:CM.M_P1 + 3] = pos
        row[CM.M_Q1:CM.M_Q1 + 4] = quat
        row[CM.M_DUR] = seconds
        row[CM.M_EL] = 0.0
        row[CM.M_VEL:CM.M_VEL + 3] = vel
        row[CM.M_AXIS:CM.M_AXIS + 3] = axis
        row[CM.M_ANGLE] = angle
        self.mode[c] = CM.MOVE            # a commanded move ends the scripted path

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

    @property
    def playing(self):
        """Indices of the colliders still playing their scripted path."""
        return set(np.flatnonzero(self.mode == CM.PATH).tolist())

    def motion_arrays(self) -> KC.ColliderMotion:
        """The arrays the compiled motion reads and writes (views of this set's own)."""
        return KC.ColliderMotion(self.mode, self.pos, self.quat, self.moves, self.done)

    def advance(self, h, t=0.0, advance_poses=CM.advance_poses):
        """Poses at the end of the next step (from time ``t``, of ``h`` s) and the
        velocities during it: one compiled call for every collider
        (``advance_poses``; the benchmark passes its Python twin)."""
        if advance_poses(self.motion_arrays(), self.keys, self.rows, float(h), float(t)):
            for c in np.flatnonzero(self.done):
                self.motion[c] = None
            self.done[:] = 0

    # ------------------------------------------------------------------ contact
    def collide(self, particles, h, thresh, stats, touched):
        """Run the pass over ``particles`` (``kinematic.Particles``: (3, N) state and the
        particles' bodies) after a step of h s (see ``kinematic.collide_range``)."""
        n = particles.x.shape[1]
        KC.collide_range(particles, 0, n, self.rows, h, thresh,
                         KC.ColliderTally(self.imp, stats, touched))

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


def _keyframes(items, pos0, quat0):
    """({collider: (times, positions, quaternions)} of the colliders with a scripted path
    (times from 0, the declared pose first), and all of them as ``kinematic.Keyframes``
    with each segment's axis and angle."""
    paths = {}
    offset, times_all, pos_all, quat_all, segments = [0], [], [], [], []
    for c, item in enumerate(items):
        frames = _path('collider', item)
        if frames:
            times = np.array([0.0] + [frame[0] for frame in frames])
            pos = [pos0[c]]
            quats = [quat0[c]]
            for _, position, quat in frames:
                pos.append(position)
                quats.append(quats[-1] if quat is None else quat)
            paths[c] = (times, np.array(pos), np.array(quats))
            times_all.extend(times)
            pos_all.extend(pos)
            quat_all.extend(quats)
            for k in range(len(times)):
                axis, angle = (rotation_between(quats[k], quats[k + 1])
                               if k + 1 < len(times) else (np.zeros(3), 0.0))
                segments.append([*axis, angle])
        offset.append(len(times_all))
    keys = KC.Keyframes(time=np.array(times_all, dtype=float),
                        pos=np.array(pos_all, dtype=float).reshape(-1, 3),
                        quat=np.array(quat_all, dtype=float).reshape(-1, 4),
                        segment=np.array(segments, dtype=float).reshape(-1, 4),
                        offset=np.array(offset, dtype=np.int64))
    return paths, keys
