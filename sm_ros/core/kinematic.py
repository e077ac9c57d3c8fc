"""The collider pass: oriented boxes, spheres and capsules, static or moving (kinematic).

Runs after the bodies' own step on world-level structure-of-arrays state: positions ``X``
and velocities ``V`` of shape (3, N) (any layout: a body's (N, 3) buffer transposed works
too), per-particle mass ``m`` and inverse mass ``w`` (0 for pinned or grabbed particles,
which the colliders then leave alone: they act as infinite mass).

A particle inside a collider is projected to the nearest surface point along the surface
normal, or, where its path entered the collider through a surface that turns from the one
nearest to its end by more than 45 degrees (a rod or a plate thinner than its step, a
particle pulled hard round a rod), back onto the tangent plane where it entered
(``_swept_contact``), so a thin collider holds what a body pulls over it instead of
letting it through; its velocity relative to the
collider's surface velocity ``v + omega x (p - c)``
gets the ground's contact rule (restitution above ``thresh``, Coulomb friction removing up
to mu * dv_n of the tangential velocity), and the step's displacement gets the same
tangential change (h times it), so static friction holds a particle where it is: without
that, a particle whose velocity friction stops has still slid by h v_t in the step, and
fingers cannot hold a ball however large mu is.  The impulse the particle received, with the
opposite sign, is added to the collider's accumulator: force and torque about the
collider's centre that the bodies exert on it.

Each collider is one row of ``rows`` (``ROW`` floats, columns named in
``kernels/colliders.py``, where ``surface_gap`` measures a point against a row); the world
writes the pose and velocities of the current substep into it (``colliders.py``).

The contact law is ``kernels.colliders.contact_velocity``, shared with the static
colliders; the cache stamp of this module includes the kernel package (``kernels/jit.py``),
so an edit of the law recompiles ``collide_range``.
``collide_numpy`` is the plain NumPy twin the tests compare against.
"""

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from .kernels.colliders import (C_ANG, C_BOUND, C_DIM, C_E, C_KIND, C_MU,  # noqa: F401
                                C_POS, C_ROT, C_VEL, ENTRY_TURN, ROW,
                                contact_velocity, held_by_friction, surface_gap)
from .kernels.jit import JIT



class Particles(NamedTuple):
    """The particles the pass acts on: (3, N) positions and velocities, inverse masses
    (0: left alone), the body index of each particle and per body the radius of the
    spheres its particles meet the colliders with."""

    x: np.ndarray
    v: np.ndarray
    inv_mass: np.ndarray
    body: np.ndarray
    radius: np.ndarray


class ColliderTally(NamedTuple):
    """What the pass adds up: ``impulse`` (C, 6) on each collider (linear, then angular
    about its centre), ``stats`` (B, 2) per body [contacts, deepest penetration (m)] and
    ``touched`` (B,) set to 1 for a body whose particles moved."""

    impulse: np.ndarray
    stats: np.ndarray
    touched: np.ndarray


@njit(**JIT)
def _came_from(row, p, v, h):
    """Where the particle at p moving at v was, relative to the collider, a step of h s
    ago: p - h (v - the collider surface's velocity at p)."""
    px, py, pz = p
    rx, ry, rz = px - row[C_POS], py - row[C_POS + 1], pz - row[C_POS + 2]
    wx, wy, wz = row[C_ANG], row[C_ANG + 1], row[C_ANG + 2]
    return (px - h * (v[0] - row[C_VEL] - (wy * rz - wz * ry)),
            py - h * (v[1] - row[C_VEL + 1] - (wz * rx - wx * rz)),
            pz - h * (v[2] - row[C_VEL + 2] - (wx * ry - wy * rx)))


@njit(**JIT)
def _passes_by(row, p, came, reach):
    """Whether the segment from ``came`` to p comes within ``reach`` of the collider's
    centre (its bounding sphere grown by the particle's radius)."""
    dx, dy, dz = p[0] - came[0], p[1] - came[1], p[2] - came[2]
    cx, cy, cz = row[C_POS] - came[0], row[C_POS + 1] - came[1], row[C_POS + 2] - came[2]
    dd = dx * dx + dy * dy + dz * dz
    t = min(max((cx * dx + cy * dy + cz * dz) / dd, 0.0), 1.0) if dd > 0.0 else 0.0
    ex, ey, ez = cx - t * dx, cy - t * dy, cz - t * dz
    return ex * ex + ey * ey + ez * ez < reach * reach


#: Halvings of the path that place its entry into a collider (1/4096 of the step's move).
ENTRY_HALVINGS = 12
#: A particle that starts its step this close to a collider's surface (a fraction of its
#: radius: one resting on it) enters where it starts.
ENTRY_SLACK = 1e-3


@njit(**JIT)
def _entry(row, came, inside, radius):
    """(gap, nx, ny, nz, point) where the path from ``came`` (outside) to ``inside`` first
    reaches the collider grown by ``radius``, by halving: the last point outside, its gap
    (>= 0) and the normal of the surface nearest to it."""
    ox, oy, oz = came
    ix, iy, iz = inside
    for _ in range(ENTRY_HALVINGS):
        mx, my, mz = 0.5 * (ox + ix), 0.5 * (oy + iy), 0.5 * (oz + iz)
        if surface_gap(row, mx, my, mz, radius)[0] >= 0.0:
            ox, oy, oz = mx, my, mz
        else:
            ix, iy, iz = mx, my, mz
    gap, nx, ny, nz = surface_gap(row, ox, oy, oz, radius)
    return gap, nx, ny, nz, (ox, oy, oz)


@njit(**JIT)
def _inside_on_path(row, came, p, radius):
    """(found, point): a point of the path from ``came`` to p inside the collider grown
    by ``radius``: its middle, or on a path longer than ``radius`` its first or third
    quarter (so a path through it on a chord longer than a quarter of the path is seen)."""
    ox, oy, oz = came
    dx, dy, dz = p[0] - ox, p[1] - oy, p[2] - oz
    long_path = dx * dx + dy * dy + dz * dz >= radius * radius
    for t in (0.5, 0.25, 0.75):
        qx, qy, qz = ox + t * dx, oy + t * dy, oz + t * dz
        if surface_gap(row, qx, qy, qz, radius)[0] < 0.0:
            return True, (qx, qy, qz)
        if not long_path:
            break
    return False, p


@njit(**JIT)
def _swept_contact(row, p, came, radius):
    """(depth, nx, ny, nz) of the particle now at p, which was at ``came``: against the
    collider's nearest surface (depth > 0: overlap), or, where its path went inside and
    the surface it entered through turns from the one nearest to p by more than 45
    degrees, against that entry's tangent plane (``came``'s nearest surface where it
    started on or inside it), so a rod or a plate thinner than a step holds it and a
    particle pulled hard over a rod stays on the side it came from."""
    px, py, pz = p
    gap, nx, ny, nz = surface_gap(row, px, py, pz, radius)
    inside = p
    if gap >= 0.0:
        found, inside = _inside_on_path(row, came, p, radius)
        if not found:
            return -gap, nx, ny, nz
    ox, oy, oz = came
    came_gap, ex, ey, ez = surface_gap(row, ox, oy, oz, radius)
    if came_gap > ENTRY_SLACK * radius:             # it came from outside: where did it enter?
        came_gap, ex, ey, ez, came = _entry(row, came, inside, radius)
        ox, oy, oz = came
    if ex * nx + ey * ny + ez * nz >= ENTRY_TURN:
        return -gap, nx, ny, nz
    return -(came_gap + (px - ox) * ex + (py - oy) * ey + (pz - oz) * ez), ex, ey, ez


@njit(**JIT)
def collide_range(particles, start, end, rows, h, thresh, tally):
    """Collide particles start..end (``Particles``) with every collider of ``rows`` after a
    step of h s, adding to ``tally`` (``ColliderTally``): the impulse (3) and the angular
    impulse about the collider centre (3) that the particles exert on each collider, one
    contact per particle and collider touched, the deepest penetration of each body, and
    the bodies whose particles moved.
    Loops over particles (outer) and colliders (inner, a few): a particle whose step's
    path stays outside a collider's bounding sphere is passed over after a few flops.
    """
    X, V, w, bid = particles.x, particles.v, particles.inv_mass, particles.body
    imp, stats, touched = tally.impulse, tally.stats, tally.touched
    nc = rows.shape[0]
    for i in range(start, end):
        if w[i] <= 0.0:
            continue
        px, py, pz = X[0, i], X[1, i], X[2, i]
        rad = particles.radius[bid[i]]
        hit = False
        for c in range(nc):
            row = rows[c]
            came = _came_from(row, (px, py, pz), (V[0, i], V[1, i], V[2, i]), h)
            if not _passes_by(row, (px, py, pz), came, row[C_BOUND] + rad):
                continue
            depth, nx, ny, nz = _swept_contact(row, (px, py, pz), came, rad)
            if depth <= 0.0:
                continue
            hit = True
            px += depth * nx
            py += depth * ny
            pz += depth * nz
            owner = bid[i]
            stats[owner, 0] += 1.0
            if depth > stats[owner, 1]:
                stats[owner, 1] = depth
            # surface velocity of the collider at the projected point
            rx, ry, rz = px - row[C_POS], py - row[C_POS + 1], pz - row[C_POS + 2]
            wx, wy, wz = row[C_ANG], row[C_ANG + 1], row[C_ANG + 2]
            sx = row[C_VEL] + wy * rz - wz * ry
            sy = row[C_VEL + 1] + wz * rx - wx * rz
            sz = row[C_VEL + 2] + wx * ry - wy * rx
            vx, vy, vz = V[0, i], V[1, i], V[2, i]
            ux, uy, uz = contact_velocity(vx - sx, vy - sy, vz - sz, nx, ny, nz, row[C_MU],
                                          row[C_E], thresh)
            # the tangential change moves the step's displacement too (the normal part is
            # the projection above)
            px, py, pz = held_by_friction(h, (px, py, pz),
                                          (ux - (vx - sx), uy - (vy - sy), uz - (vz - sz)),
                                          (nx, ny, nz))
            ux += sx
            uy += sy
            uz += sz
            # impulse on the collider = - impulse on the particle
            mi = 1.0 / w[i]
            jx = -mi * (ux - vx)
            jy = -mi * (uy - vy)
            jz = -mi * (uz - vz)
            imp[c, 0] += jx
            imp[c, 1] += jy
            imp[c, 2] += jz
            imp[c, 3] += ry * jz - rz * jy
            imp[c, 4] += rz * jx - rx * jz
            imp[c, 5] += rx * jy - ry * jx
            V[0, i], V[1, i], V[2, i] = ux, uy, uz
        if hit:
            X[0, i], X[1, i], X[2, i] = px, py, pz
            touched[bid[i]] = 1


def _surface_numpy(row, p, rad):
    """(depth, normal) of the points p (3, N) with spheres of ``rad`` against one collider
    row (``surface_gap``'s rule in NumPy; depth > 0 where they overlap)."""
    rel = p - row[C_POS:C_POS + 3, None]
    rot = row[C_ROT:C_ROT + 9].reshape(3, 3)
    kind = int(row[C_KIND])
    if kind == 0:
        d = np.linalg.norm(rel, axis=0)
        safe = np.where(d > 0, d, 1.0)
        return row[C_DIM] + rad - d, np.where(d > 0, rel / safe, np.array([[0.0], [0.0], [1.0]]))
    q = rot.T @ rel
    if kind == 1:
        half = row[C_DIM:C_DIM + 3, None]
        e = q - np.clip(q, -half, half)         # outside: towards the nearest surface point
        out = np.linalg.norm(e, axis=0)
        dd = half - np.abs(q)
        ax = np.argmin(dd, axis=0)              # first minimum: x before y before z
        s = np.where(q[ax, np.arange(q.shape[1])] >= 0, 1.0, -1.0)
        depth = np.where(out > 0, rad - out, dd.min(axis=0) + rad)
        return depth, np.where(out > 0, rot @ (e / np.where(out > 0, out, 1.0)), rot[:, ax] * s)
    z = np.clip(q[2], -row[C_DIM + 1], row[C_DIM + 1])
    e = rel - rot[:, 2:3] * z
    d = np.linalg.norm(e, axis=0)
    safe = np.where(d > 0, d, 1.0)
    return row[C_DIM] + rad - d, np.where(d > 0, e / safe, rot[:, 0:1])


def _entry_numpy(row, came, inside, rad):
    """``_entry`` for the points ``came`` (3, N) outside the collider (farther than
    ``ENTRY_SLACK``), towards ``inside``; elsewhere ``came`` itself: (the points, their
    depth and normal)."""
    depth, n = _surface_numpy(row, came, rad)
    outside = depth < -ENTRY_SLACK * rad
    lo, hi = came.copy(), inside.copy()
    for _ in range(ENTRY_HALVINGS):
        mid = 0.5 * (lo + hi)
        out = _surface_numpy(row, mid, rad)[0] <= 0.0
        lo, hi = np.where(out, mid, lo), np.where(out, hi, mid)
    depth_lo, n_lo = _surface_numpy(row, lo, rad)
    return (np.where(outside, lo, came), np.where(outside, depth_lo, depth),
            np.where(outside, n_lo, n))


def collide_numpy(particles, rows, h, thresh, tally):
    """Plain NumPy twin of ``collide_range`` over every particle (vectorised per collider;
    the same sequence of colliders per particle)."""
    X, V, w, bid = particles.x, particles.v, particles.inv_mass, particles.body
    imp, stats, touched = tally.impulse, tally.stats, tally.touched
    m = np.divide(1.0, w, out=np.zeros_like(w), where=w > 0)
    X = np.asarray(X)
    V = np.asarray(V)
    free = w > 0.0
    rad = np.asarray(particles.radius)[np.asarray(bid)][free]
    for c, row in enumerate(rows):
        p = X[:, free]
        depth, n = _surface_numpy(row, p, rad)
        # where it came from (``_swept_contact``): the tangent plane of that side if it crossed
        rel = p - row[C_POS:C_POS + 3, None]
        surface = row[C_VEL:C_VEL + 3, None] + np.cross(row[C_ANG:C_ANG + 3], rel, axis=0)
        came = p - h * (V[:, free] - surface)
        inside, on_path = p, depth > 0
        long_path = ((p - came) ** 2).sum(axis=0) >= rad * rad
        for t in (0.75, 0.25, 0.5):           # the first found by ``_inside_on_path`` last
            point = came + t * (p - came)
            hit = ((depth <= 0) & (_surface_numpy(row, point, rad)[0] > 0)
                   & (long_path | (t == 0.5)))
            inside, on_path = np.where(hit, point, inside), on_path | hit
        came, depth_came, n_came = _entry_numpy(row, came, inside, rad)
        turned = ((n * n_came).sum(axis=0) < ENTRY_TURN) & on_path
        depth = np.where(turned, depth_came - ((p - came) * n_came).sum(axis=0), depth)
        n = np.where(turned, n_came, n)
        hit = depth > 0
        if not hit.any():
            continue
        idx = np.nonzero(free)[0][hit]
        nh, dh = n[:, hit], depth[hit]
        pn = X[:, idx] + dh * nh
        np.add.at(stats[:, 0], bid[idx], 1.0)
        np.maximum.at(stats[:, 1], bid[idx], dh)
        touched[bid[idx]] = 1
        r = pn - row[C_POS:C_POS + 3, None]
        vs = row[C_VEL:C_VEL + 3, None] + np.cross(row[C_ANG:C_ANG + 3], r, axis=0)
        u = V[:, idx] - vs
        un = (u * nh).sum(axis=0)
        act = un < 0
        t = u - un * nh
        vn_new = np.where(-un > thresh, -row[C_E] * un, 0.0)
        dvn = vn_new - un
        tl = np.linalg.norm(t, axis=0)
        f = np.clip(1.0 - row[C_MU] * dvn / np.where(tl > 0, tl, 1.0), 0.0, None)
        f = np.where(tl > 0, f, 1.0)
        u_new = np.where(act, t * f + vn_new * nh, u)
        v_new = u_new + vs
        du = u_new - u
        pn = pn + h * (du - (du * nh).sum(axis=0) * nh)
        j = -m[idx] * (v_new - V[:, idx])
        imp[c, :3] += j.sum(axis=1)
        imp[c, 3:] += np.cross(r, j, axis=0).sum(axis=1)
        X[:, idx] = pn
        V[:, idx] = v_new


# ---------------------------------------------------------------------------------------
# Poses of the kinematic colliders, all in one call (state: collider_motion.py).  Here, in
# the file of the row layout, so that an edit of the columns recompiles this kernel too.
# ---------------------------------------------------------------------------------------

IDLE, MOVE, PATH = 0, 1, 2

# columns of a commanded move (a row of ``ColliderMotion.moves``)
M_P0 = 0            # start position (3)
M_Q0 = 3            # start quaternion (4)
M_P1 = 7            # target position (3)
M_Q1 = 10           # target quaternion (4)
M_DUR = 14          # duration (s)
M_EL = 15           # time elapsed (s)
M_VEL = 16          # linear velocity (3)
M_AXIS = 19         # rotation axis, world frame (3)
M_ANGLE = 22        # rotation angle over the whole move (rad)
MV = 23


class ColliderMotion(NamedTuple):
    """The motion state of every collider (``nc`` of them; ``ColliderSet`` owns it)."""

    mode: np.ndarray        # (nc,) int64: IDLE, MOVE (a commanded move) or PATH (keyframes)
    pos: np.ndarray         # (nc, 3) current positions
    quat: np.ndarray        # (nc, 4) current orientations (x, y, z, w)
    moves: np.ndarray       # (nc, MV) the commanded moves, columns M_*
    done: np.ndarray        # (nc,) int64: set to 1 where a commanded move ended


class Keyframes(NamedTuple):
    """The keyframes of every scripted path, concatenated (K of them); collider c's are
    ``offset[c]:offset[c + 1]`` (none without a path)."""

    time: np.ndarray        # (K,) s from the start
    pos: np.ndarray         # (K, 3)
    quat: np.ndarray        # (K, 4)
    segment: np.ndarray     # (K, 4) axis and angle from keyframe k to k + 1 (last unused)
    offset: np.ndarray      # (nc + 1,) int64


@njit(**JIT)
def _axis_angle_mul(ax, ay, az, angle, q):
    """quat_mul(axis_angle_quat(axis, angle), q) as four floats."""
    s = math.sin(0.5 * angle)
    x, y, z, w = ax * s, ay * s, az * s, math.cos(0.5 * angle)
    bx, by, bz, bw = q[0], q[1], q[2], q[3]
    return (w * bx + x * bw + y * bz - z * by,
            w * by - x * bz + y * bw + z * bx,
            w * bz + x * by - y * bx + z * bw,
            w * bw - x * bx - y * by - z * bz)


@njit(**JIT)
def _rotation_between(q0, q1x, q1y, q1z, q1w):
    """(ax, ay, az, angle) of the world-frame rotation taking q0 to q1 (angle in [0, pi])."""
    ax, ay, az, aw = q1x, q1y, q1z, q1w
    bx, by, bz, bw = -q0[0], -q0[1], -q0[2], q0[3]
    dx = aw * bx + ax * bw + ay * bz - az * by
    dy = aw * by - ax * bz + ay * bw + az * bx
    dz = aw * bz + ax * by - ay * bx + az * bw
    dw = aw * bw - ax * bx - ay * by - az * bz
    if dw < 0.0:
        dx, dy, dz, dw = -dx, -dy, -dz, -dw
    s = math.sqrt(dx * dx + dy * dy + dz * dz)
    if s < 1e-15:
        return 0.0, 0.0, 1.0, 0.0
    return dx / s, dy / s, dz / s, 2.0 * math.atan2(s, dw)


@njit(**JIT)
def _write_pose(row, p, q, vx, vy, vz, wx, wy, wz):
    """Position, rotation matrix of unit quaternion q, linear and angular velocity."""
    row[C_POS], row[C_POS + 1], row[C_POS + 2] = p[0], p[1], p[2]
    x, y, z, w = q[0], q[1], q[2], q[3]
    r = C_ROT
    row[r] = 1 - 2 * (y * y + z * z)
    row[r + 1] = 2 * (x * y - z * w)
    row[r + 2] = 2 * (x * z + y * w)
    row[r + 3] = 2 * (x * y + z * w)
    row[r + 4] = 1 - 2 * (x * x + z * z)
    row[r + 5] = 2 * (y * z - x * w)
    row[r + 6] = 2 * (x * z - y * w)
    row[r + 7] = 2 * (y * z + x * w)
    row[r + 8] = 1 - 2 * (x * x + y * y)
    row[C_VEL], row[C_VEL + 1], row[C_VEL + 2] = vx, vy, vz
    row[C_ANG], row[C_ANG + 1], row[C_ANG + 2] = wx, wy, wz


@njit(**JIT)
def advance_poses(motion, keys, rows, h, t):
    """Poses at the end of the next step (from world time ``t``, of ``h`` s) and the
    velocities during it, for every collider (``ColliderMotion``, ``Keyframes``); returns
    how many commanded moves ended.  One pass over the colliders (a few): each moving one
    costs a slerp, a rotation matrix and, on a path, a scan of its keyframes; a collider at
    rest only has its velocities zeroed once.  One function: a compiled callee would add
    its own compile time to a cold start."""
    pos, quat = motion.pos, motion.quat
    ktime, kpos, kquat, kseg = keys.time, keys.pos, keys.quat, keys.segment
    ended = 0
    for c in range(motion.mode.shape[0]):
        row = rows[c]
        mode = motion.mode[c]
        if mode == PATH:
            k0, k1 = keys.offset[c], keys.offset[c + 1]
            end = ktime[k1 - 1]
            if t >= end:                        # the path is over: at rest there
                motion.mode[c] = IDLE
                _write_pose(row, pos[c], quat[c], 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
                continue
            tt = t + h
            if tt >= end:
                px, py, pz = kpos[k1 - 1, 0], kpos[k1 - 1, 1], kpos[k1 - 1, 2]
                qx, qy, qz, qw = kquat[k1 - 1, 0], kquat[k1 - 1, 1], kquat[k1 - 1, 2], \
                    kquat[k1 - 1, 3]
            else:
                k = k0
                while k + 1 < k1 and ktime[k + 1] <= tt:
                    k += 1
                s = (tt - ktime[k]) / (ktime[k + 1] - ktime[k])
                px = kpos[k, 0] + (kpos[k + 1, 0] - kpos[k, 0]) * s
                py = kpos[k, 1] + (kpos[k + 1, 1] - kpos[k, 1]) * s
                pz = kpos[k, 2] + (kpos[k + 1, 2] - kpos[k, 2]) * s
                qx, qy, qz, qw = _axis_angle_mul(kseg[k, 0], kseg[k, 1], kseg[k, 2],
                                                 kseg[k, 3] * s, kquat[k])
            vx, vy, vz = (px - pos[c, 0]) / h, (py - pos[c, 1]) / h, (pz - pos[c, 2]) / h
            ax, ay, az, angle = _rotation_between(quat[c], qx, qy, qz, qw)
            pos[c, 0], pos[c, 1], pos[c, 2] = px, py, pz
            quat[c, 0], quat[c, 1], quat[c, 2], quat[c, 3] = qx, qy, qz, qw
            w = angle / h
            _write_pose(row, pos[c], quat[c], vx, vy, vz, ax * w, ay * w, az * w)
        elif mode == MOVE:
            move = motion.moves[c]
            d = move[M_DUR]
            t_new = move[M_EL] + h
            if t_new >= d * (1.0 - 1e-9):
                for i in range(3):
                    pos[c, i] = move[M_P1 + i]
                for i in range(4):
                    quat[c, i] = move[M_Q1 + i]
                motion.mode[c] = IDLE
                motion.done[c] = 1
                ended += 1
            else:
                s = t_new / d
                for i in range(3):
                    pos[c, i] = move[M_P0 + i] + (move[M_P1 + i] - move[M_P0 + i]) * s
                qx, qy, qz, qw = _axis_angle_mul(move[M_AXIS], move[M_AXIS + 1],
                                                 move[M_AXIS + 2], move[M_ANGLE] * s,
                                                 move[M_Q0:M_Q0 + 4])
                quat[c, 0], quat[c, 1], quat[c, 2], quat[c, 3] = qx, qy, qz, qw
                move[M_EL] = t_new
            w = move[M_ANGLE] / d
            _write_pose(row, pos[c], quat[c], move[M_VEL], move[M_VEL + 1], move[M_VEL + 2],
                        move[M_AXIS] * w, move[M_AXIS + 1] * w, move[M_AXIS + 2] * w)
        else:
            moving = False
            for i in range(C_VEL, C_ANG + 3):
                if row[i] != 0.0:
                    moving = True
            if moving:
                _write_pose(row, pos[c], quat[c], 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    return ended
