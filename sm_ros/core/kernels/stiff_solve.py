"""Sequential impulses on the stiff bodies' contacts (``sm_ros/core/stiff_contact.py``).

Every stiff body is one rigid motion here (its frame, ``stiff_contacts.body_frame``); a
contact's impulse changes the velocity and spin of the one or two bodies it touches.
Impulses are accumulated over symmetric sweeps and clamped (Box2D, Bullet): the normal
one never pulls, friction stays within mu times it (Coulomb), so static friction holds and
kinetic friction is mu N.  A contact's target normal speed is restitution times its
approach speed at the point, taken before the step's gravity, where the gap closes within
the step (else whatever closes the gap): no contact gives back more speed than came in.
Overlap is removed by a second, position-only solve (split impulse), which moves the
bodies without giving them speed.  ``stiff_step`` runs the whole pass before the step.
"""

from typing import NamedTuple

import numpy as np
from numba import njit

from .jit import JIT
from ..kinematic import C_ANG, C_BOUND, C_VEL
from .stiff_contacts import (F_COM, F_HI, F_INV, F_LO, F_MASS, F_REACH, F_ROW, F_SPIN,
                             F_VEL, K_A, K_APPROACH, K_B, K_BOUNCE, K_COLL, K_E, K_FALL,
                             K_GAP, K_GRIP, K_MU, K_N, K_RA, K_RB, K_ROW, K_SLOP, K_SURF, K_TARGET,
                             K_WHO, SLOTS, _tangents, body_frame, collider_contacts,
                             inverse3, pair_contacts)

#: Overlap left uncorrected (m) and the share of the rest the position solve removes in a
#: step.
SLOP = 1e-4
BAUMGARTE = 0.5
#: Sweeps stop once none changes a contact's speed by more than this share of the
#: restitution threshold speed (2 |g| h).
TOLERANCE = 0.001
#: Share of a contact's last impulses it starts the step with (warm start).
WARM = 0.9


class StiffBodies(NamedTuple):
    """The bodies of the pass: typed lists of their (N, 3) positions and velocities and
    (N,) masses, their contact radii, whether each is awake (asleep: an obstacle of
    infinite mass) and whether it collides with other bodies."""

    x: object
    v: object
    m: object
    radius: np.ndarray
    awake: np.ndarray
    collide: np.ndarray


class StiffScene(NamedTuple):
    """What the bodies meet: ``rows`` (row 0 the ground, rows 1.. the colliders in
    ``kinematic`` columns, the first ``plain`` of them the world's plain boxes and
    spheres), whether the ground is on, the body-body friction and restitution, gravity,
    the step, the restitution threshold speed and the sweeps."""

    rows: np.ndarray
    plain: int
    ground_on: bool
    pair_mu: float
    pair_e: float
    gravity: np.ndarray
    h: float
    thresh: float
    iters: int


@njit(**JIT)
def _speed(frame):
    """A bound on the speed of a body's particles (rigid part)."""
    v = frame[F_VEL:F_VEL + 3]
    w = frame[F_SPIN:F_SPIN + 3]
    return np.sqrt(v[0] ** 2 + v[1] ** 2 + v[2] ** 2) + np.sqrt(
        w[0] ** 2 + w[1] ** 2 + w[2] ** 2) * frame[F_REACH]


@njit(**JIT)
def _rows_speed(rows):
    """The fastest surface speed of the collider rows 1.. (bounding sphere)."""
    fastest = 0.0
    for c in range(1, rows.shape[0]):
        row = rows[c]
        lin = np.sqrt(row[C_VEL] ** 2 + row[C_VEL + 1] ** 2 + row[C_VEL + 2] ** 2)
        ang = np.sqrt(row[C_ANG] ** 2 + row[C_ANG + 1] ** 2 + row[C_ANG + 2] ** 2)
        fastest = max(fastest, lin + ang * row[C_BOUND])
    return fastest


@njit(**JIT)
def _pairs(frames, bodies, slack):
    """Body pairs (a, b), a < b, at least one awake, whose bounds grown by their radii
    and ``slack`` overlap: (count, 2) array."""
    nb = frames.shape[0]
    out = np.empty((16, 2), dtype=np.int64)
    count = 0
    for a in range(nb):
        for b in range(a + 1, nb):
            if not ((bodies.awake[a] or bodies.awake[b]) and bodies.collide[a]
                    and bodies.collide[b]):
                continue
            grow = bodies.radius[a] + bodies.radius[b] + slack
            apart = False
            for k in range(3):
                apart = apart or (frames[a, F_LO + k] > frames[b, F_HI + k] + grow
                                  or frames[b, F_LO + k] > frames[a, F_HI + k] + grow)
            if apart:
                continue
            if count == out.shape[0]:
                grown = np.empty((2 * count, 2), dtype=np.int64)
                grown[:count] = out
                out = grown
            out[count, 0], out[count, 1] = a, b
            count += 1
    return out[:count]


@njit(**JIT)
def _contacts(frames, bodies, scene, stats):
    """Every contact of the pass: each awake body's with the colliders (its touching
    particles in ``stats[b, :2]``), then each near body pair's (``stiff_contacts``)."""
    h, nb = scene.h, frames.shape[0]
    g = np.sqrt(scene.gravity[0] ** 2 + scene.gravity[1] ** 2 + scene.gravity[2] ** 2)
    fastest = 0.0
    for b in range(nb):
        fastest = max(fastest, _speed(frames[b]))
    pairs = _pairs(frames, bodies, 2.0 * h * (fastest + g * h) + SLOP)
    ncoll = scene.rows.shape[0]
    out = np.empty((SLOTS * (nb * ncoll + len(pairs)), K_ROW))
    count = 0
    row_speed = _rows_speed(scene.rows)
    for b in range(nb):
        if bodies.awake[b]:
            margin = h * (_speed(frames[b]) + g * h + row_speed) + SLOP
            count = collider_contacts(bodies, frames, b, margin, scene, out, count,
                                      stats[b, :2])
    for p in range(len(pairs)):
        a, b = pairs[p, 0], pairs[p, 1]
        margin = h * (_speed(frames[a]) + _speed(frames[b]) + g * h) + SLOP
        count = pair_contacts(bodies, frames, a, b, margin, scene, out, count)
    return out[:count]


@njit(**JIT)
def _velocity_at(frames, b, r, surf):
    """The velocity of body b (or, for b < 0, ``surf``) at lever arm r."""
    if b < 0:
        return surf[0], surf[1], surf[2]
    v = frames[b, F_VEL:F_VEL + 3]
    w = frames[b, F_SPIN:F_SPIN + 3]
    return (v[0] + w[1] * r[2] - w[2] * r[1], v[1] + w[2] * r[0] - w[0] * r[2],
            v[2] + w[0] * r[1] - w[1] * r[0])


@njit(**JIT)
def _pushed(frames, row, dx, dy, dz):
    """``_relative`` of the position solve: a collider is not pushed."""
    zero = np.zeros(3)
    ax, ay, az = _velocity_at(frames, int(row[K_A]), row[K_RA:K_RA + 3], zero)
    bx, by, bz = _velocity_at(frames, int(row[K_B]), row[K_RB:K_RB + 3], zero)
    return (ax - bx) * dx + (ay - by) * dy + (az - bz) * dz


@njit(**JIT)
def _relative(frames, row, dx, dy, dz):
    """The velocity of a's point relative to b's (or the collider's) along d."""
    ax, ay, az = _velocity_at(frames, int(row[K_A]), row[K_RA:K_RA + 3], row[K_SURF:K_SURF + 3])
    bx, by, bz = _velocity_at(frames, int(row[K_B]), row[K_RB:K_RB + 3],
                              row[K_SURF:K_SURF + 3])
    return (ax - bx) * dx + (ay - by) * dy + (az - bz) * dz


@njit(**JIT)
def _inv_eff(frames, inv_inertia, b, r, dx, dy, dz):
    """Body b's share of a contact's inverse effective mass along d at lever arm r."""
    if b < 0:
        return 0.0
    cx, cy, cz = r[1] * dz - r[2] * dy, r[2] * dx - r[0] * dz, r[0] * dy - r[1] * dx
    k = frames[b, F_INV]
    c = (cx, cy, cz)
    for i in range(3):
        for j in range(3):
            k += c[i] * inv_inertia[b, i, j] * c[j]
    return k


@njit(**JIT)
def _push(frames, inv_inertia, b, r, px, py, pz):
    """Add the impulse p at lever arm r to body b's motion (nothing for b < 0)."""
    if b < 0:
        return
    w = frames[b, F_INV]
    frames[b, F_VEL] += w * px
    frames[b, F_VEL + 1] += w * py
    frames[b, F_VEL + 2] += w * pz
    tx, ty, tz = r[1] * pz - r[2] * py, r[2] * px - r[0] * pz, r[0] * py - r[1] * px
    for k in range(3):
        frames[b, F_SPIN + k] += (inv_inertia[b, k, 0] * tx + inv_inertia[b, k, 1] * ty
                                  + inv_inertia[b, k, 2] * tz)


@njit(**JIT)
def _impulse(frames, inv_inertia, row, lam, dx, dy, dz):
    """Impulse ``lam`` along d: + on a, - on b."""
    _push(frames, inv_inertia, int(row[K_A]), row[K_RA:K_RA + 3], lam * dx, lam * dy, lam * dz)
    _push(frames, inv_inertia, int(row[K_B]), row[K_RB:K_RB + 3], -lam * dx, -lam * dy,
          -lam * dz)


@njit(**JIT)
def _inv_mass_along(frames, inv_inertia, row, dx, dy, dz):
    """The speed change along d per unit impulse along d at a contact."""
    return (_inv_eff(frames, inv_inertia, int(row[K_A]), row[K_RA:K_RA + 3], dx, dy, dz)
            + _inv_eff(frames, inv_inertia, int(row[K_B]), row[K_RB:K_RB + 3], dx, dy, dz))


@njit(**JIT)
def _mass_along(frames, inv_inertia, row, dx, dy, dz):
    """A contact's effective mass along d (0 between two immovable sides)."""
    k = _inv_mass_along(frames, inv_inertia, row, dx, dy, dz)
    return 1.0 / k if k > 0.0 else 0.0


@njit(**JIT)
def contact_keys(rows, nb, ncoll):
    """One integer per contact naming it from step to step: its bodies or collider, and
    its particles."""
    keys = np.empty(rows.shape[0], dtype=np.int64)
    groups = nb + ncoll + 2
    for k in range(rows.shape[0]):
        row = rows[k]
        other = int(row[K_COLL]) + 2 if row[K_B] < 0 else ncoll + 2 + int(row[K_B])
        keys[k] = ((int(row[K_A]) * groups + other) << 40) + int(row[K_WHO])
    return keys


@njit(**JIT)
def warm_start(frames, inv_inertia, rows, keys, old_keys, old_acc):
    """Start each contact from ``WARM`` times its impulses of the last step (``old_keys``
    sorted, ``old_acc`` in their order), applied to the bodies; returns the impulses."""
    acc = np.zeros((rows.shape[0], 3))
    if len(old_keys) == 0:
        return acc
    for k in range(rows.shape[0]):
        at = np.searchsorted(old_keys, keys[k])
        if at >= len(old_keys) or old_keys[at] != keys[k]:
            continue
        row = rows[k]
        acc[k] = WARM * old_acc[at]
        nx, ny, nz = row[K_N], row[K_N + 1], row[K_N + 2]
        t1x, t1y, t1z, t2x, t2y, t2z = _tangents(nx, ny, nz)
        a0, a1, a2 = acc[k, 0], acc[k, 1], acc[k, 2]
        _impulse(frames, inv_inertia, row, 1.0, a0 * nx + a1 * t1x + a2 * t2x,
                 a0 * ny + a1 * t1y + a2 * t2y, a0 * nz + a1 * t1z + a2 * t2z)
    return acc


@njit(**JIT)
def set_targets(frames, rows, h, thresh):
    """Each contact's target normal speed (``K_TARGET``): 0 where it hits within the step
    faster than ``thresh`` (``K_BOUNCE`` set: ``bounce`` adds its restitution after the
    solve), else what closes its gap within the step, no more."""
    for k in range(rows.shape[0]):
        row = rows[k]
        vn = _relative(frames, row, row[K_N], row[K_N + 1], row[K_N + 2])
        hits = -vn > thresh and row[K_GAP] < SLOP - vn * h
        row[K_APPROACH] = -vn
        row[K_BOUNCE] = 1.0 if hits and row[K_E] > 0.0 else 0.0
        row[K_TARGET] = 0.0 if hits else -max(row[K_GAP], 0.0) / h


@njit(**JIT)
def approach_after_gravity(frames, rows):
    """Each contact's approach speed once the step's gravity is in (``K_FALL``)."""
    for k in range(rows.shape[0]):
        row = rows[k]
        row[K_FALL] = -_relative(frames, row, row[K_N], row[K_N + 1], row[K_N + 2])


@njit(**JIT)
def bounce(frames, inv_inertia, rows, acc):
    """Restitution after the solve (Poisson): each bouncing contact takes e times the
    normal impulse that stopped it once more, less the share that stopped the step's
    gravity (so it leaves as fast as it came, times e).  On the stopped motion, where the
    contact impulses do no work, that gives back at most e^2 of the kinetic energy the
    stop took.  Returns the impulses added."""
    added = np.zeros(rows.shape[0])
    for k in range(rows.shape[0]):
        row = rows[k]
        if row[K_BOUNCE] > 0.0 and row[K_FALL] > 0.0:
            added[k] = row[K_E] * acc[k, 0] * min(row[K_APPROACH] / row[K_FALL], 1.0)
            _impulse(frames, inv_inertia, row, added[k], row[K_N], row[K_N + 1],
                     row[K_N + 2])
    return added


@njit(**JIT)
def energy_share(before, after, inv_inertia, awake, limit):
    """The largest s in [0, 1] such that the motion ``before`` + s (``after`` -
    ``before``) (frames) has at most ``limit`` kinetic energy (0 if even ``before`` has
    more): the share of the restitution impulses that adds no energy."""
    start, slope, curve = 0.0, 0.0, 0.0
    for b in range(before.shape[0]):
        if not awake[b]:
            continue
        inertia = inverse3(inv_inertia[b])
        v0, w0 = before[b, F_VEL:F_VEL + 3], before[b, F_SPIN:F_SPIN + 3]
        dv = after[b, F_VEL:F_VEL + 3] - v0
        dw = after[b, F_SPIN:F_SPIN + 3] - w0
        mass = before[b, F_MASS]
        start += 0.5 * mass * (v0 @ v0) + 0.5 * (w0 @ (inertia @ w0))
        slope += mass * (v0 @ dv) + w0 @ (inertia @ dw)
        curve += 0.5 * mass * (dv @ dv) + 0.5 * (dw @ (inertia @ dw))
    if start + slope + curve <= limit:
        return 1.0
    if curve <= 0.0 or start >= limit:
        return 0.0
    return max(0.0, (-slope + np.sqrt(slope * slope - 4.0 * curve * (start - limit)))
               / (2.0 * curve))


@njit(**JIT)
def kinetic_energy(frames, inv_inertia, awake):
    """The awake bodies' kinetic energy of translation and rotation."""
    total = 0.0
    for b in range(frames.shape[0]):
        if awake[b]:
            v, w = frames[b, F_VEL:F_VEL + 3], frames[b, F_SPIN:F_SPIN + 3]
            total += 0.5 * frames[b, F_MASS] * (v @ v) + 0.5 * (
                w @ (inverse3(inv_inertia[b]) @ w))
    return total


@njit(**JIT)
def _visit(frames, inv_inertia, row, acc):
    """One visit of a contact: its normal impulse, then its friction within mu times the
    normal impulse so far and the position solve's (``K_GRIP``: a finger pressed into a
    body holds it by friction)."""
    nx, ny, nz = row[K_N], row[K_N + 1], row[K_N + 2]
    lam = _mass_along(frames, inv_inertia, row, nx, ny, nz) * (
        row[K_TARGET] - _relative(frames, row, nx, ny, nz))
    mass_n = _mass_along(frames, inv_inertia, row, nx, ny, nz)
    lam = max(acc[0] + lam, 0.0) - acc[0]
    acc[0] += lam
    _impulse(frames, inv_inertia, row, lam, nx, ny, nz)
    t1x, t1y, t1z, t2x, t2y, t2z = _tangents(nx, ny, nz)
    f1 = acc[1] - _mass_along(frames, inv_inertia, row, t1x, t1y, t1z) * _relative(
        frames, row, t1x, t1y, t1z)
    f2 = acc[2] - _mass_along(frames, inv_inertia, row, t2x, t2y, t2z) * _relative(
        frames, row, t2x, t2y, t2z)
    cap = row[K_MU] * (acc[0] + row[K_GRIP])
    size = np.sqrt(f1 * f1 + f2 * f2)
    if size > cap:
        f1, f2 = f1 * cap / size, f2 * cap / size
    d1, d2 = f1 - acc[1], f2 - acc[2]
    acc[1], acc[2] = f1, f2
    _impulse(frames, inv_inertia, row, 1.0, d1 * t1x + d2 * t2x, d1 * t1y + d2 * t2y,
             d1 * t1z + d2 * t2z)
    change = abs(lam) + np.sqrt(d1 * d1 + d2 * d2)
    return change / mass_n if mass_n > 0.0 else 0.0


@njit(**JIT)
def solve_velocities(frames, inv_inertia, rows, iters, tol, acc):
    """Symmetric sweeps of ``_visit`` from the impulses ``acc`` (count, 3), at most
    ``iters``, until none changes a contact's speed by more than ``tol``; returns the
    sweeps."""
    n = rows.shape[0]
    for it in range(iters):
        largest = 0.0
        for s in range(n):
            k = s if it % 2 == 0 else n - 1 - s
            largest = max(largest, _visit(frames, inv_inertia, rows[k], acc[k]))
        if largest <= tol:
            return it + 1
    return iters


@njit(**JIT)
def solve_positions(frames, inv_inertia, rows, h, iters, tol):
    """The split impulse: frames' velocity and spin set to what, applied to positions for
    one step, removes ``BAUMGARTE`` of each contact's overlap beyond ``K_SLOP`` (sweeps as
    ``solve_velocities``); each contact's impulse in ``K_GRIP``."""
    n = rows.shape[0]
    frames[:, F_VEL:F_VEL + 3] = 0.0
    frames[:, F_SPIN:F_SPIN + 3] = 0.0
    acc = np.zeros(n)
    for it in range(iters):
        largest = 0.0
        for s in range(n):
            k = s if it % 2 == 0 else n - 1 - s
            row = rows[k]
            depth = -row[K_GAP] - row[K_SLOP]
            if depth <= 0.0:
                continue
            nx, ny, nz = row[K_N], row[K_N + 1], row[K_N + 2]
            lam = _mass_along(frames, inv_inertia, row, nx, ny, nz) * (
                BAUMGARTE * depth / h - _pushed(frames, row, nx, ny, nz))
            lam = max(acc[k] + lam, 0.0) - acc[k]
            acc[k] += lam
            _impulse(frames, inv_inertia, row, lam, nx, ny, nz)
            largest = max(largest, abs(lam) * _inv_mass_along(frames, inv_inertia, row,
                                                              nx, ny, nz))
        if largest <= tol:
            break
    rows[:, K_GRIP] = acc


@njit(**JIT)
def _add_motion(x, v, com, dvel, dspin, scale):
    """Add the rigid motion (dvel, dspin about ``com``) times ``scale`` to v (x: where
    v is x, positions)."""
    for i in range(x.shape[0]):
        rx, ry, rz = x[i, 0] - com[0], x[i, 1] - com[1], x[i, 2] - com[2]
        v[i, 0] += scale * (dvel[0] + dspin[1] * rz - dspin[2] * ry)
        v[i, 1] += scale * (dvel[1] + dspin[2] * rx - dspin[0] * rz)
        v[i, 2] += scale * (dvel[2] + dspin[0] * ry - dspin[1] * rx)


@njit(**JIT)
def _tally(rows, acc, frames, colliders, tally):
    """Each collider contact's impulse, with the opposite sign, on its collider: in
    ``tally`` (C, 6), the impulse (N s) and its moment about the collider's centre."""
    for k in range(rows.shape[0]):
        row = rows[k]
        c = int(row[K_COLL])
        if c < 0:
            continue
        nx, ny, nz = row[K_N], row[K_N + 1], row[K_N + 2]
        t1x, t1y, t1z, t2x, t2y, t2z = _tangents(nx, ny, nz)
        p = -np.array([acc[k, 0] * nx + acc[k, 1] * t1x + acc[k, 2] * t2x,
                       acc[k, 0] * ny + acc[k, 1] * t1y + acc[k, 2] * t2y,
                       acc[k, 0] * nz + acc[k, 1] * t1z + acc[k, 2] * t2z])
        a = int(row[K_A])
        arm = frames[a, F_COM:F_COM + 3] + row[K_RA:K_RA + 3] - colliders[c + 1, 1:4]
        tally[c, :3] += p
        tally[c, 3:] += np.cross(arm, p)


@njit(**JIT)
def _pair_stats(rows, stats):
    """Per body: body-pair contacts (``stats[b, 2]``) and the deepest overlap of its
    contacts (``stats[b, 3]``, m)."""
    for k in range(rows.shape[0]):
        row = rows[k]
        for side in (K_A, K_B):
            b = int(row[side])
            if b < 0:
                continue
            if row[K_B] >= 0:
                stats[b, 2] += 1
            stats[b, 3] = max(stats[b, 3], -row[K_GAP])


@njit(**JIT)
def stiff_step(bodies, scene, memory, tally, stats):
    """The pass before a step (module docstring): the awake bodies' particles get their
    change of velocity and spin, overlapping ones a position push.  ``memory``: the last
    step's contact keys (sorted) and impulses; ``stats`` (B, 5) per body: its particles
    touching the plain colliders and the others, its body-pair contacts, its deepest
    overlap, and 1 where its velocities changed, 2 where its positions did too.  Returns
    this step's contact keys and impulses, sorted."""
    nb = len(bodies.x)
    frames = np.zeros((nb, F_ROW))
    inv_inertia = np.zeros((nb, 3, 3))
    for b in range(nb):
        body_frame(bodies.x[b], bodies.v[b], bodies.m[b], frames[b], inv_inertia[b])
        if not bodies.awake[b]:
            frames[b, F_INV] = 0.0
            frames[b, F_VEL:F_VEL + 6] = 0.0
            inv_inertia[b] = 0.0
    rows = _contacts(frames, bodies, scene, stats)
    keys = contact_keys(rows, nb, scene.rows.shape[0])
    if rows.shape[0] == 0:
        return keys, np.zeros((0, 3))
    _pair_stats(rows, stats)
    h, gravity = scene.h, scene.gravity
    tol = TOLERANCE * max(scene.thresh, 1e-3)
    push = frames.copy()
    solve_positions(push, inv_inertia, rows, h, scene.iters, tol)
    start = frames.copy()
    set_targets(frames, rows, h, scene.thresh)
    for b in range(nb):
        if bodies.awake[b]:
            frames[b, F_VEL:F_VEL + 3] += h * gravity
    free = kinetic_energy(frames, inv_inertia, bodies.awake)
    approach_after_gravity(frames, rows)
    acc = warm_start(frames, inv_inertia, rows, keys, memory[0], memory[1])
    solve_velocities(frames, inv_inertia, rows, scene.iters, tol, acc)
    stopped = frames.copy()
    added = bounce(frames, inv_inertia, rows, acc)
    share = energy_share(stopped, frames, inv_inertia, bodies.awake, free)
    if share < 1.0:                                      # contacts never add energy
        frames[:] = stopped + share * (frames - stopped)
    acc[:, 0] += share * added
    _tally(rows, acc, frames, scene.rows, tally)
    for b in range(nb):
        if bodies.awake[b]:
            _move(bodies, b, start[b], frames[b] - start[b], push[b], scene, stats[b])
    order = np.argsort(keys)
    return keys[order], acc[order]


@njit(**JIT)
def _move(bodies, b, start, change, push, scene, stats):
    """Body b's particles: the velocity change (``change``, less the step's gravity,
    which the step adds) and the position push, about its centre at the start."""
    com = start[F_COM:F_COM + 3]
    dvel = change[F_VEL:F_VEL + 3] - scene.h * scene.gravity
    dspin = change[F_SPIN:F_SPIN + 3]
    if np.any(dvel != 0.0) or np.any(dspin != 0.0):
        _add_motion(bodies.x[b], bodies.v[b], com, dvel, dspin, 1.0)
        stats[4] = 1
    pvel, pspin = push[F_VEL:F_VEL + 3], push[F_SPIN:F_SPIN + 3]
    if np.any(pvel != 0.0) or np.any(pspin != 0.0):
        _add_motion(bodies.x[b], bodies.x[b], com, pvel, pspin, scene.h)
        stats[4] = 2
