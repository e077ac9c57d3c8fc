"""A change of a body's material adds no energy (``sm_ros.core.param_energy``)."""

import numpy as np
import pytest

from sm_ros.core import BodyParams, World
from sm_ros.core import param_energy as PE


def _moving_body(mode='linear', alpha=0.3, steps=1):
    """A box in zero gravity, spinning and stretching, ``steps`` in (deformed, moving)."""
    x0 = np.stack(np.meshgrid(*[np.arange(5) * 0.02] * 3, indexing='ij'), -1).reshape(-1, 3)
    centre = x0.mean(axis=0)
    v = np.cross([0.0, 0.0, 2.0], x0 - centre) + 0.8 * (x0 - centre) * [1.0, -1.0, 0.0]
    world = World(gravity=(0.0, 0.0, 0.0))
    body = world.add_body(x0, 0.01, BodyParams(mode=mode, alpha=alpha, beta=0.3, clusters=2),
                          velocities=v + [0.1, 0.0, 0.0])
    for _ in range(steps):
        world.step(1.0 / 120.0)
    return body


def _energy(body):
    return 0.5 * float(body.m @ (body.v ** 2).sum(axis=1)) + PE.elastic_energy(body)


def test_rigid_velocity_is_a_rigid_motion_with_the_same_momenta():
    rng = np.random.default_rng(4)
    x, m = rng.random((40, 3)), rng.uniform(0.5, 2.0, 40)
    centre = m @ x / m.sum()
    rigid = np.array([0.3, -0.2, 0.1]) + np.cross([1.0, 2.0, -0.5], x - centre)
    np.testing.assert_allclose(PE.rigid_velocity(x, rigid, m), rigid, atol=1e-12)
    v = rng.normal(size=(40, 3))
    fit = PE.rigid_velocity(x, v, m)
    np.testing.assert_allclose(m @ fit, m @ v, atol=1e-12)
    np.testing.assert_allclose(np.cross(x, fit).T @ m, np.cross(x, v).T @ m, atol=1e-12)


@pytest.mark.parametrize('mode', ['linear', 'quadratic', 'rigid'])
def test_a_stiffer_material_takes_its_energy_from_the_internal_motion(mode):
    """Alpha 0.3 -> 0.4 a step after a stretch: kinetic plus elastic energy does not grow,
    the internal motion gives up exactly what the elastic energy gained, and the momentum
    and angular momentum stay."""
    body = _moving_body(mode)
    before, internal = _energy(body), PE.relative_energy(body)
    gain = -PE.elastic_energy(body)
    momentum, spin = body.momentum(), body.angular_momentum()
    body.set_params(alpha=0.4)
    gain += PE.elastic_energy(body)
    assert 0.0 < gain < internal
    assert _energy(body) <= before * (1.0 + 1e-12)
    assert PE.relative_energy(body) == pytest.approx(internal - gain, rel=1e-9)
    np.testing.assert_allclose(body.momentum(), momentum, rtol=0.0, atol=1e-14)
    np.testing.assert_allclose(body.angular_momentum(), spin, rtol=0.0, atol=1e-14)


def test_more_elastic_energy_than_internal_motion_stops_the_internal_motion():
    """Alpha 0.3 -> 0.9 at the stretch's widest: the gain outweighs the internal motion,
    which is all given up (the rigid motion stays)."""
    body = _moving_body(steps=3)
    internal, gain = PE.relative_energy(body), -PE.elastic_energy(body)
    rigid = PE.rigid_velocity(body.x, body.v, body.m)
    body.set_params(alpha=0.9)
    assert PE.elastic_energy(body) + gain > internal > 0.0
    np.testing.assert_allclose(body.v, rigid, rtol=0.0, atol=1e-12)


def test_a_softer_material_and_a_body_at_rest_keep_their_velocities():
    body = _moving_body(alpha=0.6)
    v = body.v.copy()
    body.set_params(alpha=0.3, damping=0.1)
    assert body.v.tobytes() == v.tobytes()
    resting = World(gravity=(0.0, 0.0, 0.0)).add_body(np.random.default_rng(1).random((20, 3)),
                                                       0.01, BodyParams(alpha=0.2))
    resting.set_params(alpha=0.9, beta=0.5)
    assert not resting.v.any()
