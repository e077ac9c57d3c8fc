"""Published body poses: the one-pass kernel against its NumPy twin and Body.rotation()."""

import numpy as np

from sm_ros.core import BodyParams, World
from sm_ros.core.pose import BodyPose, com_apq, com_apq_numpy


def test_kernel_matches_numpy_twin():
    rng = np.random.default_rng(7)
    x, x0 = rng.normal(size=(1001, 3)), rng.normal(size=(1001, 3))
    m = rng.uniform(0.1, 3.0, 1001)
    com, apq = np.zeros(3), np.zeros((3, 3))
    com_apq(x, m, x0, com, apq)
    c2, a2 = com_apq_numpy(x, m, x0)
    np.testing.assert_allclose(com, c2, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(apq, a2, rtol=1e-12, atol=1e-12)
    com_apq(x[:, ::1][::2], m[::2], x0[::2], com, apq)       # strided views work too
    np.testing.assert_allclose(apq, com_apq_numpy(x[::2], m[::2], x0[::2])[1], rtol=1e-12)


def _turned_body(clusters):
    g = np.linspace(0.0, 0.2, 8)
    pts = np.stack(np.meshgrid(g, g, g * 0.5, indexing='ij'), -1).reshape(-1, 3)
    w = World(gravity=(0.0, 0.0, 0.0))
    masses = np.linspace(0.5, 2.0, len(pts))
    b = w.add_body(pts, masses=masses, params=BodyParams(mode='linear', clusters=clusters,
                                                          alpha=0.3))
    b.set_wrench((0.3, 0.0, 0.0), (2.0, 5.0, 40.0))
    for _ in range(40):
        w.step(1.0 / 120.0)
    return b


def test_multi_cluster_pose_equals_the_body_rotation():
    b = _turned_body(clusters=3)
    assert b.num_clusters > 1
    poser = BodyPose()
    for _ in range(2):                      # warm-started second call gives the same
        com, r = poser.pose(b)
        np.testing.assert_allclose(com, b.com(), atol=1e-14)
        np.testing.assert_allclose(r, b.rotation(), atol=1e-10)
    assert np.degrees(np.arccos((np.trace(r) - 1) / 2)) > 5.0      # it did turn
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(r) > 0.999


def test_single_cluster_pose_is_the_solvers_rotation():
    b = _turned_body(clusters=1)
    com, r = BodyPose().pose(b)
    np.testing.assert_array_equal(r, b.rotation())
    np.testing.assert_allclose(com, b.com(), atol=1e-15)


def test_forget_drops_removed_bodies():
    a, b = _turned_body(3), _turned_body(2)
    poser = BodyPose()
    poser.pose(a), poser.pose(b)
    poser.forget(keep=[b])
    assert list(poser._state) == [id(b)]
