"""A stiffer material set while a body moves takes the energy it adds from the body's
wobble (``sm_ros.core.param_energy``)."""

import numpy as np
import pytest

from sm_ros.core import BodyParams, World
from sm_ros.core import param_energy as PE


def _moving_body(mode='linear', alpha=0.3, steps=2):
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


def _energy(body, spread):
    """Kinetic energy plus the elastic energy ``param_energy`` counts."""
    return 0.5 * float(body.m @ (body.v ** 2).sum(axis=1)) + PE.elastic_energy(body.params,
                                                                                 spread)


def test_motion_keeps_a_rigid_motion_and_both_momenta():
    rng = np.random.default_rng(4)
    x, m = rng.random((40, 3)), rng.uniform(0.5, 2.0, 40)
    centre = m @ x / m.sum()
    rigid = np.array([0.3, -0.2, 0.1]) + np.cross([1.0, 2.0, -0.5], x - centre)
    c, drift, spin, relative = PE.motion(x, rigid, m)
    np.testing.assert_allclose(drift + np.cross(spin, x - c), rigid, atol=1e-12)
    assert relative < 1e-12
    v = rng.normal(size=(40, 3))
    c, drift, spin, relative = PE.motion(x, v, m)
    fit = drift + np.cross(spin, x - c)
    np.testing.assert_allclose(m @ fit, m @ v, atol=1e-12)
    np.testing.assert_allclose(np.cross(x, fit).T @ m, np.cross(x, v).T @ m, atol=1e-12)
    rel = v - fit                                   # NumPy twin of the relative energy
    assert relative == pytest.approx(0.5 * m @ (rel ** 2).sum(1), rel=1e-9)


@pytest.mark.parametrize('mode, change', [('linear', dict(alpha=0.4)),
                                          ('linear', dict(beta=0.1)),
                                          ('quadratic', dict(alpha=0.4)),
                                          ('rigid', dict(alpha=0.4)),
                                          ('linear', dict(mode='rigid'))])
def test_a_stiffer_material_takes_its_energy_from_the_internal_motion(mode, change):
    """A stiffer material a step after a stretch: kinetic plus elastic energy stays, the
    internal motion gives up exactly what the elastic energy gained, and the momentum and
    angular momentum stay."""
    body = _moving_body(mode)
    spread = body.total_mass * body.shape_error_rms() ** 2
    before, internal = _energy(body, spread), PE.motion(body.x, body.v, body.m)[3]
    momentum, spin = body.momentum(), body.angular_momentum()
    gain = -PE.elastic_energy(body.params, spread)
    body.set_params(**change)
    gain += PE.elastic_energy(body.params, spread)
    assert 0.01 * internal < gain < internal
    assert _energy(body, spread) == pytest.approx(before, rel=1e-9)
    assert PE.motion(body.x, body.v, body.m)[3] == pytest.approx(internal - gain, rel=1e-6)
    np.testing.assert_allclose(body.momentum(), momentum, rtol=0.0, atol=1e-14)
    np.testing.assert_allclose(body.angular_momentum(), spin, rtol=0.0, atol=1e-14)


def test_more_elastic_energy_than_internal_motion_stops_the_internal_motion():
    """Alpha 0.3 -> 0.95 at the stretch's widest: the gain outweighs the internal motion,
    which is all given up (the rigid motion stays)."""
    body = _moving_body(steps=3)
    spread = body.total_mass * body.shape_error_rms() ** 2
    assert (PE.elastic_energy(BodyParams(alpha=0.95, beta=0.3), spread)
            - PE.elastic_energy(body.params, spread)) > PE.motion(body.x, body.v, body.m)[3]
    c, drift, spin, _ = PE.motion(body.x, body.v, body.m)
    rigid = drift + np.cross(spin, body.x - c)
    body.set_params(alpha=0.95)
    np.testing.assert_allclose(body.v, rigid, rtol=0.0, atol=1e-12)


def test_a_softer_material_and_a_body_at_rest_keep_their_state():
    body = _moving_body(alpha=0.6)
    v = body.v.copy()
    body.set_params(alpha=0.3, beta=0.5, damping=0.1)
    assert body.v.tobytes() == v.tobytes()
    body.set_state(v=np.zeros((body.n, 3)))
    x = body.x.copy()
    body.set_params(alpha=0.9, beta=0.1)
    assert body.x.tobytes() == x.tobytes() and not body.v.any()
