"""
The ``colliders`` key of a scene file: the ground and the boxes, spheres and capsules, with
their names, orientations, kinematic flags, scripted paths, friction and restitution
(doc/scenes.md). ``sm_ros.scene`` calls ``parse_colliders``; ``scene_build`` turns the
result into the core's colliders.
"""

from __future__ import annotations

import math
from typing import Any, Dict, Mapping

import numpy as np

from sm_ros.scene_spec import fmt as _fmt, Where

#: Keys every box, sphere and capsule collider may have beside its geometry.
_COLLIDER_KEYS = ('name', 'orientation', 'kinematic', 'path', 'friction', 'restitution')


def parse_colliders(where: Where, raw: Any) -> Dict[str, Any]:
    """The top-level ``colliders`` mapping: ground, boxes, spheres, capsules (names unique)."""
    out: Dict[str, Any] = {'ground': None, 'boxes': [], 'spheres': [], 'capsules': []}
    if raw is None:
        return out
    keys = where.mapping('colliders', raw, ('ground', 'boxes', 'spheres', 'capsules'))
    raw_ground = keys.get('ground')
    if isinstance(raw_ground, bool):
        out['ground'] = {'enabled': raw_ground}
    elif raw_ground is not None:
        given = where.mapping('colliders.ground', raw_ground,
                              ('enabled', 'height', 'friction', 'restitution'))
        ground: Dict[str, Any] = {'enabled': True}
        if 'enabled' in given:
            ground['enabled'] = where.boolean('colliders.ground.enabled', given['enabled'])
        if 'height' in given:
            ground['height'] = where.number('colliders.ground.height', given['height'])
        if 'friction' in given:
            ground['friction'] = where.number('colliders.ground.friction', given['friction'],
                                              ge=0.0)
        if 'restitution' in given:
            ground['restitution'] = where.number('colliders.ground.restitution',
                                                 given['restitution'], ge=0.0, le=1.0)
        out['ground'] = ground
    names: Dict[str, str] = {}
    for kind in ('boxes', 'spheres', 'capsules'):
        items = keys.get(kind, [])
        if not isinstance(items, list):
            raise where.error(f'colliders.{kind}', f'must be a list, got {_fmt(items)}')
        for i, item in enumerate(items):
            key = f'colliders.{kind}[{i}]'
            if kind == 'boxes':
                entry = _parse_box(where, key, item)
            elif kind == 'spheres':
                given = where.mapping(key, item, ('center', 'radius') + _COLLIDER_KEYS)
                entry = {'center': where.vector(f'{key}.center', given.get('center'), 3),
                         'radius': where.number(f'{key}.radius', given.get('radius'), gt=0.0),
                         **_collider_extras(where, key, given)}
            else:
                given = where.mapping(key, item,
                                      ('center', 'radius', 'length') + _COLLIDER_KEYS)
                entry = {'center': where.vector(f'{key}.center', given.get('center'), 3),
                         'radius': where.number(f'{key}.radius', given.get('radius'), gt=0.0),
                         'length': where.number(f'{key}.length', given.get('length', 0.0),
                                                ge=0.0),
                         **_collider_extras(where, key, given)}
            name = entry.get('name')
            if name is not None:
                if name in names:
                    raise where.error(f'{key}.name', f"'{name}' is already the name of "
                                                     f'{names[name]}')
                names[name] = key
            out[kind].append(entry)
    return out


def _parse_box(where: Where, key: str, raw: Any) -> Dict[str, Any]:
    given = where.mapping(key, raw, ('lo', 'hi', 'center', 'size') + _COLLIDER_KEYS)
    if 'lo' in given or 'hi' in given:
        if 'center' in given or 'size' in given:
            raise where.error(key, 'takes either lo/hi or center/size, not both')
        lo = where.vector(f'{key}.lo', given.get('lo'), 3)
        hi = where.vector(f'{key}.hi', given.get('hi'), 3)
    else:
        centre = where.vector(f'{key}.center', given.get('center'), 3)
        size = where.vector(f'{key}.size', given.get('size'), 3, gt=0.0)
        lo, hi = centre - size / 2.0, centre + size / 2.0
    if not np.all(hi > lo):
        raise where.error(f'{key}.hi', f'must exceed lo in every axis, got lo '
                                       f'{lo.tolist()} hi {hi.tolist()}')
    return {'lo': lo, 'hi': hi, **_collider_extras(where, key, given)}


def _collider_quat(where: Where, key: str, raw: Any) -> np.ndarray:
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


def _collider_extras(where: Where, key: str, given: Mapping[str, Any]) -> Dict[str, Any]:
    """Friction, restitution and the optional name, orientation, kinematic and path."""
    out: Dict[str, Any] = _contact(where, key, given)
    if 'name' in given:
        name = given['name']
        if not isinstance(name, str) or not name or any(ch.isspace() for ch in name):
            raise where.error(f'{key}.name', 'must be a non-empty string without spaces, '
                                             f'got {_fmt(name)}')
        out['name'] = name
    if 'orientation' in given:
        out['orientation'] = _collider_quat(where, f'{key}.orientation', given['orientation'])
    kinematic = where.boolean(f'{key}.kinematic', given['kinematic']) if 'kinematic' in given \
        else False
    if kinematic and 'name' not in out:
        raise where.error(f'{key}.kinematic', 'needs a name (the frame_id of collider_pose)')
    out['kinematic'] = kinematic
    if 'path' in given:
        if not kinematic:
            raise where.error(f'{key}.path', 'needs kinematic: true')
        path = given['path']
        if not isinstance(path, list) or not path:
            raise where.error(f'{key}.path', 'must be a non-empty list of {time, position'
                                             f'[, orientation]}}, got {_fmt(path)}')
        frames = []
        last = 0.0
        for index, raw_frame in enumerate(path):
            frame_key = f'{key}.path[{index}]'
            frame = where.mapping(frame_key, raw_frame, ('time', 'position', 'orientation'))
            time = where.number(f'{frame_key}.time', frame.get('time'), gt=last)
            last = time
            pos = where.vector(f'{frame_key}.position', frame.get('position'), 3)
            quat = _collider_quat(where, f'{frame_key}.orientation', frame['orientation']) \
                if 'orientation' in frame else None
            frames.append((time, pos, quat))
        out['path'] = frames
    return out


def _contact(where: Where, key: str, given: Mapping[str, Any]) -> Dict[str, float]:
    """Friction (default 0.5) and restitution (default 0) of a box or sphere collider."""
    return {'friction': where.number(f'{key}.friction', given.get('friction', 0.5), ge=0.0),
            'restitution': where.number(f'{key}.restitution', given.get('restitution', 0.0),
                                        ge=0.0, le=1.0)}
