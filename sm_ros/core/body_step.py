"""The step of a ``Body`` (``Body._step``) and its goal read-out (``Body.goals``).

``step`` drives the Numba kernels of ``kernels/`` over the buffers ``body_build`` made, so
a step allocates nothing: per-cluster sums, the shape match (Eq. 7-12, 18-22), the turn
limit, plasticity (Eq. 24-27), damping, Eq. 13-14 with the static colliders, the speed
limit and the grabbed / pinned particles.  ``goals`` evaluates the goal positions of the
current state with scratch copies (nothing of the body changes).
"""

import functools

import numpy as np

from . import kernels as K
from .step_threads import HELPERS
from .kernels.colliders import Colliders
from .kernels.flags import DAMP_SUMS, SUMS_PACKED


def step(body, h, gravity, has_col, ground, boxes, spheres, thresh):
    """One step of h seconds of ``body`` (``Body._step``; the kernels of ``kernels/``
    in the order of algorithm.md): goals, limits, plasticity, damping, Eq. 13-14 with
    the static colliders, grabbed and pinned particles.

    A body the compiled world step covers (``Body._fast_ok``) is stepped by it, as a list
    of one record: one call instead of one per kernel, and the very code ``World.step``
    runs for it (the kernels compiled inside one caller or called one by one from Python
    can round differently under fast math).
    """
    if body._packed_ok():
        body._one_pack(h).step(h, gravity, has_col, ground, boxes, spheres, thresh)
        return
    if body._flags[SUMS_PACKED] > 0.0:     # last stepped by the pack: its sums, not the sets'
        body._flags[SUMS_PACKED] = 0.0
        body._dirty = True
    if body._fast_ok():
        K.step_single_bodies(body._one_record(h), h, gravity, has_col, ground, boxes, spheres,
                             thresh)
        return
    if body._at_step[0] != h or body._at_step[1] is not body._params:
        body._at_step = (h, body._params, body._params.at_step(h))
    p = body._at_step[2]                   # the material's coefficients at this step
    damped = p.damping > 0.0
    _take_sums(body)
    turned = _match(body, p, h)
    nchanged = _plastic_flow(body, p, h)
    _forces(body, gravity, h)
    if damped:
        _damping(body, turned)
    kin = len(body._kin_idx) > 0
    if kin:
        K.gather_rows(body._x, body._kin_idx, body._kin_prev)
    colliders = Colliders(bool(has_col), ground, boxes, spheres, float(thresh),
                          body._collider_radius, float(h))
    _integrate(body, p, h, damped, colliders)
    if kin:
        _grabbed(body, damped, h)
    body._shape_err = None                 # computed from body._err when asked
    body._flags[DAMP_SUMS] = 1.0 if damped else 0.0
    # the pass caps the speeds before it sums, so the sums are those of the new state; the
    # per-set sums do not depend on the rest shape, so plastic flow leaves them valid too
    body._dirty = False
    if nchanged:
        body._refresh_rest(body._changed)


def _rest(body):
    """The body's clusters as the passes of ``kernels/integrate.py`` read them."""
    return K.ClusterRest(body._ptr, body._cluster_ids, body._rest_lin, body._rest_off, body._ref)


def _set_particles(body):
    """The particles of a set-layout body as its passes read them (y0 for x0)."""
    return K.BodyParticles(body._x, body._v, body._sets.rest_local, body._m)


def _sets(body):
    """A set-layout body's sets as its passes read them."""
    sets = body._sets
    return K.Sets(sets.sid, sets.runs, sets.goal_maps, sets.ref, body._wuni)


def _shape(body):
    """The body's clusters' rest-shape constants as the shape match reads them."""
    return K.ClusterShape(body._wsum, body._sum_q, body._aqq3, body._aqq9, body._scale,
                          body._nmat, body._cdet)


def _set_clusters(sets):
    """A set layout's set-cluster pairs as its kernels read them."""
    return K.SetClusters(sets.ptr, sets.cluster_ids, sets.cnt, sets.phi, sets.pair_offsets,
                         sets.org)


def _take_sums(body) -> None:
    """The clusters' sums of the current state (Eq. 7-11): the per-set sums, taken afresh
    where the state changed since the last pass summed them (``body._dirty``), reduced to
    the clusters'."""
    sets = body._sets
    if body._dirty:
        _chunks(body, K.sets_accumulate_chunks, quad=body._quad, x=body._x, y0=sets.rest_local,
                mass=body._m, sid=sets.sid, runs=sets.runs, sref=sets.ref, part=sets.part)
    K.sets_reduce(sets.part, _set_clusters(sets), sets.ref, body._rest_lin, body._ref,
                  body._quad, body._part, (sets.work, sets.quad_map))


def _match(body, p, h) -> int:
    """The shape match of every cluster (Eq. 7-12, 18-22), then the turn limit; returns
    the clusters whose spin was capped."""
    s3 = body._mat3
    turn = body._params.max_turn
    if turn > 0.0:
        np.copyto(body._quat_prev, body._quat)
    match = K.ClusterMatch(body._quat, body._trans, body._goal_lin, body._goal_off, body._apq,
                           body._udv)
    scratch = K.MatchScratch(body._accbuf, s3[0], s3[1], s3[2], body._mat39, body._quat_n,
                             body._quat_v, body._match_work)
    K.solve_clusters_warm(body._part, _rest(body), _shape(body), match, scratch, body._mode,
                          p.beta, True)
    if turn <= 0.0:
        return 0
    # |q_prev . q| = cos(angle / 2): clusters whose rotation turned more than max_turn in
    # the last step have their angular velocity measured and capped
    np.less(np.abs(np.einsum('ij,ij->i', body._quat_prev, body._quat)),
            np.cos(0.5 * turn), out=body._flagged)
    if not body._flagged.any():
        return 0
    turned = K.limit_turn(body._x, body._v, body._m, (body._ptr, body._cluster_ids), body._flagged,
                          turn / h, (body._lim_lin, body._lim_w, s3[0], s3[1], s3[2], s3[3]))
    body._limit_counts[1] += turned
    return turned


def _plastic_flow(body, p, h) -> int:
    """Plasticity (Eq. 24-27) and the set layout's goal maps; returns the clusters whose
    rest shape changed."""
    s3 = body._mat3
    nchanged = 0
    if body._params.plastic:
        law = (body._params.plastic_yield, p.creep, body._params.plastic_max, h)
        nchanged = K.plastic_update(body._apq, (body._aqq3, body._scale, body._quat),
                                    body._s_plastic, law, body._changed,
                                    (body._quat_scratch, s3[0], s3[1], s3[2], body._quat_n,
                                     body._quat_v, body._match_work[0], body._match_work[1]))
    sets = body._sets
    K.sets_maps(_set_clusters(sets), body._rest_lin, (body._trans, body._goal_lin, body._goal_off),
                body._ref, body._quad, (sets.goal_maps, sets.ref),
                (sets.quad_map, sets.cluster_maps))
    return nchanged


def _forces(body, gravity, h) -> None:
    """The step's acceleration and angular acceleration (``kernels.wrench_accelerations``)."""
    s3 = body._mat3
    body._limit_counts[1] += K.wrench_accelerations(
        (body._facc, body._torque), gravity, (body._wsum, body._ref), (body._x, body._m),
        (float(h), body._params.max_turn), (body._acc, body._ang, body._com),
        (body._inertia, body._inertia_inv, s3[0], s3[1]))


def _damping(body, turned) -> None:
    """The field of the damping towards each cluster's rigid motion, which the particle
    pass applies: from the sums of the last pass, taken again if the state changed since
    (set by hand, contact, turn limit)."""
    s3 = body._mat3
    sets = body._sets
    if body._dirty or turned:
        K.damp_accumulate(x=body._x, v=body._v, mass=body._m, sid=sets.sid, dpart=body._dpart)
    K.damping_fields(body._dpart, (sets.ptr, sets.cluster_ids, sets.cnt), body._dref, body._dacc,
                     (body._lin, body._damp_spin, s3[0], s3[1], s3[2], s3[3]))
    K.damping_targets(sptr=sets.ptr, scl=sets.cluster_ids, scnt=sets.cnt, lin=body._lin,
                      w3=body._damp_spin, dref=body._dref, sref=sets.ref, dmp=body._dmp)


def _integrate(body, p, h, damped, colliders) -> None:
    """Eq. 13-14 with the static colliders (``colliders.Colliders``) and the speed cap,
    set by set, the next step's sums taken in the same pass (the speeds are capped block
    by block before they are summed)."""
    sets = body._sets
    chunk_capped = np.zeros(len(sets.part), dtype=np.int64)
    motion = K.SetMotion(p.alpha, h, body._acc, body._ang, body._com, body._params.max_speed)
    _chunks(body, K.sets_integrate_chunks, capped=chunk_capped, quad=body._quad,
            particles=_set_particles(body), sets=_sets(body), motion=motion,
            part=sets.part, err=body._err, col=colliders,
            damping=K.FusedDamping(damped, p.damping, body._dmp, body._dpart))
    K._fused_refs(body._quad, body._wuni, body._ang, sets.runs, damped, sets.ref, body._dpart)
    body._limit_counts[0] += int(chunk_capped.sum())


def _grabbed(body, damped, h) -> None:
    """The grabbed and pinned particles to their targets (their sums, and damped their
    damping sums, follow them)."""
    K.sets_hold(body._quad, _set_particles(body), _sets(body), body._sets.part,
                (body._kin_idx, body._kin_tgt, body._kin_prev), h, (damped, body._dpart))


def _chunks(body, kernel, **args):
    """Run a pass over the body's particle chunks (``kernel``: one that claims its chunks,
    such as ``K.sets_integrate_chunks``): on this thread, or on it and helper threads for a body
    built for threads (``Body._parallel``: a chunk per thread)."""
    claim = np.zeros(1, dtype=np.int64)
    nchunks = len(args['part'])
    if body._parallel and nchunks > 1:
        HELPERS.run(nchunks - 1, functools.partial(kernel, claim, **args), ())
    else:
        kernel(claim, **args)


def goals(body) -> np.ndarray:
    """Goal positions g_i for the current state (Eq. 12/18/22, averaged over clusters):
    the step's kernels on copies, the integration with alpha = h = 1 from rest (x = g)."""
    p, sets, quad = body._params, body._sets, body._quad
    claim = np.zeros(1, dtype=np.int64)
    set_sums = np.zeros((1,) + sets.part.shape[1:])
    K.sets_accumulate_chunks(claim, quad=quad, x=body._x, y0=sets.rest_local, mass=body._m,
                             sid=sets.sid, runs=sets.runs, sref=sets.ref, part=set_sums)
    part, ref = np.zeros_like(body._part), body._ref.copy()
    K.sets_reduce(set_sums, _set_clusters(sets), sets.ref, body._rest_lin, ref, quad, part,
                  (np.zeros_like(sets.work), np.zeros_like(sets.quad_map)))
    trans, goal_lin = np.zeros_like(body._trans), np.zeros_like(body._goal_lin)
    goal_off = np.zeros_like(body._goal_off)
    match = K.ClusterMatch(body._quat.copy(), trans, goal_lin, goal_off,
                           np.zeros_like(body._apq), np.zeros_like(body._udv))
    scratch = K.MatchScratch(np.zeros(32), np.zeros((3, 3)), np.zeros((3, 3)), np.zeros((3, 3)),
                             np.zeros((3, 9)), np.zeros((4, 4)), np.zeros((4, 4)),
                             np.zeros((2, 3, 3)))
    K.solve_clusters_warm(part, _rest(body)._replace(ref=ref), _shape(body), match, scratch,
                          body._mode, p.beta, np.bool_(False))     # a cold start
    maps, set_refs = np.zeros_like(sets.goal_maps), np.zeros_like(sets.ref)
    K.sets_maps(_set_clusters(sets), body._rest_lin, (trans, goal_lin, goal_off), ref, quad,
                (maps, set_refs), (np.zeros_like(sets.quad_map), np.zeros_like(sets.cluster_maps)))
    g = body._x.copy(order='K')            # the layout of x: the kernels' own specialisation
    at_rest = K.SetMotion(1.0, 1.0, np.zeros(3), np.zeros(3), np.zeros(3), 0.0)
    undamped = K.FusedDamping(False, 0.0, np.zeros((1, 6)), np.zeros((1, 1, K.NDAMP)))
    no_colliders = Colliders(False, np.zeros(4), np.zeros((0, 8)), np.zeros((0, 6)), 0.0, 0.0,
                             0.0)
    K.sets_integrate_chunks(np.zeros(1, dtype=np.int64), np.zeros(1, dtype=np.int64), quad,
                            K.BodyParticles(g, np.zeros_like(g), sets.rest_local, body._m),
                            K.Sets(sets.sid, sets.runs, maps, set_refs, body._wuni), at_rest,
                            set_sums, np.zeros(1), no_colliders, undamped)
    return g
