"""
Kernels that test for inf and nan keep doing so under the kernels' fast-math flags.

The flags (``sm_ros.core.kernels.jit.FASTMATH``) keep NaN checks, but after a comparison
such as ``det > 1e-9`` LLVM folded ``np.isfinite(det)`` to True, letting ``inf`` through.
Every such guard goes through ``jit.finite`` (a comparison with the largest float); each
case here feeds inf and nan to a kernel and checks that it is refused.
"""

import math

import numba
import numpy as np
import pytest

from sm_ros.core import contact
from sm_ros.core.kernels import jit, plasticity, rotation, unit_det

BAD = (math.inf, -math.inf, math.nan)


@numba.njit(**jit.JIT)
def _guards(v, lim):
    # the pattern that was folded: a comparison, then the finiteness test of the same value
    out = np.zeros(v.shape[0], dtype=np.bool_)
    for i in range(v.shape[0]):
        s = v[i] * v[i]
        out[i] = s > lim and jit.finite(s)
    return out


def test_finite_helper_after_a_comparison():
    v = np.array([2.0, math.inf, -math.inf, math.nan, 1e200, 0.5])
    np.testing.assert_array_equal(_guards(v, 1.0), [True, False, False, False, False, False])


@pytest.mark.parametrize('bad', BAD)
def test_volume_preserving_refuses_a_non_finite_matrix(bad):
    a = np.diag([bad, 1.0, 1.0]) if not math.isnan(bad) else np.diag([2.0, bad, 1.0])
    for m in (a, np.diag([1e200, 1e200, 1e200])):             # det overflows to inf
        assert not unit_det.volume_preserving(m, np.zeros((3, 4)), np.zeros((3, 3)),
                                           np.zeros((3, 3)), 2.0)


@pytest.mark.parametrize('bad', BAD)
def test_nearest_unit_det_refuses_a_non_finite_matrix(bad):
    for f in (np.diag([abs(bad), 1.0, 1.0]), np.diag([1e200, 1e200, 1e200])):
        assert not unit_det.nearest_unit_det(f, np.zeros((3, 3)), np.zeros((3, 3)),
                                          np.zeros((3, 3)))


@pytest.mark.parametrize('bad', BAD)
def test_extract_rotation_keeps_the_rotation_of_a_non_finite_match(bad):
    q = np.array([math.cos(0.2), math.sin(0.2), 0.0, 0.0])
    for mat in (np.diag([bad, 1.0, 1.0]), np.diag([1e308, 1e308, 1e308])):  # sums overflow
        quat, rot = q.copy(), np.zeros((3, 3))
        rotation.extract_rotation(mat, quat, rot, np.zeros((4, 4)), np.zeros((4, 4)))
        np.testing.assert_array_equal(quat, q)
        assert np.all(np.isfinite(rot))


@pytest.mark.parametrize('bad', BAD)
def test_plastic_update_leaves_the_plastic_state_of_a_non_finite_match(bad):
    for a in (np.diag([bad, 1.0, 1.0]), np.diag([1e200, 1.0, 1.0])):   # the norm overflows
        sp = np.eye(3)[None].copy()
        changed = np.ones(1, dtype=np.bool_)
        clusters = (np.eye(3)[None].copy(), np.ones(1), np.array([[1.0, 0.0, 0.0, 0.0]]))
        scratch = (np.zeros(4), np.zeros((3, 3)), np.zeros((3, 3)), np.zeros((3, 3)),
                   np.zeros((4, 4)), np.zeros((4, 4)), np.zeros((3, 3)), np.zeros((3, 3)))
        n = plasticity.plastic_update(a[None].copy(), clusters, sp, (0.05, 2.0, 0.3, 1.0 / 120.0),
                                      changed, scratch)
        assert n == 0 and not changed[0]
        np.testing.assert_array_equal(sp[0], np.eye(3))


@pytest.mark.parametrize('bad', BAD)
def test_contact_pairs_skip_non_finite_particles(bad):
    n = 4
    x = np.zeros((3, n))
    x[0] = [0.0, 0.01, bad, 0.02]
    x[1, 3] = bad
    x0 = np.zeros((3, n))
    x0[0] = [0.0, 1.0, 2.0, 3.0]                       # far apart at rest: self-contact
    hb = np.zeros(n, dtype=np.int64)
    pi, pj = np.zeros(16, dtype=np.int32), np.zeros(16, dtype=np.int32)
    src = contact.PairSource(x, np.full(n, 0.01), np.zeros(n, dtype=np.int32),
                             np.ones(1, dtype=np.bool_), np.ones(1, dtype=np.bool_), x0, 0.02,
                             0.0, 0.0)
    grid = contact.GridScratch(hb, np.zeros(65, dtype=np.int64), np.zeros(n, dtype=np.int64),
                               np.zeros((n, 4)), np.zeros(n, dtype=np.int32),
                               np.zeros(64, dtype=np.int32))
    m = contact.build_pairs_grid(src, grid, pi, pj)
    assert m == 1 and (pi[0], pj[0]) == (0, 1)
    assert hb[2] == -1 and hb[3] == -1
