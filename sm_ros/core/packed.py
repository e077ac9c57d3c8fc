"""The packed world step: one-cluster rigid/linear bodies without per-body records.

Kept beside the records of ``kernels.world_step`` for the default scene and worlds of many
small bodies: its step is smaller, so it compiles sooner (the first simulated cloud of a
cold start) and steps a small body with less overhead (figures: doc/architecture.md).  A
packable body (``Body._packed_ok``: one cluster, rigid or linear, one mass, no plasticity,
grabs or torque) keeps its per-body scalars and per-cluster state in one row of
``Pack.rows`` (nb, NCOL): its attributes (``_ref``, ``_quat``, ``_part``, ...) become views
of the row, so every reader sees what the step writes.  One pass over a body's particles,
in blocks of ``FUSED_BLOCK``, damps (the field of the last pass's sums), applies Eq. 13-14,
the static colliders and the speed limit, and takes the next step's sums while the block
is in cache (``kernels.packed_pass``).

``Body._step`` steps such a body as a pack of one (``Body._one_pack``), the same compiled
function as ``World.step``, so both agree bit for bit.  A body belongs to one pack at a
time: building a pack copies its state into the row and marks the pack it left ``stale``,
so a world packs its bodies again only after one was packed elsewhere.  A body moving
between this step and the set layout's has its sums taken afresh (``flags.SUMS_PACKED``).
"""
from collections import namedtuple

import numpy as np
from numba import njit
from numba.typed import List as TypedList

from .kernels import (JIT, NDAMP, STRETCH_LIMIT, _collide_range, damp_acc_range, det3,
                      extract_rotation, limit_turn, unit_det_match_warm)
from .kernels.fused import damp_sums_uniform
from .kernels.colliders import Colliders, ground_height, ground_range, ground_range_sums
from .kernels.packed_pass import _add_rest_sums, _int_single_fused, one_cluster_sums
from .kernels.flags import DAMP_SUMS, DIRTY, ERR_STALE, NFLAGS, SLEEP, SUMS_PACKED
from .kernels.jit import finite
from .kernels.limits import limit_speed_range
from .kernels.linalg import sym3_solve

#: Particles per call of the fused one-loop pass (``_int_single_fused``; sums, the damping
#: sums too, reduced once a call; a call with a speed over the cap, or in a world with boxes
#: or spheres, is projected, capped and summed again while it is in L2).
FUSED_BLOCK = 4096

# Row layout: parameters (written at each pack build), then the body state the rows hold
# (attribute, shape); each attribute becomes a view of its columns.
# C_WUNI: the particles' one mass where all are equal (masses are read-only), else 0
# C_RADIUS: the radius its particles meet the colliders with (``Body._collider_radius``)
C_ALPHA, C_BETA, C_DAMP, C_VMAX, C_TURN, C_WMAX, C_MODE, C_WUNI, C_RADIUS = range(9)
NPARAM = 9
STATE = (('_flags', (NFLAGS,)), ('_facc', (3,)), ('_ref', (1, 3)), ('_quat', (1, 4)),
         ('_rest_lin', (1, 3, 3)), ('_rest_off', (1, 3)), ('_sum_q', (1, 9)),
         ('_wsum', (1,)), ('_scale', (1,)), ('_cdet', (1,)), ('_aqq3', (1, 3, 3)),
         ('_nmat', (1, 3, 3)), ('_part', (1, 1, 12)), ('_err', (1,)),
         ('_dpart', (1, 1, NDAMP)), ('_udv', (1, 3, 3)))


def _columns():
    cols, off = {}, NPARAM
    for name, shape in STATE:
        size = int(np.prod(shape))
        cols[name] = (off, size, shape)
        off += size
    return cols, off


COLS, NCOL = _columns()
#: Row entries a body built for threads holds per chunk (leading axis: chunks).
_CHUNKED = ('_part', '_err', '_dpart')
# the first column of each STATE entry (C_FLAGS: the body's flags, ``kernels.flags``)
(C_FLAGS, C_FACC, C_REF, C_QUAT, C_RLIN, C_ROFF, C_SUMQ, C_WSUM, C_SCALE, C_CDET, C_AQQ3,
 C_NMAT, C_PART, C_ERR, C_DPART, C_UDV) = (COLS[name][0] for name, _ in STATE)


#: Packs built so far in this process: a body's flag array changes only when one is built
#: (``flat.FlatState.flag_list`` checks this instead of every body).
PACKS_BUILT = [0]


class Pack:
    """The rows of a list of packable bodies at the step ``h`` (see the module docstring)."""

    def __init__(self, bodies, h):
        PACKS_BUILT[0] += 1
        nb = len(bodies)
        self.bodies = list(bodies)
        self.rows = np.zeros((max(nb, 1), NCOL))
        self.counts = np.zeros((max(nb, 1), 2), dtype=np.int64)
        #: per body its particle arrays (x, v, x0 as (3, N) blocks, the masses read-only)
        self.arrays = TypedList()
        #: set when one of the bodies was packed since into another pack
        self.stale = False
        #: ``_resolve``'s compiled entry of the one-chunk call, and what it was resolved for
        self._entry = None
        self.retime(h)
        for b, body in enumerate(self.bodies):
            row = self.rows[b]
            rebuild = False
            for name, (off, size, shape) in COLS.items():
                src = np.asarray(getattr(body, name))
                if name in _CHUNKED and src.shape[1:] == shape[1:] and len(src) > 1:
                    # a body built for threads (``body._parallel``) keeps its sums per
                    # chunk: the row takes their total (shape error) or the pass takes
                    # them again (shape match and damping sums: flags below)
                    src = src.sum(axis=0, keepdims=True)
                    rebuild = True
                if src.shape != shape:
                    raise AssertionError(f'{body.name}.{name}: shape {src.shape}, packed '
                                         f'{shape}')
                view = row[off:off + size]
                view[:] = src.reshape(-1)
                setattr(body, name, view.reshape(shape))
            if rebuild:
                row[C_FLAGS + DIRTY] = 1.0        # the shape-match sums are taken again
                row[C_FLAGS + DAMP_SUMS] = 0.0    # and the damping sums
            self.counts[b] = body._limit_counts
            body._limit_counts = self.counts[b]
            old = getattr(body, '_pack_owner', None)
            if old is not None and old is not self:
                old.stale = True              # its row no longer holds this body's state
            body._pack_owner = self
            # x, v, x0 as their (3, N) blocks (``body.soa``), transposed back in the step
            arrays = (body._x.T, body._v.T, body._x0.T, body._m)
            n = body.n
            for a, shape in zip(arrays, ((3, n), (3, n), (3, n), (n,))):
                if (a.dtype != np.float64 or a.shape != shape
                        or not a.flags['C_CONTIGUOUS']):
                    raise AssertionError(f'{body.name}: particle array {a.shape} '
                                         f'{a.dtype} is not a C-contiguous float64 {shape}')
            mass = body._m.view()
            mass.flags.writeable = False       # one element type for every body's masses
            self.arrays.append(arrays[:3] + (mass,))

    def retime(self, h):
        """The parameter columns for steps of ``h``; the rows' state stays."""
        self.h = h
        for b, body in enumerate(self.bodies):
            prm = body._params
            p = prm.at_step(h)
            self.rows[b, :NPARAM] = (p.alpha, p.beta, p.damping, prm.max_speed, prm.max_turn,
                                  prm.max_turn / h, body._mode, body._wuni,
                                  body._collider_radius)

    def __len__(self):
        return len(self.bodies)

    def __reduce__(self):
        # a copy's ``arrays`` would step the bodies' own particles (copies pack again)
        raise TypeError("a Pack holds its bodies' particle arrays and is not copied: pack "
                        'the copied bodies again')

    def step(self, h, gravity, has_col, ground, boxes, spheres, thresh):
        """Step every body of the pack once, on the calling thread (``step_packed``)."""
        call = self._entry
        if (call is None or call[1] is not gravity or call[2] is not ground
                or call[3] is not boxes or call[4] is not spheres):
            call = self._entry = self._resolve(gravity, ground, boxes, spheres)
        first, turned, nb = 0, -1, len(self.bodies)   # the body to step from, its turn
        while first < nb:
            col = Colliders(bool(has_col), ground, boxes, spheres, float(thresh), 0.0, float(h))
            first = call[0](self.rows, self.counts, self.arrays, float(h), gravity, col, first,
                            turned)
            turned = self._limit_turn(first) if first < nb else -1

    def _limit_turn(self, b):
        """``limits.limit_turn`` of body ``b`` (its cluster turned past ``max_turn``), the
        number of clusters it limited: compiled apart, when a body first spins that fast."""
        xt, vt, _, mass = self.arrays[b]
        m3 = np.zeros((4, 3, 3))
        one_cluster = (np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int32))
        scratch = (np.zeros((1, 13)), np.zeros((1, 6)), m3[0], m3[1], m3[2], m3[3])
        turned = int(limit_turn(xt.T, vt.T, mass, one_cluster, np.ones(1, dtype=np.bool_),
                                self.rows[b, C_WMAX], scratch))
        self.counts[b, 1] += turned
        return turned

    def _resolve(self, gravity, ground, boxes, spheres):
        """(compiled entry of ``step_packed`` for these arrays, the arrays): its compiled
        specialisation called without Numba's dispatch, which types every argument at each
        call.  Used only while the collider arrays and gravity are the very objects it was
        resolved for (the world replaces them when they change); a test's spy that is no
        dispatcher is called as it is."""
        fn = step_packed
        entry = fn
        overloads = getattr(fn, 'overloads', None)
        if overloads is not None:
            args = (self.rows, self.counts, self.arrays, 0.0, gravity,
                    Colliders(False, ground, boxes, spheres, 0.0, 0.0, 0.0), 0, 0)
            sig = tuple(fn.typeof_pyval(a) for a in args)
            if sig not in overloads:
                fn.compile(sig)
            entry = overloads[sig].entry_point
        return entry, gravity, ground, boxes, spheres


@njit(**JIT)
def step_packed(rows, counts, arrays, h, gravity, colliders, first, turned_first):
    """The bodies ``first``, ... of a pack, on the calling thread (``arrays``: ``Pack.arrays``;
    ``colliders``: the static colliders, each body meeting them with its own radius).
    Returns their number, or the first body whose cluster turned past its ``max_turn``, its
    row unchanged: ``Pack._limit_turn`` (a large kernel, rarely needed) limits its spin,
    then this call resumes at it with ``turned_first`` the clusters limited (-1: none yet;
    the goal map, independent of v, is taken again).

    Serial: the bodies are small, and a split pass's sums would depend on the split.
    ``Work`` is allocated once a call; the helpers are inlined into this function."""
    work = _work()
    part0, ref, pnt, quat1, rest_lin = work.part, work.ref, work.pnt, work.quat, work.rest_lin
    rest_off, acc, dpart0, dmp, udv0 = work.rest_off, work.acc, work.dpart, work.dmp, work.udv
    dp = dpart0[0]
    for b in range(first, len(arrays)):
        row = rows[b]
        if row[C_FLAGS + SLEEP] > 0.0:         # asleep (``sm_ros.core.sleep``): not stepped
            continue
        xt, vt, x0t, mass = arrays[b]
        n = mass.shape[0]
        x, v, x0 = xt.T, vt.T, x0t.T
        _load_rest(row, work)                  # the rest map and ref the pass reads
        damp = row[C_DAMP] > 0.0
        if not row[C_FLAGS + SUMS_PACKED] > 0.0:
            # new, or last stepped by the set layout's step: the sums are taken here
            row[C_FLAGS + SUMS_PACKED] = 1.0
            row[C_FLAGS + DIRTY] = 1.0
        dirty = row[C_FLAGS + DIRTY] > 0.0
        for j in range(12):
            part0[0, j] = 0.0 if dirty else row[C_PART + j]
        if dirty:
            # an int64 argument, not the literal 0: the specialisation ``_pass`` calls
            one_cluster_sums(start=np.int64(0), end=n, x=x, x0=x0, mass=mass,
                             rest_lin=rest_lin, rest_off=rest_off, ref=ref, sums=part0)
        q0, q1, q2, q3, matched = _goal_map(row, work)
        turned, turn = 0, row[C_TURN]
        if b == first and turned_first >= 0:
            turned = turned_first
        elif turn > 0.0:
            # |q_prev . q| = cos(angle / 2), as Body._step
            dot = q0 * quat1[0] + q1 * quat1[1] + q2 * quat1[2] + q3 * quat1[3]
            if abs(dot) < np.cos(0.5 * turn):
                return b                       # limited, then resumed at b
        for i in range(9 if matched else 0):   # the next step's warm start
            row[C_UDV + i] = udv0[i // 3, i % 3]
        for i in range(3):
            acc[i] = row[C_FACC + i] + gravity[i]
        if damp:
            # the rigid field damping moves towards, from the sums of the last pass (taken
            # again if the state changed since: set by hand, contact, turn limit, not damped)
            if dirty or turned or not row[C_FLAGS + DAMP_SUMS] > 0.0:
                for j in range(NDAMP):
                    dpart0[0, j] = 0.0
                damp_acc_range(np.int64(0), n, x, v, mass, np.zeros(0, dtype=np.int32), dpart0)
            else:
                for j in range(NDAMP):
                    dpart0[0, j] = row[C_DPART + j]
            _damping_field(work)
        # ---- the one particle pass, then the next step's sums about the point pnt (the
        # body's next ref; any point serves): damped, where the centre of mass goes, so a
        # very fast body is not lost to rounding; undamped, ref (no velocity sums)
        for j in range(3):
            pnt[0, j] = ref[0, j] + (h * (dmp[0, j] + h * acc[j]) if damp else 0.0)
        for j in range(12):
            part0[0, j] = 0.0
        for j in range(NDAMP):
            dpart0[0, j] = 0.0
        for j in range(3):
            dp[15 + j] = pnt[0, j]
        dp[18] = 1.0
        col = Colliders(colliders.on, colliders.ground, colliders.boxes, colliders.spheres,
                        colliders.thresh, row[C_RADIUS], colliders.h)
        err2, capped = _pass(0, n, x, v, x0, mass, row, h, work, col)
        counts[b, 0] += capped
        _store(row, err2, damp, work)
    return len(arrays)


#: The work arrays of ``step_packed``: the shape-match sums and their point, the point
#: the next sums are taken about, the last quaternion, the rest and goal maps, 3x3 / 4x4
#: scratch of the eigen-solvers (``m3``: four 3x3), the linear match's eigenvectors, the
#: damping field, the acceleration, the damping sums and the damping solve's scratch.
Work = namedtuple('Work', 'part ref pnt quat rest_lin rest_off goal_lin goal_off m3 m39 n4 '
                          'v4 nmat udv dmp acc dpart wa wv')


@njit(inline='always', **JIT)
def _work():
    """``Work``, zeroed: C-contiguous arrays each, the layout the body build's calls of
    the eigen-solvers use (one specialisation of them)."""
    return Work(np.zeros((1, 12)), np.zeros((1, 3)), np.zeros((1, 3)), np.zeros(4),
                np.zeros((1, 3, 3)), np.zeros((1, 3)), np.zeros((1, 3, 3)), np.zeros((1, 3)),
                np.zeros((4, 3, 3)), np.zeros((3, 9)), np.zeros((4, 4)), np.zeros((4, 4)),
                np.zeros((3, 3)), np.zeros((3, 3)), np.zeros((1, 6)), np.zeros(3),
                np.zeros((1, NDAMP)), np.zeros((3, 3)), np.zeros((3, 3)))


@njit(inline='always', **JIT)
def _load_rest(row, work):
    """A row's rest map and reference point into the work arrays the pass reads."""
    for j in range(3):
        work.ref[0, j] = row[C_REF + j]
        work.rest_off[0, j] = row[C_ROFF + j]
    for i in range(3):
        for j in range(3):
            work.rest_lin[0, i, j] = row[C_RLIN + 3 * i + j]


@njit(inline='always', **JIT)
def _goal_map(row, work):
    """The one-cluster shape match of a body's row (``goals.solve_clusters_warm`` for one
    cluster of one chunk, rigid or linear) from the sums ``work.part`` about ``work.ref``:
    writes the centre of mass into ``work.ref``, the quaternion into ``work.quat``, the
    goal map into ``work.goal_lin``/``goal_off``, the linear match's eigenvectors into
    ``work.udv``; returns
    the last step's quaternion and whether the linear match ran (the caller stores them).

    Its 3x3 algebra is written out on scalars read from the row instead of calling the
    general kernel, which takes 26 arrays and loops over clusters and chunks; only Horn's
    rotation (``extract_rotation``) and the linear mode's minimiser
    (``unit_det_match_warm``, warm started from the body's last eigenvectors ``_udv``, as
    ``Body._step`` and the record step do) are calls."""
    part0, ref, quat1, rest_lin, rest_off, goal_lin, goal_off = (
        work.part, work.ref, work.quat, work.rest_lin, work.rest_off, work.goal_lin,
        work.goal_off)
    m3, m39, n4, v4, nmat0, udv0 = work.m3, work.m39, work.n4, work.v4, work.nmat, work.udv
    ma, mb, mc = m3[0], m3[1], m3[2]
    w1, w2 = m39[:, 3:6], m39[:, 6:9]
    wa, wv = work.wa, work.wv
    beta, mode = row[C_BETA], int(row[C_MODE])
    # x_cm = ref + sum w d / W, A_pq-hat = sum w d q^T - (x_cm - ref) (sum w q)^T, R (Horn,
    # ``extract_rotation``), linear: B (``unit_det_match_warm``, warm started from the
    # last step's V), then the affine goal map T (G x0 + h) + x_cm
    inv_w = 1.0 / row[C_WSUM]
    d0 = part0[0, 0] * inv_w
    d1 = part0[0, 1] * inv_w
    d2 = part0[0, 2] * inv_w
    for j in range(3):
        ma[0, j] = part0[0, 3 + j] - d0 * row[C_SUMQ + j]
        ma[1, j] = part0[0, 6 + j] - d1 * row[C_SUMQ + j]
        ma[2, j] = part0[0, 9 + j] - d2 * row[C_SUMQ + j]
    r0 = ref[0, 0] + d0
    r1 = ref[0, 1] + d1
    r2 = ref[0, 2] + d2
    ref[0, 0] = r0
    ref[0, 1] = r1
    ref[0, 2] = r2
    q0, q1, q2, q3 = row[C_QUAT], row[C_QUAT + 1], row[C_QUAT + 2], row[C_QUAT + 3]
    quat1[0] = q0
    quat1[1] = q1
    quat1[2] = q2
    quat1[3] = q3
    extract_rotation(mat=ma, quat=quat1, rot=mb, n4=n4, v4=v4)        # mb = R
    s_k = row[C_SCALE]
    lin_b = False
    matched = False
    if mode == 1:
        # A s = A_pq-hat A_qq-hat (``matmul``), its determinant over s^3
        for i in range(3):
            for j in range(3):
                mc[i, j] = (ma[i, 0] * row[C_AQQ3 + j] + ma[i, 1] * row[C_AQQ3 + 3 + j]
                            + ma[i, 2] * row[C_AQQ3 + 6 + j])
        det = det3(mc) / (s_k * s_k * s_k)
        c_det = row[C_CDET]
        if det > 1e-9 and finite(det) and c_det > 0.0:
            for i in range(9):
                nmat0[i // 3, i % 3] = row[C_NMAT + i]
                udv0[i // 3, i % 3] = row[C_UDV + i]
            lin_b = unit_det_match_warm(apq=ma, nmat=nmat0, c_s=s_k * c_det, rot=mb,
                                        out=mc, work=(w1, w2, wa, wv), limit=STRETCH_LIMIT,
                                        vw=udv0, warm=np.bool_(True))
            matched = True
    # T = s (beta B + (1 - beta) R) or s R, then the goal map
    for i in range(3):
        if lin_b:
            t0 = s_k * (beta * mc[i, 0] + (1.0 - beta) * mb[i, 0])
            t1 = s_k * (beta * mc[i, 1] + (1.0 - beta) * mb[i, 1])
            t2 = s_k * (beta * mc[i, 2] + (1.0 - beta) * mb[i, 2])
        else:
            t0 = s_k * mb[i, 0]
            t1 = s_k * mb[i, 1]
            t2 = s_k * mb[i, 2]
        for j in range(3):
            goal_lin[0, i, j] = (t0 * rest_lin[0, 0, j] + t1 * rest_lin[0, 1, j]
                                 + t2 * rest_lin[0, 2, j])
        goal_off[0, i] = (t0 * rest_off[0, 0] + t1 * rest_off[0, 1] + t2 * rest_off[0, 2]
                          + ref[0, i])
    return q0, q1, q2, q3, matched


@njit(inline='always', **JIT)
def _damping_field(work):
    """The rigid field c + omega x (x - ref) of the damping sums ``work.dpart`` (about
    their point p = dp[15:18]; ``damping._rigid_fields`` for one cluster, on scalars) into
    ``work.dmp``: v_cm and L about the centre of mass, the inertia tensor I,
    omega = I^+ L (``sym3_solve``: the adjugate where I is well posed)."""
    ref, m3, dmp, dp = work.ref, work.m3, work.dmp, work.dpart[0]
    ma, mb, mc, md = m3[0], m3[1], m3[2], m3[3]
    wk = dp[19]
    u0, u1, u2 = dp[3] / wk, dp[4] / wk, dp[5] / wk
    e0, e1, e2 = dp[0] / wk, dp[1] / wk, dp[2] / wk
    l0 = dp[6] - wk * (e1 * u2 - e2 * u1)
    l1 = dp[7] - wk * (e2 * u0 - e0 * u2)
    l2 = dp[8] - wk * (e0 * u1 - e1 * u0)
    ee = e0 * e0 + e1 * e1 + e2 * e2
    ma[0, 0] = (dp[10] + dp[11]) - wk * (ee - e0 * e0)
    ma[1, 1] = (dp[9] + dp[11]) - wk * (ee - e1 * e1)
    ma[2, 2] = (dp[9] + dp[10]) - wk * (ee - e2 * e2)
    ma[0, 1] = ma[1, 0] = -dp[12] + wk * e0 * e1
    ma[1, 2] = ma[2, 1] = -dp[13] + wk * e1 * e2
    ma[2, 0] = ma[0, 2] = -dp[14] + wk * e2 * e0
    o0, o1, o2 = sym3_solve(mat=ma, b0=l0, b1=l1, b2=l2, rcond=1e-12, wout=mb, wa=mc,
                            wv=md)
    # the field about the body's ref: (v_cm - omega x d) + omega x (ref - p)
    f0 = ref[0, 0] - dp[15]
    f1 = ref[0, 1] - dp[16]
    f2 = ref[0, 2] - dp[17]
    dmp[0, 0] = u0 - (o1 * e2 - o2 * e1) + o1 * f2 - o2 * f1
    dmp[0, 1] = u1 - (o2 * e0 - o0 * e2) + o2 * f0 - o0 * f2
    dmp[0, 2] = u2 - (o0 * e1 - o1 * e0) + o0 * f1 - o1 * f0
    dmp[0, 3] = o0
    dmp[0, 4] = o1
    dmp[0, 5] = o2


@njit(inline='always', **JIT)
def _store(row, err2, damp, work):
    """Store what the step changed into the body's row (the new ref: the point
    ``work.pnt`` the sums were taken about)."""
    part0, pnt, quat1, dpart0 = work.part, work.pnt, work.quat, work.dpart
    if damp:
        # the damping row's W and sum w (x - pnt): the shape sums' (same point)
        dpart0[0, 19] = row[C_WSUM]
        for j in range(3):
            dpart0[0, j] = part0[0, j]
    row[C_ERR] = err2
    row[C_FLAGS + DIRTY] = 0.0             # the sums are those of the state just written
    row[C_FLAGS + ERR_STALE] = 1.0
    row[C_FLAGS + DAMP_SUMS] = 1.0 if damp else 0.0
    for j in range(3):
        row[C_REF + j] = pnt[0, j]
    for j in range(4):
        row[C_QUAT + j] = quat1[j]
    for j in range(12):
        row[C_PART + j] = part0[0, j]
    for j in range(NDAMP):
        row[C_DPART + j] = dpart0[0, j]


@njit(inline='always', **JIT)
def _pass(lo, hi, x, v, x0, mass, row, h, work, col):
    """Particles lo..hi of a one-cluster body (see ``step_packed``; its parameters from
    ``row``, its colliders ``col``, a ``colliders.Colliders``); the next step's sums are
    added to ``work.part`` (12) and, damped, ``work.dpart`` (its point set by the caller).
    Returns (shape-error sum, capped speeds).

    One loop does it all (``_int_single_fused``, ``FUSED_BLOCK`` particles a call), the
    damped body's damping sums included (12 of the 20 sums of ``damp_acc_range``: the
    caller takes W and sum w d from the shape sums; ``wuni`` > 0, every particle of that
    mass: unweighted).  A block with heights below the ground (and nothing else) is
    projected by ``ground_range_sums``, which corrects the loop's sums for the particles
    it moved.  A block with a speed over the cap, or any block in a world with boxes or
    spheres, is projected onto the colliders (the ground alone: ``ground_range``, no bounds
    pass), capped and summed again (``one_cluster_sums``, ``damp_sums_uniform``, vectorised).
    """
    sums, pnt, rest_lin, rest_off, dsums = (work.part, work.pnt, work.rest_lin, work.rest_off,
                                            work.dpart)
    alpha, k_damp, v_max, wuni = row[C_ALPHA], row[C_DAMP], row[C_VMAX], row[C_WUNI]
    damp = k_damp > 0.0
    err2 = 0.0
    capped = 0
    k0, k1, k2 = pnt[0, 0], pnt[0, 1], pnt[0, 2]
    boxed = col.on and (col.boxes.shape[0] > 0 or col.spheres.shape[0] > 0)
    gz = ground_height(col)                # without a ground no height is below -inf
    step = FUSED_BLOCK
    for bs in range(lo, hi, step):
        be = min(bs + step, hi)
        e, over, low = _int_single_fused(bs, be, (x, v, x0), wuni, work,
                                         (alpha, h, damp, k_damp, v_max), gz, boxed)
        err2 += e
        if low and not (over or boxed):
            # the loop added its sums: the ground's projection, and what it changed in them
            g = ground_range_sums(bs, be, x, v, x0, wuni, col, (k0, k1, k2), damp)
            _add_rest_sums(rest_lin, rest_off, sums[0], (0.0, 0.0, g[0], 0.0, 0.0, 0.0, 0.0,
                                                         0.0, 0.0, g[1], g[2], g[3]))
            if damp:
                for j in range(12):                # rows 3-14, damp_sums_range's order
                    dsums[0, 3 + j] += g[4 + j]
        elif over or low or boxed:
            # the loop did not add the sums: colliders, cap, then the sums of what they left
            if boxed:
                _collide_range(bs, be, x, v, col)
            elif low:
                ground_range(bs, be, x, v, col)
            # the speeds were counted before the colliders, which never speed a particle up
            # (``colliders.contact_velocity``)
            if over:
                capped += limit_speed_range(bs, be, x, v, h, v_max)
            one_cluster_sums(start=bs, end=be, x=x, x0=x0, mass=mass, rest_lin=rest_lin,
                             rest_off=rest_off, ref=pnt, sums=sums)
            if damp:
                # the damping sums of what they left about pnt (``damp_acc_range``'s rows
                # 3-14; its W and sum w d are the shape sums', the caller copies them)
                t = damp_sums_uniform(bs, be, x, v, wuni, k0, k1, k2)
                for j in range(12):
                    dsums[0, 3 + j] += t[j]
    return err2, capped
