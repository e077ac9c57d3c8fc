"""A change of a body's material gives up the elastic energy it would add
(``sm_ros.core.param_energy``)."""

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


def test_more_elastic_energy_than_internal_motion_also_shrinks_the_deformation():
    """Alpha 0.3 -> 0.9 at the stretch's widest: the gain outweighs the internal motion,
    which is all given up (the rigid motion stays), and the deformation shrinks towards
    the goals.  Goals averaged over overlapping clusters do not all follow it, so a few
    per cent are left of the two thirds the energy grew by without this."""
    body = _moving_body(steps=3)
    before, internal = _energy(body), PE.relative_energy(body)
    rigid = PE.rigid_velocity(body.x, body.v, body.m)
    unshed = before + PE.elastic_energy(body) * (PE.stiffness(BodyParams(alpha=0.9))
                                                 / PE.stiffness(body.params) - 1.0)
    spread = np.abs(PE.deviation(body)).max()
    body.set_params(alpha=0.9)
    np.testing.assert_allclose(body.v, rigid, rtol=0.0, atol=1e-12)
    assert 0.0 < internal and np.abs(PE.deviation(body)).max() < 0.9 * spread
    assert unshed > 1.5 * before and _energy(body) < 1.05 * before


def test_a_sagging_body_made_rigid_rises_into_its_shape_without_a_jump():
    """A soft box resting on the ground, sagged under gravity, made rigid: it takes its
    shape where it lies, its centre rising by the sag it loses and no higher (it sprang
    1.8x as high before a change took the energy it adds from the deformation)."""
    from sm_ros.core import Ground
    x0 = np.stack(np.meshgrid(*[np.arange(6) * 0.02] * 3, indexing='ij'), -1).reshape(-1, 3)
    world = World()
    world.set_colliders(ground=Ground(friction=0.5))
    body = world.add_body(x0 + [0.0, 0.0, 0.011], 0.01, BodyParams(alpha=0.1, damping=0.3))
    for _ in range(240):
        world.step(1.0 / 120.0)
    assert np.abs(body.v).max() < 0.01 and np.abs(PE.deviation(body)).max() > 1e-3   # sags
    low = body.com()[2]
    body.set_params(mode='rigid', alpha=1.0)
    heights = []
    for _ in range(60):
        world.step(1.0 / 120.0)
        heights.append(body.com()[2] - low)
    assert 0.01 < heights[-1] and max(heights) < 1.1 * heights[-1]
