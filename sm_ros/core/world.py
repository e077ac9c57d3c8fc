"""A world of shape-matched bodies and static colliders (algorithm.md)."""

import math

import numpy as np

from .body import Body
from .contact import BodyContact, Contact, ContactParams, default_radius
from .flat import FlatState
from .params import Box, Ground, Sphere


class World:
    """Bodies, gravity and static colliders; ``step(dt)`` advances every body once."""

    def __init__(self, gravity=(0.0, 0.0, -9.81)):
        self._gravity = np.zeros(3)
        self.gravity = gravity
        self._bodies = {}
        self._contacts = {}                    # body name -> (BodyContact, default radius)
        self._contact_params = ContactParams()
        self._flat = None                      # FlatState + Contact, rebuilt lazily
        self._contact = None
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
                 pinned=None, contact=None) -> Body:
        """Build a body from a point set (N, 3); see ``Body``.

        ``contact``: a ``BodyContact`` (collide with other bodies, contact radius,
        self-collision); default: collides, radius half the median neighbour distance.
        """
        if name is None:
            name = f'body{len(self._bodies)}'
        if not isinstance(name, str) or not name:
            raise ValueError('body name must be a non-empty string')
        if name in self._bodies:
            raise ValueError(f'a body called {name!r} exists already')
        if contact is None:
            contact = BodyContact()
        if not isinstance(contact, BodyContact):
            raise ValueError('contact must be a BodyContact or None')
        contact = contact.validate()
        body = Body(points, masses, params, name, velocities, pinned)
        r0 = default_radius(body.x_init) if contact.radius is None else contact.radius
        self._bodies[name] = body
        self._contacts[name] = (contact, r0)
        self._flat = None
        return body

    def remove_body(self, name: str):
        """Remove the body called ``name`` (KeyError if there is none)."""
        del self._bodies[name]
        self._contacts.pop(name, None)
        self._flat = None

    # ------------------------------------------------------------------ contact
    @property
    def contact_params(self) -> ContactParams:
        """Scene-wide contact settings (assign a ``ContactParams``; validated)."""
        return self._contact_params

    @contact_params.setter
    def contact_params(self, value):
        if not isinstance(value, ContactParams):
            raise ValueError('contact_params must be a ContactParams')
        new = value.validate()
        old = self._contact_params
        rebuild = new.radius_scale != old.radius_scale or new.enabled != old.enabled
        self._contact_params = new
        if rebuild:
            self._flat = None
        elif self._contact is not None:
            self._contact.params = new

    def body_contact(self, name: str) -> BodyContact:
        """The contact settings of the body called ``name``."""
        return self._contacts[name][0]

    def set_body_contact(self, name: str, contact: BodyContact):
        """Replace a body's contact settings (validated; the radius rule as in add_body)."""
        if name not in self._bodies:
            raise KeyError(name)
        if not isinstance(contact, BodyContact):
            raise ValueError('contact must be a BodyContact')
        contact = contact.validate()
        body = self._bodies[name]
        r0 = default_radius(body.x_init) if contact.radius is None else contact.radius
        self._contacts[name] = (contact, r0)
        self._flat = None

    def contact_radius(self, name: str) -> float:
        """The contact radius (m) the body called ``name`` uses."""
        c, r0 = self._contacts[name]
        return r0 if c.radius is not None else r0 * self._contact_params.radius_scale

    @property
    def contact(self):
        """The contact pass (``Contact``: per-body counts, deepest, fast particles) or None
        when contact is off or cannot happen (fewer than two colliding bodies and no
        self-collision)."""
        self._ensure_flat()
        c = self._contact
        return c if c is not None and c.needed else None

    def _ensure_flat(self):
        """(Re)build the flat state and the contact pass after the bodies changed."""
        if self._flat is not None:
            return
        bodies = list(self._bodies.values())
        for b in bodies:                       # bodies put in by hand get the defaults
            if b.name not in self._contacts:
                self._contacts[b.name] = (BodyContact(), default_radius(b.x_init))
        self._flat = FlatState(bodies)
        p = self._contact_params
        if p.enabled and bodies:
            bcs = [self._contacts[b.name][0] for b in bodies]
            radii = [self.contact_radius(b.name) for b in bodies]
            self._contact = Contact(self._flat, p, bcs, radii)
        else:
            self._contact = None

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
        self._world_passes(h, thresh)
        self.time += h

    def _world_passes(self, h, thresh):
        """Passes over the world's flat state after the bodies' step (flat.py).

        Gather every body's state into ``FlatState`` X/V, run body-body contact, copy the
        touched bodies back.  Nothing runs (no copy) when no pass is needed: contact off,
        or one colliding body without self-collision.  Other world-level passes (moving
        colliders) go between ``gather`` and ``scatter`` and set ``flat.touched[b]``.
        """
        self._ensure_flat()
        c = self._contact
        if c is None or not c.needed:
            return
        f = self._flat
        f.gather()
        c.run(h, thresh)
        f.scatter()

    def reset(self):
        """Every body back to its initial state; time 0."""
        for body in self._bodies.values():
            body.reset()
        if self._contact is not None:
            self._contact.invalidate()
        self.time = 0.0
