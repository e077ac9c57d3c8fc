"""A world of shape-matched bodies and static colliders (algorithm.md)."""

import math

import numpy as np

from .body import Body
from .params import Box, Ground, Sphere


class World:
    """Bodies, gravity and static colliders; ``step(dt)`` advances every body once."""

    def __init__(self, gravity=(0.0, 0.0, -9.81)):
        self._gravity = np.zeros(3)
        self.gravity = gravity
        self._bodies = {}
        self.time = 0.0
        self.set_colliders()

    @property
    def gravity(self) -> np.ndarray:
        """Gravity (m/s^2) as a copy; assign 3 finite numbers to change it."""
        return self._gravity.copy()

    @gravity.setter
    def gravity(self, value):
        g = np.asarray(value, dtype=float).reshape(-1)
        if g.shape != (3,) or not np.all(np.isfinite(g)):
            raise ValueError(f'gravity must be 3 finite numbers, got {value!r}')
        self._gravity[:] = g

    def set_colliders(self, ground=None, boxes=(), spheres=()):
        """Replace the static colliders (validated; all or nothing)."""
        if ground is not None and not isinstance(ground, Ground):
            raise ValueError('ground must be a Ground or None')
        if not all(isinstance(b, Box) for b in boxes):
            raise ValueError('boxes must be Box instances')
        if not all(isinstance(s, Sphere) for s in spheres):
            raise ValueError('spheres must be Sphere instances')
        g = np.array(ground.row() if ground else [0.0, 0.0, 0.0, 0.0])
        b = np.array([x.row() for x in boxes], dtype=float).reshape(-1, 8)
        s = np.array([x.row() for x in spheres], dtype=float).reshape(-1, 6)
        self.ground, self.boxes, self.spheres = ground, tuple(boxes), tuple(spheres)
        self._ground_row, self._box_rows, self._sphere_rows = g, b, s
        self._has_col = ground is not None or len(b) > 0 or len(s) > 0

    @property
    def bodies(self):
        """The bodies, in the order they were added."""
        return list(self._bodies.values())

    def body(self, name: str) -> Body:
        """The body called ``name`` (KeyError if there is none)."""
        return self._bodies[name]

    def add_body(self, points, masses=1.0, params=None, name=None, velocities=None,
                 pinned=None) -> Body:
        """Build a body from a point set (N, 3); see ``Body``."""
        if name is None:
            name = f'body{len(self._bodies)}'
        if not isinstance(name, str) or not name:
            raise ValueError('body name must be a non-empty string')
        if name in self._bodies:
            raise ValueError(f'a body called {name!r} exists already')
        body = Body(points, masses, params, name, velocities, pinned)
        self._bodies[name] = body
        return body

    def remove_body(self, name: str):
        """Remove the body called ``name`` (KeyError if there is none)."""
        del self._bodies[name]

    def step(self, dt: float):
        """Advance every body by one step of ``dt`` seconds (Eq. 13-14, then colliders)."""
        h = float(dt)
        if not (math.isfinite(h) and h > 0.0):
            raise ValueError(f'dt must be a finite number > 0, got {dt!r}')
        # restitution applies only above this approach speed, so resting contact stays put
        thresh = max(1e-3, 2.0 * float(np.linalg.norm(self._gravity)) * h)
        for body in self._bodies.values():
            body._step(h, self._gravity, self._has_col, self._ground_row, self._box_rows,
                       self._sphere_rows, thresh)
        self.time += h

    def reset(self):
        """Every body back to its initial state; time 0."""
        for body in self._bodies.values():
            body.reset()
        self.time = 0.0
