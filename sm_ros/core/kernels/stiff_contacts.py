"""Contact points of the stiff bodies (``sm_ros/core/stiff_contact.py``): each body's rigid frame
and the few points at which it touches a collider or another stiff body.

A body's mass, centre, velocity, spin and inertia come from its particles
(``body_frame``).  Against a collider, each particle's gap is the distance between its
outline (its lattice cell, or its sphere of the contact radius) and the collider's
surface; a round body meets it as one sphere.  Of the particles in reach, a few are kept
per collider (and per body pair, ``stiff_pairs``): the deepest and the farthest along 8
directions of the contact plane, so a face keeps its outline (``SLOTS``).  A contact is a
row of ``K_*`` columns (``stiff_solve`` solves them); ``touches`` lists the body pairs that
touch for the sleep pass.
"""

import numpy as np
from numba import njit

from .colliders import C_ANG, C_BOUND, C_E, C_MU, C_POS, C_VEL, surface_gap
from .jit import JIT, JIT_NO_REFCOUNT
from .linalg import ZERO16, add_damping

#: Contact points kept per collider or body pair: the deepest and the farthest along 8
#: directions of the contact plane.
SLOTS = 9
#: Those 8 directions in the plane's two tangents: +-t1, +-t2 and the four diagonals.
AROUND = np.array([[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [0.0, -1.0], [1.0, 1.0],
                   [-1.0, -1.0], [1.0, -1.0], [-1.0, 1.0]])
#: Columns of a contact row: bodies a and b (b -1: a collider, ``K_COLL`` its row in the
#: collider rows, -1 the ground, -2 a body pair), the gap (m, < 0: overlap), the normal
#: pointing from b towards a, the contact point relative to a's and b's centres, the
#: collider's surface velocity there, friction, the target normal speed, its slot
#: (``SLOTS``: which of the pair's or collider's points it is), the position solve's
#: impulse on it (which grips like a normal impulse), the restitution, 1 where it
#: bounces this step, its approach speed before and after the step's gravity, and the
#: overlap it keeps (``SLOP_SHARE``).
K_A, K_B, K_COLL, K_GAP, K_N, K_RA, K_RB, K_SURF, K_MU, K_TARGET, K_WHO = (
    0, 1, 2, 3, 4, 7, 10, 13, 16, 17, 18)
K_GRIP, K_E, K_BOUNCE, K_APPROACH, K_FALL, K_SLOP = 19, 20, 21, 22, 23, 24
K_ROW = 25
#: Overlap a contact keeps without a position push, as a share of its radii: a push moves
#: bodies without their momentum and so changes the angular momentum a little.
SLOP_SHARE = 0.1
#: A particle whose sphere is within this gap (m) of a collider touches it (counts).
TOUCH = 1e-3
#: A particle's cell meets a surface at its edge or corner once that edge tilts this
#: share of its half length towards the surface (in proportion below: no jump at rest).
CORNER_TILT = 0.05
#: Columns of a body's frame: mass, inverse mass, centre (3), velocity (3), spin (3),
#: reach (the largest distance of a particle from the centre), bounds lo (3), hi (3).
F_MASS, F_INV, F_COM, F_VEL, F_SPIN, F_REACH, F_LO, F_HI = 0, 1, 2, 5, 8, 11, 12, 15
F_ROW = 18


@njit(**JIT)
def body_frame(x, v, m, frame, inertia_out, inv_inertia):
    """Fill ``frame`` (``F_*`` columns), the inertia tensor ``inertia_out`` and its inverse
    ``inv_inertia`` (3, 3) of a body: the rigid motion that keeps its particles' momentum
    and angular momentum, and their bounds.  Two passes over the particles, their sums in
    registers (the loops vectorise): mass, centre, velocity and bounds, then the inertia
    tensor, the angular momentum and the reach about the centre."""
    _moments(x, v, m, frame)
    a0, a1, a2, reach = _second_moments(x, v, m, frame, inertia_out)
    inv_inertia[:, :] = inverse3(inertia_out)
    for k in range(3):
        frame[F_SPIN + k] = (inv_inertia[k, 0] * a0 + inv_inertia[k, 1] * a1
                             + inv_inertia[k, 2] * a2)
    frame[F_REACH] = np.sqrt(reach)


@njit(inline='always', **JIT)
def _moments(x, v, m, frame):
    """The mass, its inverse, the centre of mass, the mean velocity and the lowest and
    highest coordinates of particles x, v (N, 3) of masses m, into ``frame``."""
    mass = cx = cy = cz = px = py = pz = 0.0
    lx = ly = lz = np.inf
    hx = hy = hz = -np.inf
    for i in range(x.shape[0]):
        w, x0, x1, x2 = m[i], x[i, 0], x[i, 1], x[i, 2]
        mass += w
        cx += w * x0
        cy += w * x1
        cz += w * x2
        px += w * v[i, 0]
        py += w * v[i, 1]
        pz += w * v[i, 2]
        lx, ly, lz = min(lx, x0), min(ly, x1), min(lz, x2)
        hx, hy, hz = max(hx, x0), max(hy, x1), max(hz, x2)
    inv = 1.0 / mass
    frame[F_MASS], frame[F_INV] = mass, inv
    frame[F_COM], frame[F_COM + 1], frame[F_COM + 2] = cx * inv, cy * inv, cz * inv
    frame[F_VEL], frame[F_VEL + 1], frame[F_VEL + 2] = px * inv, py * inv, pz * inv
    frame[F_LO], frame[F_LO + 1], frame[F_LO + 2] = lx, ly, lz
    frame[F_HI], frame[F_HI + 1], frame[F_HI + 2] = hx, hy, hz


@njit(inline='always', **JIT)
def _second_moments(x, v, m, frame, inertia_out):
    """About the centre of ``frame``, moving at its velocity: the inertia tensor
    sum m (|r|^2 I - r r^T) into ``inertia_out``; returns the angular momentum
    sum m r x (v - vel) (3 numbers) and the largest |r|^2."""
    c0, c1, c2 = frame[F_COM], frame[F_COM + 1], frame[F_COM + 2]
    u0, u1, u2 = frame[F_VEL], frame[F_VEL + 1], frame[F_VEL + 2]
    sums, reach = ZERO16, 0.0
    for i in range(x.shape[0]):
        rx, ry, rz = x[i, 0] - c0, x[i, 1] - c1, x[i, 2] - c2
        reach = max(reach, rx * rx + ry * ry + rz * rz)
        sums = add_damping(sums, m[i], rx, ry, rz, v[i, 0] - u0, v[i, 1] - u1, v[i, 2] - u2)
    sxx, syy, szz, sxy, syz, szx = sums[9:15]
    inertia_out[0, 0], inertia_out[1, 1], inertia_out[2, 2] = syy + szz, sxx + szz, sxx + syy
    inertia_out[0, 1] = inertia_out[1, 0] = -sxy
    inertia_out[0, 2] = inertia_out[2, 0] = -szx
    inertia_out[1, 2] = inertia_out[2, 1] = -syz
    return sums[6], sums[7], sums[8], reach


@njit(**JIT)
def inverse3(a):
    """Inverse of a symmetric 3x3 matrix (zeros where it is singular: a body of one
    particle or a line of them does not turn)."""
    c00 = a[1, 1] * a[2, 2] - a[1, 2] * a[2, 1]
    c01 = a[1, 2] * a[2, 0] - a[1, 0] * a[2, 2]
    c02 = a[1, 0] * a[2, 1] - a[1, 1] * a[2, 0]
    det = a[0, 0] * c00 + a[0, 1] * c01 + a[0, 2] * c02
    out = np.zeros((3, 3))
    scale = a[0, 0] + a[1, 1] + a[2, 2]
    if not abs(det) > 1e-12 * scale * scale * scale:
        return out
    out[0, 0] = c00 / det
    out[1, 0] = c01 / det
    out[2, 0] = c02 / det
    out[0, 1] = (a[0, 2] * a[2, 1] - a[0, 1] * a[2, 2]) / det
    out[1, 1] = (a[0, 0] * a[2, 2] - a[0, 2] * a[2, 0]) / det
    out[2, 1] = (a[0, 1] * a[2, 0] - a[0, 0] * a[2, 1]) / det
    out[0, 2] = (a[0, 1] * a[1, 2] - a[0, 2] * a[1, 1]) / det
    out[1, 2] = (a[0, 2] * a[1, 0] - a[0, 0] * a[1, 2]) / det
    out[2, 2] = (a[0, 0] * a[1, 1] - a[0, 1] * a[1, 0]) / det
    return out


@njit(**JIT)
def _tangents(nx, ny, nz):
    """Two unit vectors spanning the plane normal to n."""
    if abs(nx) < 0.6:
        ax, ay, az = 0.0, nz, -ny          # n x (1, 0, 0)
    else:
        ax, ay, az = -nz, 0.0, nx          # n x (0, 1, 0)
    s = np.sqrt(ax * ax + ay * ay + az * az)
    ax, ay, az = ax / s, ay / s, az / s
    return ax, ay, az, ny * az - nz * ay, nz * ax - nx * az, nx * ay - ny * ax




@njit(**JIT_NO_REFCOUNT)
def _collider_gap(rows, c, px, py, pz, radius):
    """``surface_gap`` against collider row c of ``rows``; c -1 is the ground, whose
    height is row 0's z."""
    if c < 0:
        return pz - rows[0, C_POS + 2] - radius, 0.0, 0.0, 1.0
    return surface_gap(rows[c + 1], px, py, pz, radius)


@njit(**JIT_NO_REFCOUNT)
def _slot(slots, best, gap, p, frame, tol, tangents, who):
    """Offer point p to the slots: the deepest (slot 0) and the farthest along the 8
    directions of the plane spanned by ``tangents`` (t1 then t2).  Of points within ``tol``
    of the farthest, the one farthest from the body's centre (a face's corner), of those
    within ``tol`` of the deepest, the nearest (a face's middle), not whichever rounding
    favours: the points stay from step to step."""
    dx, dy, dz = p[0] - frame[F_COM], p[1] - frame[F_COM + 1], p[2] - frame[F_COM + 2]
    a = tangents[0] * dx + tangents[1] * dy + tangents[2] * dz
    b = tangents[3] * dx + tangents[4] * dy + tangents[5] * dz
    spread = dx * dx + dy * dy + dz * dz
    if gap < best[0, 0] - tol or (gap < best[0, 0] + tol and spread < best[0, 1]):
        best[0, 0], best[0, 1], slots[0] = min(gap, best[0, 0]), spread, who
    for k in range(1, SLOTS):
        s = AROUND[k - 1, 0] * a + AROUND[k - 1, 1] * b
        if s > best[k, 0] + tol or (s > best[k, 0] - tol and spread > best[k, 1]):
            best[k, 0], best[k, 1], slots[k] = max(s, best[k, 0]), spread, who


@njit(**JIT_NO_REFCOUNT)
def _fresh(slots, best):
    slots[:] = -1
    best[:, 0] = -np.inf
    best[:, 1] = -1.0
    best[0, 0], best[0, 1] = np.inf, np.inf


@njit(**JIT_NO_REFCOUNT)
def _distinct(slots, k):
    """Whether slot k holds a point no earlier slot holds."""
    if slots[k] < 0:
        return False
    for j in range(k):
        if slots[j] == slots[k]:
            return False
    return True


@njit(**JIT)
def collider_contacts(bodies, frames, a, margin, scene, out, count, touching):
    """Append to ``out`` (from ``count``) body a's contacts with the ground (when on) and
    the collider rows 1.. of ``scene.rows`` whose bounding spheres come within ``margin``
    of its own; returns the new count.  ``touching`` (2,) counts a's particles within
    ``TOUCH`` of the ground and the plain colliders (rows 1..``scene.plain``), then of the
    others (one per particle and collider).  A round body meets each collider as the
    sphere about its centre through its outermost particles' outline: one point.  A body
    on a lattice meets it with its particles' cells (``bodies.cells``), so it rests and
    tips on its outline's edges, not on spheres inside them."""
    x, radius, frame, rows = bodies.x[a], bodies.radius[a], frames[a], scene.rows
    cell = bodies.cells[a]
    slots = np.empty(SLOTS, dtype=np.int64)
    best = np.empty((SLOTS, 2))
    tangents = np.empty(6)
    com = frame[F_COM:F_COM + 3]
    ball = frame[F_REACH] + radius
    outer = radius * np.sqrt(3.0) if _boxy(cell) else radius
    lowest = com[2] - ball if bodies.round[a] else frame[F_LO + 2] - outer
    for c in range(-1 if scene.ground_on else 0, rows.shape[0] - 1):
        if c < 0:
            if lowest - rows[0, C_POS + 2] > margin:
                continue
            nx, ny, nz = 0.0, 0.0, 1.0
        else:
            row = rows[c + 1]
            dx, dy, dz = com[0] - row[C_POS], com[1] - row[C_POS + 1], com[2] - row[C_POS + 2]
            if (np.sqrt(dx * dx + dy * dy + dz * dz)
                    > row[C_BOUND] + frame[F_REACH] + outer + margin):
                continue
            # every particle's outline lies within reach + outer of the centre: a collider
            # that far from it (a long wall whose bounding sphere holds the body) is not met
            centre_gap, nx, ny, nz = surface_gap(row, com[0], com[1], com[2], 0.0)
            if centre_gap > frame[F_REACH] + outer + margin:
                continue
        if bodies.round[a]:
            gap = _collider_row(com, a, c, (ball, radius), cell, com, rows, out[count])
            if gap < margin:
                if gap < TOUCH:
                    touching[0 if c < scene.plain else 1] += 1
                count += 1
            continue
        tangents[:] = _tangents(nx, ny, nz)
        _fresh(slots, best)
        _offer_particles((x, radius, cell), frame, (c, rows), margin, (slots, best, tangents),
                         touching, 0 if c < scene.plain else 1)
        for k in range(SLOTS):
            if _distinct(slots, k):
                _collider_row(x[slots[k]], a, c, (radius, radius), cell, com, rows,
                              out[count])
                out[count, K_WHO] = k
                count += 1
    return count


@njit(**JIT_NO_REFCOUNT)
def _offer_particles(particles, frame, collider, margin, picks, touching, side):
    """Offer to the slots (``picks``: slots, best, tangents) each particle whose outline
    (``particles``: positions, radius, cell) comes within ``margin`` of ``collider`` (its
    index and the collider rows); count in ``touching[side]`` those within ``TOUCH``."""
    x, radius, cell = particles
    c, rows = collider
    slots, best, tangents = picks
    # an outline reaches at most ``outer`` past its centre: a particle whose centre is that
    # much farther than the margin is left out without its outline's gap
    outer = _outer(cell, radius)
    for i in range(x.shape[0]):
        gap, nx, ny, nz = _collider_gap(rows, c, x[i, 0], x[i, 1], x[i, 2], 0.0)
        if gap - outer >= margin:
            continue
        gap -= _reach(cell, radius, nx, ny, nz)
        if gap < margin:
            _slot(slots, best, gap, x[i], frame, 0.25 * radius, tangents, i)
            if gap < TOUCH:
                touching[side] += 1


@njit(**JIT_NO_REFCOUNT)
def _boxy(cell):
    """Whether ``cell`` holds a lattice cell's half edges (else zeros or none: a sphere)."""
    total = 0.0
    for j in range(cell.shape[1]):
        for k in range(3):
            total += abs(cell[k, j])
    return total > 0.0


@njit(**JIT_NO_REFCOUNT)
def _outer(cell, radius):
    """How far a particle's outline reaches past its centre at most: the sum of its cell's
    half edges' lengths, or its sphere's radius (``_outline_gap``)."""
    if not _boxy(cell):
        return radius
    total = 0.0
    for k in range(3):
        total += np.sqrt(cell[0, k] ** 2 + cell[1, k] ** 2 + cell[2, k] ** 2)
    return total


@njit(**JIT_NO_REFCOUNT)
def _outline_gap(rows, c, p, radius, cell):
    """(gap, normal) of particle p's outline against collider c: its lattice cell (``cell``
    (3, 3), its half edges as columns), whose reach along the normal is the sum of
    |n . edge|; or its sphere of ``radius``."""
    gap, nx, ny, nz = _collider_gap(rows, c, p[0], p[1], p[2], 0.0)
    return gap - _reach(cell, radius, nx, ny, nz), nx, ny, nz


@njit(inline='always', **JIT)
def _reach(cell, radius, nx, ny, nz):
    """How far a particle's outline reaches past its centre along the normal n: the sum of
    |n . edge| over its cell's half edges, or its sphere's radius."""
    if not _boxy(cell):
        return radius
    reach = 0.0
    for k in range(3):
        reach += abs(nx * cell[0, k] + ny * cell[1, k] + nz * cell[2, k])
    return reach


@njit(**JIT)
def _outline_point(p, radius, cell, nx, ny, nz):
    """The point of particle p's outline that meets a surface of normal n: its sphere's,
    or its cell's face, edge or corner (each half edge taken in full once it tilts
    ``CORNER_TILT`` of its length towards the surface, in proportion below)."""
    if not _boxy(cell):
        return p[0] - radius * nx, p[1] - radius * ny, p[2] - radius * nz
    q = p.copy()
    for k in range(3):
        along = nx * cell[0, k] + ny * cell[1, k] + nz * cell[2, k]
        share = min(max(along / (CORNER_TILT * radius), -1.0), 1.0)
        for j in range(3):
            q[j] -= share * cell[j, k]
    return q[0], q[1], q[2]


@njit(**JIT)
def _collider_row(centre, a, c, radii, cell, com, rows, row):
    """Fill a contact row of body a against collider c (-1: the ground) at the outline
    about ``centre`` (a particle's, or a round body's): its cell, or its sphere of
    ``radii[0]``; it keeps an overlap of ``SLOP_SHARE`` of its particles' radius
    ``radii[1]``.  Returns the gap."""
    radius, grain = radii
    gap, nx, ny, nz = _outline_gap(rows, c, centre, radius, cell)
    px, py, pz = _outline_point(centre, radius, cell, nx, ny, nz)
    row[:] = 0.0
    row[K_A], row[K_B], row[K_COLL], row[K_GAP] = a, -1, c, gap
    row[K_N], row[K_N + 1], row[K_N + 2] = nx, ny, nz
    row[K_RA], row[K_RA + 1], row[K_RA + 2] = px - com[0], py - com[1], pz - com[2]
    coll = rows[c + 1]
    if c >= 0:                           # the collider's surface velocity at the point
        ox, oy, oz = px - coll[C_POS], py - coll[C_POS + 1], pz - coll[C_POS + 2]
        wx, wy, wz = coll[C_ANG], coll[C_ANG + 1], coll[C_ANG + 2]
        row[K_SURF] = coll[C_VEL] + wy * oz - wz * oy
        row[K_SURF + 1] = coll[C_VEL + 1] + wz * ox - wx * oz
        row[K_SURF + 2] = coll[C_VEL + 2] + wx * oy - wy * ox
    row[K_MU], row[K_E], row[K_SLOP] = coll[C_MU], coll[C_E], SLOP_SHARE * grain
    return gap


@njit(**JIT)
def _touching(row, radius, touch):
    """Whether a contact row is a body pair within ``touch`` times its contact distance
    (the sum of its bodies' ``radius``)."""
    a, b = int(row[K_A]), int(row[K_B])
    return b >= 0 and row[K_GAP] < (touch - 1.0) * (radius[a] + radius[b])


@njit(**JIT)
def touches(rows, gravity, radius, touch):
    """The body pairs of the body-pair contacts within ``touch`` times their contact
    distance (``_touching``), (c, 3): a, b and which lies above the other against
    ``gravity`` along the contact's normal (1: a, -1: b, 0: side by side or no gravity),
    one row per contact (the sleep pass's who touches whom)."""
    count = 0
    for k in range(rows.shape[0]):
        count += _touching(rows[k], radius, touch)
    out = np.empty((count, 3), dtype=np.int64)
    count = 0
    for k in range(rows.shape[0]):
        if not _touching(rows[k], radius, touch):
            continue
        up = -(rows[k, K_N] * gravity[0] + rows[k, K_N + 1] * gravity[1]
               + rows[k, K_N + 2] * gravity[2])
        out[count, 0], out[count, 1] = int(rows[k, K_A]), int(rows[k, K_B])
        out[count, 2] = 1 if up > 0.0 else (-1 if up < 0.0 else 0)
        count += 1
    return out
