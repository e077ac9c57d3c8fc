"""
Inputs of the simulation (no ROS): validation of wrenches and gripper poses, and grippers.

Every check raises :class:`InputError` with the reason the node reports as a refusal;
nothing is changed by a refused input.
"""

from dataclasses import dataclass
from typing import Dict, Iterable, List, Optional, Tuple

import numpy as np

from sm_ros.params import MAX_COORDINATE
from sm_ros.rotations import matrix_from_quaternion

#: Largest force (N) or torque (N*m) component; beyond it a wrench is refused.
MAX_WRENCH = 1e9


class InputError(ValueError):
    """An input the simulation refuses; the message says why."""


def checked_wrench(force, torque) -> Tuple[np.ndarray, np.ndarray]:
    """Return force and torque as float arrays; raise InputError on NaN/Inf or too large."""
    f = np.asarray(force, dtype=np.float64).reshape(3)
    t = np.asarray(torque, dtype=np.float64).reshape(3)
    if not (np.isfinite(f).all() and np.isfinite(t).all()):
        raise InputError('NaN or Inf in the wrench')
    if np.abs(f).max() > MAX_WRENCH or np.abs(t).max() > MAX_WRENCH:
        raise InputError(f'wrench component beyond +-{MAX_WRENCH:g} (out of range)')
    return f, t


def checked_pose(name: str, position, quaternion) -> Tuple[np.ndarray, np.ndarray]:
    """Return (position, rotation matrix) of a gripper pose; raise InputError if bad."""
    if not name:
        raise InputError('empty gripper name (header.frame_id)')
    pos = np.asarray(position, dtype=np.float64).reshape(3)
    quat = np.asarray(quaternion, dtype=np.float64).reshape(4)
    if not (np.isfinite(pos).all() and np.isfinite(quat).all()):
        raise InputError(f"NaN or Inf in the pose of gripper '{name}'")
    if np.abs(pos).max() > MAX_COORDINATE:
        raise InputError(f"position of gripper '{name}' beyond +-{MAX_COORDINATE:g} m")
    norm = float(np.linalg.norm(quat))
    if not 1e-6 < norm < 1e6:
        raise InputError(f"orientation of gripper '{name}' is not a rotation "
                         f'(quaternion norm {norm:g})')
    return pos, matrix_from_quaternion(*quat)


def checked_points(points) -> np.ndarray:
    """Return cloud points (N, 3); raise InputError when a coordinate is out of range."""
    pts = np.asarray(points, dtype=np.float64)
    if pts.size and np.abs(pts).max() > MAX_COORDINATE:
        raise InputError(f'coordinates beyond +-{MAX_COORDINATE:g} m')
    return pts


@dataclass
class Attachment:
    """The particles of one body held by one gripper, in the gripper's frame."""

    body: str
    indices: np.ndarray
    local: np.ndarray
    targets: Optional[np.ndarray] = None


class Grippers(Dict[str, List[Attachment]]):
    """
    The attached grippers: gripper name -> attachments (one per body it holds).

    A gripper's first pose attaches every particle within the grab radius; later poses
    move them rigidly. Held particles become kinematic (``Body.set_kinematic``).
    """

    def grab(self, world, name: str, position, quaternion, radius: float) -> None:
        """Attach (first pose) or move gripper ``name``; raise InputError if refused."""
        pos, rot = checked_pose(name, position, quaternion)
        attachments = self.get(name)
        if attachments is None:
            attachments = []
            for body in world.bodies:
                d = body.x - pos
                idx = np.flatnonzero(np.einsum('ij,ij->i', d, d) <= radius * radius)
                if idx.size:
                    attachments.append(Attachment(body.name, idx, d[idx] @ rot))
            if not attachments:
                raise InputError(f'no particle within grab_radius {radius:g} m of gripper '
                                 f"'{name}' at ({pos[0]:g}, {pos[1]:g}, {pos[2]:g})")
            self[name] = attachments
        for a in attachments:
            a.targets = pos + a.local @ rot.T
        self.apply(world, {a.body for a in attachments})

    def release(self, world, name: str) -> None:
        """Release gripper ``name``, or all of them for ''; raise InputError if unknown."""
        if name and name not in self:
            known = ', '.join(self) or 'none'
            raise InputError(f"unknown gripper '{name}' (grippers: {known})")
        names = [name] if name else list(self)
        bodies = {a.body for n in names for a in self[n]}
        for n in names:
            del self[n]
        self.apply(world, bodies)

    def apply(self, world, body_names: Iterable[str]) -> None:
        """Give each named body the kinematic targets of all grippers holding it."""
        for body_name in body_names:
            body = world.body(body_name)
            held = [a for atts in self.values() for a in atts if a.body == body_name]
            if not held:
                body.clear_kinematic()
                continue
            idx = np.concatenate([a.indices for a in held])
            targets = np.concatenate([a.targets for a in held])
            idx, first = np.unique(idx, return_index=True)
            body.set_kinematic(idx, targets[first])

    def drop_body(self, body_name: str) -> None:
        """Forget every attachment to ``body_name`` (its kinematic state is not touched)."""
        for name in list(self):
            kept = [a for a in self[name] if a.body != body_name]
            if kept:
                self[name] = kept
            else:
                del self[name]


class Forces(Dict[str, float]):
    """Wrenches held on bodies: body name -> clock time of its last force.

    A force lasts until a zero wrench clears it or, with a ``force_timeout``, until it is
    not renewed in time (``expire``).
    """

    def hold(self, bodies, force: np.ndarray, torque: np.ndarray, now: float) -> None:
        """Set a checked wrench on ``bodies`` at clock time ``now``; zero clears it."""
        clear = not force.any() and not torque.any()
        for b in bodies:
            if clear:
                b.clear_wrench()
                self.pop(b.name, None)
            else:
                b.set_wrench(force, torque)
                self[b.name] = now

    def expire(self, world, timeout: float, clock) -> None:
        """Clear the wrenches of ``world``'s bodies not renewed within ``timeout`` s (0:
        never); ``clock()`` is read only when some force could expire."""
        if timeout <= 0.0 or not self:
            return
        now = clock()
        for name in [n for n, t in self.items() if now - t > timeout]:
            del self[name]
            world.body(name).clear_wrench()
