"""Numba kernels of the solver, one file per part of the method (algorithm.md numbering).

==================  ==========================================================  ============
file                what it computes                                            equations
==================  ==========================================================  ============
``linalg.py``       hand-written 3x3 / 4x4 / 9x9 eigen-solver, pseudo-inverse    (support)
``rotation.py``     R of the polar decomposition of A_pq (Horn's quaternion)     11
``goals.py``        per-cluster sums -> x_cm, A_pq, A, goal transforms; A_qq    7-12, 19-22
``unit_det.py``     the linear mode's unit-determinant goal matrix               18
``integrate.py``    Eq. 13-14 for one particle; the tuples the passes read       13-14
``sets.py``         the particle passes, particles grouped by cluster sets      7-9, 13-14,
                    (goals averaged over clusters, the next step's sums)        21, 23
``sets_sums.py``    the per-set sums                                            7-9
``set_maps.py``     per-set sums to per-cluster sums; the per-set goal maps     7-9, 23
``fused.py``        the one loop of the fused passes (a set's run, one cluster)  13-14
``grabs.py``        grabbed and pinned particles; a body's inertia tensor        (grabs)
``plasticity.py``   plastic state update and its caps                            24-27
``colliders.py``    static ground, boxes, spheres (projection, friction)         (collisions)
``damping.py``      damping towards each cluster's rigid motion                  (damping)
``limits.py``       speed and turn-per-step limits (what one step represents)   (limits)
``world_step.py``   one compiled call steps the bodies of a world                7-14
``packed_pass.py``  the packed step's one-cluster pass (``core/packed.py``)       7-9, 13-14
``flags.py``        the indices of a body's flag array                          -
``jit.py``          compile options; the cache directory keyed on all files      -
==================  ==========================================================  ============

Public kernels never raise and assume clean, contiguous input; ``sm_ros.core.body``
validates and owns every buffer, so nothing here allocates.  ``x``, ``v`` and ``h`` are
the paper's positions, velocities and time step; ``rest_lin`` / ``rest_off`` the map
q-hat = rest_lin x0 + rest_off from rest positions (about the body's mass centre) to a
cluster's plastic, scaled rest offsets; ``trans`` the goal transform T (3 x 3 or 3 x 9),
``goal_lin`` / ``goal_off`` the affine goal map g = goal_lin x0 + goal_off of the
rigid/linear modes.  Everything is re-exported here: ``from sm_ros.core import kernels``.
"""

from .colliders import Colliders, _collide_range, collide_point, contact_velocity
from .damping import (NDAMP, damp_acc_range, damp_accumulate, damp_kinematic, damp_velocity,
                      damping_fields, damping_targets)
from .goals import (ClusterMatch, ClusterShape, MatchScratch, _goal_quad, _qhat,
                    invert_moments, moments, quad_features, solve_clusters_warm)
from .grabs import gather_rows, inertia, wrench_accelerations
from .integrate import BLOCK, BodyParticles, ClusterRest, FusedDamping, advance
from .jit import FASTMATH, JIT
from .limits import limit_speed, limit_turn
from .linalg import det3, jacobi3, jacobi3_warm, jacobi_eigh, matmul, norm2, pinv_sym
from .plasticity import (RCOND, PlasticWork, RestShape, _add_null_projector, _cap_plastic,
                         plastic_update, refresh_rest, rest_maps)
from .rotation import extract_rotation, quat_to_mat
from .sets import (SetMotion, Sets, _fused_refs, sets_hold, sets_integrate_chunks,
                   sets_kinematic)
from .set_maps import SetClusters, sets_maps, sets_reduce
from .sets_sums import sets_accumulate_chunks
from .spread import moved_box, spread_of
from .unit_det import (STRETCH_LIMIT, _logprod, _logx, _stretch_ok, _unit_det_sum,
                       nearest_unit_det, nearest_unit_det_warm, unit_det_frames, unit_det_match,
                       unit_det_match_warm, volume_preserving)
from .world_step import (PlasticRecord, StepRecord, flow_plastic_bodies, record_begins,
                         record_ends, record_goals, record_integrate_chunks,
                         record_sums_chunks, step_single_bodies)

__all__ = ['Colliders', '_collide_range', 'contact_velocity', 'collide_point', 'NDAMP',
           'damp_acc_range',
           'damp_accumulate', 'damp_kinematic', 'damp_velocity', 'damping_fields',
           'damping_targets', 'STRETCH_LIMIT', '_goal_quad', '_logprod', '_logx', '_qhat',
           '_stretch_ok', '_unit_det_sum', 'invert_moments', 'moments', 'nearest_unit_det',
           'nearest_unit_det_warm', 'quad_features', 'solve_clusters_warm', 'ClusterMatch',
           'ClusterShape', 'MatchScratch',
           'unit_det_frames', 'unit_det_match', 'unit_det_match_warm',
           'volume_preserving', 'BLOCK', 'BodyParticles', 'ClusterRest', 'FusedDamping',
           'advance', 'gather_rows', 'inertia', 'wrench_accelerations',
           'FASTMATH', 'JIT', 'limit_speed', 'limit_turn', 'det3', 'jacobi3', 'jacobi3_warm',
           'jacobi_eigh', 'matmul',
           'norm2', 'pinv_sym', '_add_null_projector', '_cap_plastic', 'plastic_update',
           'PlasticWork', 'RestShape', 'RCOND', 'refresh_rest', 'rest_maps',
           'extract_rotation', 'quat_to_mat', 'moved_box', 'spread_of', 'step_single_bodies',
           'PlasticRecord', 'StepRecord', 'flow_plastic_bodies', 'record_begins',
           'record_ends', 'record_goals',
           'record_integrate_chunks', 'record_sums_chunks',
           'sets_accumulate_chunks', '_fused_refs', 'sets_integrate_chunks',
           'sets_hold', 'sets_kinematic', 'sets_maps', 'sets_reduce', 'SetMotion', 'Sets',
           'SetClusters']
