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

from .jit import JIT, JIT_NO_REFCOUNT
from .colliders import C_ANG, C_BOUND, C_VEL
from .stiff_rows import J_D, J_MASS, apply, jacobians, push_visit, speed_along, visit
from .stiff_contacts import (F_COM, F_HI, F_INV, F_LO, F_MASS, F_REACH, F_ROW, F_SPIN,
                             F_VEL, K_A, K_APPROACH, K_B, K_BOUNCE, K_COLL, K_E, K_FALL,
                             K_GAP, K_GRIP, K_RA, K_ROW, K_SLOP, K_TARGET,
                             K_WHO, SLOTS, body_frame, collider_contacts, touches)
from .stiff_pairs import append_pair, pair_contacts

#: A gap (m) within which a contact counts as reached, and the share of an overlap beyond
#: its slop (``stiff_contacts.SLOP_SHARE``) the position solve removes in a step.
SLOP = 1e-4
BAUMGARTE = 0.5
#: Sweeps stop once none changes a contact's speed by more than this share of the
#: restitution threshold speed (2 |g| h).
TOLERANCE = 0.001
#: Contact visits a solve may take (a tall stack needs about 100 sweeps over its few
#: contacts, a heap of hundreds of bodies gets fewer, but at least ``MIN_SWEEPS``).
VISITS = 20000
MIN_SWEEPS = 12
#: Share of a contact's last impulses it starts the step with (warm start; Box2D's full
#: share: a heap's load carries over from step to step, so its bodies come to rest).
WARM = 1.0


class StiffBodies(NamedTuple):
    """The bodies of the pass: typed lists of their (N, 3) positions and velocities and
    (N,) masses, their contact radii, whether each is awake (asleep: an obstacle of
    infinite mass), whether it collides with other bodies, whether it is stiff (else it
    meets the colliders here only while near another body of the pass: alone, its own
    step's per-particle contact dents it), whether it is round (meets
    the colliders as one sphere, ``stiff_contacts.collider_contacts``) and (B, 3, 3) the
    half edges of its particles' lattice cells, in world axes (zeros: no lattice, its
    particles meet the colliders as spheres)."""

    x: object
    v: object
    m: object
    radius: np.ndarray
    awake: np.ndarray
    collide: np.ndarray
    stiff: np.ndarray
    round: np.ndarray
    cells: np.ndarray


class StiffScene(NamedTuple):
    """What the bodies meet: ``rows`` (row 0 the ground, rows 1.. the colliders in
    ``kinematic`` columns, the first ``plain`` of them the world's plain boxes and
    spheres), whether the ground is on, the body-body friction and restitution, gravity,
    the step, the restitution threshold speed, the sweeps, the speed at which a hit
    wakes a sleeping body and the distance, in contact distances, within which two bodies
    touch for the sleep pass (``tuning.TOUCH_FACTOR``)."""

    rows: np.ndarray
    plain: int
    ground_on: bool
    pair_mu: float
    pair_e: float
    gravity: np.ndarray
    h: float
    thresh: float
    iters: int
    wake_speed: float
    touch: float


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
    and ``slack`` overlap (a round body's by half its reach more: its sphere reaches past
    its particles' bounds): (count, 2) array."""
    nb = frames.shape[0]
    out = np.empty((16, 2), dtype=np.int64)
    count = np.int64(0)
    for a in range(nb):
        for b in range(a + 1, nb):
            if not ((bodies.awake[a] or bodies.awake[b]) and bodies.collide[a]
                    and bodies.collide[b]):
                continue
            grow = bodies.radius[a] + bodies.radius[b] + slack
            for side in (a, b):
                if bodies.round[side]:
                    grow += 0.5 * frames[side, F_REACH]
            apart = False
            for k in range(3):
                apart = apart or (frames[a, F_LO + k] > frames[b, F_HI + k] + grow
                                  or frames[b, F_LO + k] > frames[a, F_HI + k] + grow)
            if apart:
                continue
            out = append_pair(out, count, a, b)
            count += 1
    return out[:count]


@njit(**JIT)
def _contacts(frames, bodies, scene, stats):
    """Every contact of the pass: each awake body's with the colliders (its touching
    particles in ``stats[b, :2]``; a body not stiff only while near another), then each
    near body pair's (``stiff_contacts``)."""
    h, nb = scene.h, frames.shape[0]
    g = np.sqrt(scene.gravity[0] ** 2 + scene.gravity[1] ** 2 + scene.gravity[2] ** 2)
    fastest = 0.0
    for b in range(nb):
        fastest = max(fastest, _speed(frames[b]))
    pairs = _pairs(frames, bodies, 2.0 * h * (fastest + g * h) + SLOP)
    near = bodies.stiff.copy()
    for p in range(len(pairs)):
        near[pairs[p, 0]] = near[pairs[p, 1]] = True
    ncoll = scene.rows.shape[0]
    out = np.empty((SLOTS * (nb * ncoll + len(pairs)), K_ROW))
    count = np.int64(0)
    row_speed = _rows_speed(scene.rows)
    for b in range(nb):
        if bodies.awake[b] and near[b]:
            margin = h * (_speed(frames[b]) + g * h + row_speed) + SLOP
            count = collider_contacts(bodies, frames, b, margin, scene, out, count,
                                      stats[b, :2])
    for p in range(len(pairs)):
        a, b = pairs[p, 0], pairs[p, 1]
        margin = h * (_speed(frames[a]) + _speed(frames[b]) + g * h) + SLOP
        count = pair_contacts(bodies, frames, a, b, margin, scene, out, count)
    return out[_bottom_up(out[:count], frames, scene.gravity)]


@njit(**JIT)
def _bottom_up(rows, frames, gravity):
    """The order of the contacts from the ground up (the lower body's centre against
    gravity; a collider's contacts first): a sweep in that order carries a stack's load
    down in one pass, the next sweep (reversed) carries the answer up."""
    height = np.empty(rows.shape[0])
    for k in range(rows.shape[0]):
        a, b = int(rows[k, K_A]), int(rows[k, K_B])
        up = -_dot3(frames[a, F_COM:F_COM + 3], gravity)
        if b < 0:
            up -= 1e9
        else:
            up = min(up, -_dot3(frames[b, F_COM:F_COM + 3], gravity))
        height[k] = up
    return np.argsort(height, kind='mergesort')


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
def warm_start(frames, jac, rows, keys, memory):
    """Start each contact from ``WARM`` times its impulses of the last step (``memory``:
    keys sorted, impulses in their order), applied to the bodies; returns the impulses."""
    old_keys, old_acc = memory
    acc = np.zeros((rows.shape[0], 3))
    if len(old_keys) == 0:
        return acc
    for k in range(rows.shape[0]):
        at = np.searchsorted(old_keys, keys[k])
        if at >= len(old_keys) or old_keys[at] != keys[k]:
            continue
        acc[k] = WARM * old_acc[at]
        a, b = int(rows[k, K_A]), int(rows[k, K_B])
        for e in range(3):
            apply(frames, jac[k, e], a, b, acc[k, e])
    return acc


@njit(**JIT)
def set_targets(frames, jac, rows, h, thresh):
    """Each contact's target normal speed (``K_TARGET``): 0 where it hits within the step
    faster than ``thresh`` with restitution (``K_BOUNCE`` set: ``bounce`` adds it after the
    solve), else what closes its gap within the step, no more."""
    for k in range(rows.shape[0]):
        row = rows[k]
        vn = speed_along(frames, jac[k, 0], int(row[K_A]), int(row[K_B]), True)
        hits = -vn > thresh and row[K_GAP] < SLOP - vn * h
        row[K_APPROACH] = -vn
        row[K_BOUNCE] = 1.0 if hits and row[K_E] > 0.0 else 0.0
        row[K_TARGET] = 0.0 if row[K_BOUNCE] > 0.0 else -max(row[K_GAP], 0.0) / h


@njit(**JIT)
def approach_after_gravity(frames, jac, rows):
    """Each contact's approach speed once the step's gravity is in (``K_FALL``)."""
    for k in range(rows.shape[0]):
        rows[k, K_FALL] = -speed_along(frames, jac[k, 0], int(rows[k, K_A]),
                                       int(rows[k, K_B]), True)


@njit(**JIT)
def bounce(frames, jac, rows, acc):
    """Restitution after the solve (Poisson): each bouncing contact takes e times the
    normal impulse that stopped it once more, less the share that stopped the step's
    gravity (so it leaves as fast as it came, times e).  On the stopped motion, where the
    contact impulses do no work, that gives back at most e^2 of the kinetic energy the
    stop removed.  Returns the impulses added."""
    added = np.zeros(rows.shape[0])
    for k in range(rows.shape[0]):
        row = rows[k]
        if row[K_BOUNCE] > 0.0 and row[K_FALL] > 0.0:
            added[k] = row[K_E] * acc[k, 0] * min(row[K_APPROACH] / row[K_FALL], 1.0)
            apply(frames, jac[k, 0], int(row[K_A]), int(row[K_B]), added[k])
    return added


@njit(**JIT)
def energy_share(before, after, inertia, awake, limit):
    """The largest s in [0, 1] such that the motion ``before`` + s (``after`` -
    ``before``) (frames) has at most ``limit`` kinetic energy (0 if even ``before`` has
    more): the share of the restitution impulses that adds no energy."""
    start, slope, curve = 0.0, 0.0, 0.0
    for b in range(before.shape[0]):
        if not awake[b]:
            continue
        v0, w0 = before[b, F_VEL:F_VEL + 3], before[b, F_SPIN:F_SPIN + 3]
        dv = after[b, F_VEL:F_VEL + 3] - v0
        dw = after[b, F_SPIN:F_SPIN + 3] - w0
        mass = before[b, F_MASS]
        start += 0.5 * mass * _dot3(v0, v0) + 0.5 * _quad(inertia[b], w0, w0)
        slope += mass * _dot3(v0, dv) + _quad(inertia[b], w0, dw)
        curve += 0.5 * mass * _dot3(dv, dv) + 0.5 * _quad(inertia[b], dw, dw)
    if start + slope + curve <= limit:
        return 1.0
    if curve <= 0.0 or start >= limit:
        return 0.0
    return max(0.0, (-slope + np.sqrt(slope * slope - 4.0 * curve * (start - limit)))
               / (2.0 * curve))


@njit(**JIT_NO_REFCOUNT)
def _dot3(u, w):
    """u . w of two 3-vectors."""
    return u[0] * w[0] + u[1] * w[1] + u[2] * w[2]


@njit(**JIT_NO_REFCOUNT)
def _quad(mat, u, w):
    """u . (mat w) of a 3x3 matrix and two 3-vectors."""
    total = 0.0
    for i in range(3):
        total += u[i] * (mat[i, 0] * w[0] + mat[i, 1] * w[1] + mat[i, 2] * w[2])
    return total


@njit(**JIT)
def kinetic_energy(frames, inertia, awake):
    """The awake bodies' kinetic energy of translation and rotation."""
    total = 0.0
    for b in range(frames.shape[0]):
        if awake[b]:
            v, w = frames[b, F_VEL:F_VEL + 3], frames[b, F_SPIN:F_SPIN + 3]
            total += 0.5 * frames[b, F_MASS] * _dot3(v, v) + 0.5 * _quad(inertia[b], w, w)
    return total


@njit(**JIT_NO_REFCOUNT)
def solve_velocities(frames, jac, rows, iters, tol, acc):
    """Symmetric sweeps of ``stiff_rows.visit`` from the impulses ``acc`` (count, 3), at
    most ``iters``, until none changes a contact's speed by more than ``tol``; returns the
    sweeps."""
    n = rows.shape[0]
    for it in range(iters):
        largest = 0.0
        for s in range(n):
            k = s if it % 2 == 0 else n - 1 - s
            largest = max(largest, visit(frames, jac[k], rows[k], acc[k]))
        if largest <= tol:
            return it + 1
    return iters


@njit(**JIT)
def solve_positions(frames, jac, rows, h, iters, tol):
    """The split impulse: frames' velocity and spin set to what, applied to positions for
    one step, removes ``BAUMGARTE`` of each contact's overlap beyond ``K_SLOP`` (sweeps as
    ``solve_velocities``); each contact's impulse in ``K_GRIP``."""
    n = rows.shape[0]
    frames[:, F_VEL:F_VEL + 6] = 0.0
    acc = np.zeros(n)
    for it in range(iters):
        largest = 0.0
        for s in range(n):
            k = s if it % 2 == 0 else n - 1 - s
            depth = -rows[k, K_GAP] - rows[k, K_SLOP]
            if depth <= 0.0:
                continue
            lam = push_visit(frames, jac[k, 0], rows[k], acc[k], BAUMGARTE * depth / h)
            acc[k] += lam
            if jac[k, 0, J_MASS] > 0.0:
                largest = max(largest, abs(lam) / jac[k, 0, J_MASS])
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
def _tally(rows, jac, acc, frames, colliders, tally):
    """Each collider contact's impulse, with the opposite sign, on its collider: in
    ``tally`` (C, 6), the impulse (N s) and its moment about the collider's centre."""
    for k in range(rows.shape[0]):
        row = rows[k]
        c = int(row[K_COLL])
        if c < 0:
            continue
        p = -(acc[k, 0] * jac[k, 0, J_D:J_D + 3] + acc[k, 1] * jac[k, 1, J_D:J_D + 3]
              + acc[k, 2] * jac[k, 2, J_D:J_D + 3])
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
    overlap, and 1 where its velocities changed, 2 where its positions did too, 3 where a
    hit woke it.  Returns this step's contact keys and impulses, sorted, and the body
    pairs in contact (``touches``)."""
    nb = len(bodies.x)
    frames = np.zeros((nb, F_ROW))
    inertia, inv_inertia = np.zeros((nb, 3, 3)), np.zeros((nb, 3, 3))
    for b in range(nb):
        body_frame(bodies.x[b], bodies.v[b], bodies.m[b], frames[b], inertia[b],
                   inv_inertia[b])
    real_inv, real_inertia = frames[:, F_INV].copy(), inv_inertia.copy()
    awake = bodies.awake.copy()
    for b in range(nb):
        if not awake[b]:                 # asleep: an obstacle of infinite mass
            frames[b, F_INV] = 0.0
            frames[b, F_VEL:F_VEL + 6] = 0.0
            inv_inertia[b] = 0.0
    rows = _contacts(frames, bodies, scene, stats)
    keys = contact_keys(rows, nb, scene.rows.shape[0])
    if rows.shape[0] == 0:
        return keys, np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
    _pair_stats(rows, stats)
    for _ in range(2):
        start = frames.copy()
        done, push, acc, jac = _solve(frames, (inertia, inv_inertia), rows, (keys, memory),
                                      scene, awake)
        woken = _woken(rows, awake, scene.wake_speed)
        if not woken.any():
            break
        for b in np.flatnonzero(woken):  # hit hard: solved again as a body, woken
            frames[b, F_INV], inv_inertia[b] = real_inv[b], real_inertia[b]
            awake[b], stats[b, 4] = True, 3
    _tally(rows, jac, acc, done, scene.rows, tally)
    for b in range(nb):
        if awake[b]:
            _move(bodies, b, start[b], done[b] - start[b], push[b], scene, stats[b])
    order = np.argsort(keys)
    return keys[order], acc[order], touches(rows, scene.gravity, bodies.radius, scene.touch)


@njit(**JIT)
def _solve(frames, inertias, rows, keys, scene, awake):
    """The velocity and position solves of the pass from ``frames`` (left as they are;
    ``inertias``: the bodies' inertia tensors and their inverses): (the bodies' frames
    after it, their position push, the contact impulses, the contacts' directions)."""
    inertia, inv_inertia = inertias
    frames = frames.copy()
    h, gravity = scene.h, scene.gravity
    tol = TOLERANCE * max(scene.thresh, 1e-3)
    iters = min(scene.iters, max(MIN_SWEEPS, VISITS // rows.shape[0]))
    jac = jacobians(frames, inv_inertia, rows)
    push = frames.copy()
    solve_positions(push, jac, rows, h, iters, tol)
    set_targets(frames, jac, rows, h, scene.thresh)
    for b in range(frames.shape[0]):
        if awake[b]:
            frames[b, F_VEL:F_VEL + 3] += h * gravity
    free = kinetic_energy(frames, inertia, awake)
    approach_after_gravity(frames, jac, rows)
    acc = warm_start(frames, jac, rows, keys[0], keys[1])
    solve_velocities(frames, jac, rows, iters, tol, acc)
    stopped = frames.copy()
    added = bounce(frames, jac, rows, acc)
    share = energy_share(stopped, frames, inertia, awake, free)
    if share < 1.0:                                      # contacts never add energy
        frames[:] = stopped + share * (frames - stopped)
    acc[:, 0] += share * added
    return frames, push, acc, jac


@njit(**JIT)
def _woken(rows, awake, wake_speed):
    """The sleeping bodies an awake one runs into faster than ``wake_speed``."""
    woken = np.zeros(len(awake), dtype=np.bool_)
    for k in range(rows.shape[0]):
        if rows[k, K_APPROACH] > wake_speed:
            for side in (K_A, K_B):
                b = int(rows[k, side])
                if b >= 0 and not awake[b]:
                    woken[b] = True
    return woken


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
