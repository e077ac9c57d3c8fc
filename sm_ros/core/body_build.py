"""Rest data and buffers of a ``Body``: built once per rest shape and parameter set.

``build`` precomputes what a body's mode needs (cluster memberships, rest moments, the
set layout ``_SetLayout``, scratch buffers, the damping sets) and ``refresh_rest`` the
plastic rest data of changed clusters (Eq. 7-9, 21 of algorithm.md); ``merge_kinematic``
merges grabbed and pinned particles; ``fast_record`` hands a body's buffers to the
compiled world step (``kernels.world_step``).  The functions set the body's private
buffers; ``sm_ros.core.body.Body`` calls them and owns the state.
"""

import numba
import numpy as np
from numba.typed import List as TypedList

from . import kernels as K
from .clusters import build_memberships
from .kernels import world_step as R
from .kernels.flags import DAMP_SUMS


#: Bytes a state block's first element is aligned to: the particle loops' vector loads and
#: stores of a column that starts off a 32-byte boundary cost more.
STATE_ALIGN = 64


def soa(a):
    """``a`` (N, 3) stored per component: the transpose of a C-contiguous (3, N) block.

    The result is an F-contiguous (N, 3) array: ``a[:, j]`` is unit-stride, so the compiled
    particle loops (which index ``x[i, j]``, typed with layout F) run over i with unit
    stride and vectorise across particles; ``a.T`` is the (3, N) block itself.  Every
    body's per-particle state (x, v, rest positions, set offsets) is kept this way.  The
    block starts on a ``STATE_ALIGN`` boundary (numpy's own allocations
    start 16 bytes past one), so its first column is aligned, and all three when N is a
    multiple of 4.  A copy (pickle, ``copy.deepcopy``) has numpy's allocation: the same
    values and layout, its loops a little slower.
    """
    a = np.asarray(a, dtype=np.float64)
    n = a.shape[0]
    pad = STATE_ALIGN // 8
    buf = np.empty(3 * n + pad)
    off = (-buf.ctypes.data % STATE_ALIGN) // 8
    block = buf[off:off + 3 * n].reshape(3, n)
    block[:] = a.T
    return block.T


_MODE_ID = {'rigid': 0, 'linear': 1, 'quadratic': 2}
_EMPTY_I64 = np.zeros(0, dtype=np.int64)
#: Bumped whenever a body's buffers, parameters, grabs or wrench kind change: ``World``
#: rebuilds its list of compiled-step records (``kernels.world_step``) when it moved.
_GENERATION = [0]
_EMPTY_I32 = np.zeros(0, dtype=np.int32)


def group_sets(ptr, cluster_ids):
    """The sets of a particle-major membership CSR (``ptr``, ``cluster_ids``): ``(sid, uniq)``.

    ``sid`` (N,) int64 is each particle's set, ``uniq`` (S, width) the clusters of each
    set padded with -1 (set ids in the order of the sets' hash keys, which does not depend
    on the particles' order).
    """
    n = len(ptr) - 1
    counts = np.diff(ptr)
    rows = np.repeat(np.arange(n), counts)
    pos = np.arange(len(cluster_ids)) - ptr[rows]
    pad = np.full((n, int(counts.max())), -1, dtype=np.int64)
    pad[rows, pos] = cluster_ids
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
    return sid.reshape(-1), uniq


def set_order(x0, clusters):
    """The order of the particles by cluster set, for a body of rest positions ``x0``
    (N, 3) with ``clusters`` cubes per axis: ``(perm, members)``.

    ``perm`` (N,) int64 lists the particles set by set (each set one run of consecutive
    particles, the given order kept within a set), or is None for one cluster (one set)
    or where the particles are in that order already.  ``members`` is
    ``(clusters, ptr, cluster_ids, n_clusters, (sid, uniq))`` of the reordered particles (``build``
    reuses it: the memberships and sets are computed once; None for one cluster).

    Cost: the memberships (``build_memberships``) and the grouping, no body build.
    """
    if clusters <= 1:
        return None, None
    ptr, cluster_ids, nk = build_memberships(x0, clusters)
    sid, uniq = group_sets(ptr, cluster_ids)
    if np.all(sid[1:] >= sid[:-1]):
        return None, (clusters, ptr, cluster_ids, nk, (sid, uniq))
    perm = np.argsort(sid, kind='stable').astype(np.int64)
    counts = np.diff(ptr)[perm]
    nptr = np.zeros(len(ptr), dtype=np.int64)
    np.cumsum(counts, out=nptr[1:])
    # the memberships of particle perm[i], moved to row i
    src = np.repeat(ptr[:-1][perm] - nptr[:-1], counts) + np.arange(len(cluster_ids))
    return perm, (clusters, nptr, np.ascontiguousarray(cluster_ids[src]), nk, (sid[perm], uniq))


class _SetLayout:
    """Particles grouped by the set of clusters they belong to (see ``kernels.sets_*``).

    ``sid`` (N,) set of each particle, ``ptr``/``cluster_ids`` the clusters of each set (CSR),
    ``cnt`` their number, ``org`` (S, 3) a rest-space origin per set, ``rest_local`` (N, 3) the
    rest offsets from it, ``phi`` (S, 10) sum m phi(y), ``ref`` (S, 3) the reference point
    of the per-set sums, ``goal_maps`` (S, 3, 10); ``pair_offsets`` (pairs, 3) the offset
    org[s] - cm0[k] of each set-cluster pair (``cluster_ids`` order) from the cluster's rest centre
    ``cm0``; scratch: ``work`` (2, 3, 10), ``quad_map`` (9, 10: a cluster's quadratic rest
    map) and ``cluster_maps`` (clusters, 3, 10: each cluster's goal map in those terms);
    ``runs`` (R + 1,) the first particle of each run of consecutive particles of one set,
    then N (``sets._sets_fused_lin``
    steps run by run without looking for the ends).
    """

    def __init__(self, x0, m, ptr, cluster_ids, c0, cm0, quad, groups=None):
        n = len(x0)
        sid, uniq = group_sets(ptr, cluster_ids) if groups is None else groups
        ns = len(uniq)
        self.sid = np.ascontiguousarray(sid, dtype=np.int32)
        self.runs = np.concatenate(([0], np.flatnonzero(np.diff(self.sid)) + 1, [n])).astype(
            np.int64)
        valid = uniq >= 0
        self.cnt = valid.sum(axis=1).astype(np.float64)
        self.ptr = np.zeros(ns + 1, dtype=np.int64)
        np.cumsum(valid.sum(axis=1), out=self.ptr[1:])
        self.cluster_ids = np.ascontiguousarray(uniq[valid], dtype=np.int32)
        pop = np.bincount(self.sid, minlength=ns).astype(np.float64)
        self.org = np.stack([np.bincount(self.sid, weights=x0[:, j], minlength=ns)
                             for j in range(3)], axis=1) / pop[:, None]
        # per component, as the body's positions (``body.soa``)
        self.rest_local = soa(x0 - self.org[self.sid])
        y = self.rest_local
        phi = np.stack([np.ones(n), y[:, 0], y[:, 1], y[:, 2], y[:, 0] ** 2, y[:, 1] ** 2,
                        y[:, 2] ** 2, y[:, 0] * y[:, 1], y[:, 1] * y[:, 2],
                        y[:, 2] * y[:, 0]], axis=1)
        self.phi = np.stack([np.bincount(self.sid, weights=m * phi[:, j], minlength=ns)
                             for j in range(10)], axis=1)
        self.ref = self.org + c0
        # goal maps: 4 coefficients a row (rigid/linear) or 10 (quadratic)
        self.goal_maps = np.zeros((ns, 3, 10 if quad else 4))
        self.pair_offsets = np.ascontiguousarray(np.repeat(self.org, valid.sum(axis=1), axis=0)
                                       - cm0[self.cluster_ids])
        self.cluster_maps = np.zeros((len(cm0) if quad else 0, 3, 10))
        self.work = np.zeros((2, 3, 10))
        self.quad_map = np.zeros((9, 10))
        self.pairs = len(self.cluster_ids)
        self.part = None

    def step_state(self) -> tuple:
        """What a step changes and the next reads (``snapshot``): the per-set sums and
        their reference points."""
        return ('part', 'ref')


def build(body, *, parallel_min_work):
    """Precompute everything of ``body`` that depends on the rest shape and the parameters;
    ``parallel_min_work``: ``tuning.PARALLEL_MIN_WORK`` (passed by ``Body._build``, read
    there at each build)."""
    body.shape_error_rms()                 # keep the last step's figure across a rebuild
    p = body._params
    mode = _MODE_ID[p.mode]
    body._mode = mode
    body._quad = mode == 2
    body._need3 = mode == 1 or p.plastic
    body._need9 = body._quad
    groups = _rest_moments(body)
    _cluster_state(body)
    _layout(body, groups, parallel_min_work)
    _damping_buffers(body)
    body._dirty = True
    body._flags[DAMP_SUMS] = 0.0           # no fused damping sums yet
    _GENERATION[0] += 1


def _rest_moments(body):
    """The memberships (``body._ptr``, ``body._cluster_ids``; none for one cluster), and each
    cluster's weight, rest centre, scale and rest moments about its centre; returns the
    set grouping ``set_order`` computed with the memberships (or None)."""
    p, n = body._params, body.n
    x0, m = body._x0, body._m
    groups = None
    if p.clusters == 1:
        body._ptr, body._cluster_ids, nk = _EMPTY_I64, _EMPTY_I32, 1
        w = m
        member = np.zeros(n, dtype=np.int64)
        rows = np.arange(n)
    else:
        pre = getattr(body, '_members', None)   # from set_order (``Body.__init__``)
        if pre is not None and pre[0] == p.clusters:
            body._ptr, body._cluster_ids, nk, groups = pre[1:]
        else:
            body._ptr, body._cluster_ids, nk = build_memberships(x0, p.clusters)
        counts = np.diff(body._ptr)
        rows = np.repeat(np.arange(n), counts)
        w = (m / counts)[rows]
        member = body._cluster_ids.astype(np.int64)
    body.num_clusters = nk
    wsum = np.bincount(member, weights=w, minlength=nk)
    cm0 = np.stack([np.bincount(member, weights=w * x0[rows, j], minlength=nk)
                    for j in range(3)], axis=1) / wsum[:, None]
    d = x0[rows] - cm0[member]
    rms = np.sqrt(np.bincount(member, weights=w * np.einsum('ij,ij->i', d, d),
                              minlength=nk) / wsum)
    body._wsum = wsum
    body._cm0 = cm0
    # rest moments about each cluster's rest centre, sum w d and sum w d d^T: with them
    # a plastic refresh of the rigid/linear rest data costs per cluster, not per particle
    body._dsum0 = np.stack([np.bincount(member, weights=w * d[:, j], minlength=nk)
                            for j in range(3)], axis=1)
    body._cov0 = np.zeros((nk, 3, 3))
    for i in range(3):
        for j in range(i, 3):
            body._cov0[:, i, j] = body._cov0[:, j, i] = np.bincount(
                member, weights=w * d[:, i] * d[:, j], minlength=nk)
    body._scale = np.where(rms > 0.0, rms, 1.0)
    return groups


def _cluster_state(body) -> None:
    """Each cluster's plastic state, rest data, rotation and the shape match's buffers."""
    nk, mode = body.num_clusters, body._mode
    body._s_plastic = np.tile(np.eye(3), (nk, 1, 1))
    body._rest_lin = np.zeros((nk, 3, 3))
    body._rest_off = np.zeros((nk, 3))
    body._quat = np.tile([1.0, 0.0, 0.0, 0.0], (nk, 1))
    body._apq = np.zeros((nk, 3, 3))
    body._quat_scratch = np.zeros(4)
    body._sum_q = np.zeros((nk, 9))
    body._mom3 = np.zeros((nk if body._need3 else 1, 3, 3))
    body._mom9 = np.zeros((nk if body._need9 else 1, 9, 9))
    body._aqq3 = np.zeros_like(body._mom3)
    body._aqq9 = np.zeros_like(body._mom9)
    # linear mode: the unit-determinant frames of A_qq (kernels.unit_det_frames)
    body._nmat = np.zeros((nk if mode == 1 else 1, 3, 3))
    body._cdet = np.zeros(nk if mode == 1 else 1)
    # linear mode: each cluster's eigenvectors of its last unit-determinant match, the
    # warm start of the next (kernels.nearest_unit_det_warm)
    body._udv = np.tile(np.eye(3), (nk if mode == 1 else 1, 1, 1))
    body._changed = np.ones(nk, dtype=np.bool_)
    body._refresh_rest(body._changed)
    body._trans = np.zeros((nk, 3, 9))
    body._goal_lin = np.zeros((nk, 3, 3))
    body._goal_off = np.zeros((nk, 3))
    body._ref = body._cm0 + body._rest_centre
    # speed and turn limits (kernels/limits.py): previous rotations, scratch, flags
    body._quat_prev = np.zeros((nk, 4))
    body._flagged = np.zeros(nk, dtype=np.bool_)
    body._lim_lin = np.zeros((nk, 13))
    body._lim_w = np.zeros((nk, 6))


def _layout(body, groups, parallel_min_work):
    """The set layout (a one-cluster body is one set), whether the body runs on threads,
    and the per-chunk sums."""
    p, n, nk = body._params, body.n, body.num_clusters
    na = 30 if body._quad else 12
    if p.clusters > 1:
        body._sets = _SetLayout(body._x0, body._m, body._ptr, body._cluster_ids,
                                body._rest_centre, body._cm0, body._quad, groups)
    else:
        body._sets = _SetLayout(body._x0, body._m, np.arange(n + 1, dtype=np.int64),
                                np.zeros(n, dtype=np.int32), body._rest_centre, body._cm0,
                                body._quad)
    body._parallel = n >= parallel_min_work and numba.get_num_threads() > 1
    nch = max(1, min(numba.get_num_threads() if body._parallel else 1, n))
    body._sets.part = np.zeros((nch, len(body._sets.cnt), na))
    body._part = np.zeros((1, nk, na))     # the per-set sums reduced to the clusters
    body._err = np.zeros(nch)


def _damping_buffers(body) -> None:
    """Damping's buffers: it runs inside the particle pass, towards each set's share of
    its clusters' rigid motion (kernels/damping.py)."""
    nk, sets = body.num_clusters, body._sets
    body._lin = np.zeros((nk, 13))
    body._damp_spin = np.zeros((nk, 3))
    body._dpart = np.zeros((len(sets.part), len(sets.cnt), K.NDAMP))
    body._dmp = np.zeros((len(sets.cnt), 6))
    body._dref = np.zeros((nk, 3))
    body._dacc = np.zeros(K.NDAMP)


def refresh_rest(body, which):
    """Plastic rest shape and A_qq of the clusters in ``which``: the kernels of
    ``kernels.refresh_rest`` (which the compiled step runs after plastic flow) one by one,
    so that building a body compiles only those it needs."""
    rest, needs = rest_shape(body), (body._need3, body._need9)
    K.rest_maps(which, rest, body._need3 and not body._need9)
    if body._need9:
        K.moments(body._x0, body._m, (body._ptr, body._cluster_ids),
                  (body._rest_lin, body._rest_off), body._wsum, which, needs,
                  (body._sum_q, body._mom3, body._mom9), body._features9)
    K.invert_moments(which, needs, (body._mom3, body._mom9), (body._aqq3, body._aqq9),
                     (body._mat3[0], body._mat3[1], body._mat9[0], body._mat9[1]), K.RCOND)
    if body._mode == 1:
        K.unit_det_frames(which=which, mom3=body._mom3, nmat=body._nmat, cdet=body._cdet,
                          wa=body._mat3[0], wv=body._mat3[1], rcond=K.RCOND)


def rest_shape(body):
    """The body's rest shape as ``kernels.refresh_rest`` reads and rebuilds it."""
    return K.RestShape(body._x0.T, body._m, body._ptr, body._cluster_ids, body._s_plastic,
                       body._scale, body._cm0, body._dsum0, body._cov0, body._wsum,
                       body._rest_lin, body._rest_off, body._sum_q, body._mom3, body._mom9,
                       body._aqq3, body._aqq9, body._nmat, body._cdet)


def plastic_work(body):
    """The plastic flow's buffers (``kernels.PlasticWork``)."""
    return K.PlasticWork(body._changed, body._features9, body._mat9[0], body._mat9[1],
                         body._quat_scratch)


def merge_kinematic(body):
    """The particles ``body`` moves to targets: grabbed ones, then the pinned ones
    not grabbed (at their initial positions)."""
    pins = body._pinned
    grab = body._grab_idx
    keep = ~np.isin(grab, pins)
    idx = np.concatenate([grab[keep], pins]).astype(np.int64)
    targets = np.concatenate([body._grab_tgt[keep], body._x_init[pins]])
    held = getattr(body, '_kin_idx', None)
    if held is not None and np.array_equal(held, idx):
        # the same particles, moved: in place, so the step's records keep their arrays
        body._kin_tgt[:] = targets
        return
    body._kin_idx = idx
    body._kin_tgt = np.ascontiguousarray(targets, dtype=np.float64)
    body._kin_prev = np.zeros_like(body._kin_tgt)
    _GENERATION[0] += 1


def fast_record(body, h):
    """The buffers ``kernels.world_step`` steps, a ``StepRecord`` (valid until the next
    rebuild)."""
    body._fstate = np.zeros(R.R_SIZE)
    retime_record(body, body._fstate, h)
    s3 = body._mat3
    # x, v (and the set layout's rest_local) as their (3, N) C-contiguous blocks: a typed
    # list fixes the element type from its first record, and a one-particle body's (1, 3)
    # view is typed C (both orders at once); the world step transposes them back (layout F)
    own = (body._x.T, body._v.T, body._m, body._ptr, body._cluster_ids, body._rest_lin,
           body._rest_off, body._part, body._wsum, body._sum_q, body._ref, body._quat,
           body._aqq3, body._aqq9, body._scale, body._trans, body._goal_lin, body._goal_off,
           body._apq, body._accbuf, s3[0], s3[1], s3[2], s3[3], body._mat39, body._quat_n,
           body._quat_v, body._nmat, body._cdet, body._acc, body._ang, body._com, body._err,
           body._dpart, body._dmp, body._dref, body._dacc, body._lin, body._damp_spin,
           body._quat_prev, body._flagged, body._lim_lin, body._lim_w, body._facc,
           body._fstate, body._flags, body._limit_counts)
    wrench = (body._torque, body._inertia, body._inertia_inv, body._kin_idx, body._kin_tgt,
              body._kin_prev)
    return K.StepRecord(*own, *body._fast_sets(), body._udv, body._match_work, *wrench)


def plastic_record(body):
    """What plastic flow reads and writes of ``body`` (``kernels.PlasticRecord``), with
    the state of its record (``fast_record``, made first)."""
    s3 = body._mat3
    scratch = (s3[0], s3[1], s3[2], body._quat_n, body._quat_v, body._match_work[0],
               body._match_work[1])
    return K.PlasticRecord(body._fstate, body._flags, body._apq, body._aqq3, body._scale,
                           body._quat, scratch, rest_shape(body), plastic_work(body))


def retime_record(body, fstate, h):
    """Write the numbers of a record for steps of ``h`` (``fast_record``'s ``_fstate``:
    the material's coefficients at the step, the turn limit's rate, the collider radius)
    into ``fstate``."""
    params = body._params
    p = params.at_step(h)
    numbers = {R.R_ALPHA: p.alpha, R.R_BETA: p.beta, R.R_DAMPING: p.damping,
               R.R_MAX_SPEED: params.max_speed, R.R_MAX_TURN: params.max_turn,
               R.R_TURN_RATE: params.max_turn / h, R.R_MODE: body._mode,
               R.R_QUAD: body._quad, R.R_WUNI: body._wuni,
               R.R_RADIUS: body._collider_radius,
               R.R_PLASTIC: params.plastic and body.n > 1, R.R_YIELD: params.plastic_yield,
               R.R_CREEP: p.creep, R.R_PLASTIC_MAX: params.plastic_max}
    for slot, value in numbers.items():
        fstate[slot] = float(value)


def one_record(body, h):
    """A typed list holding ``fast_record(body, h)``, kept until a body changes or h or its
    collider radius does."""
    key = (_GENERATION[0], h, body._collider_radius)
    one = getattr(body, '_one', None)
    if one is None or one[0] != key or not isinstance(one[1], TypedList):
        record = TypedList([fast_record(body, h)])
        plastic = TypedList([plastic_record(body)]) if body._params.plastic else None
        one = body._one = (key, record, plastic)
    return one[1]


def one_plastic_record(body, h):
    """A typed list holding ``plastic_record(body)``, kept with ``one_record``'s."""
    one_record(body, h)
    return body._one[2]


def fast_sets(body):
    """The set-layout buffers of a record."""
    st = body._sets
    return (st.rest_local.T, st.sid, st.goal_maps, st.ref, st.part, st.ptr, st.cluster_ids,
            st.cnt, st.phi, st.org, st.work, st.quad_map, st.pair_offsets, st.cluster_maps,
            st.runs)
