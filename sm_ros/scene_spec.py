"""
What the scene loader produces, and how it words its errors (no ROS, no solver).

:class:`SceneSpec` and :class:`BodySpec` hold a validated scene as plain NumPy arrays,
:class:`BodyMeta` what the node keeps per body; :class:`SceneError` is every refusal, and
:class:`Where` builds its message ('<file>: body '<name>': <key> <reason>') while checking
values. ``sm_ros.scene`` parses files into these; ``sm_ros.scene_build`` turns them into a
``sm_ros.core.World``.
"""

from __future__ import annotations

import difflib
import math
from dataclasses import dataclass, field
from typing import Any, Dict, List, Mapping, Optional, Sequence

import numpy as np

from sm_ros.shapes import Surface

#: Keys of a scene's top-level ``contact`` mapping (node parameters ``contact.<key>``).
CONTACT_SCENE_KEYS = ('enabled', 'friction', 'restitution', 'radius_scale', 'stacking',
                      'rigid', 'sleep', 'sleep_speed', 'sleep_time')


class SceneError(ValueError):
    """A scene that cannot be loaded; the message names the file, the body and the key."""


# ----------------------------------------------------------------------------------------
# Results
# ----------------------------------------------------------------------------------------

@dataclass
class BodySpec:
    """
    One body ready for ``World.add_body``.

    Attributes:
        name: body name (the ``frame_id`` that ``force`` and ``poses`` use).
        points: (N, 3) rest and initial positions in world coordinates (m).
        masses: (N,) particle masses (kg).
        velocities: (N, 3) initial velocities (m/s) or None for rest.
        pinned: indices of particles held fixed (int64, possibly empty).
        overrides: parameter overrides in node naming (subset of ``sm_ros.params.OVERRIDE_KEYS``).
        surface: a :class:`sm_ros.shapes.Surface` for bodies from a mesh file, else None.
        shape: the shape keyword it was made from ('box', 'mesh', 'cloud', ...).
        contact: the body's contact keys that the scene set (collide, contact_radius,
            self_collision).
    """

    name: str
    points: np.ndarray
    masses: np.ndarray
    velocities: Optional[np.ndarray] = None
    pinned: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    overrides: Dict[str, Any] = field(default_factory=dict)
    surface: Optional[Surface] = None
    shape: str = ''
    contact: Dict[str, Any] = field(default_factory=dict)

    @property
    def n(self) -> int:
        """Number of particles."""
        return len(self.points)


@dataclass
class SceneSpec:
    """
    A validated scene.

    Attributes:
        bodies: the bodies, in file order (copies expanded).
        colliders: ``{'ground': None or dict, 'boxes': [{'lo', 'hi', ...}], 'spheres':
            [{'center', 'radius', ...}], 'capsules': [{'center', 'radius', 'length',
            ...}]}`` (each with friction, restitution, kinematic and, when given, name,
            orientation (x, y, z, w) and path); ground None means "use the node's ground
            parameters", a dict holds the keys the scene set (enabled, height, friction,
            restitution).
        source: the file it came from (or a label for scenes built in code).
        description: the scene's description text.
        contact: the keys of the top-level ``contact`` mapping the scene set (enabled,
            friction, restitution, radius_scale, stacking); the others come from the node.
    """

    bodies: List[BodySpec]
    colliders: Dict[str, Any]
    source: str = '<scene>'
    description: str = ''
    contact: Dict[str, Any] = field(default_factory=dict)

    @property
    def n_points(self) -> int:
        """Total number of particles."""
        return sum(b.n for b in self.bodies)


@dataclass
class BodyMeta:
    """What the node keeps per body beside the core Body: name, overrides and surface."""

    name: str
    overrides: Dict[str, Any]
    surface: Optional[Surface] = None
    shape: str = ''


# ----------------------------------------------------------------------------------------
# Validation helpers
# ----------------------------------------------------------------------------------------

def kind(value: Any) -> str:
    """Return what kind of value an error message found, never its text: a file that is
    not a scene (``scene:=/etc/passwd``) must not reach a log or a parameter reply."""
    if value is None:
        return 'nothing'
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, (int, float)):
        return 'a number'
    if isinstance(value, str):
        return 'a string' if value.strip() else 'an empty string'
    if isinstance(value, (list, tuple)):
        return f'a list of {len(value)} item' + ('' if len(value) == 1 else 's')
    if isinstance(value, dict):
        return 'a mapping'
    return f'a value of type {type(value).__name__}'


def fmt(value: Any) -> str:
    """Return a value as an error message quotes it: a number as itself (1.0 as 1), any
    other value as its kind (:func:`kind`), never a string's text."""
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        if isinstance(value, float) and value.is_integer() and abs(value) < 1e15:
            return str(int(value))
        return str(value)
    return kind(value)


def _parent(path: str) -> str:
    """'a.b[2].c' -> 'a.b[2]' -> 'a.b' -> 'a' -> ''."""
    cut = max(path.rfind('.'), path.rfind('['))
    return path[:max(cut, 0)]


def yaml_lines(node: Any, limit: int = 100_000) -> Dict[str, int]:
    """
    Return the 1-based line of every key and list item of a composed YAML document, by
    the dotted path the loader names it with ('bodies[0].position'; '' the document).

    Visits at most ``limit`` nodes (aliases can make a small file a huge tree).
    """
    import yaml
    lines: Dict[str, int] = {}
    stack = [('', node)]
    while stack and len(lines) < limit:
        path, nd = stack.pop()
        lines.setdefault(path, nd.start_mark.line + 1)
        if isinstance(nd, yaml.MappingNode):
            for key, value in nd.value:
                if isinstance(key, yaml.ScalarNode):
                    sub = f'{path}.{key.value}' if path else str(key.value)
                    lines.setdefault(sub, key.start_mark.line + 1)
                    stack.append((sub, value))
        elif isinstance(nd, yaml.SequenceNode):
            stack.extend((f'{path}[{i}]', item) for i, item in enumerate(nd.value))
    return lines


def yaml_problem(exc: Exception) -> str:
    """Return where and what a YAML error is, without the excerpt of the file that
    PyYAML's message quotes (nor any quoted token): 'line 3, column 7: could not find
    expected ':''."""
    import re
    mark = getattr(exc, 'problem_mark', None)
    problem = getattr(exc, 'problem', None) or type(exc).__name__
    problem = re.sub(r"'[^']*'|\"[^\"]*\"", '(...)', str(problem))
    if mark is None:
        return problem
    return f'line {mark.line + 1}, column {mark.column + 1}: {problem}'


def read_yaml(path, label: str, max_bytes: int):
    """
    Return (data, lines) of a YAML file: the parsed document and :func:`yaml_lines` of it.

    Raises SceneError naming ``label`` for a file larger than ``max_bytes``, unreadable,
    not UTF-8 or not YAML, with the place of the fault and never the file's text.
    """
    import yaml
    try:
        if path.stat().st_size > max_bytes:
            raise SceneError(f'{label}: is larger than {max_bytes >> 20} MiB: not a scene '
                             'file')
        raw = path.read_bytes()
    except OSError as exc:
        raise SceneError(f'{label}: cannot read: {exc.strerror or type(exc).__name__}') \
            from None
    try:
        text = raw.decode('utf-8')
    except UnicodeDecodeError as exc:
        raise SceneError(f'{label}: is not UTF-8 text (byte {exc.start}): not a scene '
                         'file') from None
    try:
        loader = yaml.SafeLoader(text)
        try:
            node = loader.get_single_node()
            data = None if node is None else loader.construct_document(node)
        finally:
            loader.dispose()
    except yaml.YAMLError as exc:
        raise SceneError(f'{label}: invalid YAML at {yaml_problem(exc)}') from None
    return data, ({} if node is None else yaml_lines(node))


class Where:
    """Builds error messages: '<file>: line <n>: body '<name>': <key> <reason>'.

    ``lines`` (:func:`yaml_lines`) gives the line of each key; ``path`` is where this
    Where's keys are ('bodies[2]' for a body's keys)."""

    def __init__(self, source: str, body: Optional[str] = None,
                 lines: Optional[Mapping[str, int]] = None, path: str = ''):
        self.source = source
        self.body = body
        self.lines = lines or {}
        self.path = path

    def line(self, key: Optional[str]) -> Optional[int]:
        """The line of ``key`` (or of the nearest enclosing key that the file has)."""
        path = '.'.join(p for p in (self.path, key or '') if p)
        while path:
            if path in self.lines:
                return self.lines[path]
            path = _parent(path)
        return self.lines.get('') if not (self.path or key) else None

    def error(self, key: Optional[str], reason: str, at: Optional[str] = None
              ) -> SceneError:
        """Return the SceneError for ``key`` (None: the body or file itself); ``at`` is
        the key whose line to give when it is not ``key``."""
        parts = [self.source]
        line = self.line(at or key)
        if line is not None:
            parts.append(f'line {line}')
        if self.body is not None:
            parts.append(f"body '{self.body}'")
        parts.append(f'{key} {reason}' if key else reason)
        return SceneError(': '.join(parts))

    def number(self, key: str, value: Any, *, gt: Optional[float] = None,
               ge: Optional[float] = None, le: Optional[float] = None) -> float:
        """Return ``value`` as a finite float within the bounds; raise SceneError if not."""
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise self.error(key, f'must be a number, got {fmt(value)}')
        v = float(value)
        if not math.isfinite(v):
            raise self.error(key, f'must be finite, got {fmt(value)}')
        if gt is not None and not v > gt:
            raise self.error(key, f'must be > {fmt(gt)}, got {fmt(value)}')
        if ge is not None and not v >= ge:
            raise self.error(key, f'must be >= {fmt(ge)}, got {fmt(value)}')
        if le is not None and not v <= le:
            raise self.error(key, f'must be <= {fmt(le)}, got {fmt(value)}')
        return v

    def integer(self, key: str, value: Any, *, ge: int = 1, le: Optional[int] = None) -> int:
        """Return ``value`` as an int within the bounds; raise SceneError if not."""
        if isinstance(value, bool) or not isinstance(value, int):
            if isinstance(value, float) and value.is_integer():
                value = int(value)
            else:
                raise self.error(key, f'must be an integer, got {fmt(value)}')
        if value < ge:
            raise self.error(key, f'must be >= {ge}, got {value}')
        if le is not None and value > le:
            raise self.error(key, f'must be <= {le}, got {value}')
        return int(value)

    def vector(self, key: str, value: Any, n: int, *, gt: Optional[float] = None
               ) -> np.ndarray:
        """Return ``value`` as n finite floats (each > ``gt``); raise SceneError if not."""
        if not isinstance(value, (list, tuple)) or len(value) != n:
            raise self.error(key, f'must be a list of {n} numbers, got {fmt(value)}')
        out = np.empty(n)
        for i, v in enumerate(value):
            if isinstance(v, bool) or not isinstance(v, (int, float)) \
                    or not math.isfinite(float(v)):
                raise self.error(key, f'must be a list of {n} finite numbers, '
                                      f'got {fmt(value)}')
            out[i] = float(v)
        if gt is not None and not np.all(out > gt):
            raise self.error(key, f'must be > {fmt(gt)} in every component, '
                                  f'got {fmt(value)}')
        return out

    def string(self, key: str, value: Any) -> str:
        """Return ``value`` stripped if it is a non-empty string; raise SceneError if not."""
        if not isinstance(value, str) or not value.strip():
            raise self.error(key, f'must be a non-empty string, got {fmt(value)}')
        return value.strip()

    def choice(self, key: str, value: Any, options: Sequence[str]) -> str:
        """Return ``value`` if it is one of ``options``; raise SceneError if not."""
        if value not in options:
            raise self.error(key, f"must be one of {', '.join(options)}, got {fmt(value)}")
        return value

    def boolean(self, key: str, value: Any) -> bool:
        """Return ``value`` if it is a bool; raise SceneError if not."""
        if not isinstance(value, bool):
            raise self.error(key, f'must be true or false, got {fmt(value)}')
        return value

    def mapping(self, key: Optional[str], value: Any, allowed: Sequence[str]
                ) -> Mapping[str, Any]:
        """Return ``value`` if it is a mapping with only ``allowed`` keys (suggests one)."""
        if not isinstance(value, dict):
            raise self.error(key, f'must be a mapping, got {kind(value)}')
        for k in value:
            if k not in allowed:
                name = f'{key}.{k}' if key else str(k)
                close = difflib.get_close_matches(str(k), allowed, n=1)
                hint = f" (did you mean '{close[0]}'?)" if close else ''
                # a file's own top-level keys are named only when they are a typo of a
                # scene key: any other file must not have its text quoted
                if not (key or self.body or close):
                    name = 'at the top level'
                else:
                    name = f"'{name}'"
                raise self.error(None, f'unknown key {name}{hint}; '
                                       f"allowed: {', '.join(allowed)}",
                                 at=f'{key}.{k}' if key else str(k))
        return value
