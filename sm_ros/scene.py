"""
Scene files: find, parse and validate a scene YAML into a SceneSpec.

The format is documented in doc/scenes.md. The data path is::

    load_scene(name or path) -> SceneSpec (plain NumPy arrays, fully validated)
    build_world(spec, defaults) -> (sm_ros.core.World, [BodyMeta])

``load_scene`` and the parsing are here; the results and the error wording are in
``sm_ros.scene_spec``, ``build_world`` and the rules that combine a scene with the node's
parameters in ``sm_ros.scene_build`` (both importable from here too).

A bad scene raises :class:`SceneError` naming the file, the body and the key, e.g.
``scenes/x.yaml: body 'sponge': spacing must be > 0, got -1``; nothing is half-loaded
(``load_scene`` returns only after every body was built, ``build_world`` makes a new World).
No rclpy here; the solver core is imported only by the functions that need it, and trimesh
only when a scene has a mesh body.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any, Dict, List, Mapping, Optional, Tuple, Union

import numpy as np

from sm_ros import params, point_files, shapes
from sm_ros.scene_build import (add_spec_body, body_contact_from, build_world,  # noqa: F401
                                cloud_body_spec, contact_from, core_colliders, DEFAULT_MASS,
                                ground_from, params_from)
from sm_ros.scene_colliders import parse_colliders
from sm_ros.scene_spec import (BodyMeta, BodySpec, CONTACT_SCENE_KEYS, fmt as _fmt,  # noqa: F401
                               kind as _kind, read_yaml, SceneError, SceneSpec,
                               Where as _Where)
from sm_ros.shapes import GeometryError, Surface

SHAPES = ('box', 'sphere', 'cylinder', 'capsule', 'sheet', 'rope', 'mesh', 'cloud')

#: Largest total number of particles a scene may have.
MAX_SCENE_POINTS = 2_000_000

DEFAULT_SPACING = 0.05      # m

#: Largest scene file read (bytes): anything larger is no scene.
MAX_SCENE_BYTES = 16 << 20

_COMMON_KEYS = ('name', 'shape', 'position', 'orientation', 'mass', 'density', 'velocity',
                'angular_velocity', 'pinned', 'copies', 'collide', 'contact_radius',
                'self_collision') + tuple(
                    dict.fromkeys(k.split('.', 1)[0] for k in params.OVERRIDE_KEYS))
_SHAPE_KEYS = {
    'box': ('size', 'spacing'),
    'sphere': ('radius', 'spacing'),
    'cylinder': ('radius', 'length', 'spacing'),
    'capsule': ('radius', 'length', 'spacing'),
    'sheet': ('size', 'spacing'),
    'rope': ('length', 'spacing'),
    'mesh': ('file', 'fill', 'spacing', 'scale', 'center'),
    'cloud': ('file', 'scale', 'center', 'max_points', 'voxel'),
}
_LATTICE_SHAPES = ('box', 'sphere', 'cylinder', 'capsule')
_TOP_KEYS = ('description', 'bodies', 'colliders', 'contact')


# ----------------------------------------------------------------------------------------
# Finding scenes
# ----------------------------------------------------------------------------------------

def scene_dirs() -> List[Path]:
    """
    Folders searched for bundled scenes, in order.

    1. ``<repo>/config/scenes`` next to the package (a source checkout or develop install);
    2. ``<share>/sm_ros/config/scenes`` from ament_index (a colcon install);
    3. ``<sys.prefix>/share/sm_ros/config/scenes`` (a pip install with data_files).
    """
    dirs = [Path(__file__).resolve().parent.parent / 'config' / 'scenes']
    try:
        from ament_index_python.packages import get_package_share_directory
        dirs.append(Path(get_package_share_directory('sm_ros')) / 'config' / 'scenes')
    except Exception:  # noqa: B902 - not installed, not found: fall through
        pass
    dirs.append(Path(sys.prefix) / 'share' / 'sm_ros' / 'config' / 'scenes')
    return [folder for folder in dirs if folder.is_dir()]


def list_scenes() -> List[str]:
    """Names of the bundled scenes."""
    names = set()
    for folder in scene_dirs():
        names.update(path.stem for path in folder.glob('*.yaml'))
    return sorted(names)


def resolve_scene(name_or_path: Union[str, Path]) -> Path:
    """
    The file of a scene: an existing path as given, or a bundled scene by name.

    '' means 'default'. Raises SceneError when neither exists.
    """
    text = str(name_or_path).strip() or 'default'
    path = Path(text).expanduser()
    if path.is_file():
        return path
    looks_like_path = ('/' in text or text.endswith(('.yaml', '.yml')))
    if not looks_like_path:
        for folder in scene_dirs():
            candidate = folder / f'{text}.yaml'
            if candidate.is_file():
                return candidate
    bundled = ', '.join(list_scenes()) or 'none found'
    raise SceneError(f'{text}: no such scene file and no bundled scene of that name '
                     f'(bundled: {bundled})')


# ----------------------------------------------------------------------------------------
# Parsing
# ----------------------------------------------------------------------------------------

def load_scene(name_or_path: Union[str, Path] = '') -> SceneSpec:
    """
    Load and validate a scene: a bundled scene name ('' = 'default') or a YAML path.

    Returns a SceneSpec whose bodies are fully built (world coordinates). Raises SceneError
    naming the file, body and key; nothing is half-loaded.
    """
    path = resolve_scene(name_or_path)
    given = str(name_or_path).strip()
    label = str(path) if (not given or not Path(given).expanduser().is_file()) else given
    data, lines = read_yaml(path, label, MAX_SCENE_BYTES)
    return parse_scene(data, label, path.resolve().parent, lines=lines)


def parse_scene(data: Any, source: str = '<scene>',
                base_dir: Union[str, Path, None] = None,
                lines: Optional[Mapping[str, int]] = None) -> SceneSpec:
    """
    Validate a scene given as already-parsed YAML data (a dict) and build its bodies.

    `source` labels error messages; relative ``file`` paths resolve against `base_dir`
    (default: the current directory); ``lines`` (``scene_spec.yaml_lines``) adds the
    line of the key to each error.  An error names the kind of a bad value, never its text.
    """
    where = _Where(source, lines=lines)
    base = Path(base_dir) if base_dir is not None else Path.cwd()
    if data is None:
        raise where.error(None, 'is empty (expected a mapping with a bodies list)')
    top = where.mapping(None, data, _TOP_KEYS)
    description = top.get('description', '')
    if not isinstance(description, str):
        raise where.error('description', f'must be a string, got {_kind(description)}')
    colliders = parse_colliders(where, top.get('colliders'))
    contact = _parse_contact(where, top.get('contact'))
    raw_bodies = top.get('bodies')
    if not isinstance(raw_bodies, list) or not raw_bodies:
        raise where.error('bodies', f'must be a non-empty list, got {_kind(raw_bodies)}')
    bodies: List[BodySpec] = []
    seen: Dict[str, int] = {}
    total = 0
    for i, raw in enumerate(raw_bodies):
        for b in _parse_body(where, base, i, raw):
            if b.name in seen:
                raise _Where(source, b.name, lines, f'bodies[{i}]').error(
                    'name', f'is used twice (bodies #{seen[b.name]} and #{i})')
            seen[b.name] = i
            total += b.n
            if total > MAX_SCENE_POINTS:
                raise _Where(source, b.name, lines, f'bodies[{i}]').error(
                    None, f'the scene exceeds {MAX_SCENE_POINTS} particles')
            bodies.append(b)
    return SceneSpec(bodies=bodies, colliders=colliders, source=source,
                     description=description.strip(), contact=contact)


def _parse_contact(where: _Where, raw: Any) -> Dict[str, Any]:
    """The top-level ``contact`` mapping (ranges of the ``contact.*`` node parameters)."""
    if raw is None:
        return {}
    c = where.mapping('contact', raw, CONTACT_SCENE_KEYS)
    out: Dict[str, Any] = {}
    for key, value in c.items():
        param = params.BY_NAME[f'contact.{key}']
        if param.type_name == 'bool':
            out[key] = where.boolean(f'contact.{key}', value)
            continue
        number = where.number(f'contact.{key}', value)
        why = param.check(number)
        if why:
            raise where.error(f'contact.{key}', why.split(' ', 1)[1])
        out[key] = number
    return out


def _parse_body_contact(where: '_Where', entry: Mapping[str, Any]) -> Dict[str, Any]:
    """A body's ``collide``, ``contact_radius`` and ``self_collision`` keys."""
    out: Dict[str, Any] = {}
    if 'collide' in entry:
        out['collide'] = where.boolean('collide', entry['collide'])
    if 'self_collision' in entry:
        out['self_collision'] = where.boolean('self_collision', entry['self_collision'])
    if 'contact_radius' in entry:
        out['contact_radius'] = where.number('contact_radius', entry['contact_radius'], gt=0.0)
    return out


def _parse_overrides(where: _Where, entry: Mapping[str, Any]) -> Dict[str, Any]:
    """Return the parameter overrides a body sets, validated with the parameter table."""
    found: Dict[str, Any] = {}
    groups: Dict[str, List[str]] = {}
    for key in params.OVERRIDE_KEYS:
        group, _, sub = key.rpartition('.')
        if group:
            groups.setdefault(group, []).append(sub)
    for group, subs in groups.items():
        if group in entry:
            where.mapping(group, entry[group], subs)
    for key in params.OVERRIDE_KEYS:
        group, _, sub = key.rpartition('.')
        source = entry.get(group, {}) if group else entry
        if sub in source:
            found[key] = _override(where, params.BY_NAME[key], source[sub])
    return found


def _override(where: _Where, param: 'params.Param', value: Any) -> Any:
    """Validate one override against its row of the parameter table."""
    if param.choices:
        return where.choice(param.name, value, param.choices)
    if param.type_name == 'integer':
        return where.integer(param.name, value, ge=int(param.lo), le=int(param.hi))
    if param.type_name == 'double':
        if param.positive:
            return where.number(param.name, value, gt=param.lo, le=param.hi)
        return where.number(param.name, value, ge=param.lo, le=param.hi)
    raise TypeError(f'parameter {param.name}: a scene override of type {param.type_name} is not '
                    'supported')


def _orientation(where: _Where, raw: Any) -> np.ndarray:
    if raw is None:
        return np.eye(3)
    if isinstance(raw, (list, tuple)) and len(raw) == 4:
        q = where.vector('orientation', raw, 4)
        if not np.linalg.norm(q) > 1e-12:
            raise where.error('orientation', 'quaternion must be non-zero')
        return shapes.quat_to_matrix(q)
    if isinstance(raw, (list, tuple)) and len(raw) == 3:
        return shapes.rpy_to_matrix(where.vector('orientation', raw, 3))
    raise where.error('orientation', 'must be [roll, pitch, yaw] (radians) or a quaternion '
                                 f'[x, y, z, w], got {_fmt(raw)}')


def _resolve_file(where: _Where, base: Path, raw: Any) -> Path:
    name = where.string('file', raw)
    path = Path(name).expanduser()
    if not path.is_absolute():
        path = base / path
    if not path.is_file():
        raise where.error('file', f"'{name}' not found (looked for {path})")
    return path


def _load_mesh(where: _Where, path: Path) -> Tuple[np.ndarray, np.ndarray]:
    """Vertices (V, 3) and faces (F, 3) of a mesh file, read with trimesh (lazily)."""
    try:
        import trimesh
    except ImportError:
        raise where.error('file', 'needs trimesh for mesh bodies '
                              '(pip install trimesh, or the sm_ros[mesh] extra)') from None
    try:
        mesh = trimesh.load(str(path), force='mesh', process=True)
    except Exception as exc:  # noqa: B902 - trimesh raises many kinds
        # the reader's message may quote the file: only its kind is reported
        raise where.error('file', f"'{path.name}' cannot be read as a mesh "
                              f'({type(exc).__name__})') from None
    faces = np.asarray(getattr(mesh, 'faces', np.zeros((0, 3))), dtype=np.int64)
    if faces.ndim != 2 or len(faces) == 0:
        raise where.error('file', f"'{path.name}' has no triangles "
                              '(a point cloud? use shape: cloud)')
    mesh.remove_unreferenced_vertices()
    verts = np.asarray(mesh.vertices, dtype=np.float64)
    faces = np.asarray(mesh.faces, dtype=np.int64)
    if not np.all(np.isfinite(verts)):
        raise where.error('file', f"'{path.name}' has non-finite vertices")
    return verts, faces


def _build_local(where: _Where, shape: str, entry: Mapping[str, Any], base: Path
                 ) -> Tuple[np.ndarray, Optional[np.ndarray], Optional[np.ndarray]]:
    """Local points (N, 3), and for meshes faces and local surface vertices."""
    spacing = None
    if 'spacing' in entry or shape in _LATTICE_SHAPES + ('sheet', 'rope') or (
            shape == 'mesh' and entry.get('fill', 'lattice') == 'lattice'):
        spacing = where.number('spacing', entry.get('spacing', DEFAULT_SPACING), gt=0.0)
    faces = surf = None
    try:
        if shape == 'box':
            pts = shapes.box_lattice(where.vector('size', entry.get('size'), 3, gt=0.0), spacing)
        elif shape == 'sphere':
            radius = where.number('radius', entry.get('radius'), gt=0.0)
            pts = shapes.sphere_lattice(radius, spacing)
        elif shape in ('cylinder', 'capsule'):
            radius = where.number('radius', entry.get('radius'), gt=0.0)
            length = where.number('length', entry.get('length'),
                              **({'gt': 0.0} if shape == 'cylinder' else {'ge': 0.0}))
            lattice = shapes.cylinder_lattice if shape == 'cylinder' else shapes.capsule_lattice
            pts = lattice(radius, length, spacing)
        elif shape == 'sheet':
            pts = shapes.sheet_lattice(where.vector('size', entry.get('size'), 2, gt=0.0), spacing)
        elif shape == 'rope':
            pts = shapes.rope_points(where.number('length', entry.get('length'), gt=0.0), spacing)
        elif shape == 'mesh':
            fill = where.choice('fill', entry.get('fill', 'lattice'), ('lattice', 'vertices'))
            verts, faces = _load_mesh(where, _resolve_file(where, base, entry.get('file')))
            verts = _scale_center(where, entry, verts)
            if fill == 'vertices':
                pts, surf = verts, None
            else:
                pts, surf = shapes.mesh_lattice(verts, faces, spacing), verts
        else:  # cloud
            path = _resolve_file(where, base, entry.get('file'))
            pts = _scale_center(where, entry, point_files.read_cloud_file(path))
            voxel = None
            if 'voxel' in entry:
                voxel = where.number('voxel', entry['voxel'], gt=0.0)
                pts = shapes.voxel_downsample(pts, voxel)
            if 'max_points' in entry:
                cap = where.integer('max_points', entry['max_points'], ge=1)
                pts = shapes.voxel_downsample(pts, shapes.voxel_size_for(pts, cap))
            if len(pts) > shapes.MAX_BODY_POINTS:
                raise GeometryError(f'has {len(pts)} points (limit {shapes.MAX_BODY_POINTS}); '
                                    'set max_points or voxel', key='max_points')
    except GeometryError as exc:
        key = exc.key or ('file' if shape in ('mesh', 'cloud') else 'spacing')
        reason = f"'{entry.get('file')}': {exc}" if key == 'file' else str(exc)
        raise where.error(key, reason) from None
    return pts, faces, surf


def _scale_center(where: _Where, entry: Mapping[str, Any], pts: np.ndarray) -> np.ndarray:
    if 'scale' in entry:
        s = entry['scale']
        if isinstance(s, (list, tuple)):
            pts = pts * where.vector('scale', s, 3, gt=0.0)
        else:
            pts = pts * where.number('scale', s, gt=0.0)
    if where.boolean('center', entry.get('center', False)):
        pts = pts - (pts.min(axis=0) + pts.max(axis=0)) / 2.0
    return pts


def _pinned(where: _Where, raw: Any, points: np.ndarray, offset: np.ndarray) -> np.ndarray:
    if raw is None:
        return np.zeros(0, dtype=np.int64)
    regions = raw if isinstance(raw, list) else [raw]
    mask = np.zeros(len(points), dtype=bool)
    for i, r in enumerate(regions):
        key = 'pinned' if not isinstance(raw, list) else f'pinned[{i}]'
        region = where.mapping(key, r, ('lo', 'hi'))
        lo = where.vector(f'{key}.lo', region.get('lo'), 3) + offset
        hi = where.vector(f'{key}.hi', region.get('hi'), 3) + offset
        if not np.all(hi >= lo):
            raise where.error(f'{key}.hi', f'must be >= lo in every axis, got lo '
                                       f'{(lo - offset).tolist()} hi {(hi - offset).tolist()}')
        inside = np.all((points >= lo) & (points <= hi), axis=1)
        if not inside.any():
            raise where.error(key, 'contains no particle of the body (the region is in world '
                               'coordinates)')
        mask |= inside
    return np.flatnonzero(mask).astype(np.int64)


def _parse_body(top: _Where, base: Path, index: int, raw: Any) -> List[BodySpec]:
    """Validate and build one body entry (several with ``copies``)."""
    at = f'bodies[{index}]'
    if not isinstance(raw, dict):
        raise top.error(at, f'must be a mapping, got {_kind(raw)}')
    name = raw.get('name', f'body{index}')
    if not isinstance(name, str) or not name.strip() or any(c.isspace() for c in name):
        raise _Where(top.source, f'#{index}', top.lines, at).error(
            'name', f'must be a non-empty string without spaces, got {_fmt(name)}')
    where = _Where(top.source, name, top.lines, at)
    shape = raw.get('shape')
    if shape is None:
        raise where.error('shape', f"is required (one of {', '.join(SHAPES)})")
    where.choice('shape', shape, SHAPES)
    entry = where.mapping(None, raw, _COMMON_KEYS + _SHAPE_KEYS[shape])
    overrides = _parse_overrides(where, entry)
    contact = _parse_body_contact(where, entry)
    position = where.vector('position', entry.get('position', [0.0, 0.0, 0.0]), 3)
    rot = _orientation(where, entry.get('orientation'))
    local, faces, surf_local = _build_local(where, shape, entry, base)
    points = local @ rot.T + position
    surf_world = None if surf_local is None else surf_local @ rot.T + position
    masses = _masses(where, shape, entry, len(points))
    # velocities (linear + angular about the centre of mass)
    velocity = (where.vector('velocity', entry['velocity'], 3) if 'velocity' in entry
                else np.zeros(3))
    omega = (where.vector('angular_velocity', entry['angular_velocity'], 3)
             if 'angular_velocity' in entry else np.zeros(3))
    offsets = _copy_offsets(where, entry, len(points))
    out = []
    for copy, offset in enumerate(offsets):
        pts = points + offset
        vel = None
        if np.any(velocity) or np.any(omega):
            com = np.average(pts, axis=0, weights=masses)
            vel = velocity + np.cross(omega, pts - com)
        surface = None
        if faces is not None:
            surface = (Surface.direct(faces, pts) if surf_world is None
                       else Surface.embedded(faces, surf_world + offset, pts))
        out.append(BodySpec(name=name if len(offsets) == 1 else f'{name}_{copy}',
                            points=np.ascontiguousarray(pts), masses=masses.copy(),
                            velocities=vel,
                            pinned=_pinned(where, entry.get('pinned'), pts, offset),
                            overrides=dict(overrides), surface=surface, shape=shape,
                            contact=dict(contact)))
    return out


def _masses(where: _Where, shape: str, entry: Mapping[str, Any], count: int) -> np.ndarray:
    """Per-particle masses from ``mass`` (shared equally) or ``density`` (a lattice's)."""
    if 'mass' in entry and 'density' in entry:
        raise where.error('density', 'and mass are exclusive: give one')
    if 'density' not in entry:
        mass = where.number('mass', entry.get('mass', DEFAULT_MASS), gt=0.0)
        return np.full(count, mass / count)
    density = where.number('density', entry['density'], gt=0.0)
    if shape in _LATTICE_SHAPES or (shape == 'mesh' and entry.get('fill', 'lattice')
                                    == 'lattice'):
        spacing = where.number('spacing', entry.get('spacing', DEFAULT_SPACING), gt=0.0)
        return np.full(count, density * spacing ** 3)
    raise where.error('density', f'needs a volume lattice (box, sphere, cylinder, capsule, '
                                 f'mesh with fill: lattice); shape {shape} takes mass')


def _copy_offsets(where: _Where, entry: Mapping[str, Any], count: int) -> List[np.ndarray]:
    """The offset of each copy (``copies``: a grid of count[0] x count[1] x count[2])."""
    if 'copies' not in entry:
        return [np.zeros(3)]
    copies = where.mapping('copies', entry['copies'], ('count', 'step'))
    grid = copies.get('count')
    if not isinstance(grid, list) or len(grid) != 3:
        raise where.error('copies.count', f'must be a list of 3 integers, got {_fmt(grid)}')
    counts = [where.integer('copies.count', k, ge=1) for k in grid]
    step = where.vector('copies.step', copies.get('step'), 3)
    offsets = [np.array([i, j, k]) * step for i in range(counts[0])
               for j in range(counts[1]) for k in range(counts[2])]
    if len(offsets) * count > MAX_SCENE_POINTS:
        raise where.error('copies.count', f'makes {len(offsets) * count} particles '
                                          f'(limit {MAX_SCENE_POINTS})')
    return offsets
