"""Named, oriented, capsule and kinematic colliders, core level.

The collider pass kernel against its NumPy twin, the geometry of each shape, kinematic
motion (positions and slerp reached at the end of a move, implied velocities), refused
poses, the averaged wrench against a body's weight, friction carrying a box on an
accelerating plate (or not), and two capsule fingers lifting a ball by friction.
"""

import math

import numpy as np
import pytest

from sm_ros.core import BodyParams, Box, Capsule, Ground, Sphere, World
from sm_ros.core import kinematic as KC
from sm_ros.core.colliders import ColliderSet, quat_matrix

G = 9.81


def _rows(items, vel=None, ang=None):
    cs = ColliderSet(items)
    for c in range(len(items)):
        if vel is not None:
            cs.rows[c, KC.C_VEL:KC.C_VEL + 3] = vel[c]
        if ang is not None:
            cs.rows[c, KC.C_ANG:KC.C_ANG + 3] = ang[c]
    return cs


def _quat(axis, angle):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    return tuple(np.append(axis * math.sin(angle / 2), math.cos(angle / 2)))


def _collide(X, V, w, rows, h, thresh, imp=None, nbodies=1, bid=None, radius=None):
    """Run the kernel over every particle (spheres of ``radius`` per body, default 0);
    returns (stats (nbodies, 2), touched)."""
    n = X.shape[1]
    bid = np.zeros(n, dtype=np.int32) if bid is None else bid
    radius = np.zeros(nbodies) if radius is None else radius
    stats = np.zeros((nbodies, 2))
    touched = np.zeros(nbodies, dtype=np.uint8)
    imp = np.zeros((rows.shape[0], 6)) if imp is None else imp
    KC.collide_range(KC.Particles(X, V, w, bid, radius), 0, n, rows, h, thresh,
                     KC.ColliderTally(imp, stats, touched))
    return stats, touched


@pytest.mark.parametrize('named', [False, True])
def test_a_soft_body_dropped_on_a_thin_plate_stays_on_it(named):
    """A soft cube dropped 2 m onto a 2 cm plate (6.3 m/s at impact: 5 cm a step, more
    than the plate grown by the particles' radius) rests on it, whether the plate is a
    plain box (the body's own step) or a named one (the world's collider pass)."""
    world = World(gravity=(0.0, 0.0, -9.81))
    world.set_colliders(boxes=[Box(lo=(-0.5, -0.5, 0.48), hi=(0.5, 0.5, 0.5), friction=0.5,
                                   name='plate' if named else None)])
    grid = np.arange(5) * 0.02
    cube = np.stack(np.meshgrid(grid, grid, grid, indexing='ij'), -1).reshape(-1, 3)
    body = world.add_body(cube + [-0.04, -0.04, 2.5], 0.01,
                          BodyParams(mode='linear', alpha=0.3, beta=0.5), 'soft')
    for _ in range(180):
        world.step(1.0 / 120.0)
    assert body.x[:, 2].min() > 0.5 and body.x[:, 2].max() < 0.65


@pytest.mark.parametrize('twin', [False, True])
def test_a_thin_collider_sends_a_particle_back_to_the_side_it_came_from(twin):
    """A step that carries a particle past a thin collider's middle: a 1 cm rod (a capsule)
    a particle was pulled 7 cm down through, ending inside it below its axis or past it
    altogether, goes back on top of it; a 5 mm ball moving 2 m/s past a particle at rest
    pushes it ahead instead of leaving it behind.  The nearest surface alone sends both
    out on the far side (compiled pass and NumPy twin alike)."""
    rod = _rows([Capsule(center=(0.0, 0.0, 0.5), radius=0.01, length=0.4,
                         orientation=_quat((1, 0, 0), math.pi / 2), friction=0.0)])
    h, r = 1.0 / 120.0, 0.01                         # the particle's sphere: 1 cm
    for end in (0.49, 0.44):                         # inside below the axis; past the rod
        X = np.array([[0.0], [0.0], [end]])
        V = np.array([[0.0], [0.0], [(end - 0.53) / h]])   # it was at 0.53, on top
        _run_pass(twin, X, V, rod.rows, h, r)
        assert X[2, 0] == pytest.approx(0.5 + 0.01 + r)     # back on the tangent plane
        assert V[2, 0] == pytest.approx(0.0, abs=1e-12)
    ball = _rows([Sphere(center=(0.01, 0.0, 0.0), radius=0.005, friction=0.0)],
                 vel=np.array([[2.0, 0.0, 0.0]]))
    X, V = np.zeros((3, 1)), np.zeros((3, 1))        # at rest; the ball came from -0.0067
    _run_pass(twin, X, V, ball.rows, h, r)
    assert X[0, 0] > 0.01 + 0.005 + r - 1e-12 and V[0, 0] == pytest.approx(2.0)


@pytest.mark.parametrize('twin', [False, True])
def test_a_particle_pulled_hard_over_a_rod_stays_on_the_side_it_came_from(twin):
    """Paths whose end the nearest surface alone would send out the wrong way: a particle
    touching a 4 cm rod 1.5 cm off its top, pulled 3.6 cm down in a step, ends inside it
    beside the axis (the surfaces nearest to its start and its end turn by 90 degrees:
    it went out sideways and slid round the rod); one on top of a 1 cm rod pulled 6 cm
    down ends below it with its path's middle outside (it went straight through). Both
    go back onto the tangent plane where their path entered, above the axis."""
    turn = _quat((1, 0, 0), math.pi / 2)
    h, r = 1.0 / 120.0, 0.01
    for rod_radius, start, end in ((0.02, (0.015, 0.530), (0.0129, 0.4942)),
                                   (0.005, (0.0, 0.515), (0.0, 0.4534))):
        rod = _rows([Capsule(center=(0.0, 0.0, 0.5), radius=rod_radius, length=0.4,
                             orientation=turn, friction=0.0)])
        X = np.array([[end[0]], [0.0], [end[1]]])
        V = np.array([[end[0] - start[0]], [0.0], [end[1] - start[1]]]) / h
        _run_pass(twin, X, V, rod.rows, h, r)
        assert X[2, 0] > 0.5
        assert math.hypot(X[0, 0], X[2, 0] - 0.5) >= rod_radius + r - 1e-12


@pytest.mark.parametrize('rod_radius', [0.01, 0.02])
def test_a_sheet_dropped_on_a_rod_as_thin_as_its_particle_spacing_hangs_on_it(rod_radius):
    """``sheet_rod`` with a rod 2 or 4 cm across (the sheet's particles are 2 cm apart):
    after 4 s at the node's step the sheet still hangs on it, its top row on the rod's top
    and its ends below it (with the nearest surface alone, the fold pulls through the 4 cm
    rod and drops the sheet on the ground)."""
    import yaml
    from sm_ros.scene import build_world, parse_scene, resolve_scene
    spec = yaml.safe_load(resolve_scene('sheet_rod').read_text())
    spec['colliders']['capsules'][0]['radius'] = rod_radius
    world, _ = build_world(parse_scene(spec))
    for _ in range(480):
        world.step(1.0 / 120.0)
    x, top = world.body('sheet').x, 0.5 + rod_radius
    assert top < x[:, 2].max() < top + 0.02
    assert x[:, 2].min() > 0.1


@pytest.mark.parametrize('named', [False, True])
def test_a_sheet_hangs_on_a_small_sphere_static_or_in_the_collider_pass(named):
    """``sheet_rod``'s sheet (no self-collision) dropped on a sphere of radius 5 cm,
    friction 0.5, instead of the rod: after 2 s it still hangs on it, its top on the
    sphere's, whether the sphere is static (the body's own step) or named (the collider
    pass): friction holds the same way on both (the step's displacement gets the
    tangential change of velocity; with the velocity alone the sheet slid off the static
    sphere within 0.4 s)."""
    import yaml
    from sm_ros.scene import build_world, parse_scene, resolve_scene
    spec = yaml.safe_load(resolve_scene('sheet_rod').read_text())
    sphere = {'center': [0.0, 0.0, 0.5], 'radius': 0.05, 'friction': 0.5}
    spec['colliders'] = {'ground': {'friction': 0.5},
                         'spheres': [dict(sphere, name='ball') if named else sphere]}
    spec['bodies'][0]['self_collision'] = False
    world, _ = build_world(parse_scene(spec))
    for _ in range(240):
        world.step(1.0 / 120.0)
    top = world.body('sheet').x[:, 2].max()
    assert 0.55 < top < 0.57                         # the sphere's top + the particle radius


def _run_pass(twin, X, V, rows, h, radius):
    """One collider pass over the particles X, V (one body, spheres of ``radius``)."""
    n = X.shape[1]
    args = (KC.Particles(X, V, np.ones(n), np.zeros(n, dtype=np.int32), np.array([radius])),)
    tally = KC.ColliderTally(np.zeros((len(rows), 6)), np.zeros((1, 2)), np.zeros(1, np.uint8))
    if twin:
        KC.collide_numpy(*args, rows, h, 0.05, tally)
    else:
        KC.collide_range(*args, 0, n, rows, h, 0.05, tally)


def test_kernel_matches_numpy_twin():
    rng = np.random.default_rng(3)
    items = [Box(lo=(-0.3, -0.2, -0.1), hi=(0.3, 0.2, 0.1), orientation=_quat((1, 2, 3), 0.7),
                 friction=0.4, restitution=0.3, name='b'),
             Sphere(center=(0.2, 0.1, 0.0), radius=0.25, friction=0.8, name='s'),
             Capsule(center=(-0.2, 0.0, 0.1), radius=0.12, length=0.4,
                     orientation=_quat((0, 1, 1), 1.1), friction=1.2, restitution=0.5)]
    cs = _rows(items, vel=rng.normal(size=(3, 3)), ang=rng.normal(size=(3, 3)))
    n = 4000
    X = rng.uniform(-0.5, 0.5, (3, n))
    V = rng.normal(size=(3, n))
    m = rng.uniform(0.5, 2.0, n)
    w = 1.0 / m
    w[::7] = 0.0
    X2, V2 = X.copy(), V.copy()
    imp, imp2 = np.zeros((3, 6)), np.zeros((3, 6))
    bid = (np.arange(n) % 3).astype(np.int32)          # three bodies interleaved
    radius = np.array([0.0, 0.01, 0.04])               # points, and spheres of two sizes
    st, touched = _collide(X, V, w, cs.rows, 0.01, 0.05, imp, 3, bid, radius)
    st2, touched2 = np.zeros((3, 2)), np.zeros(3, dtype=np.uint8)
    KC.collide_numpy(KC.Particles(X2, V2, w, bid, radius), cs.rows, 0.01, 0.05,
                     KC.ColliderTally(imp2, st2, touched2))
    assert st[:, 0].sum() > 400                        # the test exercises many contacts
    np.testing.assert_array_equal(st[:, 0], st2[:, 0])
    np.testing.assert_allclose(st[:, 1], st2[:, 1], atol=1e-14)
    assert list(touched) == [1, 1, 1] == list(touched2)
    np.testing.assert_allclose(X, X2, atol=1e-12)
    np.testing.assert_allclose(V, V2, atol=1e-12)
    np.testing.assert_allclose(imp, imp2, atol=1e-9)
    # fixed particles untouched
    assert np.array_equal(X[:, ::7], X2[:, ::7])


def test_kernel_on_transposed_body_buffers_matches():
    """A body's (N, 3) buffer seen as (3, N) gives the same result as a (3, N) copy."""
    rng = np.random.default_rng(4)
    cs = _rows([Capsule(center=(0, 0, 0), radius=0.2, length=0.3, name='c')])
    x = rng.uniform(-0.4, 0.4, (500, 3))
    v = rng.normal(size=(500, 3))
    m = np.full(500, 0.1)
    X, V = x.T.copy(), v.T.copy()
    _collide(x.T, v.T, 1 / m, cs.rows, 0.01, 0.01)
    _collide(X, V, 1 / m, cs.rows, 0.01, 0.01)
    np.testing.assert_array_equal(x.T, X)
    np.testing.assert_array_equal(v.T, V)


@pytest.mark.parametrize('shape', ['box', 'sphere', 'capsule'])
def test_projection_lands_on_the_surface(shape):
    q = _quat((0.3, -1, 0.5), 0.9)
    r = quat_matrix(np.array(q))
    if shape == 'box':
        item = Box(lo=(-0.2, -0.1, -0.05), hi=(0.2, 0.1, 0.05), orientation=q, name='x')
    elif shape == 'sphere':
        item = Sphere(center=(0, 0, 0), radius=0.1, name='x')
    else:
        item = Capsule(center=(0, 0, 0), radius=0.05, length=0.3, orientation=q, name='x')
    cs = _rows([item])
    rng = np.random.default_rng(5)
    X = rng.uniform(-0.25, 0.25, (3, 3000))
    V = np.zeros_like(X)
    m = np.ones(3000)
    st, _ = _collide(X, V, m, cs.rows, 0.01, 0.0)
    assert st[0, 0] > 50
    loc = r.T @ X
    if shape == 'box':
        d = np.abs(loc) - np.array([[0.2], [0.1], [0.05]])
        # outside or on the surface: the largest signed distance to a face is >= 0
        assert d.max(axis=0).min() >= -1e-12
    elif shape == 'sphere':
        assert np.linalg.norm(X, axis=0).min() >= 0.1 - 1e-12
    else:
        z = np.clip(loc[2], -0.15, 0.15)
        e = loc - np.vstack([0 * z, 0 * z, z])
        assert np.linalg.norm(e, axis=0).min() >= 0.05 - 1e-12


def test_box_projects_along_the_nearest_face_normal():
    q = _quat((0, 0, 1), math.pi / 4)              # box turned 45 degrees about z
    cs = _rows([Box(lo=(-1, -1, -1), hi=(1, 1, 1), orientation=q, name='b')])
    X = np.array([[0.0], [0.0], [0.9]])            # just under the top face
    V = np.array([[0.0], [0.0], [-1.0]])
    imp = np.zeros((1, 6))
    _collide(X, V, np.ones(1), cs.rows, 0.01, 0.0, imp)
    np.testing.assert_allclose(X[:, 0], [0, 0, 1.0], atol=1e-12)
    np.testing.assert_allclose(V[:, 0], [0, 0, 0], atol=1e-12)
    np.testing.assert_allclose(imp[0, :3], [0, 0, -1.0], atol=1e-12)   # pushed down
    # a point near the turned side face goes out along the rotated x axis
    X = np.array([[0.6], [0.6], [0.0]])
    _collide(X, np.zeros((3, 1)), np.ones(1), cs.rows, 0.01, 0.0)
    np.testing.assert_allclose(X[:, 0], [1 / math.sqrt(2), 1 / math.sqrt(2), 0], atol=1e-12)


def test_moving_collider_imparts_its_surface_velocity():
    """A particle pressed onto a spinning, moving plate (mu large) leaves with the
    plate's surface velocity v + w x r; restitution counts relative to the surface."""
    cs = _rows([Box(lo=(-1, -1, -0.1), hi=(1, 1, 0.0), friction=100.0, name='p')],
               vel=[(0.5, 0.0, 0.0)], ang=[(0.0, 0.0, 2.0)])
    X = np.array([[0.3], [0.0], [-0.001]])
    V = np.array([[0.0], [0.0], [-1.0]])                # pressed onto it
    _collide(X, V, np.ones(1), cs.rows, 0.01, 0.0)
    # surface velocity at (0.3, 0, 0): (0.5, 0, 0) + (0, 0, 2) x (0.3, 0, 0) = (0.5, 0.6, 0)
    np.testing.assert_allclose(V[:, 0], [0.5, 0.6, 0.0], atol=1e-12)
    # bouncing off a plate moving up at 1 m/s with e = 1: leaves at 1 + (1 + 2) = 4 m/s
    cs = _rows([Box(lo=(-1, -1, -0.1), hi=(1, 1, 0.0), friction=0.0, restitution=1.0,
                    name='p')], vel=[(0.0, 0.0, 1.0)])
    X = np.array([[0.0], [0.0], [-0.001]])
    V = np.array([[0.0], [0.0], [-2.0]])
    _collide(X, V, np.ones(1), cs.rows, 0.01, 0.01)
    np.testing.assert_allclose(V[:, 0], [0.0, 0.0, 4.0], atol=1e-12)


def test_kinematic_move_reaches_the_pose_at_the_end_with_implied_velocity():
    world = World(gravity=(0, 0, 0))
    world.set_colliders(capsules=[Capsule(center=(0, 0, 0), radius=0.1, length=0.2,
                                          name='f', kinematic=True)])
    q1 = np.array(_quat((1, 1, 0), 1.2))
    world.move_collider('f', (0.4, -0.2, 0.1), q1, duration=0.04)
    cs = world._cset
    for k in range(1, 5):
        world.step(0.01)
        p, q = world.collider_pose('f')
        s = k / 4
        np.testing.assert_allclose(p, np.array([0.4, -0.2, 0.1]) * s, atol=1e-12)
        # slerp: the rotation angle from identity grows linearly about a fixed axis
        ang = 2 * math.atan2(np.linalg.norm(q[:3]), q[3])
        assert ang == pytest.approx(1.2 * s, abs=1e-12)
        np.testing.assert_allclose(q[:3] / np.linalg.norm(q[:3]), np.array([1, 1, 0]) /
                                   math.sqrt(2), atol=1e-12)
        np.testing.assert_allclose(cs.rows[0, KC.C_VEL:KC.C_VEL + 3], [10, -5, 2.5],
                                   atol=1e-9)
        np.testing.assert_allclose(cs.rows[0, KC.C_ANG:KC.C_ANG + 3],
                                   np.array([1, 1, 0]) / math.sqrt(2) * 30.0, atol=1e-9)
    np.testing.assert_allclose(world.collider_pose('f')[1], q1, atol=1e-12)
    world.step(0.01)                                   # arrived: at rest again
    assert not cs.rows[0, KC.C_VEL:KC.C_ANG + 3].any()
    np.testing.assert_allclose(world.collider_pose('f')[0], [0.4, -0.2, 0.1], atol=1e-12)
    world.reset()
    np.testing.assert_allclose(world.collider_pose('f')[0], [0, 0, 0])


BAD_POSES = [
    ('ghost', (0, 0, 0), (0, 0, 0, 1), 'unknown collider'),
    ('fixed', (0, 0, 0), (0, 0, 0, 1), 'static'),
    ('f', (math.nan, 0, 0), (0, 0, 0, 1), 'position'),
    ('f', (0, math.inf, 0), (0, 0, 0, 1), 'position'),
    ('f', (0, 0, 0), (math.nan, 0, 0, 1), 'finite'),
    ('f', (0, 0, 0), (0, 0, 0, 0), 'zero quaternion'),
    ('f', (0, 0, 0), (0, 0, 0, 2), 'unit quaternion'),
    ('f', (0, 0, 0), (0.1, 0, 0, 0.9), 'unit quaternion'),
    ('f', (0, 0), (0, 0, 0, 1), 'position'),
]


@pytest.mark.parametrize('name,pos,quat,reason', BAD_POSES)
def test_bad_pose_refused_and_nothing_changes(name, pos, quat, reason):
    world = World()
    world.set_colliders(
        boxes=[Box(lo=(0, 0, 0), hi=(1, 1, 1), name='fixed')],
        capsules=[Capsule(center=(0, 0, 1), radius=0.1, length=0.2, name='f',
                          kinematic=True)])
    world.move_collider('f', (0.2, 0, 1), duration=0.1)
    world.step(0.01)
    before = (world.collider_pose('f'), list(world._cset.motion), world._cset.rows.copy())
    with pytest.raises(ValueError, match=reason):
        world.move_collider(name, pos, quat, duration=0.05)
    after = (world.collider_pose('f'), list(world._cset.motion), world._cset.rows.copy())
    np.testing.assert_array_equal(before[0][0], after[0][0])
    np.testing.assert_array_equal(before[0][1], after[0][1])
    assert before[1][1] is after[1][1]                 # the same motion object
    np.testing.assert_array_equal(before[2], after[2])


@pytest.mark.parametrize('kwargs,reason', [
    (dict(capsules=[Capsule(radius=0.0)]), 'capsule.radius'),
    (dict(capsules=[Capsule(length=-1.0)]), 'capsule.length'),
    (dict(capsules=[Capsule(kinematic=True)]), 'needs a name'),
    (dict(capsules=[Capsule(name='a b')]), 'without spaces'),
    (dict(boxes=[Box(orientation=(0, 0, 0, 0))]), 'unit quaternion'),
    (dict(boxes=[Box(name='a')], capsules=[Capsule(name='a')]), 'unique'),
    (dict(spheres=[Sphere(kinematic='yes', name='s')]), 'true or false'),
])
def test_bad_colliders_refused_and_world_unchanged(kwargs, reason):
    world = World()
    keep = [Capsule(name='keep', kinematic=True)]
    world.set_colliders(ground=Ground(), capsules=keep)
    with pytest.raises(ValueError, match=reason):
        world.set_colliders(**kwargs)
    assert world.collider_names == ('keep',) and world.ground is not None


def _block(world, centre, size=0.1, spacing=0.025, mass=1.0, **params):
    a = np.arange(-size / 2, size / 2 + 1e-9, spacing)
    pts = np.stack(np.meshgrid(a, a, a, indexing='ij'), -1).reshape(-1, 3) + centre
    return world.add_body(pts, masses=mass / len(pts), params=BodyParams(**params))


def test_wrench_of_a_resting_body_is_its_weight():
    """A block resting on a named static box: the averaged force on the box is -M g, the
    torque about the box centre (-M g at the block's centre offset) r x F."""
    world = World()
    world.set_colliders(boxes=[Box(lo=(-0.5, -0.5, -0.2), hi=(0.5, 0.5, 0.0), name='table')])
    body = _block(world, (0.2, 0.1, 0.05), mass=2.0, alpha=0.5, damping=0.1)
    for _ in range(240):
        world.step(1 / 120)
    world.take_collider_wrenches()
    for _ in range(120):
        world.step(1 / 120)
    f, t = world.take_collider_wrenches()['table']
    np.testing.assert_allclose(f, [0, 0, -2.0 * G], atol=0.01 * 2 * G)
    r = body.com() - np.array([0, 0, -0.1])
    np.testing.assert_allclose(t, np.cross(r, [0, 0, -2.0 * G]), atol=0.02 * 2 * G * 0.25)
    n, depth = world.collider_contacts()[body.name]
    assert n >= 25 and 0.0 < depth < 0.25 * 0.025      # the bottom layer touches each step


def test_two_bodies_go_through_the_flat_state_and_weigh_on_the_table():
    """With two bodies the body-body contact pass runs, so the collider pass works on the
    world's flat state: both blocks rest on the named table, which feels their weight."""
    world = World()
    world.set_colliders(boxes=[Box(lo=(-0.5, -0.5, -0.2), hi=(0.5, 0.5, 0.0), name='table')])
    a = _block(world, (-0.2, 0.0, 0.05), mass=1.0, alpha=0.5, damping=0.1)
    b = _block(world, (0.2, 0.0, 0.05), mass=3.0, alpha=0.5, damping=0.1)
    assert world.contact is not None                   # the flat path
    for _ in range(240):
        world.step(1 / 120)
    world.take_collider_wrenches()
    for _ in range(120):
        world.step(1 / 120)
    f, _ = world.take_collider_wrenches()['table']
    np.testing.assert_allclose(f, [0, 0, -4.0 * G], atol=0.01 * 4 * G)
    counts = world.collider_contacts()
    assert counts[a.name][0] >= 25 and counts[b.name][0] >= 25
    assert a.com()[2] > 0.03 and b.com()[2] > 0.03


def _plate_run(accel, mu=0.5, dt=1 / 240, substeps=2):
    """A soft block on a kinematic plate that accelerates along x from rest, driven one
    pose per tick like the node does; returns the block's acceleration (least-squares slope
    of its mean velocity over 0.3 .. 1 s, which averages out its rocking) and whether it
    stayed on the plate."""
    world = World()
    plate = Box(lo=(-6.0, -0.5, -0.05), hi=(6.0, 0.5, 0.0), friction=mu, name='plate',
                kinematic=True)
    world.set_colliders(boxes=[plate])
    body = _block(world, (0.0, 0.0, 0.0625 + 1e-4), alpha=0.5, damping=0.1)   # on its spheres
    for _ in range(60):                                # settle on the plate
        world.step(dt)
    tick = substeps * dt
    centre0 = world.collider_pose('plate')[0]
    ts, vs = [], []
    for k in range(1, int(round(1.0 / tick)) + 1):
        t = k * tick
        world.move_collider('plate', centre0 + (0.5 * accel * t * t, 0, 0), duration=tick)
        for _ in range(substeps):
            world.step(dt)
        if t >= 0.3:
            ts.append(t)
            vs.append(body.momentum()[0] / body.total_mass)
    return np.polyfit(ts, vs, 1)[0], body.com()[2] > 0.03


def test_friction_carries_a_box_on_a_plate_accelerating_below_mu_g():
    a = 0.5 * 0.5 * G                                   # a = mu g / 2
    acc, on_top = _plate_run(accel=a)
    assert on_top and acc == pytest.approx(a, rel=0.02)


def test_box_slides_on_a_plate_accelerating_above_mu_g():
    a = 2.0 * 0.5 * G                                   # a = 2 mu g
    acc, on_top = _plate_run(accel=a)
    # kinetic friction drags it at mu g, half the plate's acceleration
    assert on_top and acc == pytest.approx(0.5 * G, rel=0.05)


# ------------------------------------------------------------------------ scene keys

def _scene(colliders):
    from sm_ros.scene import parse_scene
    return parse_scene({'bodies': [{'name': 'b', 'shape': 'box', 'size': [0.1, 0.1, 0.1],
                                    'spacing': 0.05, 'position': [0, 0, 1]}],
                        'colliders': colliders}, 'x.yaml')


def test_scene_colliders_with_names_orientation_capsules_and_paths():
    from sm_ros.scene import build_world
    spec = _scene({
        'boxes': [{'center': [0, 0, 0.5], 'size': [0.4, 0.2, 0.1], 'name': 'plate',
                   'orientation': [0, 0, math.pi / 2], 'kinematic': True},
                  {'lo': [1, 1, 0], 'hi': [2, 2, 1]}],
        'spheres': [{'center': [3, 0, 0], 'radius': 0.5, 'name': 'ball'}],
        'capsules': [{'center': [0, 1, 0], 'radius': 0.05, 'length': 0.2, 'name': 'finger',
                      'kinematic': True, 'orientation': [0, 0, 0, 1], 'friction': 2.0,
                      'path': [{'time': 1.0, 'position': [0, 2, 0]},
                               {'time': 2.0, 'position': [0, 2, 1],
                                'orientation': [1, 0, 0]}]}]})
    world, _ = build_world(spec)
    assert world.collider_names == ('plate', 'ball', 'finger')
    assert len(world._box_rows) == 1 and len(world._sphere_rows) == 0   # fused: plain box
    p, q = world.collider_pose('plate')
    np.testing.assert_allclose(q, [0, 0, math.sin(math.pi / 4), math.cos(math.pi / 4)])
    assert world.collider('finger').friction == 2.0
    for _ in range(100):
        world.step(0.01)                              # 1 s: the path's first keyframe
    np.testing.assert_allclose(world.collider_pose('finger')[0], [0, 2, 0], atol=1e-9)


BAD_SCENE_COLLIDERS = [
    ({'capsules': [{'center': [0, 0, 0], 'radius': 0}]},
     'colliders.capsules[0].radius must be > 0'),
    ({'capsules': [{'center': [0, 0, 0], 'radius': 0.1, 'length': -1}]},
     'colliders.capsules[0].length must be >= 0'),
    ({'capsules': [{'radius': 0.1}]}, 'colliders.capsules[0].center must be a list of 3'),
    ({'capsules': [{'center': [0, 0, 0], 'radius': 0.1, 'lenght': 1}]},
     "did you mean 'length'"),
    ({'capsules': {'center': [0, 0, 0]}}, 'colliders.capsules must be a list'),
    ({'boxes': [{'lo': [0, 0, 0], 'hi': [1, 1, 1], 'name': 3}]},
     'colliders.boxes[0].name must be a non-empty string'),
    ({'boxes': [{'lo': [0, 0, 0], 'hi': [1, 1, 1], 'name': 'a b'}]}, 'without spaces'),
    ({'boxes': [{'lo': [0, 0, 0], 'hi': [1, 1, 1], 'orientation': [0, 0, 0, 0]}]},
     'colliders.boxes[0].orientation quaternion must be non-zero'),
    ({'boxes': [{'lo': [0, 0, 0], 'hi': [1, 1, 1], 'orientation': [0, 'x', 0]}]},
     'colliders.boxes[0].orientation must be a list of 3 finite numbers'),
    ({'boxes': [{'lo': [0, 0, 0], 'hi': [1, 1, 1], 'orientation': [1, 2]}]},
     'must be [roll, pitch, yaw]'),
    ({'spheres': [{'center': [0, 0, 0], 'radius': 1, 'kinematic': True}]},
     'colliders.spheres[0].kinematic needs a name'),
    ({'spheres': [{'center': [0, 0, 0], 'radius': 1, 'kinematic': 'yes', 'name': 's'}]},
     'colliders.spheres[0].kinematic must be true or false'),
    ({'spheres': [{'center': [0, 0, 0], 'radius': 1, 'name': 's'}],
      'capsules': [{'center': [0, 0, 0], 'radius': 1, 'name': 's'}]},
     "colliders.capsules[0].name 's' is already the name of colliders.spheres[0]"),
    ({'capsules': [{'center': [0, 0, 0], 'radius': 1, 'name': 'f',
                    'path': [{'time': 1, 'position': [0, 0, 0]}]}]},
     'colliders.capsules[0].path needs kinematic: true'),
    ({'capsules': [{'center': [0, 0, 0], 'radius': 1, 'name': 'f', 'kinematic': True,
                    'path': [{'time': 1, 'position': [0, 0, 0]},
                             {'time': 1, 'position': [0, 0, 1]}]}]},
     'colliders.capsules[0].path[1].time must be > 1'),
    ({'capsules': [{'center': [0, 0, 0], 'radius': 1, 'name': 'f', 'kinematic': True,
                    'path': [{'time': 1, 'position': [0, 0]}]}]},
     'colliders.capsules[0].path[0].position must be a list of 3'),
    ({'capsules': [{'center': [0, 0, 0], 'radius': 1, 'name': 'f', 'kinematic': True,
                    'path': []}]}, 'colliders.capsules[0].path must be a non-empty list'),
]


@pytest.mark.parametrize('colliders, message', BAD_SCENE_COLLIDERS,
                         ids=[m[:40] for _, m in BAD_SCENE_COLLIDERS])
def test_bad_scene_colliders_are_clear_errors(colliders, message):
    from sm_ros.scene import SceneError
    with pytest.raises(SceneError) as info:
        _scene(colliders)
    assert str(info.value).startswith('x.yaml: ')
    assert message in str(info.value)


# ------------------------------------------------------------------------ grasp

def test_grasp_scene_fingers_lift_the_ball_and_wrenches_sum_to_its_weight():
    """The bundled grasp scene at the node's default step (1/120 s): the capsule fingers
    close, lift the ball off the ground by friction alone, and once it hangs at rest the
    vertical forces the two fingers report add up to the ball's weight within 5 %."""
    from sm_ros.scene import build_world, load_scene
    world, _ = build_world(load_scene('grasp'))
    ball = world.body('ball')
    z0 = ball.com()[2]
    dt = 1 / 120
    for _ in range(int(2.0 / dt)):
        world.step(dt)
    world.take_collider_wrenches()
    for _ in range(int(1.0 / dt)):
        world.step(dt)
    wr = world.take_collider_wrenches()
    assert ball.com()[2] > z0 + 0.07                    # lifted: the centre from 5 to 12+ cm
    assert ball.com()[2] > 0.12
    assert ball.x[:, 2].min() > 0.05                    # off the ground
    weight = ball.total_mass * G
    fz = wr['left_finger'][0][2] + wr['right_finger'][0][2]
    assert fz == pytest.approx(-weight, rel=0.05)
    # the fingers squeeze: equal and opposite horizontal forces pushing them apart
    fl, fr = wr['left_finger'][0][0], wr['right_finger'][0][0]
    assert fl > 0.2 * weight and fr == pytest.approx(-fl, rel=0.05)
    n, depth = world.collider_contacts()['ball']
    assert n > 20 and depth < 0.03


def test_changing_the_ground_keeps_moving_colliders_where_they_are():
    """The node re-sets the colliders when a ground.* parameter changes: passing the same
    collider objects keeps the kinematic ones' poses, motion and scripted paths."""
    world = World()
    world.set_colliders(ground=Ground(), capsules=[Capsule(name='f', kinematic=True)])
    world.move_collider('f', (1.0, 0.0, 0.0), duration=0.02)
    world.step(0.01)
    before = world.collider_pose('f')[0].copy()
    world.set_colliders(ground=Ground(height=-1.0), boxes=world.boxes, spheres=world.spheres,
                        capsules=world.capsules)
    np.testing.assert_array_equal(world.collider_pose('f')[0], before)
    world.step(0.01)
    np.testing.assert_allclose(world.collider_pose('f')[0], (1.0, 0.0, 0.0), atol=1e-12)
    world.set_colliders(ground=Ground(), capsules=[Capsule(name='f', kinematic=True)])
    np.testing.assert_array_equal(world.collider_pose('f')[0], (0.0, 0.0, 0.0))   # new ones


@pytest.mark.parametrize('surface', ['ground', 'box', 'sphere'])
def test_a_soft_body_rests_on_its_particles_spheres(surface):
    """A soft block settles with its nearest particles one contact radius off the ground,
    a static box's top or a static sphere (as a stiff body rests, and as bodies rest on
    one another), not with their centres on the surface."""
    world = World()
    top = {'ground': 0.0, 'box': 0.2, 'sphere': 0.3}[surface]
    if surface == 'ground':
        world.set_colliders(ground=Ground(friction=0.8))
    elif surface == 'box':
        world.set_colliders(boxes=[Box(lo=(-0.5, -0.5, 0.0), hi=(0.5, 0.5, top), friction=0.8)])
    else:
        world.set_colliders(spheres=[Sphere(center=(0.0, 0.0, top - 2.0), radius=2.0,
                                            friction=0.8)])
    body = _block(world, (0.0, 0.0, top + 0.07), alpha=0.5, damping=0.1)
    for _ in range(120):
        world.step(1 / 120)
    r = world.contact_radius(body.name)
    assert r == pytest.approx(0.0125)                  # half the spacing
    if surface == 'sphere':
        gap = np.linalg.norm(body.x - (0.0, 0.0, top - 2.0), axis=1).min() - 2.0
    else:
        gap = body.x[:, 2].min() - top
    assert abs(gap - r) < 1e-3


def _sweep(shape, gravity):
    """A soft block (spacing 2.5 cm) swept 0.25 m in +x in 1 s by a kinematic collider
    thinner than its particle spacing, centred on a layer of its particles: a plate 4 mm
    thick or a rod of radius 3 mm across it; returns how far the block's centre moved."""
    world = World(gravity=(0.0, 0.0, -G * gravity))
    z, turn = 0.0625, _quat((1, 0, 0), math.pi / 2)
    if shape == 'plate':
        plate = Box(lo=(-0.102, -0.15, z - 0.0375), hi=(-0.098, 0.15, z + 0.0375), name='c',
                    kinematic=True)
        world.set_colliders(ground=Ground(friction=0.3), boxes=[plate])
    else:
        rod = Capsule(center=(-0.1, 0.0, z), radius=0.003, length=0.3, orientation=turn,
                      name='c', kinematic=True)
        world.set_colliders(capsules=[rod])
    body = _block(world, (0.0, 0.0, 0.0625), alpha=0.5, damping=0.1)
    for _ in range(30):
        world.step(1 / 120)
    x0 = body.com()[0]
    world.move_collider('c', (0.15, 0.0, z), (0, 0, 0, 1) if shape == 'plate' else turn,
                        duration=1.0)
    for _ in range(120):
        world.step(1 / 120)
    return body.com()[0] - x0


def test_a_plate_thinner_than_the_particle_spacing_pushes_a_soft_block():
    """A plate 4 mm thick pushes a soft block across the ground (friction 0.3) with it
    instead of cutting through it: it meets the particles' spheres (a point model lets it
    slice between them: the block moved 1.1 cm)."""
    assert _sweep('plate', gravity=1.0) > 0.18


def test_a_rod_thinner_than_the_particle_spacing_carries_a_floating_soft_block():
    """Without gravity, a rod of radius 3 mm sweeping through a layer of a soft block's
    particles carries the block along the 0.25 m (a point model let it through after 0.10 m)."""
    assert _sweep('rod', gravity=0.0) > 0.25
