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
#: Internal motion slower than this (m/s, RMS) is left alone: it holds no energy to speak of.
STILL_SPEED = 1e-3


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


def stiffness(params) -> float:
    """k (1/s^2 per unit mass) of the shape match's pull under ``params``."""
    return params.alpha / max(1.0 - params.alpha, 1e-12) / params.material_dt ** 2


def spread(body) -> float:
    """sum m |x - g|^2 of the body's goals under its present parameters."""
    d = body._x - body_step.goals(body)
    return float(body._m @ np.einsum('ij,ij->i', d, d))


def elastic_energy(body) -> float:
    """U = k / 2 sum m |x - g|^2 (J) under the body's present parameters."""
    return 0.5 * stiffness(body.params) * spread(body)


class MaterialChange:
    """Made before ``Body.set_params`` puts ``new`` parameters in place of ``old``;
    ``finish()`` after it takes what the change added to the elastic energy from the
    body's internal motion.  Only alpha raised: U grows with k at the same goals; other
    changes move the goals (U from them, before and after)."""

    def __init__(self, body, old, new):
        self.body, self.gain, self.before = body, 0.0, None
        changed = {key for key in SHAPE_KEYS if getattr(new, key) != getattr(old, key)}
        if not changed or changed == {'alpha'} and new.alpha < old.alpha:
            return
        if not (body.is_finite() and relative_energy(body) > 0.5 * body.total_mass
                * STILL_SPEED ** 2):
            return
        if changed == {'alpha'}:
            self.gain = 0.5 * (stiffness(new) - stiffness(old)) * spread(body)
        else:
            self.before = elastic_energy(body)

    def finish(self) -> None:
        """Take the gain of elastic energy from the body's internal motion."""
        if self.before is not None:
            self.gain = elastic_energy(self.body) - self.before
        if self.gain > 0.0:
            shed(self.body, self.gain)


def shed(body, energy: float) -> None:
    """Take up to ``energy`` (J) from the body's motion relative to its rigid motion."""
    kinetic = relative_energy(body)
    if not (energy > 0.0 and kinetic > 0.0):
        return
    keep = math.sqrt(max(0.0, 1.0 - energy / kinetic))
    if keep == 1.0:                      # a gain below round-off: nothing to take
        return
    rigid = rigid_velocity(body._x, body._v, body._m)
    body._v[:] = rigid + keep * (body._v - rigid)
    body._dirty = True
