"""The step of a ``Body`` (``Body._step``) and its goal read-out (``Body.goals``).

Every body is stepped by compiled code: a one-cluster rigid or linear body by the pack
(``packed``), any other by its record (``kernels.world_step``), as ``World.step`` steps
them.  A body built for threads runs the record step's phases one by one, its two particle
passes shared out to helper threads.  ``goals`` evaluates the goal positions of the
current state with scratch copies (nothing of the body changes).
"""

import numpy as np

from . import body_build, kernels as K
from .kernels.colliders import Colliders
from .kernels.flags import DIRTY
from .step_threads import HELPERS


def step(body, h, gravity, has_col, ground, boxes, spheres, thresh):
    """One step of h seconds of ``body``: the packed step, its record, or (built for
    threads) the record's phases with helper threads."""
    if body._packed_ok():
        body._one_pack(h).step(h, gravity, has_col, ground, boxes, spheres, thresh)
        return
    records = body._one_record(h)
    if not body._parallel:
        K.step_single_bodies(records, h, gravity, has_col, ground, boxes, spheres, thresh)
    elif not _step_threaded(body, records[0], h, gravity,
                            Colliders(bool(has_col), ground, boxes, spheres, float(thresh),
                                      body._collider_radius, float(h))):
        return
    if body._params.plastic:
        K.flow_plastic_bodies(body_build.one_plastic_record(body, h), float(h))


def _step_threaded(body, rec, h, gravity, colliders) -> bool:
    """The record step's phases one by one, the particle passes shared with helper
    threads; whether the body was stepped (not asleep)."""
    if not K.record_begins(rec):
        return False
    helpers = len(body._sets.part) - 1
    if body._flags[DIRTY] > 0.0:
        HELPERS.run(helpers, K.record_sums_chunks, (rec, np.zeros(1, dtype=np.int64)))
    K.record_goals(rec, float(h), gravity)
    chunk_capped = np.zeros(len(body._sets.part), dtype=np.int64)
    HELPERS.run(helpers, K.record_integrate_chunks,
                (rec, np.zeros(1, dtype=np.int64), chunk_capped, colliders))
    K.record_ends(rec, float(h), chunk_capped)
    return True


def _rest(body):
    """The body's clusters as the shape match reads them."""
    return K.ClusterRest(body._ptr, body._cluster_ids, body._rest_lin, body._rest_off, body._ref)


def _shape(body):
    """The body's clusters' rest-shape constants as the shape match reads them."""
    return K.ClusterShape(body._wsum, body._sum_q, body._aqq3, body._aqq9, body._scale,
                          body._nmat, body._cdet)


def _set_clusters(sets):
    """A set layout's set-cluster pairs as its kernels read them."""
    return K.SetClusters(sets.ptr, sets.cluster_ids, sets.cnt, sets.phi, sets.pair_offsets,
                         sets.org)


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
