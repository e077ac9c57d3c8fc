"""One compiled call steps every one-cluster body of a world (Eq. 7-14, damping, limits).

``World.step`` used to call 4-6 kernels per body and step from Python; each call of a
Numba function with 10-30 array arguments costs several microseconds in the dispatcher,
while a 144-particle body's own work is about one.  ``step_single_bodies`` runs the same
kernels, in the same order and with the same arguments as ``Body._step``, for every body
of a typed list of per-body records, so the Python cost of a step no longer grows with the
number of such bodies.  It covers one-cluster rigid/linear bodies without plasticity,
kinematic particles or torque (``Body._fast_ok``); the others keep ``Body._step``.

A record (``Body._fast_record``) is a tuple of the body's own buffers; ``state`` holds
[alpha, beta, damping (per step), max_speed, max_turn, 1 / total mass, mode, fused
damping], ``flags`` [dirty, shape error stale], ``counts`` the limit counters.
"""

import numpy as np
from numba import njit

from .damping import damp_accumulate, damp_rigid, damping_fields, damping_targets
from .goals import solve_clusters
from .integrate import accumulate_serial, integrate_serial
from .jit import JIT
from .limits import limit_speed, limit_turn


@njit(**JIT)
def step_single_bodies(bodies, h, gravity, has_col, ground, boxes, spheres, thresh):
    """``Body._step`` for every record of ``bodies`` (one-cluster bodies)."""
    for b in range(len(bodies)):
        (x, v, x0, mass, ptr, cl, rest_lin, rest_off, part, wsum, sum_q, ref, quat, aqq3,
         aqq9, scale, trans, goal_lin, goal_off, apq, accbuf, m3a, m3b, m3c, m3d, m39, n4, v4,
         nmat, cdet, acc, ang, com, err, dpart, dmp, dref, dacc, lin, w3, sptr, scl, scnt,
         quat_prev, flagged, lim_lin, lim_w, force, state, flags, counts) = bodies[b]
        alpha, beta, k_damp = state[0], state[1], state[2]
        v_max, turn, inv_mass = state[3], state[4], state[5]
        mode = int(state[6])
        fused = state[7] > 0.0 and k_damp > 0.0
        dirty = flags[0] > 0.0
        if dirty:
            accumulate_serial(quad=False, x=x, x0=x0, mass=mass, ptr=ptr, cl=cl,
                              rest_lin=rest_lin, rest_off=rest_off, ref=ref, part=part)
        if turn > 0.0:
            quat_prev[:, :] = quat
        solve_clusters(part=part, wsum=wsum, sum_q=sum_q, ref=ref, quat=quat, aqq3=aqq3,
                       aqq9=aqq9, rest_lin=rest_lin, rest_off=rest_off, scale=scale,
                       trans=trans, goal_lin=goal_lin, goal_off=goal_off, mode=mode, beta=beta,
                       apq=apq, acc=accbuf, m3a=m3a, m3b=m3b, m3c=m3c, m39=m39, n4=n4, v4=v4,
                       nmat=nmat, cdet=cdet)
        turned = 0
        if turn > 0.0:
            # |q_prev . q| = cos(angle / 2), as Body._step
            limit = np.cos(0.5 * turn)
            any_flagged = False
            for k in range(quat.shape[0]):
                dot = (quat_prev[k, 0] * quat[k, 0] + quat_prev[k, 1] * quat[k, 1]
                       + quat_prev[k, 2] * quat[k, 2] + quat_prev[k, 3] * quat[k, 3])
                flagged[k] = abs(dot) < limit
                any_flagged = any_flagged or flagged[k]
            if any_flagged:
                turned = limit_turn(x=x, v=v, mass=mass, ptr=ptr, cl=cl, flagged=flagged,
                                    w_max=turn / h, lin=lim_lin, w3=lim_w, m3a=m3a, m3b=m3b,
                                    m3c=m3c, m3d=m3d)
                counts[1] += turned
        for i in range(3):
            acc[i] = force[i] * inv_mass + gravity[i]
            ang[i] = 0.0
        if fused:
            if dirty or turned:
                damp_accumulate(x=x, v=v, mass=mass, sid=ptr, dpart=dpart)
            damping_fields(dpart=dpart, sptr=sptr, scl=scl, scnt=scnt, lin=lin, w3=w3,
                           dref=dref, acc=dacc, m3a=m3a, m3b=m3b, m3c=m3c, m3d=m3d)
            damping_targets(sptr=sptr, scl=scl, scnt=scnt, lin=lin, w3=w3, dref=dref, sref=ref,
                            dmp=dmp)
        elif k_damp > 0.0:
            damp_rigid(x=x, v=v, mass=mass, ptr=ptr, cl=cl, ref=ref, k_damp=k_damp, lin=lin,
                       w3=w3, m3a=m3a, m3b=m3b, m3c=m3c, m3d=m3d)
        integrate_serial(quad=False, x=x, v=v, x0=x0, mass=mass, ptr=ptr, cl=cl,
                         rest_lin=rest_lin, rest_off=rest_off, trans=trans, goal_lin=goal_lin,
                         goal_off=goal_off, ref=ref, alpha=alpha, h=h, acc=acc, ang=ang,
                         com=com, part=part, err=err, has_col=has_col, ground=ground,
                         boxes=boxes, spheres=spheres, thresh=thresh, damp=fused,
                         k_damp=k_damp, dmp=dmp, dpart=dpart)
        capped = 0
        if v_max > 0.0:
            capped = limit_speed(x=x, v=v, h=h, v_max=v_max)
            counts[0] += capped
        flags[0] = 1.0 if capped > 0 else 0.0
        flags[1] = 1.0
