"""A deformable body: its state, its precomputed rest data and its step (algorithm.md).

The public methods validate their input and raise ``ValueError``; the private ``_step``
drives the Numba kernels in ``kernels/`` over buffers made when the body is built, so a
step allocates nothing.  What a body computes is chosen when it is built: a rigid body has
no A_qq, a linear body no 9x9 data, a body without plasticity no plastic state, a
one-cluster body no membership lists.
"""

import numpy as np
import numba

from . import kernels as K
from .clusters import build_memberships
from .params import BodyParams

_MODE_ID = {'rigid': 0, 'linear': 1, 'quadratic': 2}
#: Bodies with at least this much work per step (particles, or cluster memberships on the
#: membership path) run the multi-threaded kernels.  Below it a step takes well under a
#: millisecond on one thread, and on a loaded machine (other nodes on the same cores) the
#: threads' fork/join waits cost far more than they save: on 2 shared cores, 100k particles
#: took 1.5 ms/step (median) on one thread and 13 ms on two (benchmarks.md).
PARALLEL_MIN_WORK = 262144
#: Bodies with at least this many particles damp inside the particle pass (``kernels.
#: damping``); smaller ones keep the separate pass, which costs less than the two extra
#: kernel calls there (a call costs several microseconds, a pass over 1,000 particles ~1).
FUSED_DAMPING_MIN = 1024
#: Relative eigenvalue cut-off of the A_qq / A~_qq pseudo-inverses.
RCOND = 1e-10
#: A multi-cluster body uses the set layout (``kernels.sets_*``) when its cluster
#: memberships outnumber its set-cluster pairs by at least this factor (each pair costs
#: about as much per step as this many memberships).
SET_LAYOUT_MIN_RATIO = 8
#: Single-cluster quadratic bodies use the set layout too (one set).
SINGLE_QUADRATIC_SETS = True
_EMPTY_I64 = np.zeros(0, dtype=np.int64)
#: Bumped whenever a body's buffers, parameters, grabs or wrench kind change: ``World``
#: rebuilds its list of compiled-step records (``kernels.world_step``) when it moved.
_GENERATION = [0]
_EMPTY_I32 = np.zeros(0, dtype=np.int32)


def _as_points(points, name='points'):
    a = np.array(points, dtype=np.float64, order='C', copy=True)
    if a.ndim != 2 or a.shape[1] != 3 or a.shape[0] == 0:
        raise ValueError(f'{name} must be an (N, 3) array with N >= 1, got shape {a.shape}')
    if not np.all(np.isfinite(a)):
        raise ValueError(f'{name} must be finite')
    return a


class _SetLayout:
    """Particles grouped by the set of clusters they belong to (see ``kernels.sets_*``).

    ``sid`` (N,) set of each particle, ``ptr``/``cl`` the clusters of each set (CSR),
    ``cnt`` their number, ``org`` (S, 3) a rest-space origin per set, ``y0`` (N, 3) the
    rest offsets from it, ``phi`` (S, 10) sum m phi(y), ``ref`` (S, 3) the reference point
    of the per-set sums, ``gm`` (S, 3, 10) the goal maps; scratch ``wk``, ``pm``.
    """

    def __init__(self, x0, m, ptr, cl, c0):
        n = len(x0)
        counts = np.diff(ptr)
        rows = np.repeat(np.arange(n), counts)
        pos = np.arange(len(cl)) - ptr[rows]
        pad = np.full((n, int(counts.max())), -1, dtype=np.int64)
        pad[rows, pos] = cl
        # group equal membership lists by a 64-bit hash (np.unique over rows is ~50x
        # slower), then check that every particle's list equals its set's first one
        mult = np.random.default_rng(12345).integers(1, 2 ** 62, pad.shape[1],
                                                     dtype=np.uint64) | np.uint64(1)
        key = ((pad + 1).astype(np.uint64) * mult).sum(axis=1, dtype=np.uint64)
        _, first, sid = np.unique(key, return_index=True, return_inverse=True)
        sid = sid.reshape(-1)
        uniq = pad[first]
        if not np.array_equal(uniq[sid], pad):     # a hash collision: exact grouping
            uniq, sid = np.unique(pad, axis=0, return_inverse=True)
        ns = len(uniq)
        self.sid = np.ascontiguousarray(sid.reshape(-1), dtype=np.int32)
        valid = uniq >= 0
        self.cnt = valid.sum(axis=1).astype(np.float64)
        self.ptr = np.zeros(ns + 1, dtype=np.int64)
        np.cumsum(valid.sum(axis=1), out=self.ptr[1:])
        self.cl = np.ascontiguousarray(uniq[valid], dtype=np.int32)
        pop = np.bincount(self.sid, minlength=ns).astype(np.float64)
        self.org = np.stack([np.bincount(self.sid, weights=x0[:, j], minlength=ns)
                             for j in range(3)], axis=1) / pop[:, None]
        self.y0 = np.ascontiguousarray(x0 - self.org[self.sid])
        y = self.y0
        phi = np.stack([np.ones(n), y[:, 0], y[:, 1], y[:, 2], y[:, 0] ** 2, y[:, 1] ** 2,
                        y[:, 2] ** 2, y[:, 0] * y[:, 1], y[:, 1] * y[:, 2],
                        y[:, 2] * y[:, 0]], axis=1)
        self.phi = np.stack([np.bincount(self.sid, weights=m * phi[:, j], minlength=ns)
                             for j in range(10)], axis=1)
        self.ref = self.org + c0
        self.gm = np.zeros((ns, 3, 10))
        self.wk = np.zeros((2, 3, 10))
        self.pm = np.zeros((9, 10))
        self.pairs = len(self.cl)
        self.part = None


class Body:
    """One shape-matched body; made by ``World.add_body``."""

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
        self._pinned = self._check_indices(pinned if pinned is not None else [], n, 'pinned')
        self.n = n
        self.m = m
        self.m.flags.writeable = False
        self.total_mass = float(m.sum())
        self.x_init = x.copy()
        self.x_init.flags.writeable = False
        self._v_init = v.copy()
        self._x = x
        self._v = v
        # rest positions about the mass centre: every kernel reads these (exact for any
        # far-away placement)
        self._c0 = (m @ x) / self.total_mass
        self._x0 = np.ascontiguousarray(x - self._c0)
        self._force = np.zeros(3)
        self._facc = np.zeros(3)               # force / total mass
        self._torque = np.zeros(3)
        self._has_torque = False
        self._grab_idx = _EMPTY_I64
        self._grab_tgt = np.zeros((0, 3))
        self._acc = np.zeros(3)
        self._ang = np.zeros(3)
        self._com = np.zeros(3)
        self._i3 = np.zeros((3, 3))
        self._i3inv = np.zeros((3, 3))
        self._s3 = [np.zeros((3, 3)) for _ in range(4)]
        self._m39 = np.zeros((3, 9))
        self._n4 = np.zeros((4, 4))
        self._v4 = np.zeros((4, 4))
        self._w9 = [np.zeros((9, 9)) for _ in range(2)]
        self._f9 = np.zeros(9)
        self._accbuf = np.zeros(32)
        self._shape_err = 0.0
        # body-level match for poses of multi-cluster bodies
        self._quat_body = np.array([1.0, 0.0, 0.0, 0.0])
        self._params = params
        self._at_step = (None, None, None)
        self._limit_counts = np.zeros(2, dtype=np.int64)
        self._flags = np.zeros(2)             # [dirty, shape error stale] (world_step)
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
        """Precompute everything that depends on the rest shape and the parameters."""
        self.shape_error_rms()                 # keep the last step's figure across a rebuild
        p = self._params
        n = self.n
        x0, m = self._x0, self.m
        mode = _MODE_ID[p.mode]
        self._mode = mode
        self._quad = mode == 2
        self._need3 = mode == 1 or p.plastic
        self._need9 = self._quad
        if p.clusters == 1:
            self._ptr, self._cl, nk = _EMPTY_I64, _EMPTY_I32, 1
            w = m
            member = np.zeros(n, dtype=np.int64)
            rows = np.arange(n)
        else:
            self._ptr, self._cl, nk = build_memberships(x0, p.clusters)
            counts = np.diff(self._ptr)
            rows = np.repeat(np.arange(n), counts)
            w = (m / counts)[rows]
            member = self._cl.astype(np.int64)
        self.num_clusters = nk
        wsum = np.bincount(member, weights=w, minlength=nk)
        cm0 = np.stack([np.bincount(member, weights=w * x0[rows, j], minlength=nk)
                        for j in range(3)], axis=1) / wsum[:, None]
        d = x0[rows] - cm0[member]
        rms = np.sqrt(np.bincount(member, weights=w * np.einsum('ij,ij->i', d, d),
                                  minlength=nk) / wsum)
        self._wsum = wsum
        self._cm0 = cm0
        # rest moments about each cluster's rest centre, sum w d and sum w d d^T: with them
        # a plastic refresh of the rigid/linear rest data costs per cluster, not per particle
        self._dsum0 = np.stack([np.bincount(member, weights=w * d[:, j], minlength=nk)
                                for j in range(3)], axis=1)
        self._cov0 = np.zeros((nk, 3, 3))
        for i in range(3):
            for j in range(i, 3):
                self._cov0[:, i, j] = self._cov0[:, j, i] = np.bincount(
                    member, weights=w * d[:, i] * d[:, j], minlength=nk)
        self._scale = np.where(rms > 0.0, rms, 1.0)
        self._s_plastic = np.tile(np.eye(3), (nk, 1, 1))
        self._rest_lin = np.zeros((nk, 3, 3))
        self._rest_off = np.zeros((nk, 3))
        self._quat = np.tile([1.0, 0.0, 0.0, 0.0], (nk, 1))
        self._apq = np.zeros((nk, 3, 3))
        self._q4 = np.zeros(4)
        self._sum_q = np.zeros((nk, 9))
        self._mom3 = np.zeros((nk if self._need3 else 1, 3, 3))
        self._mom9 = np.zeros((nk if self._need9 else 1, 9, 9))
        self._aqq3 = np.zeros_like(self._mom3)
        self._aqq9 = np.zeros_like(self._mom9)
        # linear mode: the unit-determinant frames of A_qq (kernels.unit_det_frames)
        self._nmat = np.zeros((nk if mode == 1 else 1, 3, 3))
        self._cdet = np.zeros(nk if mode == 1 else 1)
        self._changed = np.ones(nk, dtype=np.bool_)
        self._refresh_rest(self._changed)
        na = 30 if self._quad else 12
        self._sets = None
        if p.clusters > 1:
            sets = _SetLayout(x0, m, self._ptr, self._cl, self._c0)
            if sets.pairs * SET_LAYOUT_MIN_RATIO <= len(self._cl):
                self._sets = sets
        elif self._quad and SINGLE_QUADRATIC_SETS:
            # one set: the quadratic goal as one polynomial of x0 (27 multiply-adds less
            # per particle than features-then-transform)
            self._sets = _SetLayout(x0, m, np.arange(n + 1, dtype=np.int64),
                                    np.zeros(n, dtype=np.int32), self._c0)
        # work per step: one unit per particle (one cluster, set layout) or per membership
        work = len(self._cl) if p.clusters > 1 and self._sets is None else n
        self._parallel = work >= PARALLEL_MIN_WORK and numba.get_num_threads() > 1
        nch = numba.get_num_threads() if self._parallel else 1
        nch = max(1, min(nch, n))
        if self._sets is not None:
            self._sets.part = np.zeros((nch, len(self._sets.cnt), na))
            nch = 1                            # self._part: the reduced per-cluster sums
        self._part = np.zeros((nch, nk, na))
        self._err = np.zeros(len(self._sets.part) if self._sets is not None else nch)
        self._trans = np.zeros((nk, 3, 9))
        self._goal_lin = np.zeros((nk, 3, 3))
        self._goal_off = np.zeros((nk, 3))
        self._ref = cm0 + self._c0
        # speed and turn limits (kernels/limits.py): previous rotations, scratch, flags
        self._quat_prev = np.zeros((nk, 4))
        self._flagged = np.zeros(nk, dtype=np.bool_)
        self._lim_lin = np.zeros((nk, 13))
        self._lim_w = np.zeros((nk, 6))
        self._lin = np.zeros((nk, 13)) if p.damping > 0 else None
        self._w3 = np.zeros((nk, 3)) if p.damping > 0 else None
        # damping fused into the particle pass (set layout, one cluster; kernels/damping.py)
        # where the pass it saves costs more than the two small kernel calls it adds
        self._damp_fused = (p.damping > 0 and (self._sets is not None or p.clusters == 1)
                            and n >= FUSED_DAMPING_MIN)
        if self._damp_fused and self._sets is not None:
            sets = self._sets
            self._dsets = (sets.ptr, sets.cl, sets.cnt)
            self._dpart = np.zeros((len(sets.part), len(sets.cnt), K.NDAMP))
        elif self._damp_fused:
            self._dsets = (np.array([0, 1], dtype=np.int64), np.zeros(1, dtype=np.int32),
                           np.ones(1))
            self._dpart = np.zeros((len(self._part), 1, K.NDAMP))
        else:
            self._dsets = None
            self._dpart = np.zeros((1, 1, K.NDAMP))
        self._dmp = np.zeros((len(self._dsets[2]) if self._dsets else 1, 6))
        self._dref = np.zeros((nk, 3))
        self._dacc = np.zeros(K.NDAMP)
        self._dirty = True
        _GENERATION[0] += 1

    def _refresh_rest(self, which):
        """Plastic rest shape q = Sp (x0 - cm0) / s of the clusters in ``which``; A_qq.

        Rigid/linear: q = G d with d = x0 - cm0, so sum w q = G sum w d and the centred
        moments are G (sum w d d^T) G^T - (sum w q)(sum w q)^T / W, from the rest moments
        kept since the build: the cost is per changed cluster (plasticity at cluster cost).
        Quadratic features need moments up to degree 4: one pass over the particles.
        """
        idx = np.nonzero(which)[0]
        self._rest_lin[idx] = self._s_plastic[idx] / self._scale[idx, None, None]
        self._rest_off[idx] = -np.einsum('kij,kj->ki', self._rest_lin[idx], self._cm0[idx])
        if not self._need9:
            g = self._rest_lin[idx]
            sq = np.einsum('kij,kj->ki', g, self._dsum0[idx])
            self._sum_q[idx] = 0.0
            self._sum_q[idx, :3] = sq
            if self._need3:
                mom = (np.einsum('kia,kab,kjb->kij', g, self._cov0[idx], g)
                       - sq[:, :, None] * sq[:, None, :] / self._wsum[idx, None, None])
                self._mom3[idx] = 0.5 * (mom + mom.transpose(0, 2, 1))
        else:
            K.moments(x0=self._x0, mass=self.m, ptr=self._ptr, cl=self._cl,
                      rest_lin=self._rest_lin, rest_off=self._rest_off, wsum=self._wsum,
                      which=which, need3=self._need3, need9=self._need9, sum_q=self._sum_q,
                      mom3=self._mom3, mom9=self._mom9, f9=self._f9)
        K.invert_moments(which=which, need3=self._need3, need9=self._need9, mom3=self._mom3,
                         mom9=self._mom9, aqq3=self._aqq3, aqq9=self._aqq9, w3a=self._s3[0],
                         w3b=self._s3[1], w9a=self._w9[0], w9b=self._w9[1], rcond=RCOND)
        if self._mode == 1:
            K.unit_det_frames(which=which, mom3=self._mom3, nmat=self._nmat, cdet=self._cdet,
                              wa=self._s3[0], wv=self._s3[1], rcond=RCOND)

    def _merge_kinematic(self):
        pins = self._pinned
        grab = self._grab_idx
        keep = ~np.isin(grab, pins)
        self._kin_idx = np.concatenate([grab[keep], pins]).astype(np.int64)
        self._kin_tgt = np.ascontiguousarray(
            np.concatenate([self._grab_tgt[keep], self.x_init[pins]]), dtype=np.float64)
        self._kin_prev = np.zeros_like(self._kin_tgt)
        _GENERATION[0] += 1

    # ------------------------------------------------------------------ step
    @property
    def _dirty(self) -> bool:
        """Whether the per-cluster sums must be accumulated again before the next step."""
        return bool(self._flags[0])

    @_dirty.setter
    def _dirty(self, value):
        self._flags[0] = 1.0 if value else 0.0

    def _fast_ok(self) -> bool:
        """Whether ``kernels.world_step`` may step this body (see its docstring)."""
        return ((self._sets is not None or self._params.clusters == 1)
                and not self._params.plastic and len(self._kin_idx) == 0
                and not self._has_torque and not self._parallel)

    def _fast_record(self, h):
        """The tuple of buffers ``kernels.world_step`` steps (valid until the next rebuild)."""
        p = self._params.at_step(h)
        self._at_step = (h, self._params, p)
        self._fstate = np.array([p.alpha, p.beta, p.damping, self._params.max_speed,
                                 self._params.max_turn, 1.0 / self.total_mass, self._mode,
                                 1.0 if self._damp_fused else 0.0, 1.0 if self._quad else 0.0,
                                 1.0 if self._sets is not None else 0.0,
                                 self._params.max_turn / h])
        sptr, scl, scnt = self._dsets if self._dsets else (
            np.zeros(2, dtype=np.int64), np.zeros(1, dtype=np.int32), np.ones(1))
        lin = self._lin if self._lin is not None else np.zeros((self.num_clusters, 13))
        w3 = self._w3 if self._w3 is not None else np.zeros((self.num_clusters, 3))
        s3 = self._s3
        return (self._x, self._v, self._x0, self.m, self._ptr, self._cl, self._rest_lin,
                self._rest_off, self._part, self._wsum, self._sum_q, self._ref, self._quat,
                self._aqq3, self._aqq9, self._scale, self._trans, self._goal_lin,
                self._goal_off, self._apq, self._accbuf, s3[0], s3[1], s3[2], s3[3],
                self._m39, self._n4, self._v4, self._nmat, self._cdet, self._acc, self._ang,
                self._com, self._err, self._dpart, self._dmp, self._dref, self._dacc, lin, w3,
                sptr, scl, scnt, self._quat_prev, self._flagged, self._lim_lin, self._lim_w,
                self._facc, self._fstate, self._flags, self._limit_counts) + self._fast_sets()

    def _fast_sets(self):
        """The set-layout buffers of a record (empty ones for a one-cluster body)."""
        st = self._sets
        if st is not None:
            return (st.y0, st.sid, st.gm, st.ref, st.part, st.ptr, st.cl, st.cnt, st.phi,
                    st.org, st.wk, st.pm)
        na = 30 if self._quad else 12
        return (np.zeros((0, 3)), _EMPTY_I32, np.zeros((0, 3, 10)), np.zeros((0, 3)),
                np.zeros((1, 0, na)), np.zeros(1, dtype=np.int64), _EMPTY_I32, np.zeros(0),
                np.zeros((0, 10)), np.zeros((0, 3)), np.zeros((2, 3, 10)), np.zeros((9, 10)))

    def _step(self, h, gravity, has_col, ground, boxes, spheres, thresh):
        if self._at_step[0] != h or self._at_step[1] is not self._params:
            self._at_step = (h, self._params, self._params.at_step(h))
        p = self._at_step[2]                   # the material's coefficients at this step
        plastic = self._params.plastic
        x, v = self._x, self._v
        s3 = self._s3
        sets = self._sets
        fused = self._damp_fused and p.damping > 0.0
        turned = 0
        if sets is not None:
            if self._dirty:
                acc = K.sets_accumulate_parallel if self._parallel else \
                    K.sets_accumulate_serial
                acc(quad=self._quad, x=x, y0=sets.y0, mass=self.m, sid=sets.sid, sref=sets.ref,
                    part=sets.part)
            K.sets_reduce(part=sets.part, sptr=sets.ptr, scl=sets.cl, scnt=sets.cnt, sphi=sets.phi,
                          sref=sets.ref, sorg=sets.org, rest_lin=self._rest_lin,
                          rest_off=self._rest_off, ref=self._ref, quad=self._quad, out=self._part,
                          wk=sets.wk, pm=sets.pm)
        elif self._dirty:
            acc = K.accumulate_parallel if self._parallel else K.accumulate_serial
            acc(quad=self._quad, x=x, x0=self._x0, mass=self.m, ptr=self._ptr, cl=self._cl,
                rest_lin=self._rest_lin, rest_off=self._rest_off, ref=self._ref, part=self._part)
        turn = self._params.max_turn
        if turn > 0.0:
            np.copyto(self._quat_prev, self._quat)
        K.solve_clusters(part=self._part, wsum=self._wsum, sum_q=self._sum_q, ref=self._ref,
                         quat=self._quat, aqq3=self._aqq3, aqq9=self._aqq9,
                         rest_lin=self._rest_lin, rest_off=self._rest_off, scale=self._scale,
                         trans=self._trans, goal_lin=self._goal_lin, goal_off=self._goal_off,
                         mode=self._mode, beta=p.beta, apq=self._apq, acc=self._accbuf, m3a=s3[0],
                         m3b=s3[1], m3c=s3[2], m39=self._m39, n4=self._n4, v4=self._v4,
                         nmat=self._nmat, cdet=self._cdet)
        if turn > 0.0:
            # |q_prev . q| = cos(angle / 2): clusters whose rotation turned more than
            # max_turn in the last step have their angular velocity measured and capped
            np.less(np.abs(np.einsum('ij,ij->i', self._quat_prev, self._quat)),
                    np.cos(0.5 * turn), out=self._flagged)
            if self._flagged.any():
                turned = K.limit_turn(
                    x=x, v=v, mass=self.m, ptr=self._ptr, cl=self._cl, flagged=self._flagged,
                    w_max=turn / h, lin=self._lim_lin, w3=self._lim_w, m3a=s3[0], m3b=s3[1],
                    m3c=s3[2], m3d=s3[3])
                self._limit_counts[1] += turned
        nchanged = 0
        if plastic:
            nchanged = K.plastic_update(apq=self._apq, aqq3=self._aqq3, scale=self._scale,
                                        quat=self._quat, s_plastic=self._s_plastic,
                                        c_yield=self._params.plastic_yield, c_creep=p.creep,
                                        c_max=self._params.plastic_max, h=h, changed=self._changed,
                                        q4=self._q4, m3a=s3[0], m3b=s3[1], m3c=s3[2], n4=self._n4,
                                        v4=self._v4)
        if sets is not None:
            K.sets_maps(sptr=sets.ptr, scl=sets.cl, scnt=sets.cnt, sorg=sets.org,
                        rest_lin=self._rest_lin, rest_off=self._rest_off, trans=self._trans,
                        goal_lin=self._goal_lin, goal_off=self._goal_off, ref=self._ref,
                        quad=self._quad, gm=sets.gm, sref=sets.ref, pm=sets.pm)
        np.add(self._facc, gravity, out=self._acc)
        if self._has_torque:
            np.dot(self._wsum, self._ref, out=self._com)
            self._com /= self._wsum.sum()
            K.inertia(x, self.m, self._com, self._i3)
            K.pinv_sym(mat=self._i3, out=self._i3inv, wa=s3[0], wv=s3[1], rcond=1e-12)
            np.dot(self._i3inv, self._torque, out=self._ang)
            if turn > 0.0:
                # a torque may add at most max_turn / h of spin in one step: beyond that the
                # step cannot represent the turn and the body is smeared at once
                a_norm = float(np.sqrt(self._ang @ self._ang))
                if a_norm * h * h > turn:
                    self._ang *= turn / (a_norm * h * h)
                    self._limit_counts[1] += 1
        else:
            self._ang[:] = 0.0
        if fused:
            # the rigid fields damping moves towards, from the sums of the last pass (taken
            # again if the state changed since: set by hand, contact, turn limit)
            sptr, scl, scnt = self._dsets
            dsid = sets.sid if sets is not None else self._ptr
            if self._dirty or turned:
                K.damp_accumulate(x=x, v=v, mass=self.m, sid=dsid, dpart=self._dpart)
            K.damping_fields(dpart=self._dpart, sptr=sptr, scl=scl, scnt=scnt, lin=self._lin,
                             w3=self._w3, dref=self._dref, acc=self._dacc, m3a=s3[0], m3b=s3[1],
                             m3c=s3[2], m3d=s3[3])
            K.damping_targets(sptr=sptr, scl=scl, scnt=scnt, lin=self._lin, w3=self._w3,
                              dref=self._dref, sref=sets.ref if sets is not None else self._ref,
                              dmp=self._dmp)
        elif p.damping > 0.0:
            K.damp_rigid(x=x, v=v, mass=self.m, ptr=self._ptr, cl=self._cl, ref=self._ref,
                         k_damp=p.damping, lin=self._lin, w3=self._w3, m3a=s3[0], m3b=s3[1],
                         m3c=s3[2], m3d=s3[3])
        kin = len(self._kin_idx) > 0
        if kin:
            K.gather_rows(x, self._kin_idx, self._kin_prev)
        if sets is not None:
            integ = K.sets_integrate_parallel if self._parallel else K.sets_integrate_serial
            integ(quad=self._quad, x=x, v=v, y0=sets.y0, mass=self.m, sid=sets.sid, gm=sets.gm,
                  sref=sets.ref, alpha=p.alpha, h=h, acc=self._acc, ang=self._ang, com=self._com,
                  part=sets.part, err=self._err, has_col=has_col, ground=ground, boxes=boxes,
                  spheres=spheres, thresh=thresh, damp=fused, k_damp=p.damping, dmp=self._dmp,
                  dpart=self._dpart)
        else:
            integ = K.integrate_parallel if self._parallel else K.integrate_serial
            integ(quad=self._quad, x=x, v=v, x0=self._x0, mass=self.m, ptr=self._ptr, cl=self._cl,
                  rest_lin=self._rest_lin, rest_off=self._rest_off, trans=self._trans,
                  goal_lin=self._goal_lin, goal_off=self._goal_off, ref=self._ref, alpha=p.alpha,
                  h=h, acc=self._acc, ang=self._ang, com=self._com, part=self._part, err=self._err,
                  has_col=has_col, ground=ground, boxes=boxes, spheres=spheres, thresh=thresh,
                  damp=fused, k_damp=p.damping, dmp=self._dmp, dpart=self._dpart)
        capped = 0
        if self._params.max_speed > 0.0:
            capped = K.limit_speed(x=x, v=v, h=h, v_max=self._params.max_speed)
            self._limit_counts[0] += capped
        if kin and fused:                      # their damping sums follow them
            K.damp_kinematic(x=x, v=v, mass=self.m, sid=dsid, dpart=self._dpart,
                             idx=self._kin_idx, sign=-1.0)
        if kin and sets is not None:
            K.sets_kinematic(quad=self._quad, x=x, v=v, y0=sets.y0, mass=self.m, sid=sets.sid,
                             sref=sets.ref, part=sets.part, idx=self._kin_idx, tgt=self._kin_tgt,
                             prev=self._kin_prev, h=h)
        elif kin:
            K.apply_kinematic(quad=self._quad, x=x, v=v, x0=self._x0, mass=self.m, ptr=self._ptr,
                              cl=self._cl, rest_lin=self._rest_lin, rest_off=self._rest_off,
                              ref=self._ref, part=self._part, idx=self._kin_idx, tgt=self._kin_tgt,
                              prev=self._kin_prev, h=h)
        if kin and fused:
            K.damp_kinematic(x=x, v=v, mass=self.m, sid=dsid, dpart=self._dpart,
                             idx=self._kin_idx, sign=1.0)
        self._shape_err = None                 # computed from self._err when asked
        self._dirty = capped > 0               # capped positions: the sums are stale
        if nchanged:
            self._refresh_rest(self._changed)
            # the per-set sums do not depend on the rest shape; the per-cluster ones do
            self._dirty = self._dirty or sets is None

    # ------------------------------------------------------------------ state access
    @property
    def params(self) -> BodyParams:
        """The body's parameters (immutable; change them with ``set_params``)."""
        return self._params

    @property
    def x(self) -> np.ndarray:
        """Positions (N, 3), read-only view (write with ``set_state``)."""
        view = self._x.view()
        view.flags.writeable = False
        return view

    @property
    def v(self) -> np.ndarray:
        """Velocities (N, 3), read-only view (write with ``set_state``)."""
        view = self._v.view()
        view.flags.writeable = False
        return view

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
            self._x[:] = nx
        if nv is not None:
            self._v[:] = nv
        self._dirty = True

    def set_params(self, params=None, **changes):
        """Apply new parameters from the next step on; rebuild only what they reshape."""
        new = (params if params is not None else self._params)
        if not isinstance(new, BodyParams):
            raise ValueError('params must be a BodyParams')
        unknown = set(changes) - set(BodyParams.field_names())
        if unknown:
            raise ValueError(f'unknown body parameters: {sorted(unknown)}')
        from dataclasses import replace
        new = replace(new, **changes).validate()
        old = self._params
        self._params = new
        _GENERATION[0] += 1
        if (new.mode != old.mode or new.clusters != old.clusters or new.plastic != old.plastic
                or (new.damping > 0) != (old.damping > 0)):
            self._build()

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
        self._has_torque = bool(t.any())
        _GENERATION[0] += 1

    def clear_wrench(self):
        """Remove the external force and torque."""
        self._force[:] = 0.0
        self._facc[:] = 0.0
        self._torque[:] = 0.0
        self._has_torque = False
        _GENERATION[0] += 1

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
        self._grab_idx = idx.astype(np.int64)
        self._grab_tgt = np.ascontiguousarray(tgt)
        self._merge_kinematic()

    def clear_kinematic(self):
        """Release every grabbed particle (pins stay)."""
        self._grab_idx = _EMPTY_I64
        self._grab_tgt = np.zeros((0, 3))
        self._merge_kinematic()

    @property
    def kinematic_indices(self) -> np.ndarray:
        """Indices of the particles that currently follow targets (grabbed and pinned)."""
        return self._kin_idx.copy()

    @property
    def pinned(self) -> np.ndarray:
        """Indices of the pinned particles."""
        return self._pinned.copy()

    def com(self) -> np.ndarray:
        """Centre of mass of the current positions."""
        return (self.m @ self._x) / self.total_mass

    def rotation(self) -> np.ndarray:
        """Proper rotation of the whole body's shape match (3, 3)."""
        r = np.zeros((3, 3))
        if self.num_clusters == 1:
            K.quat_to_mat(self._quat[0], r)
            return r
        com = self.com()
        apq = np.einsum('i,ij,ik->jk', self.m, self._x - com, self._x0)
        K.extract_rotation(mat=apq, quat=self._quat_body, rot=r, n4=self._n4, v4=self._v4)
        return r

    def goals(self) -> np.ndarray:
        """Goal positions g_i for the current state (Eq. 12/18/22, averaged over clusters)."""
        p = self._params
        part = np.zeros((1,) + self._part.shape[1:])
        ref, quat = self._ref.copy(), self._quat.copy()
        trans, goal_lin = np.zeros_like(self._trans), np.zeros_like(self._goal_lin)
        goal_off = np.zeros_like(self._goal_off)
        K.accumulate_serial(quad=self._quad, x=self._x, x0=self._x0, mass=self.m, ptr=self._ptr,
                            cl=self._cl, rest_lin=self._rest_lin, rest_off=self._rest_off, ref=ref,
                            part=part)
        s3 = [np.zeros((3, 3)) for _ in range(3)]
        K.solve_clusters(part=part, wsum=self._wsum, sum_q=self._sum_q, ref=ref, quat=quat,
                         aqq3=self._aqq3, aqq9=self._aqq9, rest_lin=self._rest_lin,
                         rest_off=self._rest_off, scale=self._scale, trans=trans,
                         goal_lin=goal_lin, goal_off=goal_off, mode=self._mode, beta=p.beta,
                         apq=np.zeros_like(self._apq), acc=np.zeros(32), m3a=s3[0], m3b=s3[1],
                         m3c=s3[2], m39=np.zeros((3, 9)), n4=np.zeros((4, 4)), v4=np.zeros((4, 4)),
                         nmat=self._nmat, cdet=self._cdet)
        g = self._x.copy()
        K.integrate_serial(quad=self._quad, x=g, v=np.zeros_like(g), x0=self._x0, mass=self.m,
                           ptr=self._ptr, cl=self._cl, rest_lin=self._rest_lin,
                           rest_off=self._rest_off, trans=trans, goal_lin=goal_lin,
                           goal_off=goal_off, ref=ref, alpha=1.0, h=1.0, acc=np.zeros(3),
                           ang=np.zeros(3), com=np.zeros(3), part=part, err=np.zeros(1),
                           has_col=False, ground=np.zeros(4), boxes=np.zeros((0, 8)),
                           spheres=np.zeros((0, 6)), thresh=0.0, damp=False, k_damp=0.0,
                           dmp=np.zeros((1, 6)), dpart=np.zeros((1, 1, K.NDAMP)))
        return g

    @property
    def limit_counts(self):
        """(particles slowed to max_speed, clusters whose spin was capped) since built.

        Counted per step: a particle capped in 10 steps counts 10.
        """
        return int(self._limit_counts[0]), int(self._limit_counts[1])

    def shape_error_rms(self) -> float:
        """RMS distance of the particles to their goals in the last step (m)."""
        if self._shape_err is None or self._flags[1]:
            self._shape_err = float(np.sqrt(self._err.sum() / self.n))
            self._flags[1] = 0.0
        return self._shape_err

    def momentum(self) -> np.ndarray:
        """Linear momentum sum m v."""
        return self.m @ self._v

    def angular_momentum(self, about=(0.0, 0.0, 0.0)) -> np.ndarray:
        """Angular momentum sum m (x - about) x v."""
        r = self._x - np.asarray(about, dtype=float)
        return np.cross(r, self._v * self.m[:, None]).sum(axis=0)

    def is_finite(self) -> bool:
        """Whether every position and velocity is finite."""
        return bool(np.isfinite(self._x).all() and np.isfinite(self._v).all())

    def reset(self):
        """Initial pose and velocities, rest shape, no plastic state, wrench or grabs."""
        self._x[:] = self.x_init
        self._v[:] = self._v_init
        self.clear_wrench()
        self.clear_kinematic()
        self._quat_body[:] = (1.0, 0.0, 0.0, 0.0)
        self._build()
