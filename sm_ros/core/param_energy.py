"""A change of a body's material never adds energy to it (``Body.set_params``).

The shape match pulls each particle towards its goal like a spring of stiffness
k = alpha / ((1 - alpha) h0^2) per unit mass (``BodyParams.at_step``), so a body deformed by
d_i = x_i - g_i holds U = k / 2 sum m_i |d_i|^2.  A new alpha, beta, mode, cluster count or
material step changes U at the same positions.  Where U grows, the body's motion relative
to its rigid motion gives the rise up, and where that motion holds too little, the
deformation shrinks towards the goals (a few passes: the goals follow it; averaged over
overlapping clusters they do not all).  Without this, stiffness changed at random every
tick pumps an undamped body up like a parametric oscillator, and a deformed body made
rigid springs into its shape."""

import math

import numpy as np

from . import body_step

#: Parameters whose change can raise the elastic energy of a deformed body.
SHAPE_KEYS = ('mode', 'alpha', 'beta', 'clusters', 'material_dt')
#: A gain below this share of the energy of a deformation as large as the body and of its
#: motion is round-off: nothing changes.
ROUND_OFF = 1e-12
#: Times the deformation is shrunk towards goals that move with it.
SHRINK_PASSES = 4


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


def _weighted_square(m, d) -> float:
    return float(m @ np.einsum('ij,ij->i', d, d))


def relative_energy(body) -> float:
    """Kinetic energy (J) of the body's motion relative to its rigid motion."""
    return 0.5 * _weighted_square(body._m, body._v - rigid_velocity(body._x, body._v, body._m))


def stiffness(params) -> float:
    """k (1/s^2 per unit mass) of the shape match's pull under ``params``."""
    return params.alpha / max(1.0 - params.alpha, 1e-12) / params.material_dt ** 2


def deviation(body) -> np.ndarray:
    """x - g (N, 3, storage order) of the goals under the body's present parameters."""
    return body._x - body_step.goals(body)


def elastic_energy(body) -> float:
    """U = k / 2 sum m |x - g|^2 (J) under the body's present parameters."""
    return 0.5 * stiffness(body.params) * _weighted_square(body._m, deviation(body))


class MaterialChange:
    """Made before ``Body.set_params`` puts ``new`` parameters in place of ``old``;
    ``finish()`` after it takes what the change added to the elastic energy from the
    body's internal motion, then from its deformation.  Alpha alone keeps the goals (one
    goal pass); other changes move them (U before and after)."""

    def __init__(self, body, old, new):
        self.body, self.before, self.deviation = body, None, None
        changed = {key for key in SHAPE_KEYS if getattr(new, key) != getattr(old, key)}
        if not changed or not body.is_finite() or (changed == {'alpha'}
                                                   and new.alpha < old.alpha):
            return
        if changed == {'alpha'}:
            self.deviation = deviation(body)
            self.before = 0.5 * stiffness(old) * _weighted_square(body._m, self.deviation)
        else:
            self.before = elastic_energy(body)

    def finish(self) -> None:
        """Give up the elastic energy the change added (``Body.set_params``, after it)."""
        if self.before is None:
            return
        body, k = self.body, stiffness(self.body.params)
        d = self.deviation if self.deviation is not None else deviation(body)
        after = 0.5 * k * _weighted_square(body._m, d)
        gain = after - self.before
        spread = body._x - body._m @ body._x / body.total_mass     # a deformation as large
        scale = 0.5 * (k * _weighted_square(body._m, spread)        # as the body, the motion
                       + _weighted_square(body._m, body._v))
        if not gain > ROUND_OFF * scale:
            return
        target = after - gain + _shed(body, gain)           # the U the deformation may keep
        for _ in range(SHRINK_PASSES):                      # the goals follow x: again
            if not after > target * (1.0 + 1e-9):
                return
            body._x -= (1.0 - math.sqrt(max(target, 0.0) / after)) * d
            body._dirty = True
            d = deviation(body)
            after = 0.5 * k * _weighted_square(body._m, d)


def _shed(body, energy: float) -> float:
    """Take up to ``energy`` (J) from the body's motion relative to its rigid motion;
    return the energy taken."""
    kinetic = relative_energy(body)
    if not (energy > 0.0 and kinetic > 0.0):
        return 0.0
    keep = math.sqrt(max(0.0, 1.0 - energy / kinetic))
    if keep == 1.0:                      # a gain below round-off: nothing to take
        return 0.0
    rigid = rigid_velocity(body._x, body._v, body._m)
    body._v[:] = rigid + keep * (body._v - rigid)
    body._dirty = True
    return kinetic * (1.0 - keep * keep)
