"""A deformable body: its state, its precomputed rest data and its step (algorithm.md).

The public methods validate their input and raise ``ValueError``; the private ``_step``
(``body_step.step``) drives the Numba kernels in ``kernels/`` over buffers made when the
body is built (``body_build``), so a step allocates nothing.  What a body computes is
chosen when it is built: a rigid body has no A_qq, a linear body no 9x9 data, a body
without plasticity no plastic state, a one-cluster body no membership lists.
"""

import numpy as np

from . import body_build, body_step, param_energy, tuning
from . import kernels as K
from .kernels.flags import DIRTY, ERR_STALE, NFLAGS, SLEEP
from .body_build import _EMPTY_I64, _GENERATION, soa  # noqa: F401 (body.soa)
from .packed import Pack
from .params import BodyParams


def uniform_mass(m) -> float:
    """The one mass of every particle of ``m`` where all are equal and positive, else 0."""
    return float(m[0]) if len(m) and m[0] > 0.0 and np.all(m == m[0]) else 0.0


def _as_points(points, name='points'):
    a = np.array(points, dtype=np.float64, order='C', copy=True)
    if a.ndim != 2 or a.shape[1] != 3 or a.shape[0] == 0:
        raise ValueError(f'{name} must be an (N, 3) array with N >= 1, got shape {a.shape}')
    if not np.all(np.isfinite(a)):
        raise ValueError(f'{name} must be finite')
    return a


class Body:
    """One shape-matched body; made by ``World.add_body``.

    Every public array and index is in the caller's order (``x[i]`` is ``points[i]``).
    Inside, a body of several clusters stores its particles set by set
    (``body_build.set_order``: each set one run, which the set kernels vectorise over);
    ``_perm`` maps a stored row to the caller's index, ``_inv`` back (both None where the
    storage order is the caller's).
    """

    def __init__(self, points, masses=1.0, params=None, name='body', velocities=None,
                 pinned=None):
        self.name = str(name)
        x = _as_points(points)
        n = len(x)
        m = np.array(np.broadcast_to(np.asarray(masses, dtype=np.float64), (n,)), order='C')
        if not np.all(np.isfinite(m)) or np.any(m <= 0.0):
            raise ValueError('masses must be finite and > 0')
        if velocities is None:
            v = np.zeros_like(x)
        else:
            v = _as_points(velocities, 'velocities')
            if v.shape != x.shape:
                raise ValueError(f'velocities must have shape {x.shape}, got {v.shape}')
        params = (params or BodyParams()).validate()
        pins = self._check_indices(pinned if pinned is not None else [], n, 'pinned')
        # the storage order; the memberships computed for it are reused by the first build
        self._perm, self._inv = None, None
        perm, self._members = body_build.set_order(x - (m @ x) / m.sum(), params.clusters)
        if perm is not None:
            x, m, v = x[perm], np.ascontiguousarray(m[perm]), v[perm]
            self._perm = perm
            self._inv = np.empty(n, dtype=np.int64)
            self._inv[perm] = np.arange(n)
            pins = np.sort(self._inv[pins])
            for index in (self._perm, self._inv):
                index.flags.writeable = False
        self._pinned = pins
        self.n = n
        self._m = m                            # masses in the storage order
        self._m.flags.writeable = False
        self.total_mass = float(m.sum())
        #: the particles' one mass where all are equal, else 0 (the damping sums of such a
        #: body are taken unweighted: ``kernels.damping.damp_sums_range``)
        self._wuni = uniform_mass(m)
        #: the radius of the spheres its particles meet the static colliders with (m); the
        #: world sets it (``World._collider_radii``)
        self._collider_radius = 0.0
        self._x_init = x.copy()
        self._x_init.flags.writeable = False
        self._v_init = v.copy()
        # positions and velocities per component ((3, N) blocks seen as (N, 3), ``soa``)
        self._x = soa(x)
        self._v = soa(v)
        # rest positions about the mass centre: every kernel reads these (exact for any
        # far-away placement)
        self._rest_centre = (m @ x) / self.total_mass
        self._x0 = soa(x - self._rest_centre)
        self._force = np.zeros(3)
        self._facc = np.zeros(3)               # force / total mass
        self._torque = np.zeros(3)
        self._has_torque = False
        self._grab_idx = _EMPTY_I64
        self._grab_tgt = np.zeros((0, 3))
        self._acc = np.zeros(3)
        self._ang = np.zeros(3)
        self._com = np.zeros(3)
        self._inertia = np.zeros((3, 3))
        self._inertia_inv = np.zeros((3, 3))
        self._mat3 = [np.zeros((3, 3)) for _ in range(4)]
        self._mat39 = np.zeros((3, 9))
        self._match_work = np.zeros((2, 3, 3))
        self._quat_n = np.zeros((4, 4))
        self._quat_v = np.zeros((4, 4))
        self._mat9 = [np.zeros((9, 9)) for _ in range(2)]
        self._features9 = np.zeros(9)
        self._accbuf = np.zeros(32)
        self._shape_err = 0.0
        # body-level match for poses of multi-cluster bodies
        self._quat_body = np.array([1.0, 0.0, 0.0, 0.0])
        self._params = params
        self._limit_counts = np.zeros(2, dtype=np.int64)
        # read and written by the compiled steps too (indices: ``kernels.flags``)
        self._flags = np.zeros(NFLAGS)
        self._build()
        self._merge_kinematic()

    # ------------------------------------------------------------------ build
    @staticmethod
    def _check_indices(idx, n, what):
        a = np.asarray(idx)
        if a.size == 0:
            return _EMPTY_I64
        if a.ndim != 1 or not np.issubdtype(a.dtype, np.integer):
            raise ValueError(f'{what} must be a 1-D array of particle indices')
        if a.min() < 0 or a.max() >= n:
            raise ValueError(f'{what} indices must be in [0, {n}), got {a.min()}..{a.max()}')
        return np.unique(a.astype(np.int64))

    def _build(self):
        """Precompute everything that depends on the rest shape and the parameters
        (``body_build.build`` with ``tuning.PARALLEL_MIN_WORK``, read at each build)."""
        body_build.build(self, parallel_min_work=tuning.PARALLEL_MIN_WORK)

    def _refresh_rest(self, which):
        """Plastic rest data of the clusters in ``which`` (``body_build.refresh_rest``)."""
        body_build.refresh_rest(self, which)

    def _merge_kinematic(self):
        body_build.merge_kinematic(self)

    # ------------------------------------------------------------------ step
    @property
    def _dirty(self) -> bool:
        """Whether the per-cluster sums must be accumulated again before the next step."""
        return bool(self._flags[DIRTY])

    @_dirty.setter
    def _dirty(self, value):
        self._flags[DIRTY] = 1.0 if value else 0.0

    @property
    def asleep(self) -> bool:
        """Whether the body is asleep (``World`` sleeping: at rest in a contact world, not
        stepped until something wakes it; doc/sleeping.md)."""
        return bool(self._flags[SLEEP] > 0.0)

    def wake(self):
        """Wake the body (it is stepped again from the next step); every input that
        changes it (state, parameters, wrench, grabs, reset) wakes it too.  A force,
        torque or grab keeps it awake while it acts."""
        held = bool(self._force.any() or self._torque.any() or len(self._grab_idx))
        self._flags[SLEEP] = -1.0 if held else 0.0

    def step_state(self) -> tuple:
        """The attributes a step changes and a later step reads (``snapshot``): positions,
        velocities, flags, the clusters' reference points, rotations and the sums carried
        to the next step, the linear mode's warm start, the damping sums, the shape error,
        the limit counts, the set layout; a plastic body's plastic state and the rest
        data it reshapes too."""
        names = ('_x', '_v', '_flags', '_ref', '_quat', '_part', '_err', '_shape_err',
                 '_dpart', '_udv', '_limit_counts', '_sets')
        if self._params.plastic:
            names += ('_s_plastic', '_rest_lin', '_rest_off', '_sum_q', '_aqq3', '_aqq9',
                      '_nmat', '_cdet')
        return names

    def _packed_ok(self) -> bool:
        """Whether the packed world step (``packed.py``) may step this body: one cluster,
        rigid or linear, every particle of one mass (its loop sums unweighted), no
        plasticity, grabs or torque (a body built for threads too: it steps on one thread in
        the pack)."""
        return (self._params.clusters == 1 and not self._quad and self._wuni > 0.0
                and (self.n == 1 or not self._params.plastic) and len(self._kin_idx) == 0
                and not self._has_torque)

    def _one_pack(self, h):
        """A ``packed.Pack`` of this body alone, kept until a body changes, h or its collider
        radius does or the body was packed elsewhere."""
        key = (_GENERATION[0], h, self._collider_radius)
        one = getattr(self, '_one', None)
        if (one is None or one[0] != key or not isinstance(one[1], Pack)
                or getattr(self, '_pack_owner', None) is not one[1]):
            one = self._one = (key, Pack([self], h))
        return one[1]

    def _fast_record(self, h):
        """The tuple of buffers ``kernels.world_step`` steps (``body_build.fast_record``)."""
        return body_build.fast_record(self, h)

    def __getstate__(self):
        state = self.__dict__.copy()
        state.pop('_one', None)                # a typed list does not copy: rebuilt
        state.pop('_pack_owner', None)
        return state

    def __setstate__(self, state):
        # a copy (copy.deepcopy, pickle) makes every array writeable; Numba types a
        # read-only array differently, so the copy's first step would compile a second
        # specialisation of every kernel that reads the masses
        self.__dict__.update(state)
        for name in ('_m', '_x_init', '_perm', '_inv'):
            if self.__dict__[name] is not None:
                self.__dict__[name].flags.writeable = False

    def _one_record(self, h):
        """A typed list of this body's record alone (``body_build.one_record``)."""
        return body_build.one_record(self, h)

    def _fast_sets(self):
        """The set-layout buffers of a record (``body_build.fast_sets``)."""
        return body_build.fast_sets(self)

    def _step(self, h, gravity, has_col, ground, boxes, spheres, thresh):
        body_step.step(self, h, gravity, has_col, ground, boxes, spheres, thresh)

    # ------------------------------------------------------------------ state access
    @property
    def params(self) -> BodyParams:
        """The body's parameters (immutable; change them with ``set_params``)."""
        return self._params

    def _callers(self, stored):
        """A read-only (N, ...) array of stored rows in the caller's order: a view where
        the storage order is the caller's, else a copy (per component for (N, 3) state,
        so it stays F-contiguous)."""
        if self._inv is None:
            out = stored.view()
        elif stored.ndim == 2:
            out = np.take(stored.T, self._inv, axis=1).T
        else:
            out = stored[self._inv]
        out.flags.writeable = False
        return out

    @property
    def x(self) -> np.ndarray:
        """Positions (N, 3) in the caller's order, read-only (write with ``set_state``).

        F-contiguous (``x[:, j]`` is a unit-stride column): the live state itself where the
        body stores its particles in the caller's order, else a copy taken at each access.
        Code that needs C-ordered rows copies (``np.ascontiguousarray(body.x)``)."""
        return self._callers(self._x)

    @property
    def v(self) -> np.ndarray:
        """Velocities (N, 3) in the caller's order, read-only (as ``x``)."""
        return self._callers(self._v)

    @property
    def m(self) -> np.ndarray:
        """Particle masses (N,) in the caller's order, read-only."""
        return self._callers(self._m)

    @property
    def x_init(self) -> np.ndarray:
        """Initial positions (N, 3) in the caller's order, read-only."""
        return self._callers(self._x_init)

    def _stored(self, callers):
        """Rows given in the caller's order, in the storage order."""
        return callers if self._perm is None else callers[self._perm]

    @property
    def plastic_state(self) -> np.ndarray:
        """Per-cluster plastic deformation S^P (clusters, 3, 3); identity when elastic."""
        return self._s_plastic.copy()

    @property
    def cluster_rotations(self) -> np.ndarray:
        """Per-cluster rotations R of the last step's shape match (clusters, 3, 3)."""
        out = np.zeros((self.num_clusters, 3, 3))
        for k in range(self.num_clusters):
            K.quat_to_mat(self._quat[k], out[k])
        return out

    def set_state(self, x=None, v=None):
        """Overwrite positions and/or velocities (validated; all or nothing)."""
        nx = None if x is None else _as_points(x, 'x')
        nv = None if v is None else _as_points(v, 'v')
        for a, what in ((nx, 'x'), (nv, 'v')):
            if a is not None and a.shape != self._x.shape:
                raise ValueError(f'{what} must have shape {self._x.shape}, got {a.shape}')
        if nx is not None:
            self._x[:] = self._stored(nx)
        if nv is not None:
            self._v[:] = self._stored(nv)
        self._dirty = True
        self.wake()

    def set_params(self, params=None, **changes):
        """Apply new parameters from the next step on; rebuild only what they reshape.  Where
        the new material holds the present deformation with more elastic energy, the body's
        internal motion gives the rise up (``param_energy``)."""
        new = (params if params is not None else self._params)
        if not isinstance(new, BodyParams):
            raise ValueError('params must be a BodyParams')
        unknown = set(changes) - set(BodyParams.field_names())
        if unknown:
            raise ValueError(f'unknown body parameters: {sorted(unknown)}')
        from dataclasses import replace
        new = replace(new, **changes).validate()
        old = self._params
        spread = self.total_mass * self.shape_error_rms() ** 2
        self._params = new
        _GENERATION[0] += 1
        self.wake()
        if (new.mode != old.mode or new.clusters != old.clusters or new.plastic != old.plastic
                or (new.damping > 0) != (old.damping > 0)):
            self._build()
        param_energy.give_up(self, old, new, spread)

    def set_wrench(self, force, torque=(0.0, 0.0, 0.0)):
        """External force at the centre of mass and torque about it, held until replaced."""
        f = np.asarray(force, dtype=float).reshape(-1)
        t = np.asarray(torque, dtype=float).reshape(-1)
        if f.shape != (3,) or t.shape != (3,) or not (np.all(np.isfinite(f))
                                                       and np.all(np.isfinite(t))):
            raise ValueError('force and torque must be 3 finite numbers each')
        self._force[:] = f
        np.multiply(self._force, 1.0 / self.total_mass, out=self._facc)
        self._torque[:] = t
        torque = bool(t.any())
        # the compiled steps read the force from ``_facc`` in place; only a torque coming
        # or going changes which step a body takes (World re-splits on a new generation,
        # which a scene of many bodies notices, so a force command must not cause one)
        if torque != self._has_torque:
            _GENERATION[0] += 1
        self._has_torque = torque
        self.wake()

    def clear_wrench(self):
        """Remove the external force and torque."""
        self._force[:] = 0.0
        self._facc[:] = 0.0
        self._torque[:] = 0.0
        if self._has_torque:                   # as set_wrench
            _GENERATION[0] += 1
        self._has_torque = False
        self.wake()

    @property
    def wrench(self):
        """The held (force, torque) as copies."""
        return self._force.copy(), self._torque.copy()

    def set_kinematic(self, indices, targets):
        """Make particles follow ``targets`` exactly (grabbed); replaces earlier ones."""
        idx = np.asarray(indices)
        tgt = np.asarray(targets, dtype=float)
        if idx.ndim != 1 or (idx.size and not np.issubdtype(idx.dtype, np.integer)):
            raise ValueError('indices must be a 1-D integer array')
        if tgt.shape != (idx.size, 3) or not np.all(np.isfinite(tgt)):
            raise ValueError(f'targets must be finite with shape ({idx.size}, 3)')
        if idx.size and (idx.min() < 0 or idx.max() >= self.n):
            raise ValueError(f'indices must be in [0, {self.n})')
        if idx.size and len(np.unique(idx)) != idx.size:
            raise ValueError('indices must be unique')
        idx = idx.astype(np.int64)
        self._grab_idx = idx if self._inv is None else self._inv[idx]
        self._grab_tgt = np.ascontiguousarray(tgt)
        self._merge_kinematic()
        self.wake()

    def clear_kinematic(self):
        """Release every grabbed particle (pins stay)."""
        self._grab_idx = _EMPTY_I64
        self._grab_tgt = np.zeros((0, 3))
        self._merge_kinematic()
        self.wake()

    @property
    def kinematic_indices(self) -> np.ndarray:
        """Indices of the particles that currently follow targets (grabbed and pinned)."""
        return self._kin_idx.copy() if self._perm is None else self._perm[self._kin_idx]

    @property
    def pinned(self) -> np.ndarray:
        """Indices of the pinned particles (sorted)."""
        return self._pinned.copy() if self._perm is None else np.sort(self._perm[self._pinned])

    def com(self) -> np.ndarray:
        """Centre of mass of the current positions."""
        return (self._m @ self._x) / self.total_mass

    def rotation(self) -> np.ndarray:
        """Proper rotation of the whole body's shape match (3, 3)."""
        r = np.zeros((3, 3))
        if self.num_clusters == 1:
            K.quat_to_mat(self._quat[0], r)
            return r
        com = self.com()
        apq = np.einsum('i,ij,ik->jk', self._m, self._x - com, self._x0)
        K.extract_rotation(mat=apq, quat=self._quat_body, rot=r, n4=self._quat_n, v4=self._quat_v)
        return r

    def goals(self) -> np.ndarray:
        """Goal positions g_i for the current state (Eq. 12/18/22, averaged over clusters;
        ``body_step.goals``), in the caller's order."""
        goal = body_step.goals(self)
        return goal if self._inv is None else goal[self._inv]

    @property
    def limit_counts(self):
        """(particles slowed to max_speed, clusters whose spin was capped) since built.

        Counted per step: a particle capped in 10 steps counts 10.
        """
        return int(self._limit_counts[0]), int(self._limit_counts[1])

    def shape_error_rms(self) -> float:
        """RMS distance of the particles to their goals in the last step (m)."""
        if self._shape_err is None or self._flags[ERR_STALE]:
            self._shape_err = float(np.sqrt(self._err.sum() / self.n))
            self._flags[ERR_STALE] = 0.0
        return self._shape_err

    def momentum(self) -> np.ndarray:
        """Linear momentum sum m v."""
        return self._m @ self._v

    def angular_momentum(self, about=(0.0, 0.0, 0.0)) -> np.ndarray:
        """Angular momentum sum m (x - about) x v."""
        r = self._x - np.asarray(about, dtype=float)
        return np.cross(r, self._v * self._m[:, None]).sum(axis=0)

    def is_finite(self) -> bool:
        """Whether every position and velocity is finite."""
        return bool(np.isfinite(self._x).all() and np.isfinite(self._v).all())

    def reset(self):
        """Initial pose and velocities, rest shape, no plastic state, wrench or grabs."""
        self._x[:] = self._x_init
        self._v[:] = self._v_init
        self.clear_wrench()
        self.clear_kinematic()
        self._quat_body[:] = (1.0, 0.0, 0.0, 0.0)
        self._build()
