"""Static colliders: ground plane, solid axis-aligned boxes and spheres (no equation).

A particle inside a collider is projected onto its surface and its velocity corrected:
restitution along the normal above a threshold speed (so resting contact stays put) and
Coulomb friction along the surface.  Runs right after Eq. 13-14 inside the fused pass.
"""

import numpy as np
from numba import njit

from .jit import JIT


@njit(**JIT)
def contact_velocity(vx, vy, vz, nx, ny, nz, friction, restitution, thresh):
    """Velocity after a contact with unit normal n: the contact law of every collider.

    The one place the law is written: the static colliders here, the kinematic colliders
    (``sm_ros.core.kinematic``, on the velocity relative to the collider's surface) and the
    documentation of body-body contact (``sm_ros.core.contact``) use it.  A velocity
    leaving the surface (v . n >= 0) is returned unchanged.  Otherwise the approaching
    normal speed is reversed times ``restitution`` when it exceeds ``thresh`` (m/s) and
    removed below it, so resting contact stays put; the tangential part shrinks by at most
    ``friction`` (Coulomb mu) times the normal change, and never reverses.
    """
    vn = vx * nx + vy * ny + vz * nz
    if vn >= 0.0:
        return vx, vy, vz
    tx = vx - vn * nx
    ty = vy - vn * ny
    tz = vz - vn * nz
    vn_new = -restitution * vn if -vn > thresh else 0.0
    dvn = vn_new - vn
    tl = np.sqrt(tx * tx + ty * ty + tz * tz)
    if tl > 0.0:
        keep = 1.0 - friction * dvn / tl
        if keep < 0.0:
            keep = 0.0
        tx *= keep
        ty *= keep
        tz *= keep
    return tx + vn_new * nx, ty + vn_new * ny, tz + vn_new * nz


@njit(**JIT)
def collide_point(px, py, pz, vx, vy, vz, ground, boxes, spheres, thresh):
    """Project a particle out of the static colliders and correct its velocity.

    ``ground`` = [enabled, height, friction, restitution] (plane z = height, normal +z);
    ``boxes`` rows = [lo(3), hi(3), friction, restitution] (axis-aligned, solid);
    ``spheres`` rows = [centre(3), radius, friction, restitution] (solid).
    """
    if ground[0] > 0.5 and pz < ground[1]:
        pz = ground[1]
        vx, vy, vz = contact_velocity(vx=vx, vy=vy, vz=vz, nx=0.0, ny=0.0, nz=1.0,
                                      friction=ground[2], restitution=ground[3], thresh=thresh)
    for b in range(boxes.shape[0]):
        if (px > boxes[b, 0] and px < boxes[b, 3] and py > boxes[b, 1] and py < boxes[b, 4]
                and pz > boxes[b, 2] and pz < boxes[b, 5]):
            best = px - boxes[b, 0]
            axis = 0
            sgn = -1.0
            d = boxes[b, 3] - px
            if d < best:
                best, axis, sgn = d, 0, 1.0
            d = py - boxes[b, 1]
            if d < best:
                best, axis, sgn = d, 1, -1.0
            d = boxes[b, 4] - py
            if d < best:
                best, axis, sgn = d, 1, 1.0
            d = pz - boxes[b, 2]
            if d < best:
                best, axis, sgn = d, 2, -1.0
            d = boxes[b, 5] - pz
            if d < best:
                best, axis, sgn = d, 2, 1.0
            nx = sgn if axis == 0 else 0.0
            ny = sgn if axis == 1 else 0.0
            nz = sgn if axis == 2 else 0.0
            if axis == 0:
                px = boxes[b, 3] if sgn > 0.0 else boxes[b, 0]
            elif axis == 1:
                py = boxes[b, 4] if sgn > 0.0 else boxes[b, 1]
            else:
                pz = boxes[b, 5] if sgn > 0.0 else boxes[b, 2]
            vx, vy, vz = contact_velocity(vx=vx, vy=vy, vz=vz, nx=nx, ny=ny, nz=nz,
                                          friction=boxes[b, 6], restitution=boxes[b, 7],
                                          thresh=thresh)
    for s in range(spheres.shape[0]):
        dx = px - spheres[s, 0]
        dy = py - spheres[s, 1]
        dz = pz - spheres[s, 2]
        rad = spheres[s, 3]
        d2 = dx * dx + dy * dy + dz * dz
        if d2 < rad * rad:
            d = np.sqrt(d2)
            if d > 0.0:
                nx, ny, nz = dx / d, dy / d, dz / d
            else:
                nx, ny, nz = 0.0, 0.0, 1.0
            px = spheres[s, 0] + rad * nx
            py = spheres[s, 1] + rad * ny
            pz = spheres[s, 2] + rad * nz
            vx, vy, vz = contact_velocity(vx=vx, vy=vy, vz=vz, nx=nx, ny=ny, nz=nz,
                                          friction=spheres[s, 4], restitution=spheres[s, 5],
                                          thresh=thresh)
    return px, py, pz, vx, vy, vz


@njit(**JIT)
def _collide_range(start, end, x, v, ground, boxes, spheres, thresh):
    """Colliders for particles start..end.

    A lone ground plane is tested inline: the call to ``collide_point``, not the test, is
    what costs (100k particles resting on the ground: 3.6 -> 1.9 ms/step skipping the call
    above the ground, -> 1.4 ms with the contact inlined too).
    """
    only_ground = boxes.shape[0] == 0 and spheres.shape[0] == 0
    gz = ground[1] if ground[0] > 0.5 else -np.inf
    if only_ground:
        # collide_point for the ground alone, inlined (a resting body has a whole layer
        # of particles in contact every step)
        mu, e = ground[2], ground[3]
        for i in range(start, end):
            if x[i, 2] < gz:
                x[i, 2] = gz
                v[i, 0], v[i, 1], v[i, 2] = contact_velocity(vx=v[i, 0], vy=v[i, 1], vz=v[i, 2],
                                                             nx=0.0, ny=0.0, nz=1.0, friction=mu,
                                                             restitution=e, thresh=thresh)
        return
    for i in range(start, end):
        x[i, 0], x[i, 1], x[i, 2], v[i, 0], v[i, 1], v[i, 2] = collide_point(px=x[i, 0],
                                                                             py=x[i, 1],
                                                                             pz=x[i, 2],
                                                                             vx=v[i, 0],
                                                                             vy=v[i, 1],
                                                                             vz=v[i, 2],
                                                                             ground=ground,
                                                                             boxes=boxes,
                                                                             spheres=spheres,
                                                                            thresh=thresh)
