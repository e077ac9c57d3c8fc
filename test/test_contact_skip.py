"""Shortcuts of the contact pass (what saves it time): what it skips must never drop
a contact, and what it gathers must be what the general path reads.

``solve_bodies`` puts a carried body's particles back through the boxes and spheres at
its end only where one can be inside (``margin``: near them at the start of the pass,
moved by a pair, below the ground, or moved by ``margin`` or more); these tests compare
it with the full pass (``margin`` 0: every particle) in scenes where a body is pushed
into a wall, and show that skipping without the rule would leave a particle inside.
The later sweeps visit pairs of two carried bodies from compact rows
(``compact_row``, written by the first sweep once it changed something, the others
before the second sweep), checked against a NumPy twin.
"""

import numpy as np

from sm_ros.core import contact as C
from sm_ros.core.contact_state import (NO_WALLS, ContactLaw, ContactParticles, PairList,
                                      WallCandidates, carried_bodies_for, pair_sweep_for,
                                      report_for)
from sm_ros.core.kernels.colliders import Colliders

H = 1 / 120
THRESH = 2 * 9.81 * H
NO_COLLIDERS = Colliders(False, np.zeros(4), np.zeros((0, 8)), np.zeros((0, 6)), THRESH,
                         np.zeros(8), 0.0)
WALL = np.array([[0.05, -1.0, -1.0, 0.2, 1.0, 1.0, 0.5, 0.0]])   # box x in [0.05, 0.2]


def _scene():
    """A light two-particle body A 3 mm from the wall, a heavy one-particle body B
    overlapping A's first particle by 8 mm from the other side: B pushes A into the wall."""
    X = np.ascontiguousarray(np.array([[0.047, 0.047, 0.035],
                                       [0.0, 0.02, 0.0],
                                       [0.3, 0.3, 0.3]]))
    V = np.zeros((3, 3))
    W = np.array([1 / 0.01, 1 / 0.01, 1 / 10.0])
    B = np.array([0, 0, 1], np.int32)
    off = np.array([0, 2, 3])
    return X, V, W, B, off


def _body_rows(X, V, W, off, cpl=None):
    """The carried bodies ``Contact.run`` gives ``solve_bodies`` (every body carried
    unless ``cpl`` says otherwise) and the bodies' bounding boxes
    (``wall_candidates``)."""
    nb = len(off) - 1
    cpl = np.ones(nb, np.bool_) if cpl is None else cpl
    bw = np.zeros(nb)
    C.body_inverse_masses(W, off, bw)
    bodies = carried_bodies_for(off, bw, cpl)
    C.body_velocities(X, V, 1.0 / W, bodies, X.copy(), np.ones(nb, np.bool_), np.zeros(6))
    # the boxes of the bodies at a pair-list build just now (``body_overlaps``)
    box = np.array([np.concatenate([X[:, off[b]:off[b + 1]].min(axis=1),
                                    X[:, off[b]:off[b + 1]].max(axis=1)]) for b in range(nb)])
    return bodies, box


def _law(sweeps):
    """The law ``Contact.run`` gives ``solve_bodies`` at ``H`` (no warm start)."""
    return ContactLaw(0.5, 0.0, THRESH, H, sweeps, 0.01 * THRESH, 0.0)


def _solve(X, V, W, B, off, boxes, ground, cand_margin, margin):
    """Run the pass as ``Contact.run`` does (inverse masses, body velocities, wall
    candidates ``cand_margin`` from the boxes, ``solve_bodies``); returns (X, V, found)."""
    X = X.copy()
    V = V.copy()
    nb = len(off) - 1
    n = X.shape[1]
    bodies, box = _body_rows(X, V, W, off)
    col = Colliders(True, ground, boxes, np.zeros((0, 6)), THRESH, np.zeros(nb), 0.0)
    walls = WallCandidates(np.zeros(n, np.int64), np.zeros(nb + 1, np.int64), margin)
    m = C.wall_candidates(X, bodies, col, cand_margin, walls, np.ones(nb, np.bool_), box,
                          np.zeros(6))
    found = C.solve_bodies(
        ContactParticles(X, V, W, np.full(n, 0.01), B, np.zeros(n, np.uint8)),
        PairList(np.array([0], np.int32), np.array([2], np.int32), 1), pair_sweep_for(1),
        bodies, _law(8), col, walls._replace(particles=walls.particles[:m]), report_for(nb))
    return X, V, found


def test_body_pushed_into_a_wall_is_put_out_like_the_full_pass():
    X, V, W, B, off = _scene()
    no_ground = np.zeros(4)
    full = _solve(X, V, W, B, off, WALL, no_ground, 0.001, 0.0)
    assert full[2] == 1
    # the pair moves A by ~8 mm: without the put-out its particles end inside the wall
    # (a skip that only looked at the wall candidates would drop this contact)
    bad = _solve(X, V, W, B, off, WALL, no_ground, 0.001, np.inf)
    assert bad[0][0, 0] > 0.051 and bad[0][0, 1] > 0.051
    # the rule: moved by the margin or more -> through the colliders, as the full pass
    # (candidates found 2 cm from the wall: A is pushed out inside the sweeps too)
    for cm, margin in ((0.001, 0.001), (0.02, 0.02), (0.02, 0.001)):
        full = _solve(X, V, W, B, off, WALL, no_ground, cm, 0.0)
        got = _solve(X, V, W, B, off, WALL, no_ground, cm, margin)
        np.testing.assert_array_equal(got[0], full[0])
        np.testing.assert_array_equal(got[1], full[1])
        assert got[0][0, :2].max() <= 0.05


def test_resting_body_near_the_ground_is_put_out_like_the_full_pass():
    # A rests 1 mm above the ground, B presses it down: the ground check alone (no box,
    # the margin infinite as Contact.run passes it) gives the full pass's result
    X, V, W, B, off = _scene()
    X[0] = [0.0, 0.02, 0.0]
    X[1] = 0.0
    X[2] = [0.011, 0.011, 0.023]
    ground = np.array([1.0, 0.01, 0.5, 0.0])
    full = _solve(X, V, W, B, off, np.zeros((0, 8)), ground, 0.001, 0.0)
    got = _solve(X, V, W, B, off, np.zeros((0, 8)), ground, 0.001, np.inf)
    assert full[2] == 1
    np.testing.assert_array_equal(got[0], full[0])
    np.testing.assert_array_equal(got[1], full[1])
    assert got[0][2].min() >= 0.01


def test_compact_rows_match_numpy():
    # six bodies (0-4 of two particles: body 3 soft, per particle; body 4 with a pinned
    # particle; body 5 of one) in two rows; first in the sweep a pair overlapping by 5 mm
    # (the first sweep changes something, a second one runs: its row is written before
    # the second sweep, the later pairs' rows by the first sweep as it lists them), then
    # pairs 21 mm apart (listed, active where a side is carried, not touching) and one 84
    # mm apart (not active); the rows against a NumPy twin (every pair's law the
    # carried one, ``tg`` 2, as a resting heap's last step left it: a row keeps the
    # compact path only with that law, the others take the general one)
    rng = np.random.default_rng(3)
    nb = 6
    n = 2 * nb - 1
    X = np.zeros((3, n))
    X[0, :10] = 0.021 * (np.arange(10) // 2)          # body b < 5: particles 2b, 2b + 1
    X[1, :10] = 0.3 * (np.arange(10) % 2)             # its two particles 30 cm apart
    X[0, 10] = X[0, 8] + 0.015                        # body 5 overlaps particle 8
    X = np.ascontiguousarray(X)
    V = np.ascontiguousarray(rng.normal(scale=0.01, size=(3, n)))
    B = np.minimum(np.arange(n) // 2, 5).astype(np.int32)
    off = np.array([0, 2, 4, 6, 8, 10, 11])
    W = np.full(n, 10.0)
    W[9] = 0.0
    R = np.full(n, 0.01)
    pi = np.array([8, 0, 2, 4, 6, 1, 3, 5, 7, 0], np.int32)
    pj = np.array([10, 2, 4, 6, 8, 3, 5, 7, 9, 8], np.int32)   # (0, 8): 84 mm
    bodies, _ = _body_rows(X, V, W, off, np.array([True, True, True, False, True, True]))
    cpl, bw = bodies.carried, bodies.inv_mass
    npairs = len(pi)
    sweep = pair_sweep_for(npairs)
    sweep.target[:] = 2.0
    sweep.rows[:] = np.nan
    sweep.row_index[:] = -1
    active, cf, cij = sweep.active, sweep.rows, sweep.row_index
    x0, v0 = X.copy(), V.copy()
    C.solve_bodies(ContactParticles(X, V, W, R, B, np.zeros(n, np.uint8)),
                   PairList(pi, pj, npairs), sweep, bodies, _law(2), NO_COLLIDERS, NO_WALLS,
                   report_for(nb))
    assert not np.array_equal(X[:, 10], x0[:, 10])      # the overlap was pushed apart
    # the twin: active pairs (a carried side, closer than 1.25 (r_i + r_j)), in order
    i, j = pi.astype(int), pj.astype(int)
    bi, bj = B[i], B[j]
    ci = (bi != bj) & cpl[bi] & (bw[bi] > 0) & (W[i] > 0)
    cj = (bi != bj) & cpl[bj] & (bw[bj] > 0) & (W[j] > 0)
    d = x0[:, i] - x0[:, j]
    act = (ci | cj) & ((d ** 2).sum(axis=0) < (1.25 * 0.02) ** 2)
    na = int(act.sum())
    np.testing.assert_array_equal(active[:na], np.flatnonzero(act))
    both = (ci & cj)[act]
    assert both.any() and not both.all()
    np.testing.assert_array_equal(cij[4, :na], both.astype(np.int32))
    ia, ja = i[act][both], j[act][both]
    np.testing.assert_array_equal(cij[:4, :na][:, both], np.stack([ia, ja, B[ia], B[ja]]))
    da = x0[:, ia] - x0[:, ja]
    want = np.concatenate([da, da - H * (v0[:, ia] - v0[:, ja]), (R[ia] + R[ja])[None]])
    np.testing.assert_allclose(cf[:, :na][:, both], want, rtol=0, atol=1e-15)


def test_a_first_sweep_that_changes_nothing_writes_no_compact_rows():
    # a resting bin's pass: every listed pair active, none touching; the pass ends after
    # its first sweep and leaves the rows' buffers as they were (writing them would cost
    # a resting heap time every step for nothing)
    X = np.zeros((3, 3))
    X[0] = [0.0, 0.0205, 0.041]
    sweep = pair_sweep_for(2)
    sweep.rows[:] = np.nan
    sweep.row_index[:] = -1
    X1, _ = _solve_chain(X, 8, sweep)
    np.testing.assert_array_equal(X1, X)
    assert np.isnan(sweep.rows).all() and (sweep.row_index == -1).all()


def _solve_chain(X, iters, sweep=None):
    """Three one-particle bodies carried as a whole on a line (C, B, A: particles 0, 1,
    2; pairs (0, 1), (1, 2) in that order), at rest, no colliders; ``solve_bodies``
    with at most ``iters`` sweeps.  Returns X, V after it."""
    X = np.ascontiguousarray(X.copy())
    V = np.zeros((3, 3))
    W = np.full(3, 10.0)
    B = np.arange(3, dtype=np.int32)
    bodies, _ = _body_rows(X, V, W, np.arange(4))
    C.solve_bodies(ContactParticles(X, V, W, np.full(3, 0.01), B, np.zeros(3, np.uint8)),
                   PairList(np.array([0, 1], np.int32), np.array([1, 2], np.int32), 2),
                   pair_sweep_for(2) if sweep is None else sweep, bodies, _law(iters),
                   NO_COLLIDERS, NO_WALLS, report_for(3))
    return X, V


def test_resting_body_pushed_by_a_pair_later_in_the_sweep_still_responds():
    # C rests 0.5 mm clear of B; A overlaps B by 5 mm.  The first sweep meets (C, B)
    # apart, then pushes B 2.5 mm into C: that sweep changed something, so the sweeps go
    # on (the stop after one sweep is only for a sweep that changed nothing at all)
    X = np.zeros((3, 3))
    X[0] = [0.0, 0.0205, 0.0355]
    one, _ = _solve_chain(X, 1)
    assert one[0, 1] - one[0, 0] < 0.0185                 # one sweep leaves C, B overlapping
    got, V = _solve_chain(X, 8)
    # the sweeps (not exact in 8: a Gauss-Seidel chain) leave both under 0.1 mm
    assert got[0, 1] - got[0, 0] > 0.02 - 1e-4
    assert got[0, 2] - got[0, 1] > 0.02 - 1e-4
    np.testing.assert_allclose((got - X).sum(axis=1), 0.0, atol=1e-15)   # equal masses
    np.testing.assert_allclose(V.sum(axis=1), 0.0, atol=1e-12)
    # C, apart at its pair's first visit, is pushed by position only: the carried law,
    # no bounce (it kept the law of the pair that had its index before: with the
    # per-particle one, C left at 0.16 m/s, B and A at 0.08)
    np.testing.assert_allclose(V, 0.0, atol=1e-12)


def test_a_first_sweep_that_changes_nothing_ends_the_pass_exactly():
    # all three clear of each other (listed, active, nothing to do): one sweep and eight
    # give the same state, bit for bit
    X = np.zeros((3, 3))
    X[0] = [0.0, 0.0205, 0.041]
    np.testing.assert_array_equal(_solve_chain(X, 1)[0], _solve_chain(X, 8)[0])
    np.testing.assert_array_equal(_solve_chain(X, 8)[0], X)


def _solve_chain_acc(self_pair):
    """The chain of ``_solve_chain`` with B 5 mm into A (the pairs act in every sweep),
    A of two particles (the second 0.5 m away), 8 sweeps; ``self_pair``: the list also
    holds A's own pair (far apart, it never acts), a row of one carried body, so the
    later sweeps check whether a pair's particles were moved on their own before they
    take its compact row.  Returns X, V, acc."""
    X = np.zeros((3, 4))
    X[0] = [0.0, 0.0205, 0.0355, 0.5355]
    V = np.zeros((3, 4))
    W = np.full(4, 10.0)
    B = np.array([0, 1, 2, 2], np.int32)
    off = np.array([0, 1, 2, 4])
    nb = 3
    bodies, _ = _body_rows(X, V, W, off)
    pi = np.array([0, 1, 2] if self_pair else [0, 1], np.int32)
    pj = np.array([1, 2, 3] if self_pair else [1, 2], np.int32)
    m = len(pi)
    sweep = pair_sweep_for(m)
    C.solve_bodies(ContactParticles(X, V, W, np.full(4, 0.01), B, np.zeros(4, np.uint8)),
                   PairList(pi, pj, m), sweep, bodies, _law(8), NO_COLLIDERS, NO_WALLS,
                   report_for(nb))
    return X, V, sweep.impulse


def test_compact_rows_with_and_without_rows_of_one_body():
    # only a row of one carried body (self-collision) can move a carried body's particle
    # on its own (then its pairs leave the compact rows); without one in the list the
    # later sweeps do not look at the moved flags: the same pass either way
    Xa, Va, acca = _solve_chain_acc(False)
    Xb, Vb, accb = _solve_chain_acc(True)
    assert acca[1, 1] > 0.0                    # (B, A) held the overlap apart
    np.testing.assert_array_equal(acca, accb[:, :2])
    assert not accb[:, 2].any()
    np.testing.assert_array_equal(Xa, Xb)
    np.testing.assert_array_equal(Va, Vb)
