"""A stiffer material set while a body moves takes the energy it adds from the body's wobble
(``Body.set_params``).

The shape match pulls each particle towards its goal like a spring of stiffness
k = a / ((1 - a) h0^2) per unit mass (``BodyParams.at_step``), a = alpha for a rigid-mode body
and alpha (1 - beta) for the deformations the linear and quadratic goals do not follow.  A
body deformed by d_i = x_i - g_i (the last step's shape error) holds U = k / 2 sum m_i |d_i|^2,
so a new alpha, beta, mode or material step changes U at the same positions.  Where U
grows, the body's motion relative to its rigid motion gives the rise up (all of it at
most; momentum and angular momentum stay).  Without this, stiffness changed at random every
tick pumps an undamped body up like a parametric oscillator.  A body at rest is left as it
is.  Everything here is a few sums over the particles: no goal pass."""

import math

import numpy as np

#: Parameters whose change can raise the elastic energy of a deformed body.
SHAPE_KEYS = ('mode', 'alpha', 'beta', 'material_dt')
#: A body whose internal motion is slower than this (m/s, RMS) is left alone.
STILL_SPEED = 1e-3


def stiffness(params) -> float:
    """k (1/s^2 per unit mass) of the pull on the deformations ``params`` holds."""
    a = params.alpha if params.mode == 'rigid' else params.alpha * (1.0 - params.beta)
    return a / max(1.0 - a, 1e-12) / params.material_dt ** 2


def motion(x, v, m):
    """(centre, its velocity, spin, kinetic energy of the motion relative to the rigid
    one) of the points ``x`` (N, 3) moving at ``v`` with masses ``m``: the rigid motion
    keeps the momentum and angular momentum, and the two kinetic energies add up.  A few
    3 x N products over the particles."""
    total, weighted = m.sum(), x * m[:, None]
    centre, drift = weighted.sum(axis=0) / total, m @ v / total
    moment = weighted.T @ x - total * np.outer(centre, centre)
    cross = weighted.T @ v
    spin_l = (np.array([cross[1, 2] - cross[2, 1], cross[2, 0] - cross[0, 2],
                        cross[0, 1] - cross[1, 0]]) - total * np.cross(centre, drift))
    spin = np.linalg.pinv(np.trace(moment) * np.eye(3) - moment) @ spin_l
    kinetic = 0.5 * float(np.einsum('ij,ij->', v * m[:, None], v))
    relative = kinetic - 0.5 * total * float(drift @ drift) - 0.5 * float(spin @ spin_l)
    return centre, drift, spin, max(relative, 0.0)


def elastic_energy(params, spread: float) -> float:
    """U = k / 2 sum m |x - g|^2 (J) under ``params`` of a body with ``spread`` =
    sum m |x - g|^2 (its mass times the square of its shape error)."""
    return 0.5 * stiffness(params) * spread


def give_up(body, old, new, spread: float) -> None:
    """After ``Body.set_params`` put ``new`` in place of ``old``: take what the change added
    to the elastic energy (``spread`` as it was before) from the body's motion relative to
    its rigid motion."""
    if all(getattr(new, key) == getattr(old, key) for key in SHAPE_KEYS):
        return
    gain = elastic_energy(new, spread) - elastic_energy(old, spread)
    x, v, m = body._x, body._v, body._m
    if not (gain > 0.0 and body.is_finite()):
        return
    centre, drift, spin, kinetic = motion(x, v, m)
    if kinetic <= 0.5 * body.total_mass * STILL_SPEED ** 2:
        return
    keep = math.sqrt(max(0.0, 1.0 - gain / kinetic))
    if keep == 1.0:                      # a gain below round-off: nothing to take
        return
    rigid = drift + np.cross(spin, x - centre)
    v[:] = rigid + keep * (v - rigid)
    body._dirty = True
