"""The one loop of the fused particle passes (Eq. 13-14 with damping, the speed count and
the next step's sums in one sweep), shared by the one-cluster pass
(``packed_pass._int_single_fused``) and the set layout's runs (``sets._sets_fused_lin``).

The loop serves bodies whose particles all have one mass (``wuni`` > 0): it sums
unweighted and scales once, so a body of several masses takes the two-loop passes instead
(``Body._packed_ok``, ``sets._fused_pass``).  ``damp_constants`` folds the damping towards a
rigid field into three multiply-adds a component.
"""

from numba import njit

from .jit import JIT, U
from .linalg import ZERO12, ZERO16, add_damping, add_outer


@njit(inline='always', **JIT)
def below_ground(y, gz):
    """1 if the height ``y`` is below the ground's ``gz``, else 0 (no ground: ``gz`` is
    -inf)."""
    return int(y < gz)


@njit(inline='always', **JIT)
def damp_constants(damp, k_damp, field, ref):
    """The damping v += k (c + o x (p - r) - v) of a field (c, o) about r (``field`` = c0
    c1 c2 o0 o1 o2, ``ref`` = r), folded into v <- km v + f + o' x p: returns (km, f0, f1,
    f2, o'0, o'1, o'2), the identity map (1, 0, ..., 0) without ``damp``
    (``_fused_range``: 3 multiply-adds a component)."""
    c0, c1, c2, o0, o1, o2 = field
    r0, r1, r2 = ref
    kd = k_damp if damp else 0.0
    q0, q1, q2 = kd * o0, kd * o1, kd * o2
    return (1.0 - kd, kd * c0 - (q1 * r2 - q2 * r1), kd * c1 - (q2 * r0 - q0 * r2),
            kd * c2 - (q0 * r1 - q1 * r0), q0, q1, q2)


@njit(inline='always', **JIT)
def _fused_range(start, end, particles, wuni, gmap, damp, field, motion, point, limits):
    """One loop over particles start..end of ``particles`` = (x, v, x0): the damping
    (``field``, ``damp_constants``; with ``damp``), Eq. 13-14 towards the goal G x0 + b
    (``gmap``: G row by row, then b; ``motion`` = (alpha / h, h, h times the acceleration
    (3))), and the 12 sums of the new state about ``point`` k (``_rest_sums``'s);
    ``limits`` = (lim2, gz).  Returns (sum of
    |g - p|^2 as ``advance``, speeds over sqrt(lim2), the 12 sums, new heights below gz:
    the ground's test, so that a run the ground cannot reach skips its collider pass; gz
    is -inf without a ground), then,
    with ``damp``, the next step's 13 damping sums of the new state about the same point
    (rows 3-14 of ``damping.damp_sums_range``'s: sum w v, sum w d x v, the six second
    moments of d; then W; zeros without ``damp``).

    Every particle weighs ``wuni``: the loop sums unweighted and scales the sums once.
    """
    t = _fused_loop(start, end, particles, gmap, damp, field, motion, point, limits)
    return (t[0], t[1], wuni * t[2], wuni * t[3], wuni * t[4], wuni * t[5], wuni * t[6],
            wuni * t[7], wuni * t[8], wuni * t[9], wuni * t[10], wuni * t[11], wuni * t[12],
            wuni * t[13], t[14], wuni * t[15], wuni * t[16], wuni * t[17], wuni * t[18],
            wuni * t[19], wuni * t[20], wuni * t[21], wuni * t[22], wuni * t[23],
            wuni * t[24], wuni * t[25], wuni * t[26], wuni * (end - start) if damp else 0.0)


@njit(inline='always', **JIT)
def _fused_loop(start, end, particles, gmap, damp, field, motion, point, limits):
    """``_fused_range``'s loop, its sums unweighted.

    Vectorises across particles (unit-stride columns, unsigned index, every constant in a
    local: one lane a particle; the 12 sums, the error and the count as vector accumulators
    reduced once a call).  Inlined by Numba into ``_int_single_fused`` (one cluster, x0 the
    rest positions) and ``sets._sets_fused_lin`` (a run of one set, x0 its offsets y).

    Damped, ``_fused_damped`` runs it block by block between the damping and the damping
    sums of the new state, each block read from the first level cache.
    """
    if damp:
        return _fused_damped(start, end, particles, gmap, field, motion, point, limits)
    return _fused_plain(start, end, particles, gmap, motion, point, limits) + (
        0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)


@njit(inline='always', **JIT)
def _fused_plain(start, end, particles, gmap, motion, point, limits):
    """``_fused_loop`` without damping: (err2, over, the 12 sums, low)."""
    x, v, x0 = particles
    alpha_h, h, hx, hy, hz = motion
    k0, k1, k2 = point
    lim2, gz = limits
    l00, l01, l02, l10, l11, l12, l20, l21, l22, b0, b1, b2 = gmap
    err2 = 0.0
    over = 0
    low = 0
    sums = ZERO12
    for i in range(U(start), U(end)):
        a0, a1, a2 = x0[i, 0], x0[i, 1], x0[i, 2]
        p0, p1, p2 = x[i, 0], x[i, 1], x[i, 2]
        e0 = l00 * a0 + l01 * a1 + l02 * a2 + b0 - p0
        e1 = l10 * a0 + l11 * a1 + l12 * a2 + b1 - p1
        e2 = l20 * a0 + l21 * a1 + l22 * a2 + b2 - p2
        v0 = v[i, 0] + alpha_h * e0 + hx
        v1 = v[i, 1] + alpha_h * e1 + hy
        v2 = v[i, 2] + alpha_h * e2 + hz
        y0 = p0 + h * v0
        y1 = p1 + h * v1
        y2 = p2 + h * v2
        x[i, 0] = y0
        x[i, 1] = y1
        x[i, 2] = y2
        v[i, 0] = v0
        v[i, 1] = v1
        v[i, 2] = v2
        err2 += e0 * e0 + e1 * e1 + e2 * e2
        over += (v0 * v0 + v1 * v1 + v2 * v2) > lim2
        low += below_ground(y2, gz)
        sums = add_outer(sums, y0 - k0, y1 - k1, y2 - k2, a0, a1, a2)
    err2 += 0.0 * (sums[0] + sums[1] + sums[2])
    return (err2, over) + sums + (low,)


#: Particles a damped loop takes at a time: its three sweeps find a block in the first
#: level cache, and none of them holds so many accumulators that they leave the registers.
DAMP_BLOCK = 256


@njit(inline='always', **JIT)
def _damp_block(lo, hi, x, v, field):
    """v <- km v + f + o x p for particles lo..hi (``damp_constants``' folded damping)."""
    km, f0, f1, f2, o0, o1, o2 = field
    for i in range(U(lo), U(hi)):
        p0, p1, p2 = x[i, 0], x[i, 1], x[i, 2]
        v[i, 0] = km * v[i, 0] + f0 + o1 * p2 - o2 * p1
        v[i, 1] = km * v[i, 1] + f1 + o2 * p0 - o0 * p2
        v[i, 2] = km * v[i, 2] + f2 + o0 * p1 - o1 * p0


@njit(inline='always', **JIT)
def _sum12(a, b):
    """The sum of two 12-tuples, entry by entry."""
    return (a[0] + b[0], a[1] + b[1], a[2] + b[2], a[3] + b[3], a[4] + b[4], a[5] + b[5],
            a[6] + b[6], a[7] + b[7], a[8] + b[8], a[9] + b[9], a[10] + b[10], a[11] + b[11])


@njit(inline='always', **JIT)
def _fused_damped(start, end, particles, gmap, field, motion, point, limits):
    """``_fused_loop`` with damping, ``DAMP_BLOCK`` particles at a time: the damping, the
    plain loop (``_fused_plain``) and the damping sums of the new state
    (``damp_sums_uniform``); returns the plain loop's 15 values and the 12 damping sums."""
    x, v, _ = particles
    k0, k1, k2 = point
    err2, over, low = 0.0, 0, 0
    shape = damped = ZERO12
    for lo in range(start, end, DAMP_BLOCK):
        hi = min(lo + DAMP_BLOCK, end)
        _damp_block(lo, hi, x, v, field)
        t = _fused_plain(lo, hi, particles, gmap, motion, point, limits)
        err2 += t[0]
        over += t[1]
        low += t[14]
        shape = _sum12(shape, t[2:14])
        damped = _sum12(damped, damp_sums_uniform(lo, hi, x, v, 1.0, k0, k1, k2)[:12])
    return (err2, over) + shape + (low,) + damped


@njit(inline='always', **JIT)
def damp_sums_uniform(lo, hi, x, v, wuni, k0, k1, k2):
    """Rows 3-14 of ``damping.damp_sums_range``'s sums (sum w v, sum w d x v, the six
    second moments of d = x - k), then W, for particles that all weigh ``wuni``: summed
    unweighted and scaled once (12 products a particle, not 18).  Inlined by Numba into the
    one-loop passes (``packed._pass``, ``sets._sets_fused_lin``) for a block or run the
    colliders or the speed cap moved after their loop (``_fused_loop`` takes the same
    sums); they take sum w d from their shape sums."""
    sums = ZERO16
    for k in range(U(lo), U(hi)):
        sums = add_damping(sums, 1.0, x[k, 0] - k0, x[k, 1] - k1, x[k, 2] - k2,
                           v[k, 0], v[k, 1], v[k, 2])
    return (wuni * sums[3], wuni * sums[4], wuni * sums[5], wuni * sums[6], wuni * sums[7],
            wuni * sums[8], wuni * sums[9], wuni * sums[10], wuni * sums[11],
            wuni * sums[12], wuni * sums[13], wuni * sums[14], wuni * (hi - lo))
