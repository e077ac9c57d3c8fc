"""Contact between bodies, and self-collision, on the world's flat state (``flat.py``).

Model (doc/contact.md): every particle of a colliding body is a sphere of
its body's contact radius ``r``; two particles of different bodies (or of one
self-colliding body whose rest distance exceeds ``tuning.SELF_REST_FACTOR`` times their contact
distance) must stay at least ``r_i + r_j`` apart.  After the bodies' own step (each
substep) every overlapping pair is pushed apart along the line of its start-of-step
positions (x - h v), weighted by inverse mass (pinned and grabbed particles have infinite
mass), equal and opposite, so linear momentum is kept to round-off; its relative velocity
then gets the ground's contact law (``solve_pairs``).  Every velocity change also moves the
particles by h times it, so without friction angular momentum is kept to round-off too.
Particles that contact moved are then projected out of the static colliders again.
With ``ContactParams.stacking`` (the default), under gravity, a stiff body (alpha at the
step at least ``tuning.COUPLE_ALPHA``, one cluster or many, no pinned or grabbed particle) carries
its contacts as a whole: an impulse on one of its particles translates the body, so its
load reaches all of it within the step instead of compressing its touching layer; such
pairs, and such bodies on the ground, are solved with accumulated impulses over several
sweeps, warm-started from the last step (``tuning.WARM_START``), and a carried body held by
another does not spin (``contact_bodies.solve_bodies``): stacks stand and heaps of such
bodies (``paper_384``) come to rest at the node's step.

Neighbour search (a Verlet pair list on a cell grid) and the per-pair solve are compiled
kernels in ``contact_build.py``, ``kernels/pair_grid.py``, ``contact_kernels.py`` and
``contact_bodies.py``; this file holds the settings
(``ContactParams``, ``BodyContact``) and the pass ``Contact`` that owns the buffers and calls
them.
"""

from dataclasses import dataclass, fields, replace
import math
from typing import Optional

import numpy as np

from .contact_bodies import solve_bodies
from .contact_build import (GridScratch, PairSource, body_overlaps, build_pairs_grid,
                            drop_rigid_pairs, moved_spread2, sort_pairs)
from .contact_kernels import (body_inverse_masses, body_velocities, count_fast,
                              inverse_sym3, median_nn_distance, solve_pairs, wall_candidates)
from .contact_state import (NO_WALLS, CarriedBodies, ContactLaw, ContactParticles,
                            ContactReport, PairList, PairSweep, WallCandidates)
from .kernels.colliders import Colliders, contact_velocity
from .params import _finite
from . import tuning

_NO_GROUND = np.zeros(4)
_NO_ROWS8 = np.zeros((0, 8))
_NO_ROWS6 = np.zeros((0, 6))


# ---------------------------------------------------------------------------------------
# Parameters
# ---------------------------------------------------------------------------------------

def _flag(name, value):
    if not isinstance(value, (bool, np.bool_)):
        raise ValueError(f'{name} must be true or false, got {value!r}')
    return bool(value)


@dataclass(frozen=True)
class ContactParams:
    """Scene-wide contact settings (doc/contact.md).

    ``enabled`` turns body-body contact on; ``friction`` (Coulomb mu) and ``restitution``
    act like the ground's; ``radius_scale`` multiplies every body's default contact
    radius (half its median nearest-neighbour distance; a body's own ``contact_radius``
    is used as given); ``iterations`` Gauss-Seidel sweeps over the pairs per step.
    ``stacking`` (on by default; scene key ``contact: {stacking: ...}``, node parameter
    ``contact.stacking``): under gravity, stiff bodies carry their contacts as a whole
    (``tuning``: ``COUPLE_ALPHA``, ``STACK_SWEEPS``, ``WARM_START``; doc/contact.md:
    stacks stand and heaps of such bodies come to rest at the node's step); False: every
    particle acts on its own (``solve_pairs``), as softer bodies always do.
    ``rigid`` (on by default; ``contact.rigid``): stiff bodies, and under gravity those
    stacking carries, take their contacts with one another as rigid bodies
    (``stiff_contact.py``); False: stacking carries them as a whole in this pass.
    ``sleep`` (on by default): a body whose particles all moved slower than
    ``sleep_speed`` (m/s) for ``sleep_time`` seconds and that touches no moving body falls
    asleep and is not stepped until something wakes it (``sleep.py``, doc/sleeping.md).
    """

    enabled: bool = True
    friction: float = 0.5
    restitution: float = 0.0
    radius_scale: float = 1.0
    iterations: int = 1
    stacking: bool = True
    rigid: bool = True
    sleep: bool = True
    sleep_speed: float = 0.01
    sleep_time: float = 0.5

    def validate(self) -> 'ContactParams':
        """Return a normalised copy; raise ValueError naming the bad field."""
        it = self.iterations
        if isinstance(it, bool) or not isinstance(it, (int, np.integer)) or not 1 <= it <= 16:
            raise ValueError(f'contact.iterations must be an integer in [1, 16], got {it!r}')
        return replace(
            self,
            enabled=_flag('contact.enabled', self.enabled),
            friction=_finite('contact.friction', self.friction, 0.0, 10.0),
            restitution=_finite('contact.restitution', self.restitution, 0.0, 1.0),
            radius_scale=_finite('contact.radius_scale', self.radius_scale, 0.0, 10.0,
                                 lo_open=True),
            iterations=int(it),
            stacking=_flag('contact.stacking', self.stacking),
            rigid=_flag('contact.rigid', self.rigid),
            sleep=_flag('contact.sleep', self.sleep),
            sleep_speed=_finite('contact.sleep_speed', self.sleep_speed, 0.0, 10.0),
            sleep_time=_finite('contact.sleep_time', self.sleep_time, 0.0, 3600.0),
        )

    @staticmethod
    def field_names():
        """Names of all fields."""
        return tuple(f.name for f in fields(ContactParams))


@dataclass(frozen=True)
class BodyContact:
    """Per-body contact settings: ``collide`` with other bodies, ``radius`` (m, of the
    spheres its particles meet other bodies and the colliders with; None = the default
    rule), ``self_collision`` (opt-in)."""

    collide: bool = True
    radius: Optional[float] = None
    self_collision: bool = False

    def validate(self) -> 'BodyContact':
        """Return a normalised copy; raise ValueError naming the bad field."""
        r = self.radius
        if r is not None:
            r = _finite('contact_radius', r, 0.0, lo_open=True)
        return replace(self, collide=_flag('collide', self.collide), radius=r,
                       self_collision=_flag('self_collision', self.self_collision))


def default_radius(points) -> float:
    """Half the median nearest-neighbour distance of a point set (N, 3); 0 for N < 2.

    For a lattice body that is half its spacing.  Measured on at most ~512 evenly strided
    points against all of them (exact for N <= 512).
    """
    x = np.ascontiguousarray(points, dtype=np.float64)
    if len(x) < 2:
        return 0.0
    step = max(1, len(x) // 512)
    d = float(median_nn_distance(x, step))
    return 0.5 * d if math.isfinite(d) else 0.0


# ---------------------------------------------------------------------------------------
# The pass
# ---------------------------------------------------------------------------------------

class Contact:
    """Body-body contact over a ``FlatState``: Verlet pair list and the response.

    Made by ``World``; ``run(flat, h, thresh)`` is called after the bodies' step.  Per
    body after each step: ``count`` contacts, ``deepest`` penetration (m) found before the
    projection (``fast_particles`` counts those moving faster than their radius per
    step, on demand).  ``builds``
    counts list rebuilds, ``pairs`` the pairs in the list, ``found`` the touching ones.
    """

    def __init__(self, flat, params: ContactParams, body_contacts, radii):
        self.flat = flat
        self.params = params
        nb = len(flat.bodies)
        self.act = np.array([c.collide for c in body_contacts], dtype=np.bool_)
        self.selfc = np.array([c.collide and c.self_collision for c in body_contacts],
                              dtype=np.bool_)
        if nb == 0:
            self.act = np.zeros(1, dtype=np.bool_)
            self.selfc = np.zeros(1, dtype=np.bool_)
        self.radii = np.asarray(radii, dtype=np.float64)
        for k in range(nb):
            flat.R[flat.off[k]:flat.off[k + 1]] = self.radii[k]
        n = flat.n
        rmax = float(self.radii[self.act[:nb]].max()) if nb and self.act[:nb].any() else 0.0
        self.skin = tuning.SKIN_FACTOR * rmax
        # the broad phase of a build (``body_overlaps``): per-body box growth, scratch,
        # and which bodies the builders take
        self._grow = np.zeros(max(nb, 1))
        self._grow[:nb] = self.radii + 0.5 * self.skin
        self._box = np.zeros((max(nb, 1), 6))
        self._order = np.zeros(max(nb, 1), dtype=np.int64)
        self._act_eff = np.zeros(max(nb, 1), dtype=np.bool_)
        self.cell = max(2.0 * rmax + self.skin, 1e-12)
        self.needed = nb > 0 and rmax > 0.0 and (int(self.act[:nb].sum()) >= 2
                                                  or bool(self.selfc[:nb].any()))
        # the grid's table: 4 to 8 cells a particle, and 27 or more for a grid that wraps
        tsize = 1 << max(5, int(math.ceil(math.log2(max(4 * n, 2)))))
        self._particle_cell = np.zeros(n, dtype=np.int64)
        self._cnt = np.zeros(tsize + 1, dtype=np.int64)
        self._srt = np.zeros(n, dtype=np.int64)
        self._sorted_points = np.zeros((n, 4))
        self._sorted_body = np.zeros(n, dtype=np.int32)
        self._cell_body = np.zeros(tsize, dtype=np.int32)
        cap = max(1024, 2 * n)
        self._pair_i = np.zeros(cap, dtype=np.int32)
        self._pair_j = np.zeros(cap, dtype=np.int32)
        self._scratch_i = np.zeros(cap, dtype=np.int32)
        self._scratch_j = np.zeros(cap, dtype=np.int32)
        self._pcnt = np.zeros(n + 1, dtype=np.int64)
        self._xref = np.zeros((3, n))
        self._moved = np.zeros(n, dtype=np.uint8)
        self.npairs = 0
        self.valid = False
        self.builds = 0
        self.found = 0
        self.count = np.zeros(max(nb, 1), dtype=np.int64)
        self.deepest = np.zeros(max(nb, 1))
        self.fast = np.zeros(max(nb, 1), dtype=np.int64)
        # solve_bodies: which bodies carry their contacts as a whole (set by World),
        # their inverse masses and moves, per-pair and per-particle impulses
        self.coupling = np.zeros(max(nb, 1), dtype=np.bool_)
        # the bodies whose pairs the stiff pass takes (stiff_contact.py; set by World)
        self.rigid = np.zeros(max(nb, 1), dtype=np.bool_)
        self._body_inv_mass = np.zeros(max(nb, 1))
        self._body_inv_mass_version = -1        # flat.w_version it was computed at
        self._body_change = np.zeros((max(nb, 1), 7))   # velocity, position changes; held
        self._pending = np.zeros(max(nb, 1), dtype=np.uint8)
        self._active_pairs = np.zeros(0, dtype=np.int64)
        self._pair_impulse = np.zeros((2, 0))
        self._pair_target = np.zeros(0)
        self._pair_rows = np.zeros((7, 0))
        self._pair_row_index = np.zeros((5, 0), dtype=np.int32)
        self._body_velocity = np.zeros((max(nb, 1), 3))
        self._lowest = np.zeros((2, max(nb, 1)))     # lowest particle: z, its v_z
        self._body_centre = np.zeros((max(nb, 1), 3))   # centre of mass
        self._body_spin = np.zeros((max(nb, 1), 3))
        self._body_inv_inertia = np.zeros((max(nb, 1), 9))
        self._dbox = np.zeros(6)        # displacements since the last build: their box
        self._ground_impulse = np.zeros((2, max(nb, 1)))
        self._floor = np.zeros((2, max(nb, 1)))      # what a carried body rests on
        self._warm = False              # the impulses are the last step's (list kept)
        self._wall_particles = np.zeros(n, dtype=np.int64)   # near boxes and spheres
        self._wall_start = np.zeros(max(nb, 1) + 1, dtype=np.int64)

    def step_state(self) -> tuple:
        """What a step changes and a later step reads (``snapshot``): the pair list and
        what its build measured (boxes, positions, displacements since), the impulses that
        warm-start the next step, the body masses and the last step's counts."""
        return ('npairs', 'valid', 'builds', 'found', '_warm', '_pair_i', '_pair_j', '_xref',
                '_box', '_dbox', '_pair_impulse', '_ground_impulse', '_body_inv_mass',
                '_body_inv_mass_version', 'count', 'deepest')

    def invalidate(self):
        """Force a rebuild of the pair list at the next step."""
        self.valid = False

    def set_rigid(self, flags):
        """Mark the bodies whose pairs with one another the stiff pass takes; the pair
        list, which leaves such pairs out, is built anew when the marks change."""
        if not np.array_equal(self.rigid[:len(flags)], flags):
            self.rigid[:len(flags)] = flags
            self.valid = False

    def add_counts(self, stiff_stats):
        """Add the stiff pass's body-pair contacts and overlaps (``World._stiff_stats``)
        to this pass's ``count``, ``deepest`` and ``found``."""
        if stiff_stats is None or not stiff_stats[:, 2].any():
            return
        n = len(stiff_stats)
        self.count[:n] += stiff_stats[:, 2].astype(np.int64)
        np.maximum(self.deepest[:n], stiff_stats[:, 3], out=self.deepest[:n])
        self.found += int(stiff_stats[:, 2].sum()) // 2

    def _solved_pairs(self):
        """(pi, pj, count) of the pairs this pass solves: the list without the pairs of
        two rigid bodies."""
        if not self.rigid.any():
            return self._pair_i, self._pair_j, self.npairs
        if len(self._scratch_i) < len(self._pair_i):
            self._scratch_i = np.zeros(len(self._pair_i), dtype=np.int32)
            self._scratch_j = np.zeros(len(self._pair_i), dtype=np.int32)
        kept = drop_rigid_pairs(self._pair_i, self._pair_j, self.npairs, self.flat.B, self.rigid,
                                self._scratch_i, self._scratch_j)
        return self._scratch_i, self._scratch_j, kept

    def _build(self):
        f = self.flat
        # broad phase: only bodies whose boxes (grown by r + skin / 2) meet another's go
        # into the grid; valid until the next build (no pair comes closer by the skin)
        act = self._act_eff
        body_overlaps(f.X, f.off, (self.act, self.selfc, self.rigid), self._grow, self._box,
                      self._order, act)
        src = PairSource(f.X, f.R, f.B, act, self.selfc, f.X0, self.cell, self.skin,
                         tuning.SELF_REST_FACTOR)
        grid = GridScratch(self._particle_cell, self._cnt, self._srt, self._sorted_points,
                           self._sorted_body, self._cell_body)
        while True:
            pairs = (self._pair_i, self._pair_j)
            m = build_pairs_grid(src, grid, *pairs)
            if m <= len(self._pair_i):
                break
            cap = int(m * 1.5) + 1024           # grows rarely (a rebuild, not a step)
            self._pair_i = np.zeros(cap, dtype=np.int32)
            self._pair_j = np.zeros(cap, dtype=np.int32)
            self._scratch_i = np.zeros(cap, dtype=np.int32)
            self._scratch_j = np.zeros(cap, dtype=np.int32)
        sort_pairs(self._pair_i, self._pair_j, m, f.n, self._pcnt, self._scratch_i,
                   self._scratch_j)
        self._warm = False                      # the impulses were of the old list's pairs
        self.npairs = m
        self._xref[:] = f.X
        self.valid = True
        self.builds += 1

    def run(self, h, thresh, col=None, gravity=None, supported=None):
        """Detect and resolve contacts on ``flat.X``/``flat.V`` (already gathered).

        ``col``: the World's static colliders (``kernels.colliders.Colliders``, its radius
        one per body in flat order; None: none), re-applied to every particle contact
        moved.  ``gravity`` (3,): with a nonzero one, ``params.stacking`` and a body
        marked in ``coupling``, the bodies so marked carry their contacts as a whole
        (``solve_bodies``); otherwise every pair acts per particle (``solve_pairs``).
        ``supported`` (bodies,) bool: the stiff bodies the stiff pass left lying on another;
        a load from a softer body cannot push them down into it here (``_set_floors``).
        """
        f = self.flat
        half = 0.5 * self.skin
        p = self.params
        if col is None:
            col = Colliders(False, _NO_GROUND, _NO_ROWS8, _NO_ROWS6, float(thresh),
                            np.zeros(len(f.bodies)), 0.0)
        grav = gravity is not None and bool(np.any(gravity != 0.0))
        carried = p.stacking and grav and self.coupling.any()
        if carried:
            if self._body_inv_mass_version != f.w_version:    # masses from W if changed
                body_inverse_masses(f.W, f.off, self._body_inv_mass)
                self._body_inv_mass_version = f.w_version
            # the carried bodies' frames, boxes and the displacements since the last
            # build in one pass over the positions
            spread2 = body_velocities(f.X, f.V, f.M, self._carried_bodies(), self._xref,
                                      self.act, self._dbox)
            # a body rests on the ground with its particles' spheres: a stiff one as the
            # stiff pass puts it (stiff_contact.py), the others as their own pass does
            n = len(self.radii)
            self._lowest[0, :n] -= np.where(self.rigid[:n], self.radii, col.radius[:n])
            self._set_floors(supported)
        else:
            spread2 = moved_spread2(f.X, self._xref, f.off, self.act)
        # rebuilt once the displacements since the last build no longer fit in a ball of
        # radius skin / 2 (no pair came closer by more than the skin; contact_build)
        if not self.valid or spread2 > half * half:
            self._build()
            self._dbox[:] = 0.0                # nothing moved since this build
        self.count[:] = 0
        self.deepest[:] = 0.0
        parts = ContactParticles(f.X, f.V, f.W, f.R, f.B, self._moved)
        pairs = PairList(*self._solved_pairs())
        report = ContactReport(f.touched, self.count, self.deepest)
        if not carried:
            self._warm = False
            law = ContactLaw(float(p.friction), float(p.restitution), float(thresh), float(h),
                             int(p.iterations), 0.0, 0.0)
            self.found = solve_pairs(parts, pairs, law, report, col)
            return
        if self._pair_impulse.shape[1] < self.npairs:
            m = len(self._pair_i)               # grows with the pair list's capacity
            self._pair_impulse = np.zeros((2, m))
            self._pair_target = np.zeros(m)
            self._active_pairs = np.zeros(m, dtype=np.int64)
            self._pair_rows = np.zeros((7, m))       # solve_bodies' compact rows
            self._pair_row_index = np.zeros((5, m), dtype=np.int32)
        sweeps = max(int(p.iterations), tuning.STACK_SWEEPS)
        law = ContactLaw(float(p.friction), float(p.restitution), float(thresh), float(h),
                         sweeps, tuning.SWEEP_TOL * float(thresh),
                         tuning.WARM_START if self._warm else 0.0)
        sweep = PairSweep(self._active_pairs, self._pair_impulse, self._pair_target,
                          self._pair_rows, self._pair_row_index)
        self.found = solve_bodies(parts, pairs, sweep, self._carried_bodies(), law, col,
                                  self._near_walls(col), report)
        self._warm = True

    def _carried_bodies(self) -> CarriedBodies:
        """The carried bodies' state, over this pass's buffers."""
        return CarriedBodies(self.flat.off, self._body_inv_mass, self.coupling,
                             self._body_velocity, self._lowest, self._body_centre,
                             self._body_inv_inertia, self._body_spin, self._body_change,
                             self._pending, self._ground_impulse, self._floor)

    def _set_floors(self, supported):
        """What a stiff body the stiff pass left lying on another rests on here, beside the
        ground: its lowest point as it is now, with the bodies' friction.  The stiff pass
        holds it up against its own weight and what the stiff bodies put on it; a softer
        body's load, which this pass meets, then goes into what it lies on instead of
        sinking it into that."""
        n = len(self.radii)
        self._floor[0, :n] = -np.inf
        self._floor[1, :n] = self.params.friction
        if supported is not None:
            held = supported[:n] & self.rigid[:n]
            self._floor[0, :n][held] = self._lowest[0, :n][held]

    def _near_walls(self, col) -> WallCandidates:
        """The carried bodies' particles near the boxes and spheres (grown by the
        particles' radius and the cell size, the margin a particle may move before it
        must go through them again: the end of ``solve_bodies`` puts the others through
        them only once they moved that far); with none, only the ground is left."""
        if not (col.on and (len(col.boxes) or len(col.spheres))):
            return NO_WALLS
        f = self.flat
        reach = self.cell + float(col.radius.max(initial=0.0))
        while True:
            walls = WallCandidates(self._wall_particles, self._wall_start, self.cell)
            ncand = wall_candidates(f.X, self._carried_bodies(), col, reach, walls, self.act,
                                    self._box, self._dbox)
            if ncand <= len(self._wall_particles):
                return walls._replace(particles=self._wall_particles[:ncand])
            self._wall_particles = np.zeros(ncand, dtype=np.int64)   # some near two

    def fast_particles(self, h):
        """Per body, the particles that moved more than their contact radius in the last
        step of ``h`` seconds (those can tunnel through a thin layer; see the module)."""
        f = self.flat
        count_fast(f.V, f.R, f.B, self.act, float(h), self.fast)
        return self.fast[:len(f.bodies)].copy()


__all__ = ['ContactParams', 'BodyContact', 'Contact', 'GridScratch', 'PairSource',
           'default_radius',
           'body_inverse_masses',
           'body_overlaps',
           'body_velocities', 'build_pairs_grid',
           'contact_velocity', 'count_fast', 'inverse_sym3',
           'moved_spread2',
           'median_nn_distance', 'solve_bodies', 'solve_pairs', 'sort_pairs',
           'wall_candidates']
