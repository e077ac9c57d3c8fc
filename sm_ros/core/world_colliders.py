"""The collider side of ``World``: static, named, oriented and kinematic colliders.

A mixin of ``World`` (``world.py``), split off so that each file answers one question:
what collides with the bodies, how a user moves it and reads its wrench, and the radius
each body's particles meet the colliders with (``_collider_radii``).  Unnamed
axis-aligned boxes and spheres and the ground run inside each body's fused step
(``kernels/colliders.py``); everything else goes through the collider pass
(``kinematic.py``, ``ColliderSet``) after the bodies' step.
"""

import numpy as np

from . import body_build
from .colliders import ColliderSet
from .kernels.colliders import Colliders
from .params import Box, Capsule, Ground, Sphere
from .stiff_contact import is_stiff, takes_part


class WorldColliders:
    """Collider state and API of a ``World`` (uses its ``_bodies``, ``_flat``,
    ``_coll_stats``)."""

    def set_colliders(self, ground=None, boxes=(), spheres=(), capsules=()):
        """Replace the colliders (validated; all or nothing).

        Unnamed, axis-aligned static boxes and spheres are handled inside each body's
        fused step as before; named, oriented or kinematic ones and capsules go through
        the collider pass (``kinematic.py``) after the bodies' step.  Passing the same
        collider objects again keeps the pass colliders' current poses and motion.
        """
        if ground is not None and not isinstance(ground, Ground):
            raise ValueError('ground must be a Ground or None')
        if not all(isinstance(b, Box) for b in boxes):
            raise ValueError('boxes must be Box instances')
        if not all(isinstance(s, Sphere) for s in spheres):
            raise ValueError('spheres must be Sphere instances')
        if not all(isinstance(c, Capsule) for c in capsules):
            raise ValueError('capsules must be Capsule instances')
        boxes, spheres, capsules = tuple(boxes), tuple(spheres), tuple(capsules)
        g = np.array(ground.row() if ground else [0.0, 0.0, 0.0, 0.0])
        b = np.array([x.row() for x in boxes if x.simple], dtype=float).reshape(-1, 8)
        s = np.array([x.row() for x in spheres if x.simple], dtype=float).reshape(-1, 6)
        passing = [x for x in boxes + spheres if not x.simple] + list(capsules)
        names = [x.name for x in passing if x.name is not None]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise ValueError(f'collider names must be unique, repeated: {dup}')
        old = getattr(self, '_cset', None)
        if old is not None and len(old.items) == len(passing) and all(
                a is b_ for a, b_ in zip(old.items, passing)):
            cset = old
        else:
            cset = ColliderSet(passing) if passing else None    # validates every shape
        self.ground, self.boxes, self.spheres = ground, boxes, spheres
        self.capsules = capsules
        self._ground_row, self._box_rows, self._sphere_rows = g, b, s
        self._has_col = ground is not None or len(b) > 0 or len(s) > 0
        self._cset = cset
        self._world_version = getattr(self, '_world_version', 0) + 1    # wakes (sleep.py)

    @property
    def collider_names(self):
        """Names of the named colliders, in the order boxes, spheres, capsules."""
        return tuple(self._cset.index) if self._cset is not None else ()

    def collider(self, name: str):
        """The Box / Sphere / Capsule called ``name`` (ValueError if there is none)."""
        cs = self._require_cset(name)
        return cs.items[cs.lookup(name)]

    def _require_cset(self, name):
        if self._cset is None:
            raise ValueError(f'unknown collider {name!r} (the world has no named colliders)')
        return self._cset

    def collider_pose(self, name: str):
        """Current (position (3,), quaternion (x, y, z, w)) of collider ``name``, copies."""
        cs = self._require_cset(name)
        c = cs.lookup(name)
        return cs.pos[c].copy(), cs.quat[c].copy()

    def move_collider(self, name: str, position, orientation=(0.0, 0.0, 0.0, 1.0),
                      duration: float = 0.0):
        """Move the kinematic collider ``name`` to a pose over the next ``duration`` s.

        Each step moves it along the way (position linearly, orientation by slerp) at the
        constant linear and angular velocity the move implies, which friction and
        restitution see; ``duration`` 0 puts it there at once, at rest.  A new move starts
        from wherever the collider is.  Unknown or static colliders, non-finite numbers and
        zero or non-unit quaternions (|q| off 1 by more than 1e-3) raise ValueError and
        change nothing.
        """
        self._require_cset(name).move(name, position, orientation, duration)

    def collider_wrench(self, name: str):
        """(force, torque about its centre) the bodies exert on collider ``name``, averaged
        over the steps since the last ``take_collider_wrenches`` (world frame; N, N m)."""
        cs = self._require_cset(name)
        return cs.wrench(cs.lookup(name))

    def take_collider_wrenches(self):
        """{name: (force, torque)} of every named collider averaged over the steps since
        the last call (impulses / time), and start a new window."""
        return self._cset.take() if self._cset is not None else {}

    def collider_contacts(self):
        """{body name: (contacts, deepest penetration in m)} with the pass colliders in the
        last step (one contact per particle and collider touched)."""
        st, f = self._coll_stats, self._flat
        if f is None:
            return dict.fromkeys(self._bodies, (0, 0.0))
        out = {}
        for k, b in enumerate(f.bodies):
            count, deepest = self._stiff_count(k, 1)
            if st is not None and len(st) == len(f.bodies):
                count, deepest = count + int(st[k, 0]), max(deepest, float(st[k, 1]))
            out[b.name] = (count, deepest)
        return out

    def _stiff_count(self, k, column):
        """(particles of flat body k the stiff pass found touching the plain colliders
        (column 0) or the others (1), its deepest overlap) in the last step."""
        stiff = self._stiff_stats
        if stiff is None or k >= len(stiff):
            return 0, 0.0
        return int(stiff[k, column]), float(stiff[k, 3])

    #: A particle within this distance (m) of a static collider's surface, or inside it,
    #: touches it (the fused step puts a penetrating particle exactly on the surface).
    STATIC_TOUCH = 1e-9

    def static_contacts(self):
        """{body name: particles touching the ground and the plain (unnamed, axis-aligned,
        static) boxes and spheres at the end of the last step}, one per particle and
        collider.

        These colliders are resolved inside each body's fused step, which projects a
        penetrating particle exactly onto the surface and keeps no record of it: the count
        is of the particles whose spheres (``Body._collider_radius``) lie on (or within
        ``STATIC_TOUCH`` of, or inside) a surface now, and how deep they were before the
        projection is not known.  Computed when asked (NumPy over each body's positions;
        ``/diagnostics`` asks once a period).
        A stiff body's particles are spheres (``stiff_contact.py``): the pass counted those
        within ``stiff_contacts.TOUCH`` of a surface before the step.
        """
        out = dict.fromkeys(self._bodies, 0)
        if not self._has_col:
            return out
        if self._flat is not None:       # the stiff bodies rest on their particles' spheres
            for k, body in enumerate(self._flat.bodies):
                out[body.name] = self._stiff_count(k, 0)[0]
        tol = self.STATIC_TOUCH
        g, boxes, spheres = self._ground_row, self._box_rows, self._sphere_rows
        for name, body in self._bodies.items():
            x = body._x
            reach = tol + body._collider_radius      # its particles meet them as spheres
            n = 0
            if g[0] > 0.5:
                n += int(np.count_nonzero(x[:, 2] <= g[1] + reach))
            for b in boxes:
                n += int(np.count_nonzero(np.all((x >= b[:3] - reach) & (x <= b[3:6] + reach),
                                                 axis=1)))
            for sp in spheres:
                d = x - sp[:3]
                n += int(np.count_nonzero(np.einsum('ij,ij->i', d, d)
                                          <= (sp[3] + reach) ** 2))
            out[name] += n
        return out

    def _contact_colliders(self, thresh):
        """The static colliders as the contact pass meets them (``Colliders`` with one
        radius per body, flat order)."""
        return Colliders(bool(self._has_col), self._ground_row, self._box_rows,
                         self._sphere_rows, float(thresh), self._collider_radius, 0.0)

    def _stiff_members(self, h):
        """(per body, flat order, whether it takes its contacts in the stiff pass; the
        indices of those that do; their (body, contact radius) pairs; per body whether it
        is stiff, ``stiff_contact.is_stiff``), kept while no body, its parameters, the
        step or the contact settings change.  A body that is not stiff joins only where it
        can meet a stiff one: a world of bodies carried as a whole and none stiff keeps
        them in the faster contact pass."""
        cp = self._contact_params
        key = (body_build._GENERATION[0], h, self._flat_builds, cp.stacking, cp.rigid,
               bool(self._gnorm))
        if key != self._stiff_key:
            bodies, on = self._flat.bodies, cp.stacking and cp.rigid
            stiff = np.array([on and is_stiff(b, h) for b in bodies], dtype=np.bool_)
            member = stiff | np.array([on and takes_part(b, h, bool(self._gnorm))
                                       and not self._contacts[b.name][0].self_collision
                                       for b in bodies], dtype=np.bool_)
            meets = np.array([cp.enabled and self._contacts[b.name][0].collide
                              for b in bodies], dtype=np.bool_)
            if not (stiff & meets).any() or (member & meets).sum() < 2:
                member = stiff                  # no stiff body to meet: the stiff ones only
            index = np.flatnonzero(member)
            members = [(bodies[k], self.contact_radius(bodies[k].name)) for k in index]
            old = self._stiff_cache
            if old is not None and old[2] == members and np.array_equal(old[3], stiff):
                members = old[2]        # the same list: the stiff pass keeps what it built
            self._stiff_cache, self._stiff_key = (member, index, members, stiff), key
        return self._stiff_cache

    def _collider_radii(self, h):
        """Every body meets the colliders with its particles' spheres of its contact
        radius, as it meets other bodies (``Body._collider_radius``, ``_collider_radius``
        per body); a stiff body meets them in the stiff pass, so its own pass and the
        collider pass only keep its particles' centres out of them (radius 0).  Set again
        when a body, its parameters, the step or the contact settings change."""
        self._ensure_flat()
        cp = self._contact_params
        key = (body_build._GENERATION[0], h, self._flat_builds, cp.stacking, cp.rigid)
        if key == self._radii_key:
            return
        bodies, stiff = self._flat.bodies, self._stiff_members(h)[3]
        radii = np.array([0.0 if stiff[k] else self.contact_radius(b.name)
                          for k, b in enumerate(bodies)])
        changed = any(b._collider_radius != r for b, r in zip(bodies, radii))
        for b, r in zip(bodies, radii):
            b._collider_radius = float(r)
        if changed and self._split is not None:
            self._retime_split(self._split[0][1])   # the pack rows and records take them
        self._collider_radius = radii
        self._radii_key = key
