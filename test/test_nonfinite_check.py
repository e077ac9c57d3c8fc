"""The one-call non-finite check of every body (sm_ros.nonfinite) against np.isfinite."""

import math

import numpy as np
import pytest

from sm_ros.nonfinite import first_nonfinite, NonFiniteCheck


class _Body:
    """What the check reads of a body: x and v buffers (and is_finite for odd layouts)."""

    def __init__(self, n, order='C', rng=None):
        rng = rng or np.random.default_rng(0)
        self._x = np.asarray(rng.normal(size=(n, 3)), order=order)
        self._v = np.asarray(rng.normal(size=(n, 3)), order=order)

    def is_finite(self):
        return bool(np.isfinite(self._x).all() and np.isfinite(self._v).all())


def test_kernel_finds_inf_and_nan_and_nothing_else():
    from numba.typed import List
    edge = np.finfo(np.float64).max
    ok = np.array([0.0, -0.0, edge, -edge, 5e-324, 1e300])
    bufs = List([ok.copy(), ok.copy(), ok.copy()])
    assert first_nonfinite(bufs, 0) == -1
    for bad in (math.inf, -math.inf, math.nan):
        for k in range(3):
            for i in (0, 3, 5):
                bufs[k][i] = bad
                assert first_nonfinite(bufs, 0) == k
                assert first_nonfinite(bufs, k + 1) == -1
                bufs[k][i] = ok[i]


@pytest.mark.parametrize('order', ['C', 'F'])
def test_check_agrees_with_isfinite_body_by_body(order):
    rng = np.random.default_rng(1)
    bodies = [_Body(n, order, rng) for n in (1, 7, 1000, 33)]
    check = NonFiniteCheck()
    assert check.bad_bodies(bodies) == [] and check.bad_bodies([]) == []
    for trial in range(40):
        picks = rng.choice(len(bodies), size=rng.integers(1, 3), replace=False)
        for k in picks:
            a = bodies[k]._x if rng.random() < 0.5 else bodies[k]._v
            a[rng.integers(a.shape[0]), rng.integers(3)] = rng.choice(
                [math.inf, -math.inf, math.nan])
        expected = [b for b in bodies if not b.is_finite()]
        assert check.bad_bodies(bodies) == expected == [bodies[k] for k in sorted(picks)]
        for k in picks:                               # repaired in place (a reset)
            bodies[k]._x[~np.isfinite(bodies[k]._x)] = 0.0
            bodies[k]._v[~np.isfinite(bodies[k]._v)] = 0.0
        assert check.bad_bodies(bodies) == []
    assert check.rebuilds == 1                        # same bodies, same buffers


def test_check_follows_new_bodies():
    rng = np.random.default_rng(2)
    a, b = _Body(10, rng=rng), _Body(20, rng=rng)
    check = NonFiniteCheck()
    assert check.bad_bodies([a]) == []
    b._v[3, 2] = math.nan
    assert check.bad_bodies([a, b]) == [b]           # a body joined
    assert check.rebuilds == 2
    assert check.bad_bodies([b]) == [b] and check.rebuilds == 3
    strided = _Body(8, rng=rng)
    strided._x = np.zeros((8, 6))[:, ::2]             # no flat view: asked one by one
    strided._x[5, 1] = -math.inf
    assert check.bad_bodies([strided, a]) == [strided]
    strided._x[5, 1] = 0.0
    assert check.bad_bodies([strided, a]) == []


def test_a_core_body_keeps_its_buffers():
    """The check holds views of each body's x and v from the first time it sees the body:
    every way the core changes a body's state or rebuilds it writes into those buffers."""
    from sm_ros.core import BodyParams, World
    world = World()
    pts = np.random.default_rng(3).uniform(-0.1, 0.1, (64, 3))
    body = world.add_body(pts, params=BodyParams(mode='linear', clusters=2))
    check = NonFiniteCheck()
    x, v = body._x, body._v
    world.step(0.01)
    body.set_state(x=pts + 1.0, v=np.ones((64, 3)))
    body.set_params(mode='quadratic', clusters=1, plastic_yield=0.1, plastic_creep=0.5,
                    plastic_max=2.0)
    body.set_kinematic([0, 1], pts[:2])
    body.set_wrench([1.0, 0, 0], [0, 0, 1.0])
    world.step(0.01)
    body.reset()
    world.step(0.01)
    assert body._x is x and body._v is v
    assert check.bad_bodies([body]) == []
    body._v[7, 1] = math.inf                # what a step that blew up leaves behind
    assert check.bad_bodies([body]) == [body]
