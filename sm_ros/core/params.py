"""Per-body solver parameters and static colliders (plain data, validated)."""

from dataclasses import dataclass, fields, replace
import math
from typing import NamedTuple, Optional

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

    ``max_speed`` (m/s) caps every particle's speed and ``max_turn`` (rad) the rotation a
    cluster may make in one step (``kernels/limits.py``); 0 disables either.  The defaults
    never bind in the bundled scenes; ``Body.limit_counts`` counts when they do.
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
    max_speed: float = BY_NAME['max_speed'].default
    max_turn: float = BY_NAME['max_turn'].default

    def validate(self) -> 'BodyParams':
        """Return a normalised copy; raise ValueError naming the bad field."""
        if self.mode not in MODES:
            raise ValueError(f'mode must be one of {", ".join(MODES)}, got {self.mode!r}')
        if isinstance(self.clusters, bool) or not isinstance(self.clusters, (int, np.integer)):
            raise ValueError(f'clusters must be an integer >= 1, got {self.clusters!r}')
        if self.clusters < 1 or self.clusters > MAX_CLUSTERS:
            raise ValueError(f'clusters must be in [1, {MAX_CLUSTERS}], got {self.clusters!r}')
        numbers = ('alpha', 'beta', 'plastic_yield', 'plastic_creep', 'plastic_max', 'damping',
                   'material_dt', 'max_speed', 'max_turn')
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


def _quat(name, value):
    """A unit quaternion (x, y, z, w) from ``value``; None stays None.

    Zero, non-finite and non-unit quaternions are refused (|q| must be 1 within 1e-3; the
    accepted one is renormalised).
    """
    if value is None:
        return None
    q = np.asarray(value, dtype=float).reshape(-1)
    if q.shape != (4,) or not np.all(np.isfinite(q)):
        raise ValueError(f'{name} must be a quaternion of 4 finite numbers (x, y, z, w), '
                         f'got {value!r}')
    n = float(np.linalg.norm(q))
    if abs(n - 1.0) > QUAT_TOLERANCE:
        raise ValueError(f'{name} must be a unit quaternion (x, y, z, w), got {value!r} '
                         f'of norm {n:.6g}')
    return q / n


#: How far from 1 the norm of a collider's quaternion may be (it is then renormalised).
QUAT_TOLERANCE = 1e-3


def _collider_common(kind, c):
    """Validate the optional name / orientation / kinematic fields of a collider."""
    if c.name is not None and (not isinstance(c.name, str) or not c.name
                               or any(ch.isspace() for ch in c.name)):
        raise ValueError(f'{kind}.name must be a non-empty string without spaces, '
                         f'got {c.name!r}')
    if not isinstance(c.kinematic, (bool, np.bool_)):
        raise ValueError(f'{kind}.kinematic must be true or false, got {c.kinematic!r}')
    if c.kinematic and c.name is None:
        raise ValueError(f'a kinematic {kind} needs a name (the frame_id of collider_pose)')
    q = _quat(f'{kind}.orientation', c.orientation)
    _finite(f'{kind}.friction', c.friction, 0.0)
    _finite(f'{kind}.restitution', c.restitution, 0.0, 1.0)
    _path(kind, c)
    return q


def _path(kind, c):
    """Validated keyframes [(time, position (3,), quaternion (4,) or None)]."""
    try:
        frames = list(c.path)
    except TypeError:
        raise ValueError(f'{kind}.path must be a list of (time, position, orientation) '
                         f'keyframes, got {c.path!r}') from None
    if frames and not c.kinematic:
        raise ValueError(f'{kind}.path needs kinematic: true')
    out = []
    last = 0.0
    for i, f in enumerate(frames):
        if not isinstance(f, (tuple, list)) or len(f) not in (2, 3):
            raise ValueError(f'{kind}.path[{i}] must be (time, position[, orientation]), '
                             f'got {f!r}')
        t = _finite(f'{kind}.path[{i}].time', f[0])
        if t <= last:
            raise ValueError(f'{kind}.path[{i}].time must be > {last:g} (times increase '
                             f'from 0), got {t!r}')
        last = t
        pos = _vec3(f'{kind}.path[{i}].position', f[1])
        quat = _quat(f'{kind}.path[{i}].orientation', f[2] if len(f) == 3 else None)
        out.append((t, pos, quat))
    return out


@dataclass(frozen=True, kw_only=True)
class _Collider:
    """What every static or moving collider has (keyword arguments): its surface's
    ``friction`` and ``restitution``; a ``name`` (reports a wrench; the frame_id of
    ``collider_pose``); an ``orientation`` (unit quaternion x, y, z, w about its centre);
    ``kinematic`` (moved by ``World.move_collider``; needs a name) and ``path`` (kinematic
    only: keyframes ``(time, position[, quaternion])`` played from the declared pose at
    time 0, piecewise linear / slerp, until the first ``move_collider`` of it)."""

    friction: float = 0.5
    restitution: float = 0.0
    name: Optional[str] = None
    orientation: Optional[tuple] = None
    kinematic: bool = False
    path: tuple = ()

    @property
    def simple(self) -> bool:
        """Unnamed, unturned and static: handled inside the fused body step."""
        return self.name is None and self.orientation is None and not self.kinematic


@dataclass(frozen=True)
class Box(_Collider):
    """A solid box from ``lo`` to ``hi`` (axis-aligned unless ``orientation`` is given,
    about the box centre); the keywords of every collider (``_Collider``)."""

    lo: tuple = (0.0, 0.0, 0.0)
    hi: tuple = (1.0, 1.0, 1.0)

    def row(self):
        """Return the validated row the kernels read."""
        lo, hi = _vec3('box.lo', self.lo), _vec3('box.hi', self.hi)
        if np.any(hi <= lo):
            raise ValueError(f'box.hi must be > box.lo on every axis, got {lo} .. {hi}')
        _collider_common('box', self)
        return [*lo, *hi, float(self.friction), float(self.restitution)]

    def shape(self):
        """(kind, centre, quaternion, dims) of the collider pass (kinematic.py)."""
        self.row()
        lo, hi = _vec3('box.lo', self.lo), _vec3('box.hi', self.hi)
        q = _collider_common('box', self)
        return (KIND_BOX, (lo + hi) / 2.0, _unit(q), (hi - lo) / 2.0)


@dataclass(frozen=True)
class Sphere(_Collider):
    """A solid sphere; the keywords of every collider (``_Collider``)."""

    center: tuple = (0.0, 0.0, 0.0)
    radius: float = 1.0

    def row(self):
        """Return the validated row the kernels read."""
        c = _vec3('sphere.center', self.center)
        _finite('sphere.radius', self.radius, 0.0, lo_open=True)
        _collider_common('sphere', self)
        return [*c, float(self.radius), float(self.friction), float(self.restitution)]

    def shape(self):
        """(kind, centre, quaternion, dims) of the collider pass (kinematic.py)."""
        self.row()
        q = _collider_common('sphere', self)
        return (KIND_SPHERE, _vec3('sphere.center', self.center), _unit(q),
                np.array([float(self.radius), 0.0, 0.0]))


@dataclass(frozen=True)
class Capsule(_Collider):
    """A solid capsule: the points within ``radius`` of a segment of ``length`` along the
    local z axis, centred on ``center`` (end to end: length + 2 radius; length 0 is a
    sphere); the keywords of every collider (``_Collider``).
    """

    center: tuple = (0.0, 0.0, 0.0)
    radius: float = 0.05
    length: float = 0.1

    @property
    def simple(self) -> bool:
        """Capsules always go through the collider pass."""
        return False

    def shape(self):
        """(kind, centre, quaternion, dims) of the collider pass (kinematic.py)."""
        c = _vec3('capsule.center', self.center)
        r = _finite('capsule.radius', self.radius, 0.0, lo_open=True)
        length = _finite('capsule.length', self.length, 0.0)
        q = _collider_common('capsule', self)
        return (KIND_CAPSULE, c, _unit(q), np.array([r, length / 2.0, 0.0]))


def _unit(q):
    return np.array([0.0, 0.0, 0.0, 1.0]) if q is None else q


#: Collider kinds of the collider pass (column 0 of its rows).
KIND_SPHERE, KIND_BOX, KIND_CAPSULE = 0, 1, 2


__all__ = ['BodyParams', 'StepParams', 'MATERIAL_DT', 'Ground', 'Box', 'Sphere', 'Capsule',
           'MODES']
