"""The storage order the core picks (``body_build.set_order``): a body with a set layout
stores its particles set by set, one run a set, and hands out every array and index in the
caller's order; the physics is that of the same body given its points in the stored
order."""

import copy

import numpy as np
import pytest

from sm_ros.core import Body, BodyParams, World
from sm_ros.core.clusters import build_memberships
from sm_ros.core.pose import BodyPose
from sm_ros.params import scene_defaults
from sm_ros.scene import build_world, parse_scene

DT = 1.0 / 120.0


def lattice(nx, ny, nz, spacing=0.05):
    grid = np.stack(np.meshgrid(np.arange(nx), np.arange(ny), np.arange(nz), indexing='ij'),
                    axis=-1).reshape(-1, 3)
    return grid * spacing + (0.0, 0.0, 0.5)


def runs(sid):
    return 1 + int(np.count_nonzero(np.diff(sid)))


@pytest.mark.parametrize('mode', ['linear', 'quadratic'])
@pytest.mark.parametrize('shape', [(8, 8, 8), (12, 9, 7)])
def test_every_set_is_one_run_and_the_body_shows_the_callers_order(mode, shape):
    pts = lattice(*shape)
    body = Body(pts, params=BodyParams(mode=mode, clusters=2))
    perm = body._perm
    assert perm is not None and np.array_equal(np.sort(perm), np.arange(len(pts)))
    assert runs(body._sets.sid) == len(body._sets.cnt) > 1
    # within a set the caller's order is kept
    for sid in range(len(body._sets.cnt)):
        assert np.all(np.diff(perm[body._sets.sid == sid]) > 0)
    assert np.array_equal(body.x, pts) and np.array_equal(body.x_init, pts)
    assert np.array_equal(body._x, pts[perm])
    assert body.x.flags.f_contiguous and not body.x.flags.writeable
    # the memberships reused from the ordering are the ones the body would compute
    ptr, cluster_ids, nk = build_memberships(body._x0, 2)
    assert nk == body.num_clusters
    assert np.array_equal(ptr, body._ptr) and np.array_equal(cluster_ids, body._cluster_ids)
    # given in the stored order already: nothing moves
    again = Body(body._x, params=BodyParams(mode=mode, clusters=2))
    assert again._perm is None and np.shares_memory(again.x, again._x)


def test_one_cluster_bodies_are_one_set_in_the_callers_order():
    pts = lattice(6, 6, 4)
    for params in (BodyParams(clusters=1), BodyParams(mode='quadratic', clusters=1)):
        body = Body(pts, params=params)
        assert body._perm is None and np.array_equal(body._x, pts)
        assert len(body._sets.cnt) == 1 and np.all(body._sets.sid == 0)


def scrambled():
    """A 12 x 9 x 7 lattice in a random order, with masses, velocities and pins."""
    rng = np.random.default_rng(3)
    pts = lattice(12, 9, 7)[rng.permutation(12 * 9 * 7)]
    masses = rng.uniform(0.5, 2.0, len(pts))
    vel = rng.normal(0.0, 0.3, pts.shape)
    pins = np.flatnonzero(pts[:, 0] < 0.01)[:6]
    return pts, masses, vel, pins


def test_a_scrambled_body_steps_as_the_stored_order_would_bit_for_bit():
    pts, masses, vel, pins = scrambled()
    params = BodyParams(mode='rigid', clusters=2, damping=0.1, alpha=0.8)
    world = World()
    body = world.add_body(pts, masses, params, velocities=vel, pinned=pins)
    perm, inv = body._perm, body._inv
    assert perm is not None
    # the body given its points in the stored order: the old explicit set-order path
    stored = World()
    ref = stored.add_body(pts[perm], masses[perm], params, velocities=vel[perm],
                          pinned=inv[pins])
    assert ref._perm is None
    for _ in range(60):
        world.step(DT)
        stored.step(DT)
    assert np.abs(body.x - pts).max() > 0.05           # it moved
    assert np.array_equal(body.x, ref.x[inv]) and np.array_equal(body.v, ref.v[inv])
    assert np.array_equal(body.goals(), ref.goals()[inv])
    assert np.array_equal(body.com(), ref.com())
    assert np.array_equal(body.rotation(), ref.rotation())


def test_every_output_is_in_the_callers_order():
    pts, masses, vel, pins = scrambled()
    world = World()
    body = world.add_body(pts, masses, BodyParams(mode='linear', clusters=2, damping=0.1),
                          velocities=vel, pinned=pins)
    assert body._perm is not None
    assert np.array_equal(body.x, pts) and np.array_equal(body.v, vel)
    assert np.array_equal(body.m, masses) and np.array_equal(body.x_init, pts)
    assert np.array_equal(body.pinned, np.sort(pins))
    grab = np.array([40, 7, 300])
    targets = pts[grab] + (0.0, 0.0, 0.2)
    body.set_kinematic(grab, targets)
    assert set(body.kinematic_indices) == set(grab) | set(pins)
    for _ in range(30):
        world.step(DT)
    # pinned particles held where the caller put them, grabbed ones on their targets
    assert np.array_equal(body.x[pins], pts[pins])
    assert np.allclose(body.x[grab], targets, rtol=0.0, atol=1e-12)
    # set_state takes rows in the caller's order
    new_x, new_v = pts + 1.0, vel * 2.0
    body.set_state(x=new_x, v=new_v)
    assert np.array_equal(body.x, new_x) and np.array_equal(body.v, new_v)
    # the published pose does not depend on the order
    same = World().add_body(pts[body._perm], masses[body._perm], body.params)
    same.set_state(x=new_x[body._perm])
    com, rot = BodyPose().pose(body)
    com2, rot2 = BodyPose().pose(same)
    assert np.allclose(com, com2, rtol=0.0, atol=1e-12)
    assert np.allclose(rot, rot2, rtol=0.0, atol=1e-12)
    # a copy keeps the order and hands out the same arrays
    dup = copy.deepcopy(body)
    assert not dup._perm.flags.writeable and np.array_equal(dup.x, new_x)


def test_the_published_cloud_is_in_the_callers_order():
    pytest.importorskip('sensor_msgs.msg', reason='ROS message wheels not installed')
    from sm_ros.cloud import CloudBuffer, read_xyz
    pts, masses, vel, _ = scrambled()
    world = World()
    body = world.add_body(pts, masses, BodyParams(clusters=2), velocities=vel)
    assert body._perm is not None
    for _ in range(5):
        world.step(DT)
    msg = CloudBuffer().fill([body.x])
    assert np.allclose(read_xyz(msg), body.x.astype(np.float32), rtol=0.0, atol=0.0)
    assert np.abs(read_xyz(msg) - pts).max() < 0.05    # row i is still particle i


SCENE = {
    'contact': {'enabled': False},
    'bodies': [
        {'name': 'box', 'shape': 'box', 'size': [0.3, 0.25, 0.2], 'spacing': 0.025,
         'position': [0.0, 0.0, 0.4], 'orientation': [0.3, 0.2, 0.1], 'mode': 'linear',
         'alpha': 0.9, 'beta': 0.2, 'clusters': 2, 'damping': 0.1,
         'angular_velocity': [1.0, -2.0, 0.5], 'velocity': [0.2, 0.0, 0.0]},
        {'name': 'hanging', 'shape': 'box', 'size': [0.3, 0.2, 0.1], 'spacing': 0.025,
         'position': [2.0, 0.0, 1.0], 'mode': 'linear', 'alpha': 0.5, 'clusters': 2,
         'damping': 0.1, 'pinned': {'lo': [1.84, -0.2, 0.9], 'hi': [1.87, 0.2, 1.1]}},
    ]}


def test_scene_bodies_keep_the_specs_order_and_pins():
    spec = parse_scene(SCENE)
    world, _ = build_world(spec, scene_defaults())
    for body, bs in zip(world.bodies, spec.bodies):
        assert body._perm is not None
        assert np.array_equal(body.x, bs.points) and np.array_equal(body.m, bs.masses)
    hanging, bs = world.body('hanging'), spec.bodies[1]
    assert np.array_equal(hanging.pinned, bs.pinned) and len(bs.pinned) > 0
    for _ in range(60):
        world.step(DT)
    assert np.array_equal(hanging.x[bs.pinned], bs.points[bs.pinned])
    free = np.setdiff1d(np.arange(hanging.n), bs.pinned)
    assert hanging.x[free, 2].min() < bs.points[:, 2].min() - 0.05    # the rest sagged


def test_a_scene_swap_carries_the_state_across_storage_orders():
    from sm_ros.sim import carry_state
    scene = {'contact': {'enabled': False}, 'bodies': [dict(SCENE['bodies'][0])]}
    del scene['bodies'][0]['clusters']                 # from the node's parameter
    spec = parse_scene(scene)
    one, _ = build_world(spec, dict(scene_defaults(), clusters=1))
    two, _ = build_world(spec, dict(scene_defaults(), clusters=2))
    three, _ = build_world(spec, dict(scene_defaults(), clusters=3))
    assert one.bodies[0]._perm is None and two.bodies[0]._perm is not None
    assert not np.array_equal(two.bodies[0]._perm, three.bodies[0]._perm)
    for _ in range(20):
        two.step(DT)
    moved = two.bodies[0]
    for other in (one, three):
        carry_state(two, other)
        assert np.array_equal(other.bodies[0].x, moved.x)
        assert np.array_equal(other.bodies[0].v, moved.v)
