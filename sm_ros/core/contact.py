"""Contact between bodies, and self-collision, on the world's flat state (``flat.py``).

Model (doc/contact.md): every particle of a colliding body is a sphere of its body's
contact radius ``r``; two particles of different bodies (or of one self-colliding body
whose rest distance exceeds ``SELF_REST_FACTOR`` times their contact distance) must stay
at least ``r_i + r_j`` apart.  After the bodies' own step (each substep) the pairs within
1.2 contact distances and the stiff bodies' particles inside colliders are the rows of a
sequential-impulse solve in which a stiff body (``COUPLE_ALPHA``, ``RIGID_CLUSTERS``)
takes every impulse as a rigid body (its velocity and spin change: contact tips, rolls and
yaws it) and a soft one per particle; accumulated, warm-started normal and friction
impulses, restitution from the approach before the step, position correction by
pseudo-velocities that never enter the velocities (``contact_solve.py``,
``contact_sweeps.py``).  The soft bodies' particles meet the static colliders with the
per-particle law first (the bodies' own step leaves the colliders to this pass when it
runs).

Neighbour search (a Verlet pair list on a cell grid) and the solve are compiled kernels in
``contact_build.py``, ``contact_cells.py``, ``contact_solve.py``, ``contact_sweeps.py``,
``contact_frames.py`` and ``contact_statics.py``; this file holds the settings
(``ContactParams``, ``BodyContact``) and the pass ``Contact`` that owns the buffers and
calls them.
"""

from dataclasses import dataclass, fields, replace
import math
from typing import Optional

import numba
import numpy as np

from .contact_build import (body_overlaps, build_pairs_grid, build_pairs_grid_par,
                            moved_spread2, sort_pairs)
from .contact_cells import build_pairs, build_pairs_cells
from .contact_kernels import count_fast, median_nn_distance, neighbour_directions
from .contact_frames import (body_frames, carry_warm, finish_rows, group_rows,
                             guarded)
from .contact_soft import collide_moved, soft_pairs
from .contact_solve import collider_offsets, fill_rows, pair_rows
from .contact_statics import collide_rows_soft, collide_soft, collider_rows, project_moved
from .contact_sweeps import POS_SWEEPS, VEL_SWEEPS, WARM, solve_rows
from .kernels.contact_rows import (LAW_GUARD, ROW_WIDTH, WARM_WIDTH, Bodies,
                                   PairList, Particles, Rows, Statics)
from .kinematic import contact_rows as kinematic_rows, row_wrenches
from .kernels.colliders import contact_velocity
from .params import _finite

#: Same-body pairs self-collide only when their rest distance exceeds this many times
#: their contact distance ``r_i + r_j`` (lattice neighbours up to two spacings apart
#: never do: they are held by the shape match).
SELF_REST_FACTOR = 2.0
#: Verlet skin as a fraction of the largest contact radius.
SKIN_FACTOR = 0.5
#: The pair list is built on the Numba threads (``build_pairs_grid_par``) from this many
#: particles when more than one thread is set: below it a threaded build loses whenever
#: another job holds a core (OpenMP waits for the descheduled thread;
#: ``python -m sm_ros.bench contact`` times both side by side).
PARALLEL_BUILD_MIN = 262144
#: A body takes its contacts as a rigid body (``Contact.coupling``, rigid share 1:
#: ``contact_solve``) when the pull of its goals towards their rigid part at the step,
#: alpha (1 - beta) (alpha in rigid mode), is at least this and it has at most
#: ``RIGID_CLUSTERS`` clusters per axis: the shape match then restores most of a
#: deviation within the step and the body does not bend between its clusters.  Softer
#: bodies, many-cluster ones (a sheet that folds), self-colliding ones and ones with a
#: pinned or grabbed particle take their contacts per particle and are dented.
COUPLE_ALPHA = 0.4
RIGID_CLUSTERS = 2
#: The velocity sweeps stop once no speed changed by more than this fraction of the
#: resting threshold (``World.step``: 2 |g| h) in a sweep.
SWEEP_TOL = 0.001
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
    is used as given); ``iterations``: velocity sweeps per step beyond the solve's own
    (``contact_sweeps.VEL_SWEEPS``).  ``stacking`` is accepted for old scenes and has no
    effect: the model is one for every setting (doc/contact.md).
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
    """Per-body contact settings: ``collide`` with other bodies, ``radius`` (m; None =
    the default rule), ``self_collision`` (opt-in)."""

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


def surface_normals(X0, M, off, radii):
    """Per particle, its outward surface normal in its body's rest shape (3, N): minus
    the mean direction to its rest neighbours within 1.5 lattice spacings (twice the
    contact radius), zero where they surround it (inside); and each body's rest centre of
    mass (nb, 3).  Stiff bodies' pairs touch along these (``contact_solve``)."""
    nb = max(len(off) - 1, 1)
    ns = np.zeros(X0.shape)
    c0 = np.zeros((nb, 3))
    for b in range(len(off) - 1):
        x = X0[:, off[b]:off[b + 1]].T
        m = M[off[b]:off[b + 1]]
        if len(x) == 0:
            continue
        c0[b] = (m[:, None] * x).sum(axis=0) / m.sum()
        reach = 3.0 * float(radii[b])
        if len(x) < 2 or not reach > 0.0:
            continue
        acc = neighbour_directions(np.ascontiguousarray(x), reach)
        size = np.linalg.norm(acc, axis=1)
        out = size > 0.5
        ns[:, off[b]:off[b + 1]][:, out] = (-acc[out] / size[out, None]).T
    return ns, c0


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
        self.act = np.array([c.collide and params.enabled for c in body_contacts],
                            dtype=np.bool_)
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
        self.skin = SKIN_FACTOR * rmax
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
        tsize = 1 << max(4, int(math.ceil(math.log2(max(4 * n, 2)))))
        self._hb = np.zeros(n, dtype=np.int64)
        self._cnt = np.zeros(tsize + 1, dtype=np.int64)
        self._srt = np.zeros(n, dtype=np.int64)
        self._skey = np.zeros(n, dtype=np.int64)
        self._sco = np.zeros((5, n))
        self._P = np.zeros((n, 4))
        self._sb = np.zeros(n, dtype=np.int32)
        self._cb = np.zeros(tsize, dtype=np.int32)
        #: None: the serial builder, or the parallel one from ``PARALLEL_BUILD_MIN``
        #: particles when more than one Numba thread is set; True / False: always / never
        #: the parallel one; 'cells': the previous builder (the benchmark's reference).
        self.parallel_build = None
        cap = max(1024, 2 * n)
        self._pi = np.zeros(cap, dtype=np.int32)
        self._pj = np.zeros(cap, dtype=np.int32)
        self._ti = np.zeros(cap, dtype=np.int32)
        self._tj = np.zeros(cap, dtype=np.int32)
        self._pcnt = np.zeros(n + 1, dtype=np.int64)
        self._xref = np.zeros((3, n))
        self._moved = np.zeros(n, dtype=np.uint8)   # particles ``soft_pairs`` moved
        self.npairs = 0
        self.valid = False
        self.builds = 0
        self.found = 0
        self.count = np.zeros(max(nb, 1), dtype=np.int64)
        self.deepest = np.zeros(max(nb, 1))
        self.fast = np.zeros(max(nb, 1), dtype=np.int64)
        # which bodies take their contacts as rigid bodies (set by World)
        self.coupling = np.zeros(max(nb, 1), dtype=np.bool_)
        self._wp = None                 # warm-start impulses per pair of the list
        self._wc = None                 # ... per particle against a collider
        self._bodies = None             # the solve's state (contact_solve), made at a run
        self._rows = None
        self._stamp = 0.0
        self.soft_w = None              # inverse masses of the particles left to colliders
        self._row_order = np.zeros(0, np.int64)     # the rows by pair of bodies
        self._row_start = np.zeros(1, np.int64)
        self.vel_sweeps = VEL_SWEEPS
        self.warm = WARM
        self.pos_sweeps = POS_SWEEPS

    def step_state(self) -> tuple:
        """What a step changes and a later step reads (``snapshot``): the pair list and
        the positions of its build, the impulses that warm-start the next step (per pair,
        per particle against a collider, with the step's number) and the last step's
        counts."""
        return ('npairs', 'valid', 'builds', 'found', '_pi', '_pj', '_pcnt', '_xref', '_wp',
                '_wc', '_stamp', 'count', 'deepest')

    def invalidate(self):
        """Force a rebuild of the pair list at the next step."""
        self.valid = False

    def _grid_builder(self):
        """'cells' (the previous builder), or the number of threads of the grid builder."""
        mode = self.parallel_build
        if mode == 'cells':
            return mode
        nt = numba.get_num_threads()
        if mode is None:
            mode = self.flat.n >= PARALLEL_BUILD_MIN and nt > 1
        return nt if mode else 1

    def _build(self):
        f = self.flat
        nt = self._grid_builder()
        old = None
        if self._wp is not None and self.valid:
            # the old list's pairs and impulses, for the new list's pairs to start from
            n0 = self.npairs
            old = (self._pi[:n0].copy(), self._pj[:n0].copy(), self._pcnt.copy(),
                   self._wp[:n0].copy())
        # broad phase: only bodies whose boxes (grown by r + skin / 2) meet another's go
        # into the grid; valid until the next build (no pair comes closer by the skin)
        act = self._act_eff
        body_overlaps(f.X, f.off, self.act, self.selfc, self._grow, self._box, self._order,
                      act)
        while True:
            if nt == 'cells':
                m = build_pairs_cells(f.X, f.R, f.B, act, self.selfc, f.X0, self.cell,
                                      self.skin, SELF_REST_FACTOR, self._hb, self._cnt,
                                      self._srt, self._sco, self._pi, self._pj)
            elif nt == 1:
                m = build_pairs_grid(f.X, f.R, f.B, act, self.selfc, f.X0, self.cell,
                                     self.skin, SELF_REST_FACTOR, self._hb, self._cnt,
                                     self._srt, self._P, self._sb, self._cb, self._pi,
                                     self._pj)
            else:
                m = build_pairs_grid_par(f.X, f.R, f.B, act, self.selfc, f.X0, self.cell,
                                         self.skin, SELF_REST_FACTOR, self._hb, self._cnt,
                                         self._srt, self._P, self._sb, self._cb, self._pi,
                                         self._pj, nt)
            if m < 0:                           # sparse world: hashed cells
                m = build_pairs(f.X, f.R, f.B, act, self.selfc, f.X0, self.cell,
                                self.skin, SELF_REST_FACTOR, self._hb, self._cnt, self._srt,
                                self._skey, self._sco, self._pi, self._pj)
            if m <= len(self._pi):
                break
            cap = int(m * 1.5) + 1024           # grows rarely (a rebuild, not a step)
            self._pi = np.zeros(cap, dtype=np.int32)
            self._pj = np.zeros(cap, dtype=np.int32)
            self._ti = np.zeros(cap, dtype=np.int32)
            self._tj = np.zeros(cap, dtype=np.int32)
        sort_pairs(self._pi, self._pj, m, f.n, self._pcnt, self._ti, self._tj)
        if old is not None:
            if len(self._wp) < len(self._pi):
                self._wp = np.full((len(self._pi), WARM_WIDTH), -np.inf)
            carry_warm(old, (self._pi, self._pj, self._wp), m)
        self.npairs = m
        self._xref[:] = f.X
        self.valid = True
        self.builds += 1

    def _solver_buffers(self):
        """The solve's buffers, sized to the pair list's capacity (grown with it)."""
        f = self.flat
        nb = max(len(f.bodies), 1)
        if self._bodies is None:
            ns, c0 = surface_normals(f.X0, f.M, f.off, self.radii)
            self._bodies = Bodies(np.zeros(nb), np.zeros((nb, 3)), np.zeros((nb, 9)),
                                  np.zeros((nb, 3)), np.zeros((nb, 3)), np.zeros(nb),
                                  np.zeros((nb, 12)), np.zeros((nb, 9)), c0)
            self._pt = Particles(f.X, f.V, f.W, f.R, f.B, f.M, np.zeros((3, f.n)), ns)
            self._wc = np.full((f.n, WARM_WIDTH), -np.inf)
            self._bbox = np.zeros((nb, 6))
        cap = len(self._pi) + f.n
        if self._rows is None or self._rows.f.shape[0] < cap:
            self._rows = Rows(np.zeros((cap, ROW_WIDTH)), np.zeros((cap, 5), np.int64))
        if self._wp is None or len(self._wp) < len(self._pi):
            self._wp = np.full((len(self._pi), WARM_WIDTH), -np.inf)

    def run(self, h, thresh, has_col=False, ground=_NO_GROUND, boxes=_NO_ROWS8,
            spheres=_NO_ROWS6, gravity=None, kin=None, kin_stats=None):
        """Detect and resolve contacts on ``flat.X``/``flat.V`` (already gathered).

        ``has_col``, ``ground``, ``boxes``, ``spheres``: the World's static colliders (rows
        as in ``kernels.colliders.collide_point``); the bodies' own step left them to this
        pass.  ``gravity`` (3,): a collider's restitution acts on the approach speed before
        the step's gravity.  ``kin``: the world's named, oriented or moving colliders
        (``colliders.ColliderSet``) or None: the stiff bodies' contacts with them are rows
        of the solve (their wrenches and ``kin_stats`` counted); the caller then runs
        their pass for the other particles with ``soft_w`` as inverse masses.
        """
        f = self.flat
        p = self.params
        if self.needed:
            half = 0.5 * self.skin
            spread2 = moved_spread2(f.X, self._xref, f.off, self.act)
            # rebuilt once the displacements since the last build no longer fit in a ball
            # of radius skin / 2 (no pair came closer by more than the skin; contact_build)
            if not self.valid or spread2 > half * half:
                self._build()
        self._solver_buffers()
        self._stamp += 1.0
        bd, pt, rows = self._bodies, self._pt, self._rows
        # a self-colliding body folds onto itself: it takes its contacts per particle
        cpl = self.coupling & ~self.selfc[:len(self.coupling)]
        body_frames(pt, f.off, cpl, bd, float(h), self._bbox, f.X0)
        st = Statics(ground if has_col else _NO_GROUND, boxes if has_col else _NO_ROWS8,
                     spheres if has_col else _NO_ROWS6)
        if has_col:
            collide_soft(pt, f.off, bd, st, thresh, f.touched)
        g = (0.0, 0.0, 0.0) if gravity is None else gravity
        law = np.array([h, thresh, p.friction, p.restitution, self._stamp, self.warm,
                        max(self.vel_sweeps, p.iterations), self.pos_sweeps, g[0], g[1],
                        g[2], 0.0])
        self.count[:] = 0
        self.deepest[:] = 0.0
        stats = (f.touched, self.count, self.deepest)
        m = soft = 0
        if self.needed:
            pairs = PairList(self._pi, self._pj, self.npairs)
            soft = soft_pairs(pt, bd.share, pairs, law, p.iterations, stats + (self._moved,))
            m = pair_rows(pt, bd, pairs, rows, law)
        m0 = m
        if has_col:
            m = collider_rows(pt, bd, f.off, st, rows, m, self._bbox)
        mk = m
        if kin is not None:
            m = kinematic_rows(f.X, f.off, bd.share, self._bbox, kin.rows, rows.f, rows.i, m)
        collider_offsets(pt, bd, rows, m0, m, float(h))
        if len(self._row_order) < m:
            self._row_order = np.zeros(rows.f.shape[0], np.int64)
            self._row_start = np.zeros(rows.f.shape[0] + 1, np.int64)
        ng = group_rows(rows, m, bd.share, self._row_order, self._row_start, f.R)
        fill_rows(pt, bd, rows, self._row_order, self._row_start[ng], law, self._wp, self._wc)
        # the energy guard needs every row between stiff bodies or with static colliders
        law[LAW_GUARD] = 1.0 if guarded(rows, m, bd.share) else 0.0
        solve_rows(pt, bd, rows, m, law, SWEEP_TOL * thresh, self._row_order, self._row_start,
                   ng)
        self.found = soft + finish_rows(pt, bd, f.off, rows, m, law, self._wp, self._wc, stats)
        if has_col:
            collide_moved(pt, self._moved, st, thresh)
            collide_rows_soft(pt, bd, rows, m, st, thresh)
            project_moved(pt, f.off, bd, st)
        if kin is not None:
            row_wrenches(f.X, kin.rows, rows.f, rows.i, mk, m, kin.imp, kin_stats)
            if self.soft_w is None or len(self.soft_w) != f.n:
                self.soft_w = np.zeros(f.n)
            np.multiply(f.W, bd.share[f.B] == 0.0, out=self.soft_w)

    def fast_particles(self, h):
        """Per body, the particles that moved more than their contact radius in the last
        step of ``h`` seconds (those can tunnel through a thin layer; see the module)."""
        f = self.flat
        count_fast(f.V, f.R, f.B, self.act, float(h), self.fast)
        return self.fast[:len(f.bodies)].copy()


__all__ = ['ContactParams', 'BodyContact', 'Contact', 'default_radius', 'SELF_REST_FACTOR',
           'COUPLE_ALPHA', 'RIGID_CLUSTERS', 'PARALLEL_BUILD_MIN', 'body_overlaps',
           'build_pairs', 'build_pairs_cells', 'build_pairs_grid', 'build_pairs_grid_par',
           'contact_velocity', 'count_fast', 'moved_spread2', 'median_nn_distance',
           'sort_pairs', 'surface_normals']
