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
from .kernels.flags import DAMP_SUMS

#: The set ids of a one-cluster body's fused damping: none, every particle in set 0.
_ONE_SET = np.zeros(0, dtype=np.int32)


def step(body, h, gravity, has_col, ground, boxes, spheres, thresh):
    """One step of h seconds of ``body`` (``Body._step``; the kernels of ``kernels/``
    in the order of algorithm.md): goals, limits, plasticity, damping, Eq. 13-14 with
    the static colliders, grabbed and pinned particles.

    A body the compiled world step covers (``Body._fast_ok``) is stepped by it, as a list
    of one record: one call instead of one per kernel, and the very code ``World.step``
    runs for it (the kernels compiled inside one caller or called one by one from Python
    can round differently under fast math).
    """
    if body._fast_ok():
        K.step_single_bodies(body._one_record(h), h, gravity, has_col, ground, boxes, spheres,
                             thresh)
        return
    if body._at_step[0] != h or body._at_step[1] is not body._params:
        body._at_step = (h, body._params, body._params.at_step(h))
    p = body._at_step[2]                   # the material's coefficients at this step
    fused = body._damp_fused and p.damping > 0.0
    _take_sums(body)
    turned = _match(body, p, h)
    nchanged = _plastic_flow(body, p, h)
    _forces(body, gravity, h)
    _damping(body, p, fused, turned)
    kin = len(body._kin_idx) > 0
    if kin:
        K.gather_rows(body._x, body._kin_idx, body._kin_prev)
    colliders = Colliders(bool(has_col), ground, boxes, spheres, float(thresh),
                          body._collider_radius, float(h))
    capped = _integrate(body, p, h, fused, colliders)
    if kin:
        _grabbed(body, fused, h)
    body._shape_err = None                 # computed from body._err when asked
    body._flags[DAMP_SUMS] = 1.0 if fused else 0.0
    # capped positions: the membership layout's sums are stale (the set layout caps
    # before it sums)
    sets = body._sets
    body._dirty = capped > 0 and sets is None
    if nchanged:
        body._refresh_rest(body._changed)
        # the per-set sums do not depend on the rest shape; the per-cluster ones do
        body._dirty = body._dirty or sets is None


def _particles(body):
    """The body's particles as the passes of ``kernels/integrate.py`` read them."""
    return K.BodyParticles(body._x, body._v, body._x0, body._m)


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
    """The clusters' sums of the current state (Eq. 7-11): taken afresh where the state
    changed since the last pass summed it (``body._dirty``); the set layout reduces its
    per-set sums to the clusters'."""
    sets = body._sets
    if sets is not None:
        if body._dirty:
            _chunks(body, K.sets_accumulate_chunks, quad=body._quad, x=body._x, y0=sets.rest_local,
                    mass=body._m, sid=sets.sid, runs=sets.runs, sref=sets.ref, part=sets.part)
        K.sets_reduce(sets.part, _set_clusters(sets), sets.ref, body._rest_lin, body._ref,
                      body._quad, body._part, (sets.work, sets.quad_map))
    elif body._dirty:
        _chunks(body, K.accumulate_chunks, quad=body._quad, particles=_particles(body),
                rest=_rest(body), part=body._part)


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
                                     body._quat_v))
    sets = body._sets
    if sets is not None:
        K.sets_maps(_set_clusters(sets), body._rest_lin,
                    (body._trans, body._goal_lin, body._goal_off), body._ref, body._quad,
                    (sets.goal_maps, sets.ref), (sets.quad_map, sets.cluster_maps))
    return nchanged


def _forces(body, gravity, h) -> None:
    """The step's acceleration (the body's force over its mass, gravity) and angular
    acceleration (the torque through the inverse inertia, at most ``max_turn`` / h of spin
    added in one step: beyond that the step cannot represent the turn)."""
    np.add(body._facc, gravity, out=body._acc)
    if not body._has_torque:
        body._ang[:] = 0.0
        return
    s3 = body._mat3
    np.dot(body._wsum, body._ref, out=body._com)
    body._com /= body._wsum.sum()
    K.inertia(body._x, body._m, body._com, body._inertia)
    K.pinv_sym(mat=body._inertia, out=body._inertia_inv, wa=s3[0], wv=s3[1], rcond=1e-12)
    np.dot(body._inertia_inv, body._torque, out=body._ang)
    turn = body._params.max_turn
    if turn > 0.0:
        a_norm = float(np.sqrt(body._ang @ body._ang))
        if a_norm * h * h > turn:
            body._ang *= turn / (a_norm * h * h)
            body._limit_counts[1] += 1


def _damping(body, p, fused, turned) -> None:
    """Damping towards each cluster's rigid motion: fused into the particle pass (the rigid
    fields from the sums of the last pass, taken again if the state changed since: set by
    hand, contact, turn limit) or a pass of its own."""
    s3 = body._mat3
    if fused:
        sets = body._sets
        sptr, scl, scnt = body._dsets
        if body._dirty or turned:
            K.damp_accumulate(x=body._x, v=body._v, mass=body._m, sid=_set_ids(body),
                              dpart=body._dpart)
        K.damping_fields(body._dpart, (sptr, scl, scnt), body._dref, body._dacc,
                         (body._lin, body._damp_spin, s3[0], s3[1], s3[2], s3[3]))
        K.damping_targets(sptr=sptr, scl=scl, scnt=scnt, lin=body._lin, w3=body._damp_spin,
                          dref=body._dref, sref=sets.ref if sets is not None else body._ref,
                          dmp=body._dmp)
    elif p.damping > 0.0:
        K.damp_rigid(body._x, body._v, body._m, (body._ptr, body._cluster_ids), body._ref,
                     p.damping,
                     (body._lin, body._damp_spin, s3[0], s3[1], s3[2], s3[3]))


def _set_ids(body):
    """The set id of each particle for the fused damping (none: one set)."""
    return body._sets.sid if body._sets is not None else _ONE_SET


def _integrate(body, p, h, fused, colliders) -> int:
    """Eq. 13-14 with the static colliders (``colliders.Colliders``) and the speed cap,
    the next step's sums taken in the same pass; returns the capped speeds."""
    sets = body._sets
    v_max = body._params.max_speed
    if sets is not None:
        # the speeds capped block by block before the sums are taken: the sums stay valid
        chunk_capped = np.zeros(len(sets.part), dtype=np.int64)
        motion = K.SetMotion(p.alpha, h, body._acc, body._ang, body._com, v_max)
        _chunks(body, K.sets_integrate_chunks, capped=chunk_capped, quad=body._quad,
                particles=_set_particles(body), sets=_sets(body), motion=motion,
                part=sets.part, err=body._err, col=colliders,
                damping=K.FusedDamping(fused, p.damping, body._dmp, body._dpart))
        K._fused_refs(body._quad, body._wuni, body._ang, sets.runs, fused, sets.ref, body._dpart)
        capped = int(chunk_capped.sum())
        body._limit_counts[0] += capped
        return capped
    goals = K.StepGoals(body._goal_lin, body._goal_off, body._trans, p.alpha, h, body._acc,
                        body._ang, body._com)
    _chunks(body, K.integrate_chunks, quad=body._quad, particles=_particles(body),
            rest=_rest(body), goals=goals, part=body._part, err=body._err, col=colliders,
            damping=K.FusedDamping(fused, p.damping, body._dmp, body._dpart))
    if v_max <= 0.0:
        return 0
    capped = K.limit_speed(x=body._x, v=body._v, h=h, v_max=v_max)
    body._limit_counts[0] += capped
    return capped


def _grabbed(body, fused, h) -> None:
    """The grabbed and pinned particles to their targets (their sums, and with fused
    damping their damping sums, follow them)."""
    sets = body._sets
    targets = (body._kin_idx, body._kin_tgt, body._kin_prev)
    if fused:
        K.damp_kinematic(x=body._x, v=body._v, mass=body._m, sid=_set_ids(body),
                         dpart=body._dpart, idx=body._kin_idx, sign=-1.0)
    if sets is not None:
        K.sets_kinematic(body._quad, _set_particles(body), _sets(body), sets.part, targets, h)
    else:
        K.apply_kinematic(body._quad, _particles(body), _rest(body), body._part, targets, h)
    if fused:
        K.damp_kinematic(x=body._x, v=body._v, mass=body._m, sid=_set_ids(body),
                         dpart=body._dpart, idx=body._kin_idx, sign=1.0)


def _chunks(body, kernel, **args):
    """Run a pass over the body's particle chunks (``kernel``: one that claims its chunks,
    such as ``K.integrate_chunks``): on this thread, or on it and helper threads for a body
    built for threads (``Body._parallel``: a chunk per thread)."""
    claim = np.zeros(1, dtype=np.int64)
    nchunks = len(args['part'])
    if body._parallel and nchunks > 1:
        HELPERS.run(nchunks - 1, functools.partial(kernel, claim, **args), ())
    else:
        kernel(claim, **args)


def goals(body) -> np.ndarray:
    """Goal positions g_i for the current state (Eq. 12/18/22, averaged over clusters)."""
    p = body._params
    part = np.zeros((1,) + body._part.shape[1:])
    ref, quat = body._ref.copy(), body._quat.copy()
    trans, goal_lin = np.zeros_like(body._trans), np.zeros_like(body._goal_lin)
    goal_off = np.zeros_like(body._goal_off)
    K.accumulate_chunks(np.zeros(1, dtype=np.int64), body._quad, _particles(body),
                        _rest(body)._replace(ref=ref), part)
    match = K.ClusterMatch(quat, trans, goal_lin, goal_off, np.zeros_like(body._apq),
                           body._nmat)
    scratch = K.MatchScratch(np.zeros(32), np.zeros((3, 3)), np.zeros((3, 3)), np.zeros((3, 3)),
                             np.zeros((3, 9)), np.zeros((4, 4)), np.zeros((4, 4)),
                             np.zeros((2, 3, 3)))
    K.solve_clusters_warm(part, _rest(body)._replace(ref=ref), _shape(body), match, scratch,
                          body._mode, p.beta, np.bool_(False))     # a cold start
    g = body._x.copy(order='K')            # the layout of x: the kernels' own specialisation
    goals = K.StepGoals(goal_lin, goal_off, trans, 1.0, 1.0, np.zeros(3), np.zeros(3),
                        np.zeros(3))
    no_colliders = Colliders(False, np.zeros(4), np.zeros((0, 8)), np.zeros((0, 6)), 0.0, 0.0,
                             0.0)
    K.integrate_chunks(np.zeros(1, dtype=np.int64), body._quad,
                       K.BodyParticles(g, np.zeros_like(g), body._x0, body._m),
                       _rest(body)._replace(ref=ref), goals, part, np.zeros(1), no_colliders,
                       K.FusedDamping(False, 0.0, np.zeros((1, 6)), np.zeros((1, 1, K.NDAMP))))
    return g
