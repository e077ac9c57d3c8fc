"""Particles stored set by set (``sm_ros.core.set_order``, ``World.add_body(order='set')``)
and scene bodies built that way: same physics, pins and surfaces on the same particles,
user bodies in the caller's order."""

import copy

import numpy as np
import pytest

from sm_ros.core import Body, BodyParams, set_order, World
from sm_ros.core import body as body_mod
from sm_ros.core import body_build
from sm_ros.core.clusters import build_memberships
from sm_ros.params import scene_defaults
from sm_ros.scene import build_world, parse_scene

DT = 1.0 / 120.0


def lattice(nx, ny, nz, h=0.05):
    g = np.stack(np.meshgrid(np.arange(nx), np.arange(ny), np.arange(nz), indexing='ij'),
                 axis=-1).reshape(-1, 3)
    return g * h + (0.0, 0.0, 0.5)


def runs(sid):
    return 1 + int(np.count_nonzero(np.diff(sid)))


@pytest.mark.parametrize('mode', ['linear', 'quadratic'])
@pytest.mark.parametrize('shape', [(8, 8, 8), (12, 9, 7)])
def test_the_order_makes_every_set_one_run(mode, shape):
    pts = lattice(*shape)
    params = BodyParams(mode=mode, clusters=2)
    plain = Body(pts, params=params)
    assert plain._sets is not None and runs(plain._sets.sid) > len(plain._sets.cnt)
    perm = set_order(pts, params)
    assert np.array_equal(np.sort(perm), np.arange(len(pts)))
    # the permutation sorts the unsorted body's sets, keeping the order within a set
    assert np.all(np.diff(plain._sets.sid[perm]) >= 0)
    for s in range(len(plain._sets.cnt)):
        assert np.all(np.diff(perm[plain._sets.sid[perm] == s]) > 0)
    body = Body(pts, params=params, order='set')
    assert np.array_equal(body.order, perm)
    assert np.array_equal(body.x, pts[perm]) and np.array_equal(body.x_init, pts[perm])
    assert runs(body._sets.sid) == len(body._sets.cnt) == len(plain._sets.cnt)
    # the memberships reused from set_order are the ones the body would compute
    ptr, cl, nk = build_memberships(body._x0, 2)
    assert nk == body.num_clusters
    assert np.array_equal(ptr, body._ptr) and np.array_equal(cl, body._cl)
    # sorted already: no permutation
    again = Body(body.x, params=params, order='set')
    assert again.order is None and np.array_equal(set_order(body.x, params),
                                                  np.arange(len(pts)))


def test_bodies_without_a_set_layout_keep_their_order():
    pts = lattice(6, 6, 4)
    for params in (BodyParams(clusters=1), BodyParams(mode='quadratic', clusters=1)):
        b = Body(pts, params=params, order='set')
        assert b.order is None and np.array_equal(b.x, pts)
        assert np.array_equal(set_order(pts, params), np.arange(len(pts)))
    # memberships that do not pass SET_LAYOUT_MIN_RATIO: the membership path, unsorted
    params = BodyParams(clusters=2)
    x0 = pts - pts.mean(axis=0)
    _, members = body_build.set_order(x0, 2, 10 ** 6)
    perm, _ = body_build.set_order(x0, 2, 10 ** 6)
    assert perm is None and members[0] == 2
    old = body_mod.SET_LAYOUT_MIN_RATIO
    body_mod.SET_LAYOUT_MIN_RATIO = 10 ** 6
    try:
        b = Body(pts, params=params, order='set')
        assert b._sets is None and b.order is None and np.array_equal(b.x, pts)
    finally:
        body_mod.SET_LAYOUT_MIN_RATIO = old


def test_user_bodies_keep_the_callers_order_unless_asked():
    pts = lattice(12, 9, 7)
    params = BodyParams(mode='linear', clusters=2, damping=0.1)
    pins = np.array([0, 5, 17, 300])
    w = World()
    b = w.add_body(pts, params=params, pinned=pins)
    assert b.order is None and np.array_equal(b.x, pts)
    assert np.array_equal(b.pinned, pins)
    s = w.add_body(pts, params=params, pinned=pins, name='sorted', order='set')
    assert s.order is not None and np.array_equal(s.x, pts[s.order])
    # the pins are remapped to the same physical particles
    assert np.array_equal(np.sort(s.order[s.pinned]), pins)
    assert np.array_equal(s.x[s.pinned][np.argsort(s.order[s.pinned])], pts[pins])
    c = copy.deepcopy(s)
    assert np.array_equal(c.order, s.order) and not c.order.flags.writeable
    with pytest.raises(ValueError, match='order must be'):
        w.add_body(pts, name='bad', order='sid')


SCENE = {
    'contact': {'enabled': False},
    'bodies': [
        {'name': 'box', 'shape': 'box', 'size': [0.3, 0.25, 0.2], 'spacing': 0.025,
         'position': [0.0, 0.0, 0.4], 'orientation': [0.3, 0.2, 0.1], 'mode': 'linear',
         'alpha': 0.9, 'beta': 0.2, 'clusters': 2, 'damping': 0.1,
         'angular_velocity': [1.0, -2.0, 0.5], 'velocity': [0.2, 0.0, 0.0]},
        {'name': 'ball', 'shape': 'sphere', 'radius': 0.15, 'spacing': 0.03,
         'position': [1.0, 0.0, 0.5], 'mode': 'quadratic', 'alpha': 0.8, 'beta': 0.5,
         'clusters': 2, 'damping': 0.05, 'angular_velocity': [0.0, 3.0, 0.0]},
        {'name': 'hanging', 'shape': 'box', 'size': [0.3, 0.2, 0.1], 'spacing': 0.025,
         'position': [2.0, 0.0, 1.0], 'mode': 'linear', 'alpha': 0.5, 'clusters': 2,
         'damping': 0.1, 'pinned': {'lo': [1.84, -0.2, 0.9], 'hi': [1.87, 0.2, 1.1]}},
        {'name': 'plain', 'shape': 'box', 'size': [0.2, 0.2, 0.2], 'spacing': 0.05,
         'position': [3.0, 0.0, 0.5]},
    ]}


def built(scene, order, steps):
    spec = parse_scene(scene)
    world, metas = build_world(spec, scene_defaults(), order=order)
    for _ in range(steps):
        world.step(DT)
    return spec, world, metas


def test_scene_bodies_are_sorted_with_the_same_physics():
    spec, plain, _ = built(SCENE, None, 0)
    _, ordered, _ = built(SCENE, 'set', 0)
    sid = {b.name: b._sets.sid for b in ordered.bodies if b._sets is not None}
    assert sorted(sid) == ['ball', 'box', 'hanging']
    for b, p, bs in zip(ordered.bodies, plain.bodies, spec.bodies):
        assert p.order is None and np.array_equal(p.x_init, bs.points)
        if b.name == 'plain':
            assert b.order is None and np.array_equal(b.x, bs.points)
            continue
        assert runs(b._sets.sid) == len(b._sets.cnt) < runs(p._sets.sid)
        assert np.array_equal(b.x, bs.points[b.order])
        assert np.array_equal(b.v, p.v[b.order]) and np.array_equal(b.m, p.m[b.order])
    for _ in range(90):
        plain.step(DT)
        ordered.step(DT)
    for b, p in zip(ordered.bodies, plain.bodies):
        perm = b.order if b.order is not None else np.arange(b.n)
        assert np.abs(p.x).max() > 0.1
        assert np.allclose(b.x, p.x[perm], rtol=0.0, atol=1e-10), b.name
        assert np.allclose(b.v, p.v[perm], rtol=0.0, atol=1e-8), b.name
        assert np.allclose(b.com(), p.com(), rtol=0.0, atol=1e-12)
        assert not np.allclose(b.x, b.x_init, atol=1e-3)      # the bodies moved


def test_scene_pins_hold_the_same_particles():
    spec, world, _ = built(SCENE, 'set', 60)
    b = world.body('hanging')
    bs = spec.bodies[2]
    assert b.order is not None and len(b.pinned) == len(bs.pinned) > 0
    assert np.array_equal(np.sort(b.order[b.pinned]), bs.pinned)
    pinned_pts = bs.points[bs.pinned]
    got = b.x[b.pinned]
    key = lambda a: a[np.lexsort(a.T)]                  # noqa: E731 - rows as a set
    assert np.array_equal(key(got), key(pinned_pts))
    free = np.setdiff1d(np.arange(b.n), b.pinned)
    assert b.x[free, 2].min() < bs.points[:, 2].min() - 0.05    # the rest sagged


@pytest.mark.parametrize('fill', ['vertices', 'lattice'])
def test_scene_surfaces_follow_the_same_points(tmp_path, fill):
    trimesh = pytest.importorskip('trimesh')
    mesh = trimesh.creation.icosphere(subdivisions=2, radius=0.15)
    mesh.export(tmp_path / 'ball.stl')
    body = {'name': 'm', 'shape': 'mesh', 'file': str(tmp_path / 'ball.stl'), 'fill': fill,
            'position': [0.0, 0.0, 0.5], 'mode': 'quadratic', 'alpha': 0.6, 'beta': 0.3,
            'clusters': 2, 'damping': 0.05, 'angular_velocity': [2.0, 0.0, 1.0]}
    if fill == 'lattice':
        body['spacing'] = 0.03
    scene = {'contact': {'enabled': False}, 'bodies': [body]}
    spec, plain, pm = built(scene, None, 0)
    _, ordered, om = built(scene, 'set', 0)
    b, p = ordered.bodies[0], plain.bodies[0]
    assert b.order is not None and b._sets is not None
    if fill == 'vertices':
        assert om[0].surface.index is None
        assert not np.array_equal(om[0].surface.faces, pm[0].surface.faces)
    # a direct surface's vertices are the (stored) particles, an embedded one's its own
    vmap = b.order if fill == 'vertices' else np.arange(len(pm[0].surface.rest_vertices))
    rest = pm[0].surface.vertices(p.x).copy()
    assert np.allclose(om[0].surface.vertices(b.x), rest[vmap], rtol=0.0, atol=1e-12)
    assert np.array_equal(om[0].surface.rest_vertices, pm[0].surface.rest_vertices[vmap])
    for _ in range(60):
        plain.step(DT)
        ordered.step(DT)
    vp = pm[0].surface.vertices(p.x)
    vo = om[0].surface.vertices(b.x)
    assert np.abs(vp - rest).max() > 0.05
    assert np.allclose(vo, vp[vmap], rtol=0.0, atol=1e-10)
    # the same triangles, corner by corner
    tri_p = vp[pm[0].surface.faces]
    tri_o = vo[om[0].surface.faces]
    assert np.allclose(tri_o, tri_p, rtol=0.0, atol=1e-10)


def test_a_scene_swap_carries_the_state_across_orders():
    from sm_ros.sim import carry_state
    scene = {'contact': {'enabled': False}, 'bodies': [dict(SCENE['bodies'][0])]}
    del scene['bodies'][0]['clusters']                 # from the node's parameter
    spec = parse_scene(scene)
    one, _ = build_world(spec, dict(scene_defaults(), clusters=1))
    two, _ = build_world(spec, dict(scene_defaults(), clusters=2))
    three, _ = build_world(spec, dict(scene_defaults(), clusters=3))
    assert one.bodies[0].order is None and two.bodies[0].order is not None
    assert three.bodies[0].order is not None
    assert not np.array_equal(two.bodies[0].order, three.bodies[0].order)
    for _ in range(20):
        two.step(DT)
    moved = two.bodies[0]
    carry_state(two, one)                              # sorted -> scene order
    assert np.array_equal(one.bodies[0].x[moved.order], moved.x)
    assert np.array_equal(one.bodies[0].v[moved.order], moved.v)
    carry_state(two, three)                            # one set order -> another
    inv = np.argsort(moved.order)
    assert np.array_equal(three.bodies[0].x, moved.x[inv][three.bodies[0].order])
    carry_state(one, two)                              # and back
    assert np.array_equal(two.bodies[0].x, moved.x)
