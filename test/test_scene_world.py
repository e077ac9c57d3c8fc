"""Scenes in the solver: every bundled scene runs, the ground rule, overrides, cloud bodies."""

import numpy as np
import pytest
import yaml

from sm_ros.core import BodyParams, World
from sm_ros.params import scene_defaults
from sm_ros.shapes import voxel_size_for
from sm_ros.scene import (add_spec_body, build_world, BodySpec, cloud_body_spec, ground_from,
                          load_scene, params_from, parse_scene, resolve_scene,
                          SceneError)

#: The node's defaults for the values a scene is built with.
NODE_DEFAULTS = scene_defaults()
#: The node's default step (parameter dt); the tests step like the node does.
DT = 1.0 / 120.0
BUNDLED = ('default', 'paper_8_clusters', 'plastic', 'sheet', 'rope', 'many', 'mesh')


def run(world, seconds, dt=DT):
    """Step `world` for `seconds`; return the largest extent ratio seen (every 0.1 s)."""
    ext0 = [max(np.ptp(b.x_init, axis=0).max(), 1e-9) for b in world.bodies]
    worst = 1.0
    every = int(round(0.1 / dt))
    for i in range(int(round(seconds / dt))):
        world.step(dt)
        if i % every == 0:
            worst = max(worst, max(np.ptp(b.x, axis=0).max() / e
                                   for b, e in zip(world.bodies, ext0)))
    return worst


@pytest.mark.parametrize('name', BUNDLED)
def test_bundled_scene_runs_five_seconds(name):
    spec = load_scene(name)
    world, metas = build_world(spec, NODE_DEFAULTS)
    assert [m.name for m in metas] == [b.name for b in world.bodies]
    assert [b.name for b in world.bodies] == [b.name for b in spec.bodies]
    worst = run(world, 5.0)
    assert world.time == pytest.approx(5.0)
    ground = world.ground.height
    for b in world.bodies:
        assert b.is_finite(), b.name
        assert b.x[:, 2].min() >= ground - 1e-9, b.name
    assert worst < 3.0, f'a body of {name} grew {worst:.1f}x'
    for b, m in zip(world.bodies, metas):
        if m.surface is not None:
            v = m.surface.vertices(b.x)
            assert v.shape == m.surface.rest_vertices.shape and np.all(np.isfinite(v))


def test_default_scene_visibly_moves():
    world, _ = build_world(load_scene(''), NODE_DEFAULTS)
    body = world.bodies[0]
    z0 = body.com()[2]
    run(world, 1.0)
    assert body.com()[2] < z0 - 0.3              # it fell
    assert np.linalg.norm(body.x - body.x_init, axis=1).min() > 0.15
    assert 1000 <= body.n <= 5000


def test_plastic_scene_keeps_its_dent():
    def settled_height(creep):
        data = yaml.safe_load(resolve_scene('plastic').read_text())
        data['bodies'][0]['plasticity']['creep'] = creep
        world, _ = build_world(parse_scene(data, 'plastic'), NODE_DEFAULTS)
        run(world, 4.0)
        return np.ptp(world.bodies[0].x[:, 2])
    diameter = np.ptp(load_scene('plastic').bodies[0].points[:, 2])
    elastic, plastic = settled_height(0.0), settled_height(5.0)
    assert elastic > 0.75 * diameter                # springs back (sags a little)
    assert plastic < 0.6 * diameter                 # keeps the flattened dent


def test_node_parameters_reach_bodies_without_overrides():
    spec = load_scene('default')
    world, metas = build_world(spec, dict(NODE_DEFAULTS, mode='quadratic', alpha=0.9,
                                          clusters=2))
    p = world.bodies[0].params
    assert (p.mode, p.alpha, p.clusters) == ('quadratic', 0.9, 2)
    assert metas[0].overrides == spec.bodies[0].overrides


def test_params_from_maps_node_names():
    p = params_from(NODE_DEFAULTS, {'mode': 'rigid', 'plasticity.yield': 0.1,
                                    'plasticity.creep': 2.0, 'plasticity.max': 0.4,
                                    'damping': 0.2})
    assert isinstance(p, BodyParams)
    assert (p.mode, p.alpha, p.beta, p.clusters) == ('rigid', 0.5, 0.5, 1)
    assert (p.plastic_yield, p.plastic_creep, p.plastic_max, p.damping) == (0.1, 2.0, 0.4, 0.2)
    assert params_from(None, None).damping == 0.0
    with pytest.raises(ValueError):
        params_from({'alpha': 2.0}, None)


def test_ground_rule():
    node = dict(NODE_DEFAULTS, **{'ground.height': -1.0, 'ground.friction': 0.9})
    g = ground_from(None, node)
    assert (g.height, g.friction) == (-1.0, 0.9)
    g = ground_from({'enabled': True, 'height': 0.5}, node)
    assert (g.height, g.friction) == (0.5, 0.9)          # key by key
    assert ground_from({'enabled': False}, node) is None
    assert ground_from(None, dict(node, **{'ground.enabled': False})) is None
    assert ground_from({'enabled': True}, dict(node, **{'ground.enabled': False})) is not None


def test_colliders_and_gravity_reach_the_world():
    data = {'bodies': [{'name': 'b', 'shape': 'sphere', 'radius': 0.1, 'spacing': 0.05,
                        'position': [0, 0, 2]}],
            'colliders': {'ground': {'height': 0.5},
                          'boxes': [{'lo': [1, 1, 0], 'hi': [2, 2, 1]}],
                          'spheres': [{'center': [0, 0, 1], 'radius': 0.3}]}}
    world, _ = build_world(parse_scene(data), dict(NODE_DEFAULTS, gravity=[0.0, 0.0, -1.0]))
    assert world.ground.height == 0.5
    assert len(world.boxes) == 1 and len(world.spheres) == 1
    assert np.allclose(world.gravity, [0, 0, -1])
    run(world, 3.0)
    # it lands on the sphere (top at z = 1.3), not on the ground
    assert world.bodies[0].x[:, 2].min() > 1.1


def test_pinned_particles_stay():
    world, _ = build_world(load_scene('rope'), NODE_DEFAULTS)
    spec = load_scene('rope').bodies[0]
    run(world, 1.0)
    b = world.bodies[0]
    assert np.array_equal(b.pinned, spec.pinned)
    assert np.allclose(b.x[b.pinned], spec.points[spec.pinned])
    assert b.x[:, 2].min() < spec.points[:, 2].min() - 0.3


def test_build_world_is_all_or_nothing():
    spec = load_scene('many')
    spec.bodies[5].masses = -spec.bodies[5].masses          # the core refuses it
    with pytest.raises(SceneError, match=f"body '{spec.bodies[5].name}': "):
        build_world(spec, NODE_DEFAULTS)


def test_add_spec_body_refusal_leaves_world_unchanged():
    world, _ = build_world(load_scene('default'), NODE_DEFAULTS)
    bad = BodySpec(name='block', points=np.zeros((3, 3)), masses=np.ones(3))   # duplicate
    with pytest.raises(SceneError, match="body 'block'"):
        add_spec_body(world, bad, NODE_DEFAULTS)
    assert [b.name for b in world.bodies] == ['block']


def test_cloud_body_joins_world_where_the_points_were():
    rng = np.random.default_rng(5)
    pts = rng.uniform(-0.2, 0.2, (20_000, 3)) + [1.0, 2.0, 0.5]
    spec = cloud_body_spec(pts, 500, name='seen')
    world, _ = build_world(load_scene('default'), NODE_DEFAULTS)
    meta = add_spec_body(world, spec, dict(NODE_DEFAULTS, mode='rigid', alpha=1.0))
    body = world.body('seen')
    assert meta.name == 'seen' and meta.surface is None
    assert 0 < body.n <= 500
    voxel = voxel_size_for(pts, 500)
    assert np.allclose(body.com(), pts.mean(axis=0), atol=voxel / 2)
    run(world, 0.5)
    assert body.is_finite() and body.com()[2] < 0.5


def test_mesh_surface_follows_simulated_particles():
    spec = load_scene('mesh')
    world, metas = build_world(spec, NODE_DEFAULTS)
    run(world, 1.5)
    for b, m in zip(world.bodies, metas):
        v = m.surface.vertices(b.x)
        # every vertex stays close to the particles it is embedded in
        d = np.min(np.linalg.norm(v[:, None, :] - b.x[None, ::3, :], axis=2), axis=1)
        assert d.max() < 0.1, b.name
        # and it moved with them
        assert np.linalg.norm(v.mean(axis=0) - m.surface.rest_vertices.mean(axis=0)) > 0.2


def test_world_type():
    world, _ = build_world(load_scene('rope'), None)
    assert isinstance(world, World)
