"""Per-body solver parameters and static colliders (plain data, validated)."""

from dataclasses import dataclass, fields, replace
import math
from typing import NamedTuple

import numpy as np

# The one parameter table (plain Python, no ROS, no NumPy) gives the modes and the range of
# every BodyParams field, so that the core refuses exactly what the node and the scene
# loader refuse.
from sm_ros.params import BY_NAME, core_range, MAX_CLUSTERS, MODES

#: The step at which ``alpha``, ``beta``, ``damping`` and the creep fraction are defined
#: by default (the node's default ``dt``): at this step they act exactly as given.
MATERIAL_DT = BY_NAME['material_dt'].default


class StepParams(NamedTuple):
    """The per-step coefficients of a material at one step h (``BodyParams.at_step``)."""

    alpha: float
    beta: float
    damping: float
    creep: float            # rate c such that min(h c, 1) is the creep fraction of one step


def _stiffness_at(a0: float, r: float) -> float:
    """A per-step stiffness a0 given at h0, at the step h = r h0 (compliance kept)."""
    if a0 >= 1.0:
        return 1.0
    return a0 * r * r / (1.0 - a0 + a0 * r * r)


def _fraction_at(f0: float, r: float) -> float:
    """A fraction removed per step of h0, at the step r h0 (same decay per second)."""
    if f0 >= 1.0:
        return 1.0
    return -math.expm1(r * math.log1p(-f0))


def _finite(name: str, value, lo=None, hi=None, lo_open=False) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f'{name} must be a number, got {value!r}') from None
    if isinstance(value, bool) or not math.isfinite(v):
        raise ValueError(f'{name} must be a finite number, got {value!r}')
    if lo is not None and (v < lo or (lo_open and v == lo)):
        raise ValueError(f"{name} must be {'>' if lo_open else '>='} {lo}, got {value!r}")
    if hi is not None and v > hi:
        raise ValueError(f'{name} must be <= {hi}, got {value!r}')
    return v


@dataclass(frozen=True)
class BodyParams:
    """Shape-matching parameters of one body (algorithm.md; names as in the paper).

    ``clusters`` is the number of cubes per axis of the overlapping cluster grid (§4.4);
    plasticity is on when ``plastic_creep > 0`` (§4.5); ``damping`` removes that fraction
    of each particle's velocity relative to its clusters' rigid motion per step (not part
    of the paper; momentum-preserving; 0 = off).

    ``alpha``, ``beta``, ``damping`` and the creep fraction min(h c_creep, 1) are the
    material's values at the step ``material_dt`` (s); ``at_step(h)`` converts them to the
    step actually taken so the simulated object does not depend on the step.  0 turns the
    conversion off (every value acts per step as given, the paper's semantics).
    """

    mode: str = 'linear'
    alpha: float = 0.5
    beta: float = 0.5
    clusters: int = 1
    plastic_yield: float = 0.0
    plastic_creep: float = 0.0
    plastic_max: float = 0.0
    damping: float = 0.0
    material_dt: float = MATERIAL_DT

    def validate(self) -> 'BodyParams':
        """Return a normalised copy; raise ValueError naming the bad field."""
        if self.mode not in MODES:
            raise ValueError(f'mode must be one of {", ".join(MODES)}, got {self.mode!r}')
        if isinstance(self.clusters, bool) or not isinstance(self.clusters, (int, np.integer)):
            raise ValueError(f'clusters must be an integer >= 1, got {self.clusters!r}')
        if self.clusters < 1 or self.clusters > MAX_CLUSTERS:
            raise ValueError(f'clusters must be in [1, {MAX_CLUSTERS}], got {self.clusters!r}')
        numbers = ('alpha', 'beta', 'plastic_yield', 'plastic_creep', 'plastic_max', 'damping',
                   'material_dt')
        return replace(self, clusters=int(self.clusters),
                       **{f: _finite(f, getattr(self, f), *core_range(f)) for f in numbers})

    def at_step(self, h: float) -> StepParams:
        """The per-step coefficients that give this material at the step ``h`` (s).

        Goal pull: v += alpha (g - x) / h is, for a fixed goal, the implicit (backward
        Euler) spring x+ = y + k h^2 / (1 + k h^2) (g - y) with compliance 1 / k: so
        alpha / (1 - alpha) = k h^2.  Keeping k (stiffness per unit mass, 1/s^2) fixed:
        alpha(h) = a0 r^2 / (1 - a0 + a0 r^2) with r = h / h0.  alpha = 1 (zero compliance,
        rigid) and alpha = 0 (free) are fixed points, alpha(h) <= 1 at every step (nothing
        is clipped) and for h -> 0 alpha(h) / h^2 -> k: a finite stiffness, so the motion
        converges to that of an ODE as the step shrinks.  ``beta``: the goal is
        alpha (beta G_A + (1 - beta) G_R); the deformations the A (or quadratic) field can
        follow are held by alpha (1 - beta) alone, converted the same way, and beta(h) =
        1 - alpha_1(h) / alpha(h).  ``damping`` and the creep fraction f = min(h0 c, 1) are
        fractions removed per step: (1 - d(h)) = (1 - d0)^r, the same decay per second.
        """
        h0 = self.material_dt
        if not h0 > 0.0 or h == h0:
            return StepParams(self.alpha, self.beta, self.damping, self.plastic_creep)
        r = h / h0
        alpha = _stiffness_at(self.alpha, r)
        beta = self.beta
        if alpha > 0.0 and 0.0 < beta < 1.0:
            beta = min(1.0, max(0.0, 1.0 - _stiffness_at(self.alpha * (1.0 - self.beta), r)
                                       / alpha))
        damping = _fraction_at(self.damping, r)
        creep = _fraction_at(min(h0 * self.plastic_creep, 1.0), r) / h
        return StepParams(alpha, beta, damping, creep)

    @property
    def plastic(self) -> bool:
        """Plasticity is active (c_creep > 0)."""
        return self.plastic_creep > 0.0

    @staticmethod
    def field_names():
        """Names of all fields (for validating overrides)."""
        return tuple(f.name for f in fields(BodyParams))


def _vec3(name, value):
    a = np.asarray(value, dtype=float).reshape(-1)
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise ValueError(f'{name} must be 3 finite numbers, got {value!r}')
    return a


@dataclass(frozen=True)
class Ground:
    """The plane z = ``height`` (normal +z), with Coulomb friction and restitution."""

    height: float = 0.0
    friction: float = 0.5
    restitution: float = 0.0

    def row(self):
        """Return the validated row the kernels read."""
        _finite('ground.height', self.height)
        _finite('ground.friction', self.friction, 0.0)
        _finite('ground.restitution', self.restitution, 0.0, 1.0)
        return [1.0, float(self.height), float(self.friction), float(self.restitution)]


@dataclass(frozen=True)
class Box:
    """A solid axis-aligned box from ``lo`` to ``hi``."""

    lo: tuple = (0.0, 0.0, 0.0)
    hi: tuple = (1.0, 1.0, 1.0)
    friction: float = 0.5
    restitution: float = 0.0

    def row(self):
        """Return the validated row the kernels read."""
        lo, hi = _vec3('box.lo', self.lo), _vec3('box.hi', self.hi)
        if np.any(hi <= lo):
            raise ValueError(f'box.hi must be > box.lo on every axis, got {lo} .. {hi}')
        _finite('box.friction', self.friction, 0.0)
        _finite('box.restitution', self.restitution, 0.0, 1.0)
        return [*lo, *hi, float(self.friction), float(self.restitution)]


@dataclass(frozen=True)
class Sphere:
    """A solid sphere."""

    center: tuple = (0.0, 0.0, 0.0)
    radius: float = 1.0
    friction: float = 0.5
    restitution: float = 0.0

    def row(self):
        """Return the validated row the kernels read."""
        c = _vec3('sphere.center', self.center)
        _finite('sphere.radius', self.radius, 0.0, lo_open=True)
        _finite('sphere.friction', self.friction, 0.0)
        _finite('sphere.restitution', self.restitution, 0.0, 1.0)
        return [*c, float(self.radius), float(self.friction), float(self.restitution)]


__all__ = ['BodyParams', 'StepParams', 'MATERIAL_DT', 'Ground', 'Box', 'Sphere', 'MODES']
