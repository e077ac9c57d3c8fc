"""The compiled per-step poses of the collider pass (sm_ros.core.collider_motion)."""

import math

import numpy as np

from sm_ros.core import Box, Capsule, Sphere, World
from sm_ros.core import collider_motion as CM
from sm_ros.core.colliders import ColliderSet


def _set():
    """Five colliders: static, two on paths (one with a rotation), two commanded."""
    rz = (0.0, 0.0, math.sin(0.4), math.cos(0.4))
    items = [
        Box(lo=(-1, -1, -0.1), hi=(1, 1, 0), name='table'),
        Capsule(center=(0.1, 0, 0.05), radius=0.02, length=0.06, name='a', kinematic=True,
                path=((0.05, (0.05, 0, 0.05)), (0.08, (0.05, 0, 0.2), rz),
                      (0.1, (0.0, 0.1, 0.2)))),
        Sphere(center=(0, 0, 1), radius=0.1, name='b', kinematic=True),
        Capsule(center=(-0.1, 0, 0.05), radius=0.02, length=0.06, name='c', kinematic=True,
                path=((0.07, (-0.05, 0, 0.05), rz),)),
        Box(lo=(2, 2, 0), hi=(3, 3, 1), name='d', kinematic=True),
    ]
    return ColliderSet(items)


def _state(colliders):
    return (colliders.mode.copy(), colliders.pos.copy(), colliders.quat.copy(),
            colliders.moves.copy(), colliders.rows.copy())


def _args(colliders, h, t):
    return colliders.motion_arrays(), colliders.keys, colliders.rows, h, t


def test_compiled_poses_match_the_python_twin_step_by_step():
    # paths through their keyframes and past their end, commanded moves that end, start
    # anew and are cut short, with rotations: the kernel and its twin agree every step
    h = 1 / 240
    a, b = _set(), _set()
    rz = (0.0, math.sin(1.2), 0.0, math.cos(1.2))
    for k in range(60):
        if k == 3:
            for cs in (a, b):
                cs.move('b', (0.2, 0.0, 1.0), rz, duration=0.02)
                cs.move('d', (2.5, 2.5, 0.7), (0, 0, 0, 1), duration=0.1)
        if k == 20:
            for cs in (a, b):
                cs.move('d', (2.4, 2.5, 0.7), rz, duration=0.05)     # cut short
        na = CM.advance_poses(*_args(a, h, k * h))
        nb = CM.advance_reference(*_args(b, h, k * h))
        assert na == nb
        np.testing.assert_array_equal(a.done, b.done)
        a.done[:] = 0
        b.done[:] = 0
        for x, y in zip(_state(a), _state(b)):
            np.testing.assert_allclose(x, y, rtol=0, atol=1e-12)
    assert (a.mode == CM.IDLE).all()
    np.testing.assert_allclose(a.pos[1], (0.0, 0.1, 0.2), atol=1e-12)
    np.testing.assert_allclose(a.pos[4], (2.4, 2.5, 0.7), atol=1e-12)         # the centre
    assert not a.rows[:, 13:19].any()                    # all at rest again


def test_a_commanded_move_does_not_change_another_colliders_path():
    # a commanded move of one collider leaves the others' scripted paths on their own clock
    # (the former loop read the move's elapsed time as the world time for the colliders
    # after it)
    h = 1 / 120
    w1, w2 = World(), World()
    caps = [Capsule(center=(0, 0, 1), radius=0.05, length=0.1, name='mover', kinematic=True),
            Capsule(center=(1, 0, 1), radius=0.05, length=0.1, name='player', kinematic=True,
                    path=((1.0, (1.0, 1.0, 1.0)),))]
    w1.set_colliders(capsules=caps)
    w2.set_colliders(capsules=caps)
    for k in range(60):
        if k == 30:
            w1.move_collider('mover', (0.5, 0, 1), duration=0.5)
        w1.step(h)
        w2.step(h)
    np.testing.assert_allclose(w1.collider_pose('player')[0], (1.0, 0.5, 1.0), atol=1e-12)
    np.testing.assert_array_equal(w1.collider_pose('player')[0], w2.collider_pose('player')[0])
    np.testing.assert_allclose(w1.collider_pose('mover')[0], (0.25, 0, 1), atol=1e-12)
