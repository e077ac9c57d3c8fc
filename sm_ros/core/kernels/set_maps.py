"""What the set layout makes of its per-set sums (``sets_sums.py``): per-cluster sums
(``sets_reduce``, Eq. 7-9) and the per-set goal maps of Eq. 23, one affine (or quadratic)
map a set from its clusters' goals (``sets_maps``).
"""

from collections import namedtuple

from numba import njit

from .jit import JIT, JIT_NO_REFCOUNT

#: The set layout's set-cluster pairs: each set's clusters (``ptr`` into ``cluster_ids``) and their
#: number (``cnt``), the set's sum of phi(y) (``phi``), each pair's offset t_ks from the
#: cluster's rest centre (``pair_offsets``) and each set's origin o_s (``org``).
SetClusters = namedtuple('SetClusters', 'ptr cluster_ids cnt phi pair_offsets org')


@njit(**JIT_NO_REFCOUNT)
def _quad_map(rest_lin, k, pm):
    """Cluster k's quadratic features as polynomials of z = x0 - cm0_k: q~ = P phi(z) with
    P into ``pm`` (9 x 10); q-hat = G_k z has no constant term (rest_off = -G_k cm0_k), so
    column 0 is zero, rows 0-2 are [0, G_k] and rows 3-8 (q_a q_c) hold only the degree-2
    columns 4-9."""
    for r in range(9):
        for fi in range(10):
            pm[r, fi] = 0.0
    for a in range(3):
        for j in range(3):
            pm[a, 1 + j] = rest_lin[k, a, j]
    for r in range(6):
        a = r if r < 3 else r - 3                  # features 3..8: q0^2, q1^2, q2^2,
        c = r if r < 3 else (r - 2) % 3            # q0 q1, q1 q2, q2 q0
        row = 3 + r
        for j in range(3):
            pm[row, 4 + j] = rest_lin[k, a, j] * rest_lin[k, c, j]
        pm[row, 7] = rest_lin[k, a, 0] * rest_lin[k, c, 1] + rest_lin[k, a, 1] * rest_lin[k, c, 0]
        pm[row, 8] = rest_lin[k, a, 1] * rest_lin[k, c, 2] + rest_lin[k, a, 2] * rest_lin[k, c, 1]
        pm[row, 9] = rest_lin[k, a, 2] * rest_lin[k, c, 0] + rest_lin[k, a, 0] * rest_lin[k, c, 2]


@njit(**JIT_NO_REFCOUNT)
def sets_reduce(part, pairs, sref, rest_lin, ref, quad, out, work):
    """Per-cluster accumulators ``out`` (1, clusters, 12 or 30) from the per-set sums.

    Set s contributes sum_{i in s} w (x - ref_k) phi(y)^T = (U_s + (r_s - ref_k) Phi_s^T) /
    n_s (w = m / n_s) to each of its clusters k.  That polynomial of the set's rest offset
    y is re-expanded about cluster k's rest centre, z = x0 - cm0_k = y + t_ks (``stp``,
    per set-cluster pair): 12 (30) multiply-adds a pair, summed per cluster in ``out``
    itself (3 x 4 or 3 x 10, the size of the final row).  Only then is each cluster's sum
    mapped once to its features q-hat = G_k z (and q~ = P_k phi(z)): the map, 9 x 10 in
    the quadratic mode, costs per cluster instead of per pair.  ``pairs``:
    ``SetClusters``; ``work`` = ((2, 3, 10), (9, 10)) scratch.
    """
    wk, pm = work
    out[0, :, :] = 0.0
    u = wk[0]
    _expand(part, pairs, sref, ref, out, u, quad)
    if quad:
        _map_quad(rest_lin, out, u, pm)
    else:
        _map_lin(rest_lin, out, u)


@njit(inline='always', **JIT)
def _set_sums(part, s, width, u):
    """Set s's sums over the chunks into ``u`` (3, ``width``)."""
    for a in range(3):
        for fi in range(width):
            acc = 0.0
            for chunk in range(part.shape[0]):
                acc += part[chunk, s, a * width + fi]
            u[a, fi] = acc


@njit(inline='always', **JIT)
def _expand(part, pairs, sref, ref, out, u, quad):
    """``sets_reduce``'s sums of every set-cluster pair about the cluster: the set's sums
    about its reference ``sref[s]`` moved to the cluster's ``ref[k]`` and into the
    cluster's features (``_pair_quad`` or ``_pair_lin``)."""
    sptr, scl, scnt = pairs.ptr, pairs.cluster_ids, pairs.cnt
    sphi, stp = pairs.phi, pairs.pair_offsets
    for s in range(part.shape[1]):
        _set_sums(part, s, 10 if quad else 4, u)
        inv_n = 1.0 / scnt[s]
        for j in range(sptr[s], sptr[s + 1]):
            k = scl[j]
            t = (stp[j, 0], stp[j, 1], stp[j, 2])
            for a in range(3):
                shift = (inv_n, sref[s, a] - ref[k, a])
                row = out[0, k]
                if quad:
                    _pair_quad(row, a, u, shift, sphi, s, t)
                else:
                    _pair_lin(row, a, u, shift, sphi, s, t)


@njit(inline='always', **JIT)
def _pair_quad(row, a, u, shift, sphi, s, t):
    """Component a's 10 quadratic sums of set s (``u[a]``), moved by dr and averaged
    (``shift`` = (1 / its count, dr); ``sphi[s]`` its phi sums), added to row[10 a ..]
    in the features of z = y + t."""
    inv_n, dr = shift
    t0, t1, t2 = t
    b = 10 * a
    v0 = inv_n * (u[a, 0] + dr * sphi[s, 0])
    v1 = inv_n * (u[a, 1] + dr * sphi[s, 1])
    v2 = inv_n * (u[a, 2] + dr * sphi[s, 2])
    v3 = inv_n * (u[a, 3] + dr * sphi[s, 3])
    v4 = inv_n * (u[a, 4] + dr * sphi[s, 4])
    v5 = inv_n * (u[a, 5] + dr * sphi[s, 5])
    v6 = inv_n * (u[a, 6] + dr * sphi[s, 6])
    v7 = inv_n * (u[a, 7] + dr * sphi[s, 7])
    v8 = inv_n * (u[a, 8] + dr * sphi[s, 8])
    v9 = inv_n * (u[a, 9] + dr * sphi[s, 9])
    # phi(y + t): z_j = y_j + t_j, z_a z_c = y_a y_c + t_c y_a + t_a y_c + t_a t_c
    row[b] += v0
    row[b + 1] += v1 + t0 * v0
    row[b + 2] += v2 + t1 * v0
    row[b + 3] += v3 + t2 * v0
    row[b + 4] += v4 + 2.0 * t0 * v1 + t0 * t0 * v0
    row[b + 5] += v5 + 2.0 * t1 * v2 + t1 * t1 * v0
    row[b + 6] += v6 + 2.0 * t2 * v3 + t2 * t2 * v0
    row[b + 7] += v7 + t1 * v1 + t0 * v2 + t0 * t1 * v0
    row[b + 8] += v8 + t2 * v2 + t1 * v3 + t1 * t2 * v0
    row[b + 9] += v9 + t0 * v3 + t2 * v1 + t2 * t0 * v0


@njit(inline='always', **JIT)
def _pair_lin(row, a, u, shift, sphi, s, t):
    """``_pair_quad`` for the rigid/linear mode's 4 sums (1 and z = y + t), to row[4 a ..]."""
    inv_n, dr = shift
    b = 4 * a
    v0 = inv_n * (u[a, 0] + dr * sphi[s, 0])
    row[b] += v0
    row[b + 1] += inv_n * (u[a, 1] + dr * sphi[s, 1]) + t[0] * v0
    row[b + 2] += inv_n * (u[a, 2] + dr * sphi[s, 2]) + t[1] * v0
    row[b + 3] += inv_n * (u[a, 3] + dr * sphi[s, 3]) + t[2] * v0


@njit(inline='always', **JIT)
def _map_quad(rest_lin, out, u, pm):
    """Each cluster's quadratic sums mapped once to its features (q-hat and q~)."""
    for k in range(out.shape[1]):
        _quad_map(rest_lin=rest_lin, k=k, pm=pm)
        row = out[0, k]
        for a in range(3):
            for fi in range(10):
                u[a, fi] = row[10 * a + fi]
        for a in range(3):
            row[a] = u[a, 0]
            for jj in range(3):
                row[3 + 9 * a + jj] = (pm[jj, 1] * u[a, 1] + pm[jj, 2] * u[a, 2]
                                       + pm[jj, 3] * u[a, 3])
            for jj in range(3, 9):
                acc = 0.0
                for fi in range(4, 10):
                    acc += pm[jj, fi] * u[a, fi]
                row[3 + 9 * a + jj] = acc


@njit(inline='always', **JIT)
def _map_lin(rest_lin, out, u):
    """Each cluster's sums mapped once to its features q-hat = G_k z."""
    for k in range(out.shape[1]):
        row = out[0, k]
        for a in range(3):
            for fi in range(4):
                u[a, fi] = row[4 * a + fi]
        for a in range(3):
            row[a] = u[a, 0]
            for jj in range(3):
                row[3 + 3 * a + jj] = (rest_lin[k, jj, 0] * u[a, 1] + rest_lin[k, jj, 1] * u[a, 2]
                                       + rest_lin[k, jj, 2] * u[a, 3])


@njit(**JIT_NO_REFCOUNT)
def sets_maps(pairs, rest_lin, match, ref, quad, out, work):
    """Goal maps ``gm`` (sets, 3, 10): mean over the set's clusters of each goal polynomial.

    Also ``sref`` <- mean of the set's cluster centres (the reference point of the per-set
    sums of the next step).  Rigid/linear: goal_k = goal_lin_k (y + o_s) + goal_off_k.
    Quadratic: each cluster's goal T_k q~ + goal_off_k as a polynomial of z = x0 - cm0_k,
    ``ck`` (clusters, 3, 10), once per cluster; per set-cluster pair only its re-expansion
    about the set's origin (z = y + t_ks, ``stp``: 20 multiply-adds a row).  ``pairs``:
    ``SetClusters``; ``match`` = (trans, goal_lin, goal_off) of the clusters; ``out`` =
    (gm, sref); ``work`` = (pm (9, 10), ck) scratch.
    """
    sptr, scl, scnt = pairs.ptr, pairs.cluster_ids, pairs.cnt
    sorg, stp = pairs.org, pairs.pair_offsets
    trans, goal_lin, goal_off = match
    gm, sref = out
    pm, ck = work
    ns = gm.shape[0]
    nphi = 10 if quad else 4
    if quad:
        for k in range(ck.shape[0]):
            _quad_map(rest_lin=rest_lin, k=k, pm=pm)
            for a in range(3):
                ck[k, a, 0] = goal_off[k, a]
                for fi in range(1, 4):
                    ck[k, a, fi] = (trans[k, a, 0] * pm[0, fi] + trans[k, a, 1] * pm[1, fi]
                                    + trans[k, a, 2] * pm[2, fi])
                for fi in range(4, 10):
                    acc = 0.0
                    for jj in range(3, 9):
                        acc += trans[k, a, jj] * pm[jj, fi]
                    ck[k, a, fi] = acc
    for s in range(ns):
        for a in range(3):
            sref[s, a] = 0.0
            for fi in range(nphi):
                gm[s, a, fi] = 0.0
        o0, o1, o2 = sorg[s, 0], sorg[s, 1], sorg[s, 2]
        for j in range(sptr[s], sptr[s + 1]):
            k = scl[j]
            for a in range(3):
                sref[s, a] += ref[k, a]
            if quad:
                t0, t1, t2 = stp[j, 0], stp[j, 1], stp[j, 2]
                for a in range(3):
                    c0, c1, c2, c3 = ck[k, a, 0], ck[k, a, 1], ck[k, a, 2], ck[k, a, 3]
                    c4, c5, c6 = ck[k, a, 4], ck[k, a, 5], ck[k, a, 6]
                    c7, c8, c9 = ck[k, a, 7], ck[k, a, 8], ck[k, a, 9]
                    # c phi(y + t) as a polynomial of y
                    gm[s, a, 0] += (c0 + c1 * t0 + c2 * t1 + c3 * t2 + c4 * t0 * t0
                                    + c5 * t1 * t1 + c6 * t2 * t2 + c7 * t0 * t1 + c8 * t1 * t2
                                    + c9 * t2 * t0)
                    gm[s, a, 1] += c1 + 2.0 * c4 * t0 + c7 * t1 + c9 * t2
                    gm[s, a, 2] += c2 + 2.0 * c5 * t1 + c7 * t0 + c8 * t2
                    gm[s, a, 3] += c3 + 2.0 * c6 * t2 + c8 * t1 + c9 * t0
                    gm[s, a, 4] += c4
                    gm[s, a, 5] += c5
                    gm[s, a, 6] += c6
                    gm[s, a, 7] += c7
                    gm[s, a, 8] += c8
                    gm[s, a, 9] += c9
            else:
                # goal_k = goal_lin_k x0 + goal_off_k with x0 = y + o
                for a in range(3):
                    gm[s, a, 0] += (goal_lin[k, a, 0] * o0 + goal_lin[k, a, 1] * o1
                                    + goal_lin[k, a, 2] * o2 + goal_off[k, a])
                    gm[s, a, 1] += goal_lin[k, a, 0]
                    gm[s, a, 2] += goal_lin[k, a, 1]
                    gm[s, a, 3] += goal_lin[k, a, 2]
        inv_n = 1.0 / scnt[s]
        for a in range(3):
            sref[s, a] *= inv_n
            for fi in range(nphi):
                gm[s, a, fi] *= inv_n
