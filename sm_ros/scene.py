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

import math
import sys
from pathlib import Path
from typing import Any, Dict, List, Mapping, Optional, Tuple, Union

import numpy as np

from sm_ros import params, point_files, shapes
from sm_ros.scene_build import (add_spec_body, body_contact_from, build_world,  # noqa: F401
                                cloud_body_spec, contact_from, core_colliders, DEFAULT_MASS,
                                ground_from, params_from)
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
    return [d for d in dirs if d.is_dir()]


def list_scenes() -> List[str]:
    """Names of the bundled scenes."""
    names = set()
    for d in scene_dirs():
        names.update(p.stem for p in d.glob('*.yaml'))
    return sorted(names)


def resolve_scene(name_or_path: Union[str, Path]) -> Path:
    """
    The file of a scene: an existing path as given, or a bundled scene by name.

    '' means 'default'. Raises SceneError when neither exists.
    """
    text = str(name_or_path).strip() or 'default'
    p = Path(text).expanduser()
    if p.is_file():
        return p
    looks_like_path = ('/' in text or text.endswith(('.yaml', '.yml')))
    if not looks_like_path:
        for d in scene_dirs():
            cand = d / f'{text}.yaml'
            if cand.is_file():
                return cand
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
    colliders = _parse_colliders(where, top.get('colliders'))
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
        p = params.BY_NAME[f'contact.{key}']
        if p.type_name == 'bool':
            out[key] = where.boolean(f'contact.{key}', value)
            continue
        v = where.number(f'contact.{key}', value)
        why = p.check(v)
        if why:
            raise where.error(f'contact.{key}', why.split(' ', 1)[1])
        out[key] = v
    return out


def _parse_body_contact(w: '_Where', b: Mapping[str, Any]) -> Dict[str, Any]:
    """A body's ``collide``, ``contact_radius`` and ``self_collision`` keys."""
    out: Dict[str, Any] = {}
    if 'collide' in b:
        out['collide'] = w.boolean('collide', b['collide'])
    if 'self_collision' in b:
        out['self_collision'] = w.boolean('self_collision', b['self_collision'])
    if 'contact_radius' in b:
        out['contact_radius'] = w.number('contact_radius', b['contact_radius'], gt=0.0)
    return out


#: Keys every box, sphere and capsule collider may have beside its geometry.
_COLLIDER_KEYS = ('name', 'orientation', 'kinematic', 'path', 'friction', 'restitution')


def _parse_colliders(where: _Where, raw: Any) -> Dict[str, Any]:
    out: Dict[str, Any] = {'ground': None, 'boxes': [], 'spheres': [], 'capsules': []}
    if raw is None:
        return out
    c = where.mapping('colliders', raw, ('ground', 'boxes', 'spheres', 'capsules'))
    g = c.get('ground')
    if isinstance(g, bool):
        out['ground'] = {'enabled': g}
    elif g is not None:
        gm = where.mapping('colliders.ground', g,
                           ('enabled', 'height', 'friction', 'restitution'))
        ground: Dict[str, Any] = {'enabled': True}
        if 'enabled' in gm:
            ground['enabled'] = where.boolean('colliders.ground.enabled', gm['enabled'])
        if 'height' in gm:
            ground['height'] = where.number('colliders.ground.height', gm['height'])
        if 'friction' in gm:
            ground['friction'] = where.number('colliders.ground.friction', gm['friction'],
                                              ge=0.0)
        if 'restitution' in gm:
            ground['restitution'] = where.number('colliders.ground.restitution',
                                                 gm['restitution'], ge=0.0, le=1.0)
        out['ground'] = ground
    names: Dict[str, str] = {}
    for kind in ('boxes', 'spheres', 'capsules'):
        items = c.get(kind, [])
        if not isinstance(items, list):
            raise where.error(f'colliders.{kind}', f'must be a list, got {_fmt(items)}')
        for i, item in enumerate(items):
            key = f'colliders.{kind}[{i}]'
            if kind == 'boxes':
                entry = _parse_box(where, key, item)
            elif kind == 'spheres':
                sm = where.mapping(key, item, ('center', 'radius') + _COLLIDER_KEYS)
                entry = {'center': where.vector(f'{key}.center', sm.get('center'), 3),
                         'radius': where.number(f'{key}.radius', sm.get('radius'), gt=0.0),
                         **_collider_extras(where, key, sm)}
            else:
                cm = where.mapping(key, item, ('center', 'radius', 'length') + _COLLIDER_KEYS)
                entry = {'center': where.vector(f'{key}.center', cm.get('center'), 3),
                         'radius': where.number(f'{key}.radius', cm.get('radius'), gt=0.0),
                         'length': where.number(f'{key}.length', cm.get('length', 0.0),
                                                ge=0.0),
                         **_collider_extras(where, key, cm)}
            name = entry.get('name')
            if name is not None:
                if name in names:
                    raise where.error(f'{key}.name', f"'{name}' is already the name of "
                                                     f'{names[name]}')
                names[name] = key
            out[kind].append(entry)
    return out


def _parse_box(where: _Where, key: str, b: Any) -> Dict[str, Any]:
    bm = where.mapping(key, b, ('lo', 'hi', 'center', 'size') + _COLLIDER_KEYS)
    if 'lo' in bm or 'hi' in bm:
        if 'center' in bm or 'size' in bm:
            raise where.error(key, 'takes either lo/hi or center/size, not both')
        lo = where.vector(f'{key}.lo', bm.get('lo'), 3)
        hi = where.vector(f'{key}.hi', bm.get('hi'), 3)
    else:
        centre = where.vector(f'{key}.center', bm.get('center'), 3)
        size = where.vector(f'{key}.size', bm.get('size'), 3, gt=0.0)
        lo, hi = centre - size / 2.0, centre + size / 2.0
    if not np.all(hi > lo):
        raise where.error(f'{key}.hi', f'must exceed lo in every axis, got lo '
                                       f'{lo.tolist()} hi {hi.tolist()}')
    return {'lo': lo, 'hi': hi, **_collider_extras(where, key, bm)}


def _collider_quat(where: _Where, key: str, raw: Any) -> np.ndarray:
    """A unit quaternion (x, y, z, w) from [roll, pitch, yaw] or a quaternion."""
    if isinstance(raw, (list, tuple)) and len(raw) == 4:
        q = where.vector(key, raw, 4)
        n = float(np.linalg.norm(q))
        if not n > 1e-12:
            raise where.error(key, 'quaternion must be non-zero')
        return q / n
    if isinstance(raw, (list, tuple)) and len(raw) == 3:
        r, p, y = where.vector(key, raw, 3)
        cr, sr = math.cos(r / 2), math.sin(r / 2)
        cp, sp = math.cos(p / 2), math.sin(p / 2)
        cy, sy = math.cos(y / 2), math.sin(y / 2)
        return np.array([sr * cp * cy - cr * sp * sy, cr * sp * cy + sr * cp * sy,
                         cr * cp * sy - sr * sp * cy, cr * cp * cy + sr * sp * sy])
    raise where.error(key, 'must be [roll, pitch, yaw] (radians) or a quaternion '
                           f'[x, y, z, w], got {_fmt(raw)}')


def _collider_extras(where: _Where, key: str, m: Mapping[str, Any]) -> Dict[str, Any]:
    """Friction, restitution and the optional name, orientation, kinematic and path."""
    out: Dict[str, Any] = _contact(where, key, m)
    if 'name' in m:
        name = m['name']
        if not isinstance(name, str) or not name or any(ch.isspace() for ch in name):
            raise where.error(f'{key}.name', 'must be a non-empty string without spaces, '
                                             f'got {_fmt(name)}')
        out['name'] = name
    if 'orientation' in m:
        out['orientation'] = _collider_quat(where, f'{key}.orientation', m['orientation'])
    kinematic = where.boolean(f'{key}.kinematic', m['kinematic']) if 'kinematic' in m \
        else False
    if kinematic and 'name' not in out:
        raise where.error(f'{key}.kinematic', 'needs a name (the frame_id of collider_pose)')
    out['kinematic'] = kinematic
    if 'path' in m:
        if not kinematic:
            raise where.error(f'{key}.path', 'needs kinematic: true')
        path = m['path']
        if not isinstance(path, list) or not path:
            raise where.error(f'{key}.path', 'must be a non-empty list of {time, position'
                                             f'[, orientation]}}, got {_fmt(path)}')
        frames = []
        last = 0.0
        for j, f in enumerate(path):
            fk = f'{key}.path[{j}]'
            fm = where.mapping(fk, f, ('time', 'position', 'orientation'))
            t = where.number(f'{fk}.time', fm.get('time'), gt=last)
            last = t
            pos = where.vector(f'{fk}.position', fm.get('position'), 3)
            quat = _collider_quat(where, f'{fk}.orientation', fm['orientation']) \
                if 'orientation' in fm else None
            frames.append((t, pos, quat))
        out['path'] = frames
    return out


def _contact(where: _Where, key: str, m: Mapping[str, Any]) -> Dict[str, float]:
    """Friction (default 0.5) and restitution (default 0) of a box or sphere collider."""
    return {'friction': where.number(f'{key}.friction', m.get('friction', 0.5), ge=0.0),
            'restitution': where.number(f'{key}.restitution', m.get('restitution', 0.0),
                                        ge=0.0, le=1.0)}


def _parse_overrides(w: _Where, b: Mapping[str, Any]) -> Dict[str, Any]:
    """Return the parameter overrides a body sets, validated with the parameter table."""
    ov: Dict[str, Any] = {}
    groups: Dict[str, List[str]] = {}
    for key in params.OVERRIDE_KEYS:
        group, _, sub = key.rpartition('.')
        if group:
            groups.setdefault(group, []).append(sub)
    for group, subs in groups.items():
        if group in b:
            w.mapping(group, b[group], subs)
    for key in params.OVERRIDE_KEYS:
        group, _, sub = key.rpartition('.')
        source = b.get(group, {}) if group else b
        if sub in source:
            ov[key] = _override(w, params.BY_NAME[key], source[sub])
    return ov


def _override(w: _Where, p: 'params.Param', value: Any) -> Any:
    """Validate one override against its row of the parameter table."""
    if p.choices:
        return w.choice(p.name, value, p.choices)
    if p.type_name == 'integer':
        return w.integer(p.name, value, ge=int(p.lo), le=int(p.hi))
    if p.type_name == 'double':
        if p.positive:
            return w.number(p.name, value, gt=p.lo, le=p.hi)
        return w.number(p.name, value, ge=p.lo, le=p.hi)
    raise TypeError(f'parameter {p.name}: a scene override of type {p.type_name} is not '
                    'supported')


def _orientation(w: _Where, raw: Any) -> np.ndarray:
    if raw is None:
        return np.eye(3)
    if isinstance(raw, (list, tuple)) and len(raw) == 4:
        q = w.vector('orientation', raw, 4)
        if not np.linalg.norm(q) > 1e-12:
            raise w.error('orientation', 'quaternion must be non-zero')
        return shapes.quat_to_matrix(q)
    if isinstance(raw, (list, tuple)) and len(raw) == 3:
        return shapes.rpy_to_matrix(w.vector('orientation', raw, 3))
    raise w.error('orientation', 'must be [roll, pitch, yaw] (radians) or a quaternion '
                                 f'[x, y, z, w], got {_fmt(raw)}')


def _resolve_file(w: _Where, base: Path, raw: Any) -> Path:
    name = w.string('file', raw)
    p = Path(name).expanduser()
    if not p.is_absolute():
        p = base / p
    if not p.is_file():
        raise w.error('file', f"'{name}' not found (looked for {p})")
    return p


def _load_mesh(w: _Where, path: Path) -> Tuple[np.ndarray, np.ndarray]:
    """Vertices (V, 3) and faces (F, 3) of a mesh file, read with trimesh (lazily)."""
    try:
        import trimesh
    except ImportError:
        raise w.error('file', 'needs trimesh for mesh bodies '
                              '(pip install trimesh, or the sm_ros[mesh] extra)') from None
    try:
        mesh = trimesh.load(str(path), force='mesh', process=True)
    except Exception as exc:  # noqa: B902 - trimesh raises many kinds
        # the reader's message may quote the file: only its kind is reported
        raise w.error('file', f"'{path.name}' cannot be read as a mesh "
                              f'({type(exc).__name__})') from None
    faces = np.asarray(getattr(mesh, 'faces', np.zeros((0, 3))), dtype=np.int64)
    if faces.ndim != 2 or len(faces) == 0:
        raise w.error('file', f"'{path.name}' has no triangles "
                              '(a point cloud? use shape: cloud)')
    mesh.remove_unreferenced_vertices()
    verts = np.asarray(mesh.vertices, dtype=np.float64)
    faces = np.asarray(mesh.faces, dtype=np.int64)
    if not np.all(np.isfinite(verts)):
        raise w.error('file', f"'{path.name}' has non-finite vertices")
    return verts, faces


def _build_local(w: _Where, shape: str, b: Mapping[str, Any], base: Path
                 ) -> Tuple[np.ndarray, Optional[np.ndarray], Optional[np.ndarray]]:
    """Local points (N, 3), and for meshes faces and local surface vertices."""
    spacing = None
    if 'spacing' in b or shape in _LATTICE_SHAPES + ('sheet', 'rope') or (
            shape == 'mesh' and b.get('fill', 'lattice') == 'lattice'):
        spacing = w.number('spacing', b.get('spacing', DEFAULT_SPACING), gt=0.0)
    faces = surf = None
    try:
        if shape == 'box':
            pts = shapes.box_lattice(w.vector('size', b.get('size'), 3, gt=0.0), spacing)
        elif shape == 'sphere':
            pts = shapes.sphere_lattice(w.number('radius', b.get('radius'), gt=0.0), spacing)
        elif shape in ('cylinder', 'capsule'):
            radius = w.number('radius', b.get('radius'), gt=0.0)
            length = w.number('length', b.get('length'),
                              **({'gt': 0.0} if shape == 'cylinder' else {'ge': 0.0}))
            fn = shapes.cylinder_lattice if shape == 'cylinder' else shapes.capsule_lattice
            pts = fn(radius, length, spacing)
        elif shape == 'sheet':
            pts = shapes.sheet_lattice(w.vector('size', b.get('size'), 2, gt=0.0), spacing)
        elif shape == 'rope':
            pts = shapes.rope_points(w.number('length', b.get('length'), gt=0.0), spacing)
        elif shape == 'mesh':
            fill = w.choice('fill', b.get('fill', 'lattice'), ('lattice', 'vertices'))
            verts, faces = _load_mesh(w, _resolve_file(w, base, b.get('file')))
            verts = _scale_center(w, b, verts)
            if fill == 'vertices':
                pts, surf = verts, None
            else:
                pts, surf = shapes.mesh_lattice(verts, faces, spacing), verts
        else:  # cloud
            path = _resolve_file(w, base, b.get('file'))
            pts = _scale_center(w, b, point_files.read_cloud_file(path))
            voxel = None
            if 'voxel' in b:
                voxel = w.number('voxel', b['voxel'], gt=0.0)
                pts = shapes.voxel_downsample(pts, voxel)
            if 'max_points' in b:
                cap = w.integer('max_points', b['max_points'], ge=1)
                pts = shapes.voxel_downsample(pts, shapes.voxel_size_for(pts, cap))
            if len(pts) > shapes.MAX_BODY_POINTS:
                raise GeometryError(f'has {len(pts)} points (limit {shapes.MAX_BODY_POINTS}); '
                                    'set max_points or voxel', key='max_points')
    except GeometryError as exc:
        key = exc.key or ('file' if shape in ('mesh', 'cloud') else 'spacing')
        reason = f"'{b.get('file')}': {exc}" if key == 'file' else str(exc)
        raise w.error(key, reason) from None
    return pts, faces, surf


def _scale_center(w: _Where, b: Mapping[str, Any], pts: np.ndarray) -> np.ndarray:
    if 'scale' in b:
        s = b['scale']
        if isinstance(s, (list, tuple)):
            pts = pts * w.vector('scale', s, 3, gt=0.0)
        else:
            pts = pts * w.number('scale', s, gt=0.0)
    if w.boolean('center', b.get('center', False)):
        pts = pts - (pts.min(axis=0) + pts.max(axis=0)) / 2.0
    return pts


def _pinned(w: _Where, raw: Any, points: np.ndarray, offset: np.ndarray) -> np.ndarray:
    if raw is None:
        return np.zeros(0, dtype=np.int64)
    regions = raw if isinstance(raw, list) else [raw]
    mask = np.zeros(len(points), dtype=bool)
    for i, r in enumerate(regions):
        key = 'pinned' if not isinstance(raw, list) else f'pinned[{i}]'
        rm = w.mapping(key, r, ('lo', 'hi'))
        lo = w.vector(f'{key}.lo', rm.get('lo'), 3) + offset
        hi = w.vector(f'{key}.hi', rm.get('hi'), 3) + offset
        if not np.all(hi >= lo):
            raise w.error(f'{key}.hi', f'must be >= lo in every axis, got lo '
                                       f'{(lo - offset).tolist()} hi {(hi - offset).tolist()}')
        inside = np.all((points >= lo) & (points <= hi), axis=1)
        if not inside.any():
            raise w.error(key, 'contains no particle of the body (the region is in world '
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
    w = _Where(top.source, name, top.lines, at)
    shape = raw.get('shape')
    if shape is None:
        raise w.error('shape', f"is required (one of {', '.join(SHAPES)})")
    w.choice('shape', shape, SHAPES)
    b = w.mapping(None, raw, _COMMON_KEYS + _SHAPE_KEYS[shape])
    overrides = _parse_overrides(w, b)
    contact = _parse_body_contact(w, b)

    # placement
    position = w.vector('position', b.get('position', [0.0, 0.0, 0.0]), 3)
    rot = _orientation(w, b.get('orientation'))

    # geometry
    local, faces, surf_local = _build_local(w, shape, b, base)
    points = local @ rot.T + position
    surf_world = None if surf_local is None else surf_local @ rot.T + position
    n = len(points)

    # masses
    if 'mass' in b and 'density' in b:
        raise w.error('density', 'and mass are exclusive: give one')
    if 'density' in b:
        density = w.number('density', b['density'], gt=0.0)
        if shape in _LATTICE_SHAPES or (shape == 'mesh' and b.get('fill', 'lattice')
                                        == 'lattice'):
            spacing = w.number('spacing', b.get('spacing', DEFAULT_SPACING), gt=0.0)
            masses = np.full(n, density * spacing ** 3)
        else:
            raise w.error('density', f'needs a volume lattice (box, sphere, cylinder, '
                                     f'capsule, mesh with fill: lattice); shape {shape} '
                                     'takes mass')
    else:
        mass = w.number('mass', b.get('mass', DEFAULT_MASS), gt=0.0)
        masses = np.full(n, mass / n)

    # velocities (linear + angular about the centre of mass)
    v = w.vector('velocity', b['velocity'], 3) if 'velocity' in b else np.zeros(3)
    omega = (w.vector('angular_velocity', b['angular_velocity'], 3)
             if 'angular_velocity' in b else np.zeros(3))

    # copies
    offsets = [np.zeros(3)]
    if 'copies' in b:
        c = w.mapping('copies', b['copies'], ('count', 'step'))
        cnt = c.get('count')
        if not isinstance(cnt, list) or len(cnt) != 3:
            raise w.error('copies.count', f'must be a list of 3 integers, got {_fmt(cnt)}')
        counts = [w.integer('copies.count', k, ge=1) for k in cnt]
        step = w.vector('copies.step', c.get('step'), 3)
        offsets = [np.array([i, j, k]) * step for i in range(counts[0])
                   for j in range(counts[1]) for k in range(counts[2])]
        if len(offsets) * n > MAX_SCENE_POINTS:
            raise w.error('copies.count', f'makes {len(offsets) * n} particles '
                                          f'(limit {MAX_SCENE_POINTS})')

    out = []
    for ci, off in enumerate(offsets):
        pts = points + off
        bname = name if len(offsets) == 1 else f'{name}_{ci}'
        vel = None
        if np.any(v) or np.any(omega):
            com = np.average(pts, axis=0, weights=masses)
            vel = v + np.cross(omega, pts - com)
        pinned = _pinned(w, b.get('pinned'), pts, off)
        surface = None
        if faces is not None:
            surface = (Surface.direct(faces, pts) if surf_world is None
                       else Surface.embedded(faces, surf_world + off, pts))
        out.append(BodySpec(name=bname, points=np.ascontiguousarray(pts),
                            masses=masses.copy(), velocities=vel, pinned=pinned,
                            overrides=dict(overrides), surface=surface, shape=shape,
                            contact=dict(contact)))
    return out
