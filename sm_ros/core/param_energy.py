"""A change of a body's material never adds energy to it (``Body.set_params``).

The shape match pulls each particle towards its goal like a spring of stiffness
k = alpha / ((1 - alpha) h0^2) per unit mass (``BodyParams.at_step``), so a body deformed by
d_i = x_i - g_i holds U = k / 2 sum m_i |d_i|^2.  A new alpha, beta, mode or cluster count
changes U at the same positions; where U grows, the body's motion relative to its rigid
motion gives the difference up (all of that motion at most).  Without this, stiffness
changed at random every tick pumps an undamped body up like a parametric oscillator."""

import math

import numpy as np

from . import body_step

#: Parameters whose change can raise the elastic energy of a deformed body.
SHAPE_KEYS = ('mode', 'alpha', 'beta', 'clusters', 'material_dt')


def rigid_velocity(x, v, m) -> np.ndarray:
    """The rigid motion (velocity of the centre, spin about it) that keeps the momentum and
    angular momentum of the points ``x`` (N, 3) moving at ``v`` with masses ``m``."""
    total = m.sum()
    centre, drift = m @ x / total, m @ v / total
    r = x - centre
    spin_l = np.cross(r, v - drift).T @ m
    inertia = np.einsum('i,ij,ik->jk', m, r, r)
    inertia = np.trace(inertia) * np.eye(3) - inertia
    return drift + np.cross(np.linalg.pinv(inertia) @ spin_l, r)


def relative_energy(body) -> float:
    """Kinetic energy (J) of the body's motion relative to its rigid motion."""
    rel = body._v - rigid_velocity(body._x, body._v, body._m)
    return 0.5 * float(body._m @ np.einsum('ij,ij->i', rel, rel))


def deforming(body) -> bool:
    """Whether the body moves relative to its rigid motion by more than round-off (a
    millionth of its speed)."""
    if not body.is_finite():
        return False
    total = 0.5 * float(body._m @ np.einsum('ij,ij->i', body._v, body._v))
    return relative_energy(body) > 1e-12 * total


def elastic_energy(body) -> float:
    """U = k / 2 sum m |x - g|^2 (J) of the body's goals under its present parameters."""
    p = body.params
    stiffness = p.alpha / max(1.0 - p.alpha, 1e-12) / p.material_dt ** 2
    d = body._x - body_step.goals(body)
    return 0.5 * stiffness * float(body._m @ np.einsum('ij,ij->i', d, d))


def shed(body, energy: float) -> None:
    """Take up to ``energy`` (J) from the body's motion relative to its rigid motion."""
    kinetic = relative_energy(body)
    if not (energy > 0.0 and kinetic > 0.0):
        return
    rigid = rigid_velocity(body._x, body._v, body._m)
    keep = math.sqrt(max(0.0, 1.0 - energy / kinetic))
    body._v[:] = rigid + keep * (body._v - rigid)
    body._dirty = True
