"""Per-body solver parameters and static colliders (plain data, validated)."""

from dataclasses import dataclass, fields, replace
import math

import numpy as np

# The one parameter table (plain Python, no ROS, no NumPy) gives the modes and the range of
# every BodyParams field, so that the core refuses exactly what the node and the scene
# loader refuse.
from sm_ros.params import core_range, MAX_CLUSTERS, MODES


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
    """

    mode: str = 'linear'
    alpha: float = 0.5
    beta: float = 0.5
    clusters: int = 1
    plastic_yield: float = 0.0
    plastic_creep: float = 0.0
    plastic_max: float = 0.0
    damping: float = 0.0

    def validate(self) -> 'BodyParams':
        """Return a normalised copy; raise ValueError naming the bad field."""
        if self.mode not in MODES:
            raise ValueError(f'mode must be one of {", ".join(MODES)}, got {self.mode!r}')
        if isinstance(self.clusters, bool) or not isinstance(self.clusters, (int, np.integer)):
            raise ValueError(f'clusters must be an integer >= 1, got {self.clusters!r}')
        if self.clusters < 1 or self.clusters > MAX_CLUSTERS:
            raise ValueError(f'clusters must be in [1, {MAX_CLUSTERS}], got {self.clusters!r}')
        numbers = ('alpha', 'beta', 'plastic_yield', 'plastic_creep', 'plastic_max', 'damping')
        return replace(self, clusters=int(self.clusters),
                       **{f: _finite(f, getattr(self, f), *core_range(f)) for f in numbers})

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


__all__ = ['BodyParams', 'Ground', 'Box', 'Sphere', 'MODES']
