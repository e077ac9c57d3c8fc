"""Contacts between two stiff bodies (``sm_ros/core/stiff_contact.py``): the few particle
pairs at which they touch and the normal they share (``pair_contacts``).

The particle pairs of both bodies closer than their radii (plus the step's reach) give one
normal for the pair: a face's where one side's particles lie in a plane (of two faces, the
one along which they overlap least), else their mean direction, and each pair's gap along
it, so two flat faces meet as flat faces.  A round
body meets the other's particles with its sphere.  Rows and slots as for the colliders
(``stiff_contacts``).
"""

import numpy as np
from numba import njit

from .jit import JIT, JIT_NO_REFCOUNT
from .linalg import jacobi3
from .stiff_contacts import (F_COM, F_HI, F_LO, F_REACH, K_A, K_B, K_COLL, K_E, K_GAP,
                             K_MU, K_N, K_RA, K_RB, K_SLOP, K_WHO, SLOP_SHARE, SLOTS,
                             _distinct, _fresh, _reach, _slot, _tangents)

#: Particle pairs of two bodies count towards their contact up to this many times the sum
#: of their radii apart (plus the step's reach): two lattices' faces offset by half a
#: spacing have their nearest particles 1.12 times it apart.
PAIR_REACH = 1.25
#: A side of a body pair's contact is a face when its points' spread across their plane
#: is at most this share of their spread along it (``_pair_normal``).
FLAT = 0.1
#: A face needs this many particles (any three lie in a plane), and its normal within
#: acos of this of the pairs' mean direction (a lattice offset tilts them by 27 deg).
FACE_POINTS = 4
FACE_TILT = 0.7
#: Up to this many particle pairs near two bodies' contact, every one is tried; more (big
#: bodies, loose bounds) are swept along an axis (``close_pairs``).
FEW_PAIRS = 4096


@njit(**JIT_NO_REFCOUNT)
def _near(x, lo, hi, grow, out):
    """Indices of the particles of x inside the box lo..hi grown by ``grow``; the count."""
    count = np.int64(0)
    for i in range(x.shape[0]):
        if (x[i, 0] > lo[0] - grow and x[i, 0] < hi[0] + grow and x[i, 1] > lo[1] - grow
                and x[i, 1] < hi[1] + grow and x[i, 2] > lo[2] - grow
                and x[i, 2] < hi[2] + grow):
            out[count] = i
            count += 1
    return count


@njit(**JIT)
def pair_contacts(bodies, frames, a, b, margin, scene, out, count):
    """Append to ``out`` (from ``count``) the contacts of stiff bodies a and b
    (``stiff_solve.StiffBodies``, their frames); returns the new count.  The pair's normal
    is ``_contact_normal``'s, each particle pair's gap is along it."""
    if bodies.round[a] or bodies.round[b]:
        return _ball_pair(bodies, frames, (a, b), margin, scene, out, count)
    xa, xb, ra, rb = bodies.x[a], bodies.x[b], bodies.radius[a], bodies.radius[b]
    fa, fb = frames[a], frames[b]
    reach = PAIR_REACH * (ra + rb) + margin
    near_a = np.empty(xa.shape[0], dtype=np.int64)
    near_b = np.empty(xb.shape[0], dtype=np.int64)
    na = _near(xa, fb[F_LO:F_LO + 3], fb[F_HI:F_HI + 3], reach, near_a)
    nb = _near(xb, fa[F_LO:F_LO + 3], fa[F_HI:F_HI + 3], reach, near_b)
    if na == 0 or nb == 0:
        return count
    close = close_pairs(xa, xb, near_a[:na], near_b[:nb], reach)
    n, face = _contact_normal(bodies, (a, b), close, _pair_normal(xa, xb, close, reach))
    if not np.any(n != 0.0):
        return count
    tangents = np.empty(6)
    tangents[:] = _tangents(n[0], n[1], n[2])
    slots = np.empty(SLOTS, dtype=np.int64)
    best = np.empty((SLOTS, 2))
    _fresh(slots, best)
    _offer_pairs((xa, xb, close), (n, face), _outlines(bodies, a, b, n, face) + (margin,), fa,
                 (slots, best, tangents), np.empty(3))
    for k in range(SLOTS):
        if _distinct(slots, k):
            _pair_row(bodies, frames, (a, b), slots[k], (n, face), scene, out[count])
            out[count, K_WHO] = k
            count += 1
    return count


@njit(**JIT_NO_REFCOUNT)
def _offer_pairs(close, normal, reach, frame, picks, mid):
    """Offer to the slots (``picks``: slots, best, tangents) the middle of each particle
    pair of ``close`` (a's positions, b's, the pairs) whose gap along the pair's
    ``normal`` (and whether a face gave it) is within its margin (``reach``: how far a's
    and b's outlines reach towards each other, ``_outlines``, and the margin); ``mid``
    scratch (3,)."""
    xa, xb, pairs = close
    n, face = normal
    ra, rb, margin = reach
    slots, best, tangents = picks
    for p in range(pairs.shape[0]):
        i, j = pairs[p, 0], pairs[p, 1]
        gap = _gap_of(xa[i, 0] - xb[j, 0], xa[i, 1] - xb[j, 1], xa[i, 2] - xb[j, 2], n,
                      face) - ra - rb
        if gap < margin:
            for k in range(3):
                mid[k] = 0.5 * (xa[i, k] + xb[j, k])
            _slot(slots, best, gap, mid, frame, 0.25 * ra, tangents, i * xb.shape[0] + j)


@njit(**JIT)
def _ball_pair(bodies, frames, pair, margin, scene, out, count):
    """Append the contacts of a body pair of which one is round: its sphere (``ball`` of
    ``collider_contacts``) against the other's particles, each with its own normal, at
    most ``SLOTS`` of them (the deepest and the farthest around), or against the other's
    sphere at one point; returns the new count.  Normals point from b towards a."""
    a, b = pair
    ball, other = (a, b) if bodies.round[a] else (b, a)
    sign = 1.0 if ball == a else -1.0
    centre = frames[ball, F_COM:F_COM + 3]
    big = frames[ball, F_REACH] + bodies.radius[ball]
    slop = SLOP_SHARE * (bodies.radius[a] + bodies.radius[b])
    if bodies.round[other]:
        x = frames[other:other + 1, F_COM:F_COM + 3]
        small = frames[other, F_REACH] + bodies.radius[other]
    else:
        x, small = bodies.x[other], bodies.radius[other]
    n = np.empty(3)
    if x.shape[0] == 1:
        gap = _sphere_normal(centre, x[0], big + small, n)
        if gap < margin:
            _body_row(pair, gap, n * sign, x[0] + small * n, frames, (scene, slop),
                        out[count])
            count += 1
        return count
    gap = _ball_on_face(centre, x, (big, small), margin, n)
    if gap < margin:                     # the other's particles in reach form a face
        _body_row(pair, gap, n * sign, centre - big * n, frames, (scene, slop), out[count])
        return count + 1
    slots = np.empty(SLOTS, dtype=np.int64)
    best = np.empty((SLOTS, 2))
    tangents = np.empty(6)
    _sphere_normal(centre, frames[other, F_COM:F_COM + 3], 0.0, n)
    tangents[:] = _tangents(n[0], n[1], n[2])
    _fresh(slots, best)
    for j in range(x.shape[0]):
        gap = _sphere_normal(centre, x[j], big + small, n)
        if gap < margin:
            _slot(slots, best, gap, x[j], frames[ball], 0.25 * small, tangents, j)
    for k in range(SLOTS):
        if _distinct(slots, k):
            j = slots[k]
            gap = _sphere_normal(centre, x[j], big + small, n)
            _body_row(pair, gap, n * sign, x[j] + small * n, frames, (scene, slop),
                        out[count])
            out[count, K_WHO] = k
            count += 1
    return count


@njit(**JIT)
def _ball_on_face(centre, x, radii, margin, n):
    """Where the particles x within reach of a ball (about ``centre``; ``radii``: the
    ball's and the particles') form a face (``_pair_normal``'s rule), the ball's gap to
    that face's plane, with ``n`` its normal towards the ball: it rolls on the face, not
    over its particles; else inf."""
    big, small = radii
    side, pull = np.zeros(10), np.zeros(3)
    count = np.int64(0)
    for j in range(x.shape[0]):
        gap = _sphere_normal(centre, x[j], big + small, n)
        if gap < margin + small:
            _add_point(side, x[j], 1.0)
            pull += n
            count += 1
    size = np.sqrt(pull @ pull)
    if not size > 0.0:
        return np.inf
    pull /= size
    flat, normal = _side_flatness(side, count, pull)
    face, normal = _face(flat, normal, pull)
    if not face:
        return np.inf
    n[:] = normal
    deepest, scratch = np.inf, np.empty(3)
    for j in range(x.shape[0]):
        if _sphere_normal(centre, x[j], big + small, scratch) < margin + small:
            along = ((centre[0] - x[j, 0]) * n[0] + (centre[1] - x[j, 1]) * n[1]
                     + (centre[2] - x[j, 2]) * n[2])
            deepest = min(deepest, along - big - small)
    return deepest


@njit(**JIT)
def _sphere_normal(centre, p, reach, n):
    """The gap between a sphere about ``centre`` and one about p whose radii sum to
    ``reach``; ``n`` the unit direction from p to the centre (up when they coincide)."""
    d = centre - p
    dist = np.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
    if dist > 0.0:
        n[:] = d / dist
    else:
        n[0], n[1], n[2] = 0.0, 0.0, 1.0
    return dist - reach


@njit(**JIT)
def _body_row(pair, gap, n, point, frames, rules, row):
    """Fill a body-pair contact row of ``gap``, normal n (from b towards a) at ``point``;
    ``rules``: the scene (friction, restitution) and the overlap kept."""
    a, b = pair
    scene, slop = rules
    row[:] = 0.0
    row[K_A], row[K_B], row[K_COLL], row[K_GAP] = a, b, -2, gap
    for k in range(3):
        row[K_N + k] = n[k]
        row[K_RA + k] = point[k] - frames[a, F_COM + k]
        row[K_RB + k] = point[k] - frames[b, F_COM + k]
    row[K_MU], row[K_E], row[K_SLOP] = scene.pair_mu, scene.pair_e, slop


@njit(**JIT)
def close_pairs(xa, xb, near_a, near_b, reach):
    """The particle pairs (i of a, j of b) of the particles ``near_a`` and ``near_b``
    closer than ``reach``, (count, 2), in the order of ``near_a``: every pair tried where
    there are few (``FEW_PAIRS``), else each of a's against b's sorted along the axis they
    spread most on, only over those within ``reach`` of it along that axis."""
    count = np.int64(0)
    if len(near_a) * len(near_b) <= FEW_PAIRS:
        out = np.empty((len(near_a) * len(near_b), 2), dtype=np.int64)
        for i in near_a:
            for j in near_b:
                if _closer(xa, xb, i, j, reach):
                    out[count, 0], out[count, 1] = i, j
                    count += 1
        return out[:count]
    out = np.empty((16, 2), dtype=np.int64)
    axis = _widest_axis(xb, near_b)
    keys = np.empty(len(near_b))
    for q in range(len(near_b)):
        keys[q] = xb[near_b[q], axis]
    order = np.argsort(keys)
    keys = keys[order]
    sorted_b = near_b[order]
    for i in near_a:
        start = np.searchsorted(keys, xa[i, axis] - reach)
        for q in range(start, len(keys)):
            if keys[q] > xa[i, axis] + reach:
                break
            if _closer(xa, xb, i, sorted_b[q], reach):
                out = append_pair(out, count, i, sorted_b[q])
                count += 1
    return out[:count]


@njit(**JIT_NO_REFCOUNT)
def _closer(xa, xb, i, j, reach):
    """Whether particle i of xa and j of xb are closer than ``reach``."""
    dx, dy, dz = xa[i, 0] - xb[j, 0], xa[i, 1] - xb[j, 1], xa[i, 2] - xb[j, 2]
    return dx * dx + dy * dy + dz * dz < reach * reach


@njit(**JIT_NO_REFCOUNT)
def _widest_axis(x, index):
    """The axis along which the particles ``index`` of x spread most."""
    widest, axis = -1.0, 0
    for k in range(3):
        lo, hi = np.inf, -np.inf
        for j in index:
            lo, hi = min(lo, x[j, k]), max(hi, x[j, k])
        if hi - lo > widest:
            widest, axis = hi - lo, k
    return axis


@njit(**JIT)
def append_pair(out, count, i, j):
    """``out`` (rows of index pairs, ``count`` used) with (i, j) as row ``count``, grown
    to twice its size when full."""
    if count == out.shape[0]:
        grown = np.empty((2 * count, 2), dtype=np.int64)
        grown[:count] = out
        out = grown
    out[count, 0], out[count, 1] = i, j
    return out


@njit(**JIT)
def _pair_normal(xa, xb, close, reach):
    """(the mean direction of a body pair's particle pairs in reach (``close``), from b
    towards a, weighted by how far in (zeros: none in reach); a's side and b's: whether
    its particles in reach form a face (``_face``), and that face's normal).

    Each body's particles in reach of the other's lie in a plane where that body meets the
    other with a face; a face's normal holds whatever the faces' offset or an edge resting
    on it (the particle pairs' own directions would tilt with the offset and push the faces
    apart sideways).  ``_contact_normal`` chooses."""
    pull = np.zeros(3)
    side_a, side_b = np.zeros(10), np.zeros(10)     # weight, sum of w x (3), of w x x^T (6)
    seen_a = np.zeros(xa.shape[0], dtype=np.bool_)
    seen_b = np.zeros(xb.shape[0], dtype=np.bool_)
    count_a = count_b = np.int64(0)
    for p in range(close.shape[0]):
        i, j = close[p, 0], close[p, 1]
        dx, dy, dz = xa[i, 0] - xb[j, 0], xa[i, 1] - xb[j, 1], xa[i, 2] - xb[j, 2]
        d = np.sqrt(dx * dx + dy * dy + dz * dz)
        if not d > 0.0:
            continue
        w = reach - d
        pull[0] += w * dx / d
        pull[1] += w * dy / d
        pull[2] += w * dz / d
        _add_point(side_a, xa[i], w)
        _add_point(side_b, xb[j], w)
        count_a += not seen_a[i]
        count_b += not seen_b[j]
        seen_a[i] = seen_b[j] = True
    size = np.sqrt(pull[0] ** 2 + pull[1] ** 2 + pull[2] ** 2)
    if not size > 0.0:
        return np.zeros(3), (False, pull), (False, pull)
    pull /= size
    flat_a, normal_a = _side_flatness(side_a, count_a, pull)
    flat_b, normal_b = _side_flatness(side_b, count_b, pull)
    return pull, _face(flat_a, normal_a, pull), _face(flat_b, normal_b, pull)


@njit(**JIT)
def _contact_normal(bodies, pair, close, sides):
    """(the normal of a body pair's contact, whether a face gave it) from
    ``_pair_normal``'s ``sides``: of the sides that form a face, the one along whose
    normal the particle pairs overlap least (the separating axis, as rigid-body engines
    pick their reference face), so a box tipped over another's edge meets it with its own
    face, not with the other's top face, below which its particles past the edge dip.
    Where neither side is a face (an edge on an edge, a corner), the mean direction: then
    a pair's gap is its own distance, not its distance along the normal (``_gap_of``)."""
    pull, (face_a, n_a), (face_b, n_b) = sides
    if face_a and face_b:
        if _least_gap(bodies, pair, close, n_a) >= _least_gap(bodies, pair, close, n_b):
            return n_a, True
        return n_b, True
    if face_a:
        return n_a, True
    if face_b:
        return n_b, True
    return pull, False


@njit(**JIT)
def _least_gap(bodies, pair, close, n):
    """The smallest gap along a face normal n between the outlines (``_outlines``) of
    the particle pairs ``close`` of the body pair (a, b)."""
    a, b = pair
    xa, xb = bodies.x[a], bodies.x[b]
    ra, rb = _outlines(bodies, a, b, n, True)
    least = np.inf
    for p in range(close.shape[0]):
        i, j = close[p, 0], close[p, 1]
        least = min(least, _gap_of(xa[i, 0] - xb[j, 0], xa[i, 1] - xb[j, 1],
                                   xa[i, 2] - xb[j, 2], n, True))
    return least - ra - rb


@njit(**JIT)
def _side_flatness(side, count, pull):
    """``_flatness`` of a side of ``count`` distinct particles; (inf, pull) below
    ``FACE_POINTS`` of them (any three lie in a plane)."""
    if count < FACE_POINTS:
        return np.inf, pull.copy()
    return _flatness(side)


@njit(**JIT)
def _face(flat, normal, pull):
    """(whether a side of flatness ``flat`` and that ``normal`` is a face against the
    mean direction ``pull`` (unit): flat enough, its normal within acos ``FACE_TILT`` of
    ``pull``; the normal turned along ``pull``)."""
    along = normal @ pull
    return flat <= FLAT and abs(along) >= FACE_TILT, (normal if along >= 0.0 else -normal)


@njit(**JIT_NO_REFCOUNT)
def _gap_of(dx, dy, dz, n, face):
    """A particle pair's distance d along the normal n of a face, else its length."""
    if face:
        return dx * n[0] + dy * n[1] + dz * n[2]
    return np.sqrt(dx * dx + dy * dy + dz * dz)


@njit(**JIT_NO_REFCOUNT)
def _add_point(side, p, w):
    """Add point p with weight w to a side's sums (``_pair_normal``)."""
    side[0] += w
    side[1] += w * p[0]
    side[2] += w * p[1]
    side[3] += w * p[2]
    side[4] += w * p[0] * p[0]
    side[5] += w * p[1] * p[1]
    side[6] += w * p[2] * p[2]
    side[7] += w * p[0] * p[1]
    side[8] += w * p[0] * p[2]
    side[9] += w * p[1] * p[2]


@njit(**JIT)
def _flatness(side):
    """(the smallest over the middle spread of a side's points, the direction of the
    smallest): 0 for points in a plane, 1 or more for points along a line or in a lump."""
    mean = side[1:4] / side[0]
    cov = np.empty((3, 3))
    cov[0, 0] = side[4] / side[0] - mean[0] * mean[0]
    cov[1, 1] = side[5] / side[0] - mean[1] * mean[1]
    cov[2, 2] = side[6] / side[0] - mean[2] * mean[2]
    cov[0, 1] = cov[1, 0] = side[7] / side[0] - mean[0] * mean[1]
    cov[0, 2] = cov[2, 0] = side[8] / side[0] - mean[0] * mean[2]
    cov[1, 2] = cov[2, 1] = side[9] / side[0] - mean[1] * mean[2]
    axes = np.empty((3, 3))
    jacobi3(cov, axes)
    spread = np.array([cov[0, 0], cov[1, 1], cov[2, 2]])
    order = np.argsort(spread)
    if not spread[order[1]] > 0.0:
        return np.inf, axes[:, order[0]].copy()
    return max(spread[order[0]], 0.0) / spread[order[1]], axes[:, order[0]].copy()


@njit(**JIT)
def _outlines(bodies, a, b, n, face):
    """How far a particle's outline of body a and of body b reach towards the other along
    a face's normal n: their lattice cells' (``stiff_contacts._reach``), so an edge or
    corner resting on a face is as sharp as the body's outline; their spheres' radii
    where no face gave the normal or a body has no lattice."""
    ra, rb = bodies.radius[a], bodies.radius[b]
    if not face:
        return ra, rb
    return (_reach(bodies.cells[a], ra, n[0], n[1], n[2]),
            _reach(bodies.cells[b], rb, n[0], n[1], n[2]))


@njit(**JIT)
def _pair_row(bodies, frames, pair, who, normal, scene, row):
    """Fill a contact row for the particle pair ``who`` (a's index times b's count plus
    b's) of the body pair (a, b); ``normal``: ``_contact_normal``'s."""
    a, b = pair
    n, face = normal
    xa, xb = bodies.x[a], bodies.x[b]
    ra, rb = _outlines(bodies, a, b, n, face)
    i, j = who // xb.shape[0], who % xb.shape[0]
    gap = _gap_of(xa[i, 0] - xb[j, 0], xa[i, 1] - xb[j, 1], xa[i, 2] - xb[j, 2], n,
                  face) - ra - rb
    point = 0.5 * (xa[i] + xb[j]) + 0.5 * (rb - ra) * n
    slop = SLOP_SHARE * (bodies.radius[a] + bodies.radius[b])
    _body_row(pair, gap, n, point, frames, (scene, slop), row)
