"""Static colliders: ground plane, solid axis-aligned boxes and spheres (no equation);
and the rows of the collider pass (``C_*`` columns), measured by ``surface_gap``.

A particle is a sphere of its body's contact radius: every collider is grown by it.  A
particle inside a grown collider is projected onto its surface and its velocity corrected:
restitution along the normal above a threshold speed (so resting contact stays put) and
Coulomb friction along the surface.  A box takes the face the particle's step entered
through where the step carried it past the box's middle (``box_entry``), so a thin plate
holds a fast body, and a sphere the tangent plane of the side the particle came from
where its step crossed the sphere's middle.  Runs right after Eq. 13-14 inside the fused
pass.
"""

from collections import namedtuple

import numpy as np
from numba import njit

from .jit import JIT, JIT_NO_REFCOUNT

#: What a particle pass meets: whether any static collider is on, the ground row
#: [enabled, height, friction, restitution] (plane z = height, normal +z), the box rows
#: [lo(3), hi(3), friction, restitution] (axis-aligned, solid), the sphere rows [centre(3),
#: radius, friction, restitution] (solid), the speed (m/s) above which restitution acts,
#: the particles' radius (m), by which every collider is grown, and the step h (s) whose
#: velocity brought each particle where it is (0 after a contact solve: not swept).
Colliders = namedtuple('Colliders', 'on ground boxes spheres thresh radius h')

#: Columns of a collider row of the collider pass (``sm_ros.core.kinematic``) and of the
#: stiff bodies' contact (``stiff_contacts``).
C_KIND = 0          # 0 sphere, 1 box, 2 capsule (params.KIND_*)
C_POS = 1           # centre (3)
C_ROT = 4           # rotation local -> world, row-major (9)
C_VEL = 13          # linear velocity of the centre (3)
C_ANG = 16          # angular velocity, world frame (3)
C_DIM = 19          # sphere: radius; box: half extents (3); capsule: radius, half length
C_MU = 22           # Coulomb friction coefficient
C_E = 23            # restitution
C_BOUND = 24        # radius of a sphere about the centre holding the collider (broad phase)
ROW = 25


@njit(**JIT_NO_REFCOUNT)
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


#: Where the surface a particle's path entered a collider through and the one nearest its
#: end turn by more than 45 degrees (cosine below this), it goes back onto the entry's
#: tangent plane.
ENTRY_TURN = 0.7071067811865476


@njit(**JIT_NO_REFCOUNT)
def box_entry(came, p, lo, hi):
    """(axis, sign) of the face of the box lo..hi through which the path from ``came`` to
    p enters it, and the axis of the face through which it leaves (slab test); (-1, 0.0,
    -1) where ``came`` is inside or the path misses."""
    enter, leave, axis, sign, out_axis = -np.inf, np.inf, -1, 0.0, -1
    for k in range(3):
        d = p[k] - came[k]
        outside = came[k] <= lo[k] or came[k] >= hi[k]
        if d == 0.0:
            if outside:
                return -1, 0.0, -1
            continue
        t0, t1 = (lo[k] - came[k]) / d, (hi[k] - came[k]) / d
        if outside and min(t0, t1) > enter:
            enter, axis, sign = min(t0, t1), k, (-1.0 if d > 0.0 else 1.0)
        if max(t0, t1) < leave:
            leave, out_axis = max(t0, t1), k
    if axis < 0 or not (0.0 <= enter <= 1.0 and enter < leave):
        return -1, 0.0, -1
    return axis, sign, out_axis


@njit(**JIT_NO_REFCOUNT)
def collide_point(px, py, pz, vx, vy, vz, col):
    """Project a particle, a sphere of radius ``col.radius``, out of the static colliders
    of ``col`` (``Colliders``) and correct its velocity.  A box grown by the radius keeps
    its square edges: near an edge a particle is pushed out slightly early.  Where the
    step (``col.h``, from p - h v) carried the particle past a box's middle (it ends
    nearest the face opposite the one it entered through) or through it, it goes back out
    of the face it entered through, so a plate thinner than a step's fall holds it; past a
    sphere, onto the tangent plane where it entered (``_sphere_entry``) where that turns
    from the surface nearest its end by more than 45 degrees.  On a box or a sphere the
    step's displacement gets the tangential change of velocity too (``held_by_friction``);
    the ground, flat, changes the velocity only."""
    ground, boxes, spheres, r = col.ground, col.boxes, col.spheres, col.radius
    came = (px - col.h * vx, py - col.h * vy, pz - col.h * vz)
    gz = ground[1] + r
    if ground[0] > 0.5 and pz < gz:
        pz = gz
        vx, vy, vz = contact_velocity(vx=vx, vy=vy, vz=vz, nx=0.0, ny=0.0, nz=1.0,
                                      friction=ground[2], restitution=ground[3],
                                      thresh=col.thresh)
    for b in range(boxes.shape[0]):
        lo0, lo1, lo2 = boxes[b, 0] - r, boxes[b, 1] - r, boxes[b, 2] - r
        hi0, hi1, hi2 = boxes[b, 3] + r, boxes[b, 4] + r, boxes[b, 5] + r
        if (max(px, came[0]) < lo0 or min(px, came[0]) > hi0 or max(py, came[1]) < lo1
                or min(py, came[1]) > hi1 or max(pz, came[2]) < lo2
                or min(pz, came[2]) > hi2):
            continue                                    # the step's path misses the box
        entry, entry_sign, exit_axis = box_entry(came, (px, py, pz), (lo0, lo1, lo2),
                                                 (hi0, hi1, hi2))
        inside = px > lo0 and px < hi0 and py > lo1 and py < hi1 and pz > lo2 and pz < hi2
        through = entry >= 0 and exit_axis == entry     # in at one face, out at its opposite
        if inside or through:
            best = px - lo0
            axis = 0
            sgn = -1.0
            d = hi0 - px
            if d < best:
                best, axis, sgn = d, 0, 1.0
            d = py - lo1
            if d < best:
                best, axis, sgn = d, 1, -1.0
            d = hi1 - py
            if d < best:
                best, axis, sgn = d, 1, 1.0
            d = pz - lo2
            if d < best:
                best, axis, sgn = d, 2, -1.0
            d = hi2 - pz
            if d < best:
                best, axis, sgn = d, 2, 1.0
            if not inside or (entry == axis and entry_sign != sgn):
                axis, sgn = entry, entry_sign
            nx = sgn if axis == 0 else 0.0
            ny = sgn if axis == 1 else 0.0
            nz = sgn if axis == 2 else 0.0
            if axis == 0:
                px = hi0 if sgn > 0.0 else lo0
            elif axis == 1:
                py = hi1 if sgn > 0.0 else lo1
            else:
                pz = hi2 if sgn > 0.0 else lo2
            ux, uy, uz = contact_velocity(vx=vx, vy=vy, vz=vz, nx=nx, ny=ny, nz=nz,
                                          friction=boxes[b, 6], restitution=boxes[b, 7],
                                          thresh=col.thresh)
            px, py, pz = held_by_friction(col.h, (px, py, pz), (ux - vx, uy - vy, uz - vz),
                               (nx, ny, nz))
            vx, vy, vz = ux, uy, uz
    for s in range(spheres.shape[0]):
        c0, c1, c2, rad = spheres[s, 0], spheres[s, 1], spheres[s, 2], spheres[s, 3] + r
        dx, dy, dz = px - c0, py - c1, pz - c2
        inside = _inside_sphere(dx, dy, dz, rad)
        if not (inside or _path_meets_sphere(came, (dx, dy, dz), (c0, c1, c2), rad)):
            continue                                    # neither it nor its path
        nx, ny, nz = _unit(dx, dy, dz)
        mx, my, mz = _sphere_entry(came, (dx, dy, dz), (c0, c1, c2), rad)
        on_plane = mx * nx + my * ny + mz * nz < ENTRY_TURN
        if on_plane:
            push = rad - (dx * mx + dy * my + dz * mz)   # onto the tangent plane it entered by
            if push <= 0.0:
                continue
            px, py, pz, nx, ny, nz = px + push * mx, py + push * my, pz + push * mz, mx, my, mz
        elif not inside:
            continue
        ux, uy, uz = contact_velocity(vx=vx, vy=vy, vz=vz, nx=nx, ny=ny, nz=nz,
                                      friction=spheres[s, 4], restitution=spheres[s, 5],
                                      thresh=col.thresh)
        px, py, pz = held_by_friction(col.h, (px, py, pz), (ux - vx, uy - vy, uz - vz),
                                      (nx, ny, nz))
        if not on_plane:               # onto the surface where friction held it, not off it
            sx, sy, sz = _unit(px - c0, py - c1, pz - c2)
            px, py, pz = c0 + rad * sx, c1 + rad * sy, c2 + rad * sz
        vx, vy, vz = ux, uy, uz
    return px, py, pz, vx, vy, vz


@njit(inline='always', **JIT)
def held_by_friction(h, p, dv, n):
    """p moved by h times the tangential part of the velocity change ``dv`` at a surface
    of normal n: friction acts over the whole step, so static friction holds a particle
    where it is (static colliders here, the collider pass in ``kinematic``)."""
    dn = dv[0] * n[0] + dv[1] * n[1] + dv[2] * n[2]
    return (p[0] + h * (dv[0] - dn * n[0]), p[1] + h * (dv[1] - dn * n[1]),
            p[2] + h * (dv[2] - dn * n[2]))


@njit(inline='always', **JIT)
def _path_meets_sphere(came, d, centre, rad):
    """Whether the path from ``came`` to the point at offset ``d`` from ``centre`` comes
    closer to it than ``rad``."""
    ox, oy, oz = came[0] - centre[0], came[1] - centre[1], came[2] - centre[2]
    ux, uy, uz = d[0] - ox, d[1] - oy, d[2] - oz
    uu = ux * ux + uy * uy + uz * uz
    t = min(max(-(ox * ux + oy * uy + oz * uz) / uu, 0.0), 1.0) if uu > 0.0 else 0.0
    return _inside_sphere(ox + t * ux, oy + t * uy, oz + t * uz, rad)


@njit(inline='always', **JIT)
def _sphere_entry(came, d, centre, rad):
    """The outward normal where the path from ``came`` to the point at offset ``d`` from
    ``centre`` enters the sphere of ``rad`` (where it starts inside, at ``came``)."""
    ox, oy, oz = came[0] - centre[0], came[1] - centre[1], came[2] - centre[2]
    ux, uy, uz = d[0] - ox, d[1] - oy, d[2] - oz
    uu = ux * ux + uy * uy + uz * uz
    b = ox * ux + oy * uy + oz * uz
    c = ox * ox + oy * oy + oz * oz - rad * rad
    if c > 0.0 and uu > 0.0 and b * b - uu * c >= 0.0:
        t = (-b - np.sqrt(b * b - uu * c)) / uu
        return _unit(ox + t * ux, oy + t * uy, oz + t * uz)
    return _unit(ox, oy, oz)


@njit(inline='always', **JIT)
def _unit(dx, dy, dz):
    """(dx, dy, dz) over its length; +z for the zero vector."""
    d = np.sqrt(dx * dx + dy * dy + dz * dz)
    if d > 0.0:
        return dx / d, dy / d, dz / d
    return 0.0, 0.0, 1.0


@njit(inline='always', **JIT)
def _inside_sphere(dx, dy, dz, rad):
    """Whether the offset (dx, dy, dz) from a sphere's centre lies inside radius ``rad``."""
    return dx * dx + dy * dy + dz * dz < rad * rad


@njit(**JIT_NO_REFCOUNT)
def _range_reach(start, end, x, v, col):
    """Which colliders of ``col`` particles start..end can be inside or have passed through
    within the step: (ground, any box or sphere), each grown by the particles' radius.

    From the bounds of the range, where the particles are and were a step ago (x - h v):
    a box whose extent the bounds do not overlap, a sphere whose bounding cube they do
    not, cannot hold any of its particles nor have been crossed (the tests below use the
    same strict comparisons, so this is exact; nan fails both).  A ground projection sets
    z to the ground height: the bounds then include it, since a box or sphere may start
    there.
    """
    lo0 = lo1 = lo2 = np.inf              # a nan coordinate never widens the bounds: it
    hi0 = hi1 = hi2 = -np.inf             # fails every collider test below as well
    h = col.h
    for i in range(start, end):
        p0, p1, p2 = x[i, 0], x[i, 1], x[i, 2]
        q0, q1, q2 = p0 - h * v[i, 0], p1 - h * v[i, 1], p2 - h * v[i, 2]
        lo0 = min(lo0, p0, q0)
        hi0 = max(hi0, p0, q0)
        lo1 = min(lo1, p1, q1)
        hi1 = max(hi1, p1, q1)
        lo2 = min(lo2, p2, q2)
        hi2 = max(hi2, p2, q2)
    ground, boxes, spheres, r = col.ground, col.boxes, col.spheres, col.radius
    gz = ground[1] + r
    on_ground = ground[0] > 0.5 and lo2 < gz
    if on_ground:
        hi2 = gz if gz > hi2 else hi2
    for b in range(boxes.shape[0]):
        if (hi0 > boxes[b, 0] - r and lo0 < boxes[b, 3] + r and hi1 > boxes[b, 1] - r
                and lo1 < boxes[b, 4] + r and hi2 > boxes[b, 2] - r
                and lo2 < boxes[b, 5] + r):
            return on_ground, True
    for s in range(spheres.shape[0]):
        c0, c1, c2, rad = spheres[s, 0], spheres[s, 1], spheres[s, 2], spheres[s, 3] + r
        # |p_a - c_a| > rad on one axis gives d^2 >= rad^2 after rounding: not inside
        if not (lo0 - c0 > rad or c0 - hi0 > rad or lo1 - c1 > rad or c1 - hi1 > rad
                or lo2 - c2 > rad or c2 - hi2 > rad):
            return on_ground, True
    return on_ground, False


@njit(inline='always', **JIT)
def ground_height(col):
    """The height below which a particle's centre is inside the ground of ``col``: the
    ground's plus the particles' radius; -inf without colliders or ground."""
    if col.on and col.ground[0] > 0.5:
        return col.ground[1] + col.radius
    return -np.inf


@njit(inline='always', **JIT)
def ground_range(start, end, x, v, col):
    """``collide_point`` for the ground alone on particles start..end (a resting body has a
    whole layer of particles in contact every step: the call, not the test, is what costs).
    ``_collide_range`` and the one-loop passes, which know from their own count that a
    particle is below the ground (``ground_height``), call it."""
    gz, mu, e = ground_height(col), col.ground[2], col.ground[3]
    for i in range(start, end):
        if x[i, 2] < gz:
            x[i, 2] = gz
            v[i, 0], v[i, 1], v[i, 2] = contact_velocity(vx=v[i, 0], vy=v[i, 1], vz=v[i, 2],
                                                         nx=0.0, ny=0.0, nz=1.0, friction=mu,
                                                         restitution=e, thresh=col.thresh)


@njit(inline='always', **JIT)
def ground_range_sums(start, end, x, v, x0, wuni, col, point, damp):
    """``ground_range`` for a range whose sums the one-loop pass has just taken about the
    point k (``point``): returns what the projection changed in them, so that the sums
    stay those of the final state without a second pass over the range (a body resting on
    the ground has a layer of particles in contact in every block it is stored in).

    A projected particle only moves up (z -> ``ground_height``, dz) and changes its
    velocity v -> v', so with w = ``wuni`` its weight (the one-loop passes serve bodies of
    one mass), d = x - k and a = x0[i]: (delta sum w d_z, delta sum w d_z a^T (3), then
    the 12 damping sums' deltas in ``damping.damp_sums_range``'s order: sum w v, sum w d x v,
    sum w d d^T as xx, yy, zz, xy, yz, zx, of which xx, yy and xy do not change; zeros
    without ``damp``), 16 numbers.  The other shape sums do not change.
    """
    gz, mu, e, thresh = ground_height(col), col.ground[2], col.ground[3], col.thresh
    k0, k1, k2 = point
    w = wuni
    s2 = c20 = c21 = c22 = 0.0
    b0 = b1 = b2 = a0 = a1 = a2 = e22 = e12 = e20 = 0.0
    for i in range(start, end):
        z = x[i, 2]
        if z < gz:
            u0, u1, u2 = v[i, 0], v[i, 1], v[i, 2]
            n0, n1, n2 = contact_velocity(vx=u0, vy=u1, vz=u2, nx=0.0, ny=0.0, nz=1.0,
                                          friction=mu, restitution=e, thresh=thresh)
            x[i, 2] = gz
            v[i, 0], v[i, 1], v[i, 2] = n0, n1, n2
            d0, d1, d2 = x[i, 0] - k0, x[i, 1] - k1, z - k2
            dz = gz - z
            f2 = d2 + dz                     # d_z after the projection
            s2 += w * dz
            c20 += w * dz * x0[i, 0]
            c21 += w * dz * x0[i, 1]
            c22 += w * dz * x0[i, 2]
            if not damp:
                continue
            b0 += w * (n0 - u0)
            b1 += w * (n1 - u1)
            b2 += w * (n2 - u2)
            a0 += w * ((d1 * n2 - f2 * n1) - (d1 * u2 - d2 * u1))
            a1 += w * ((f2 * n0 - d0 * n2) - (d2 * u0 - d0 * u2))
            a2 += w * ((d0 * n1 - d1 * n0) - (d0 * u1 - d1 * u0))
            e22 += w * (f2 * f2 - d2 * d2)
            e12 += w * d1 * dz
            e20 += w * d0 * dz
    return s2, c20, c21, c22, b0, b1, b2, a0, a1, a2, 0.0, 0.0, e22, 0.0, e12, e20


@njit(**JIT_NO_REFCOUNT)
def _collide_range(start, end, x, v, col):
    """The colliders of ``col`` (``Colliders``) for particles start..end.

    Colliders the range cannot reach are skipped (``_range_reach``: a body in the air, or
    away from the walls, pays one bounds pass).  The ground alone is tested inline: the
    call to ``collide_point``, not the test, is what costs, so particles above the ground
    skip it and the ground's contact is inlined.  The results are those of
    ``collide_point`` on every particle.
    Returns whether a collider could reach the range (False: no particle was moved).
    """
    if end <= start:
        return False
    on_ground, others = _range_reach(start, end, x, v, col)
    if not others:
        if not on_ground:
            return False
        ground_range(start, end, x, v, col)
        return True
    for i in range(start, end):
        x[i, 0], x[i, 1], x[i, 2], v[i, 0], v[i, 1], v[i, 2] = collide_point(
            x[i, 0], x[i, 1], x[i, 2], v[i, 0], v[i, 1], v[i, 2], col)
    return True


@njit(**JIT_NO_REFCOUNT)
def surface_gap(row, px, py, pz, radius):
    """(gap, nx, ny, nz) of a sphere of ``radius`` at p against a collider row
    (``kinematic`` columns): the distance between the two surfaces (< 0: overlap) and the
    collider's outward normal there."""
    kind = row[C_KIND]
    cx, cy, cz = px - row[C_POS], py - row[C_POS + 1], pz - row[C_POS + 2]
    if kind == 0.0:
        d = np.sqrt(cx * cx + cy * cy + cz * cz)
        if d > 0.0:
            return d - row[C_DIM] - radius, cx / d, cy / d, cz / d
        return -row[C_DIM] - radius, 0.0, 0.0, 1.0
    r00, r01, r02 = row[C_ROT], row[C_ROT + 1], row[C_ROT + 2]
    r10, r11, r12 = row[C_ROT + 3], row[C_ROT + 4], row[C_ROT + 5]
    r20, r21, r22 = row[C_ROT + 6], row[C_ROT + 7], row[C_ROT + 8]
    q0 = r00 * cx + r10 * cy + r20 * cz
    q1 = r01 * cx + r11 * cy + r21 * cz
    q2 = r02 * cx + r12 * cy + r22 * cz
    if kind == 1.0:
        h0, h1, h2 = row[C_DIM], row[C_DIM + 1], row[C_DIM + 2]
        e0 = q0 - min(max(q0, -h0), h0)
        e1 = q1 - min(max(q1, -h1), h1)
        e2 = q2 - min(max(q2, -h2), h2)
        d = np.sqrt(e0 * e0 + e1 * e1 + e2 * e2)
        if d > 0.0:                     # outside: towards the nearest surface point
            return (d - radius, (r00 * e0 + r01 * e1 + r02 * e2) / d,
                    (r10 * e0 + r11 * e1 + r12 * e2) / d, (r20 * e0 + r21 * e1 + r22 * e2) / d)
        d0, d1, d2 = h0 - abs(q0), h1 - abs(q1), h2 - abs(q2)
        if d0 <= d1 and d0 <= d2:       # inside: out through the nearest face
            s = 1.0 if q0 >= 0.0 else -1.0
            return -d0 - radius, s * r00, s * r10, s * r20
        if d1 <= d2:
            s = 1.0 if q1 >= 0.0 else -1.0
            return -d1 - radius, s * r01, s * r11, s * r21
        s = 1.0 if q2 >= 0.0 else -1.0
        return -d2 - radius, s * r02, s * r12, s * r22
    hl = row[C_DIM + 1]                 # capsule: the segment [-hl, hl] along local z
    z = min(max(q2, -hl), hl)
    ex, ey, ez = cx - r02 * z, cy - r12 * z, cz - r22 * z
    d = np.sqrt(ex * ex + ey * ey + ez * ez)
    if d > 0.0:
        return d - row[C_DIM] - radius, ex / d, ey / d, ez / d
    return -row[C_DIM] - radius, r00, r10, r20
