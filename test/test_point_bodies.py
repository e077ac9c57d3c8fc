"""Bodies of one particle: a point has no shape to turn or deform, so whatever its mode,
clusters, plasticity, damping or torque it moves as a point mass, on the compiled step that
holds its x as a (3, 1) block (its record)."""

import numpy as np
import pytest

from sm_ros.core import BodyParams, Ground, World

PLASTIC = dict(plastic_yield=0.01, plastic_creep=1.0, plastic_max=0.5)
CONFIGS = [BodyParams(mode='rigid', damping=0.05, **PLASTIC),
           BodyParams(mode='linear', clusters=2, **PLASTIC),
           BodyParams(mode='quadratic', **PLASTIC),
           BodyParams(mode='quadratic', clusters=2, damping=0.05)]


@pytest.mark.parametrize('params', CONFIGS, ids=lambda p: f'{p.mode}-{p.clusters}')
def test_a_point_body_falls_as_a_point_mass_and_stops_on_the_ground(params):
    g, h, z0, vx = 9.81, 1.0 / 120.0, 0.5, 0.3
    world = World(gravity=(0.0, 0.0, -g))
    world.set_colliders(ground=Ground(height=0.0, friction=0.0))
    body = world.add_body(np.array([[0.0, 0.0, z0]]), masses=0.2, params=params,
                          velocities=np.array([[vx, 0.0, 0.0]]))
    body.set_wrench((0.0, 0.0, 0.0), (0.0, 0.0, 1.0))     # a torque moves no point
    assert len(world._split_bodies(h)[1]) == 1         # a record
    n = 20
    for _ in range(n):
        world.step(h)
    # symplectic Euler: v_k = v0 - k g h, x_n = x0 + h sum v_k
    z = z0 - g * h * h * n * (n + 1) / 2.0
    np.testing.assert_allclose(body.x[0], [vx * h * n, 0.0, z], rtol=0, atol=1e-12)
    for _ in range(200):
        world.step(h)
    assert body.x[0, 2] == pytest.approx(0.0, abs=1e-9)      # resting on the ground
    assert body.x[0, 0] > vx * h * n                         # no friction: still sliding
    assert np.isfinite(body.x).all()
