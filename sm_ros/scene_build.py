"""
Scenes into the solver: a validated scene (``sm_ros.scene_spec``) becomes a World.

``build_world(spec, values)`` makes a new ``sm_ros.core.World`` with the scene's colliders
and bodies; ``params_from``, ``ground_from`` and ``contact_from`` apply the rules that
combine a scene with the node's parameters (a body's overrides win; a scene's ground and
contact keys win key by key); ``cloud_body_spec`` makes a body from a point cloud. The
solver core is imported only when a function needs it.
"""

from typing import Any, Dict, Mapping, Optional

import numpy as np

from sm_ros import params, shapes
from sm_ros.scene_spec import BodyMeta, BodySpec, CONTACT_SCENE_KEYS, SceneSpec, Where

DEFAULT_MASS = 1.0          # kg, per body


def _merged(defaults: Optional[Mapping[str, Any]]) -> Dict[str, Any]:
    d = params.scene_defaults()
    if defaults:
        d.update(defaults)
    return d


def params_from(defaults: Optional[Mapping[str, Any]], overrides: Optional[Mapping[str, Any]]
                ):
    """
    The core BodyParams for a body: its overrides over the node's parameters.

    Keys are node-parameter names (see ``sm_ros.params.OVERRIDE_KEYS``); missing ones fall
    back to the table's defaults (``sm_ros.params.scene_defaults``). Every key with a
    ``core_field`` in the parameter table sets that BodyParams field. Raises ValueError (from
    BodyParams.validate) on bad values.
    """
    from sm_ros.core import BodyParams
    d = dict(params.defaults(list(params.BODY_FIELDS)), **_merged(defaults))
    if overrides:
        d.update(overrides)
    return BodyParams(**{field: d[key] for key, field in params.BODY_FIELDS.items()}).validate()


def ground_from(scene_ground: Optional[Mapping[str, Any]],
                defaults: Optional[Mapping[str, Any]]):
    """
    The core Ground (or None when disabled) from a scene's ground and the node's parameters.

    Rule: a scene that sets ``colliders.ground`` wins key by key (enabled, height, friction,
    restitution); keys it leaves out, and scenes without a ground entry, use the node's
    ``ground.*`` parameters.
    """
    from sm_ros.core import Ground
    d = _merged(defaults)
    g = {'enabled': bool(d['ground.enabled']), 'height': float(d['ground.height']),
         'friction': float(d['ground.friction']),
         'restitution': float(d['ground.restitution'])}
    if scene_ground:
        g.update(scene_ground)
    if not g['enabled']:
        return None
    return Ground(height=g['height'], friction=g['friction'], restitution=g['restitution'])


def contact_from(scene_contact: Optional[Mapping[str, Any]],
                 defaults: Optional[Mapping[str, Any]]):
    """
    The core ContactParams from a scene's ``contact`` mapping and the node's parameters.

    Rule (as for the ground): the keys the scene sets win; the others use the node's
    ``contact.*`` parameters.
    """
    from sm_ros.core.contact import ContactParams
    d = _merged(defaults)
    c = {k: d[f'contact.{k}'] for k in CONTACT_SCENE_KEYS}
    if scene_contact:
        c.update(scene_contact)
    return ContactParams(enabled=bool(c['enabled']), friction=float(c['friction']),
                         restitution=float(c['restitution']),
                         radius_scale=float(c['radius_scale']),
                         stacking=c['stacking'], rigid=c['rigid'], sleep=c['sleep'],
                         sleep_speed=float(c['sleep_speed']),
                         sleep_time=float(c['sleep_time'])).validate()


def body_contact_from(body: BodySpec):
    """The core BodyContact of a scene body (its keys over the defaults)."""
    from sm_ros.core.contact import BodyContact
    c = body.contact or {}
    return BodyContact(collide=c.get('collide', True), radius=c.get('contact_radius'),
                       self_collision=c.get('self_collision', False))


def add_spec_body(world, body: BodySpec, defaults: Optional[Mapping[str, Any]] = None,
                  source: str = '<scene>') -> BodyMeta:
    """
    Add one BodySpec to a World; returns its BodyMeta. The world is unchanged on error.

    ``body.x`` rows are the spec's points in their order (the core picks its own storage
    order inside). Raises SceneError (naming the body) when the core refuses the body or
    its parameters.
    """
    try:
        params = params_from(defaults, body.overrides)
        world.add_body(body.points, masses=body.masses, params=params, name=body.name,
                       velocities=body.velocities,
                       pinned=body.pinned if len(body.pinned) else None,
                       contact=body_contact_from(body))
    except ValueError as exc:
        raise Where(source, body.name).error(None, str(exc)) from None
    return BodyMeta(name=body.name, overrides=dict(body.overrides), surface=body.surface,
                    shape=body.shape)


def core_colliders(colliders: Mapping[str, Any]):
    """(boxes, spheres, capsules) as sm_ros.core Box / Sphere / Capsule from a scene's
    parsed ``colliders``."""
    from sm_ros.core import Box, Capsule, Sphere

    def extra(c):
        out = {'friction': c.get('friction', 0.5), 'restitution': c.get('restitution', 0.0),
               'name': c.get('name'), 'kinematic': bool(c.get('kinematic', False))}
        if c.get('orientation') is not None:
            out['orientation'] = tuple(float(v) for v in c['orientation'])
        if c.get('path'):
            out['path'] = tuple(c['path'])
        return out
    boxes = [Box(lo=tuple(b['lo']), hi=tuple(b['hi']), **extra(b))
             for b in colliders.get('boxes', [])]
    spheres = [Sphere(center=tuple(s['center']), radius=float(s['radius']), **extra(s))
               for s in colliders.get('spheres', [])]
    capsules = [Capsule(center=tuple(c['center']), radius=float(c['radius']),
                        length=float(c['length']), **extra(c))
                for c in colliders.get('capsules', [])]
    return boxes, spheres, capsules


def build_world(spec: SceneSpec, defaults: Optional[Mapping[str, Any]] = None):
    """
    A new sm_ros.core.World holding the scene: gravity from `defaults`, colliders (the
    ground per :func:`ground_from`), and every body (:func:`add_spec_body`).
    Returns (world, metas) with metas in the order of ``world.bodies``. Raises SceneError;
    no partial world is returned.
    """
    from sm_ros.core import World
    d = _merged(defaults)
    world = World(gravity=tuple(float(g) for g in d['gravity']))
    boxes, spheres, capsules = core_colliders(spec.colliders)
    world.set_colliders(ground=ground_from(spec.colliders.get('ground'), d), boxes=boxes,
                        spheres=spheres, capsules=capsules)
    world.contact_params = contact_from(spec.contact, d)
    metas = [add_spec_body(world, b, d, spec.source) for b in spec.bodies]
    return world, metas


def cloud_body_spec(points: np.ndarray, max_points: int, name: str = 'cloud',
                    mass: float = DEFAULT_MASS) -> BodySpec:
    """
    A body from a point cloud (N, 3), voxel-downsampled to at most `max_points`.

    The voxel edge is the smallest (by bisection) that leaves at most `max_points` voxel
    centroids; the body sits where the points were, total mass `mass` shared equally.
    Raises SceneError on empty, non-finite or badly shaped input.
    """
    w = Where('cloud_in', name)
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise w.error('points', f'must have shape (N, 3), got {pts.shape}')
    if len(pts) == 0:
        raise w.error('points', 'is empty')
    if not np.all(np.isfinite(pts)):
        raise w.error('points', 'contain NaN or Inf')
    if isinstance(max_points, bool) or int(max_points) < 1:
        raise w.error('max_points', f'must be >= 1, got {max_points}')
    w.number('mass', mass, gt=0.0)
    voxel = shapes.voxel_size_for(pts, int(max_points))
    if voxel > 0.0:
        pts = shapes.voxel_downsample(pts, voxel)
    return BodySpec(name=name, points=np.ascontiguousarray(pts),
                    masses=np.full(len(pts), float(mass) / len(pts)), shape='cloud')
