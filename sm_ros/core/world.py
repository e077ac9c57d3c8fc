"""A world of shape-matched bodies and static colliders (algorithm.md)."""

import math

import numpy as np

import numba
from numba.typed import List as TypedList

from . import body as body_mod, body_build, tuning
from .body import Body
from .kernels.world_step import flow_plastic_bodies, step_bodies_parallel, step_single_bodies
from .packed import Pack
from .contact import BodyContact, Contact, ContactParams, default_radius
from .flat import FlatState
from .kernels.flags import SLEEP
from .kinematic import Particles
from .sleep import NO_TOUCHES, Sleep
from .stiff_contact import StiffContact, lying_on_another
from .world_colliders import WorldColliders


class World(WorldColliders):
    """Bodies, gravity and colliders; ``step(dt)`` advances every body once.

    The collider API (``set_colliders``, named and moving colliders, their wrenches) is
    the mixin ``WorldColliders`` in ``world_colliders.py``.
    """

    def __init__(self, gravity=(0.0, 0.0, -9.81)):
        self._gravity = np.zeros(3)
        self.gravity = gravity
        self._bodies = {}
        self._contacts = {}                    # body name -> (BodyContact, default radius)
        self._contact_params = ContactParams()
        self._flat = None                      # FlatState + Contact, rebuilt lazily
        self._split = None                     # compiled-step records (_split_bodies)
        self._split_fstates = []               # (body, numbers of its record) in _split
        self._layout = 0                       # bumped when bodies are added or removed
        self._contact = None
        self._sleep = None                     # sleep.Sleep with the contact pass
        self._wake_key = None                  # the colliders and gravity last seen
        self._coll_stats = None                # (bodies, 2) contacts, deepest: collider pass
        self._zeros = np.zeros(0, dtype=np.int32)
        self._one_touch = np.zeros(1, dtype=np.uint8)
        self._coupling_key = None
        self._stiff = StiffContact()            # stiff bodies' contacts (stiff_contact.py)
        self._stiff_stats = None                # (bodies, 5) what that pass counted
        self._stiff_touches = NO_TOUCHES        # its body pairs in contact (flat order)
        self._collider_radius = np.zeros(0)     # per body (flat order): _collider_radii
        self._radii_key = None
        self._stiff_key = self._stiff_cache = None      # _stiff_members
        self._flat_builds = 0                  # flat states built (keys what was made of one)
        self._flagged = False                  # see state_flagged
        self.time = 0.0
        self.set_colliders()

    def step_state(self) -> tuple:
        """What a step changes and a later step reads (``snapshot``): the time, the bodies,
        the flat state, contact, sleep, the collider pass, the stiff bodies' pass and what
        the last step saw."""
        return ('time', '_flagged', '_wake_key', '_coll_stats', '_stiff_stats', '_bodies',
                '_flat', '_contact', '_sleep', '_cset', '_stiff')

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
        self._gnorm = float(np.linalg.norm(g))      # for the restitution threshold (step)
        self._world_version = getattr(self, '_world_version', 0) + 1    # wakes (sleep.py)

    def contact_stats(self):
        """{body name: (contacts, deepest penetration in m)} of the last step: the collider
        pass (particle-collider contacts), body-body contact (pairs) and the particles
        resting on the ground and plain boxes and spheres (``static_contacts``: counted,
        their depth before the fused step projected them is not known) together."""
        out = self.collider_contacts()
        for name, n in self.static_contacts().items():
            if n:
                m, d = out.get(name, (0, 0.0))
                out[name] = (m + n, d)
        c, f = self._contact, self._flat
        if c is not None and c.needed and f is not None:
            for k, b in enumerate(f.bodies):
                n, d = out.get(b.name, (0, 0.0))
                out[b.name] = (n + int(c.count[k]), max(d, float(c.deepest[k])))
        return out

    @property
    def bodies(self):
        """The bodies, in the order they were added."""
        return list(self._bodies.values())

    def body(self, name: str) -> Body:
        """The body called ``name`` (KeyError if there is none)."""
        return self._bodies[name]

    def add_body(self, points, masses=1.0, params=None, name=None, velocities=None,
                 pinned=None, contact=None) -> Body:
        """Build a body from a point set (N, 3); see ``Body`` (it picks the storage order of
        its particles; every array it hands out is in the caller's order).

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
        r0 = default_radius(body._x_init) if contact.radius is None else contact.radius
        self._bodies[name] = body
        self._contacts[name] = (contact, r0)
        self._flat = None
        self._layout += 1
        return body

    def remove_body(self, name: str):
        """Remove the body called ``name`` (KeyError if there is none)."""
        del self._bodies[name]
        self._contacts.pop(name, None)
        self._flat = None
        self._layout += 1

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
        if new != old and self._sleep is not None:
            self._sleep.wake_all()             # new contact settings: every body awake

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
        r0 = default_radius(body._x_init) if contact.radius is None else contact.radius
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
                self._contacts[b.name] = (BodyContact(), default_radius(b._x_init))
        self._flat = FlatState(bodies)
        self._flat_builds += 1
        p = self._contact_params
        if p.enabled and bodies:
            bcs = [self._contacts[b.name][0] for b in bodies]
            radii = [self.contact_radius(b.name) for b in bodies]
            self._contact = Contact(self._flat, p, bcs, radii)
        else:
            self._contact = None
        # sleeping needs the contact pass (sleep.py): a world of one body never sleeps
        c = self._contact
        self._sleep = Sleep(self._flat) if c is not None and c.needed else None
        if self._sleep is None:
            for b in bodies:
                b._flags[SLEEP] = min(b._flags[SLEEP], 0.0)

    @property
    def asleep(self):
        """Names of the sleeping bodies (doc/sleeping.md)."""
        return [b.name for b in self._bodies.values() if b.asleep]

    @property
    def asleep_count(self) -> int:
        """How many bodies are asleep (as of the last step; 0 without sleeping)."""
        sl = self._sleep
        return int(sl.slept.sum()) if sl is not None and self._flat is not None else 0

    @property
    def all_asleep(self) -> bool:
        """Whether there are bodies and every one is asleep now (their flags: a body
        woken since the last step counts as awake; one compiled call)."""
        sl = self._sleep
        return sl is not None and self._flat is not None and sl.all_asleep()

    def wake(self):
        """Wake every body (they are stepped again from the next step)."""
        for b in self._bodies.values():
            if b._flags[SLEEP] > 0.0:
                b._flags[SLEEP] = 0.0
        if self._sleep is not None:
            self._sleep.wake_all()

    def _sleep_check(self):
        """Wake every body when gravity or the colliders changed; return whether every
        body is asleep (then the step has nothing to do).  A world with collider-pass
        colliders (named, oriented, moving: their wrenches are published) does not sleep:
        a sleeping body would not weigh on them (doc/sleeping.md)."""
        sl = self._sleep
        if sl is None:
            return False
        cs = self._cset
        key = self._world_version              # gravity or colliders set since
        if key != self._wake_key or cs is not None:
            self._wake_key = key
            if sl.slept.any():
                self.wake()
            return False
        return bool(sl.slept.all()) and sl.all_asleep()

    def step(self, dt: float):
        """Advance every body by one step of ``dt`` seconds (Eq. 13-14, then colliders)."""
        h = float(dt)
        if not (math.isfinite(h) and h > 0.0):
            raise ValueError(f'dt must be a finite number > 0, got {dt!r}')
        # restitution applies only above this approach speed, so resting contact stays put
        thresh = max(1e-3, 2.0 * self._gnorm * h)
        cs = self._cset
        if cs is not None:
            cs.advance(h, self.time)
        if self._flat is None:
            self._ensure_flat()
        if self._sleep is not None and self._sleep_check():
            # every body asleep (sleep.py): nothing moves; the collider wrenches average
            # over the time as before
            self._flagged = True
            if cs is not None:
                cs.imp_time += h
            self.time += h
            return
        self._stiff_pass(h, thresh)
        _, pack, records, slow, helpers, nrec, plastic = self._split_now(h)
        args = (h, self._gravity, self._has_col, self._ground_row, self._box_rows,
                self._sphere_rows, thresh)
        # the one-cluster rigid/linear bodies: one compiled call over their rows (packed.py)
        step_pack = None if pack is None else (lambda: pack.step(*args))
        if nrec and helpers:
            # the records (kernels/world_step.py) shared with helper threads; the pack is
            # stepped here while they wake
            step_bodies_parallel(records, *args, before=step_pack)
        else:
            if step_pack is not None:
                step_pack()
            if nrec:
                # one compiled call for the bodies it covers (kernels/world_step.py)
                step_single_bodies(records, *args)
        if plastic is not None:
            flow_plastic_bodies(plastic, h)    # after their step (kernels/world_step.py)
        for body in slow:
            if not body.asleep:                # asleep: not stepped (sleep.py)
                body._step(*args)
        c = self._contact
        # the bodies' own passes ended the step unless a world pass runs (state_flagged)
        self._flagged = cs is None and (c is None or not c.needed)
        if not self._flagged:
            self._world_passes(h, thresh)
        if cs is not None:
            cs.imp_time += h
        self.time += h

    @property
    def state_flagged(self) -> bool:
        """Whether the last ``step`` ended with the bodies' own integration passes.

        Then a body whose positions or velocities are not finite has a non-finite entry in
        its shape-error sums (``Body._err``, written by the pass: ``kernels.integrate.
        advance``), so a check of a few numbers per body finds it (``sm_ros.nonfinite``)
        without reading x and v.  False before the first step and after a step whose
        body-body contact or pass colliders moved particles after those passes; valid until
        the state is written by hand (``set_state``, ``reset``: those write finite values).
        """
        return getattr(self, '_flagged', False)

    def __getstate__(self):
        state = self.__dict__.copy()
        state['_split'] = None                 # a typed list does not copy: rebuilt
        state['_split_fstates'] = []
        return state

    #: Step the bodies ``kernels.world_step`` covers in one compiled call (tests compare).
    compiled_step = True

    def _split_bodies(self, h):
        """The pack, the records, the bodies stepped on their own and whether the records
        are shared with helper threads (``_split_now``'s)."""
        return self._split_now(h)[1:5]

    def _split_now(self, h):
        """The split of the bodies at the step ``h``: (key, ``packed.Pack`` of the
        one-cluster rigid/linear bodies or None, typed list of compiled-step records of the
        other bodies, bodies stepped on their own (built for threads: ``Body._step``),
        whether the records are shared with helper threads, how many records, the records
        of plastic bodies or None), rebuilt only when a body's buffers,
        parameters, grabs or wrench kind, the bodies, the step or the packing
        (``Pack.stale``: one of its bodies was packed elsewhere since) changed.  Python
        cost per step does not grow with the number of bodies.  The records are shared
        with helper threads with several threads, several records and
        ``tuning.RECORDS_PARALLEL_MIN_WORK`` particles in records (``step_bodies_parallel``
        never waits for a helper that has not started).  The record count is kept: a typed
        list's ``len`` is a compiled call."""
        self._collider_radii(h)                # their radii before their records take them
        key = (body_mod._GENERATION[0], h, self._layout, self.compiled_step)
        split = self._split
        fresh = split is not None and not (split[1] is not None and split[1].stale)
        if fresh and split[0] != key and split[0][:1] + split[0][2:] == key[:1] + key[2:]:
            # only the step changed (the live error estimate's half steps): the numbers
            # that depend on it, in place
            self._retime_split(h)
            split = self._split = (key,) + split[1:]
        if split is None or split[0] != key or (split[1] is not None and split[1].stale):
            records, packed, slow, rec_work, plastic = TypedList(), [], [], 0, []
            self._split_fstates = []            # each record's numbers (``retime_record``)
            for body in self._bodies.values():
                if self.compiled_step and body._packed_ok():
                    packed.append(body)
                elif self.compiled_step and not body._parallel:
                    records.append(body._fast_record(h))
                    if body._params.plastic:
                        plastic.append(body_build.plastic_record(body))
                    self._split_fstates.append((body, body._fstate))
                    rec_work += body.n
                else:
                    slow.append(body)
            pack = Pack(packed, h) if packed else None
            helpers = (numba.get_num_threads() > 1 and len(records) > 1
                       and rec_work >= tuning.RECORDS_PARALLEL_MIN_WORK)
            plastic = TypedList(plastic) if plastic else None
            split = self._split = (key, pack, records, slow, helpers, len(records), plastic)
        return split

    def _retime_split(self, h):
        """Write the numbers of the split's pack rows and records for steps of ``h`` in
        place (``Pack.retime``, ``body_build.retime_record``)."""
        pack = self._split[1]
        if pack is not None:
            pack.retime(h)
        for body, fstate in self._split_fstates:
            body_build.retime_record(body, fstate, h)

    def _world_passes(self, h, thresh):
        """Passes over the world's flat state after the bodies' step (flat.py), called by
        ``step`` only when one is needed: body-body contact to run (not off, and two
        colliding bodies or self-collision) or pass colliders.

        Gather every body's state into ``FlatState`` X/V, run body-body contact and the
        collider pass (colliders last: no particle ends a step inside one), copy the
        touched bodies back.  With pass colliders but no contact to run, the collider
        pass works on each body's own buffers (seen as (3, N)) and copies nothing.
        """
        c, cs = self._contact, self._cset
        need_contact = c is not None and c.needed
        f = self._flat
        st = self._coll_stats
        if st is None or len(st) != len(f.bodies):
            st = self._coll_stats = np.zeros((len(f.bodies), 2))
        if need_contact:
            self._contact_coupling(h)
            sl = self._sleep
            if sl is not None:
                sl.sync()                      # bodies woken from outside: masses back
            f.gather()
            c.run(h, thresh, self._contact_colliders(thresh), self._gravity,
                  lying_on_another(self._stiff_touches, len(f.bodies)))
            c.add_counts(self._stiff_stats)
            if cs is not None:
                st[:] = 0.0
                cs.collide(Particles(f.X, f.V, f.W, f.B, self._collider_radius), h, thresh,
                           st, f.touched)
            # bodies sleep only under gravity: without it nothing rests on anything, and
            # freezing a slow drift would take momentum out of a conservative world
            if sl is not None and cs is None and self._contact_params.sleep and self._gnorm:
                sl.update(c, h, self._contact_params, self._gravity, self._stiff_touches)
            f.scatter()
            return
        f.refresh_masses()
        for k, body in enumerate(f.bodies):
            o0, o1 = f.off[k], f.off[k + 1]
            sk = st[k:k + 1]
            sk[:] = 0.0
            cs.collide(Particles(body._x.T, body._v.T, f.W[o0:o1], self._zero_bid(body.n),
                                 self._collider_radius[k:k + 1]), h, thresh, sk,
                       self._one_touch)
            if sk[0, 0] > 0.0:
                body._dirty = True            # moved particles: re-accumulate the next step

    def _contact_coupling(self, h):
        """Mark the bodies that carry their contacts as a whole (``Contact.coupling``):
        alpha at the step at least ``tuning.COUPLE_ALPHA``, with one cluster or many
        (doc/contact.md).  Recomputed when a body, its parameters or the step change.
        Keyed by the count of flat states built, not the flat state's id: a deep copy of
        the world holds the coupling flags with the key they were set for, and keeps them."""
        key = (body_mod._GENERATION[0], h, self._flat_builds)
        if self._coupling_key == key:
            return
        c = self._contact.coupling
        for k, b in enumerate(self._flat.bodies):
            c[k] = b._params.at_step(h).alpha >= tuning.COUPLE_ALPHA
        self._coupling_key = key

    def _stiff_pass(self, h, thresh):
        """The stiff bodies take their contacts as rigid bodies (``stiff_contact.py``)
        before their own step; the contact pass leaves their pairs alone.  Their contact
        figures wait in ``_stiff_stats`` (flat body order) for the diagnostics."""
        bodies = self._flat.bodies
        stiff, index, members, hard = self._stiff_members(h)
        c = self._contact
        if c is not None:
            c.set_rigid(stiff)
        stats = self._stiff_stats
        if stats is None or len(stats) != len(bodies):
            stats = self._stiff_stats = np.zeros((len(bodies), 5))
        stats[:] = 0.0
        self._stiff_touches = NO_TOUCHES
        if not any(not body.asleep for body, _ in members):
            return
        if not self._stiff_can_touch(members):  # nothing to meet: a step adds no contact
            self._stiff.forget()
            return
        stats[index], pairs = self._stiff.run(self, members, hard[index], h, thresh)
        # the pairs name members: in flat body indices for the sleep pass
        self._stiff_touches = np.column_stack((index[pairs[:, 0]], index[pairs[:, 1]],
                                               pairs[:, 2]))

    def _stiff_can_touch(self, members):
        """Whether the stiff bodies ``members`` may meet anything in the stiff pass: a
        collider, or each other (two of them colliding).  A lone rigid body in the air
        pays nothing for contact."""
        if self._has_col or self._cset is not None:
            return True
        if not self._contact_params.enabled:
            return False
        colliding = 0
        for body, _ in members:
            colliding += self._contacts[body.name][0].collide
            if colliding == 2:
                return True
        return False

    def _zero_bid(self, n):
        """Body index 0 for n particles (the per-body path of the collider pass)."""
        z = self._zeros
        if len(z) < n:
            z = self._zeros = np.zeros(max(n, 2 * len(z)), dtype=np.int32)
        return z[:n]

    def reset(self):
        """Every body back to its initial state; time 0."""
        for body in self._bodies.values():
            body.reset()
        if self._contact is not None:
            self._contact.invalidate()
        if self._cset is not None:
            self._cset.reset()
        self.time = 0.0
