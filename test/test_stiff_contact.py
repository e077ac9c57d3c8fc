"""Stiff bodies take their contacts as rigid bodies (``sm_ros/core/stiff_contact.py``):
the cases of ``sm_ros.bench.cases`` at the node's step against their physical outcomes, the
invariants of the impulse solve (no energy from any contact, momenta kept), and the
kernels against plain NumPy twins."""

import math

import numpy as np
import pytest

from sm_ros.bench import cases as C
from sm_ros.core.kernels import stiff_contacts as SC
from sm_ros.core.kernels import stiff_pairs as SP
from sm_ros.core.kernels import stiff_solve as SS
from sm_ros.core.kinematic import C_BOUND, C_DIM, C_E, C_KIND, C_MU, C_POS, C_ROT, ROW
from test_contact import lattice

#: No collider, no gravity: two stiff bodies meeting each other (``pair_contacts``).
_PAIR_SCENE = SS.StiffScene(np.zeros((1, ROW)), 0, False, 0.5, 0.0, np.zeros(3), 1.0 / 120.0,
                            0.16, 100, 0.04, 1.1)


def _run(name):
    return C.run(C.case(name))


@pytest.mark.parametrize('on', ['body', 'table'])
def test_a_box_past_the_edge_topples_and_one_inside_stays(on):
    """Centre of mass 5 cm past the edge: over 45 deg within 1.5 s, and off the top (its
    centre of mass ends below it: whether a plastic landing on its corner leaves it
    enough spin to flip over is a matter of micrometres, doc/contact.md); 5 cm inside:
    under 2 deg and 5 mm after 10 s."""
    case = C.case(f'topple_{on}_past')
    track = C.simulate(C.SmRos(case), case)
    past = case.measure(case, track)
    base = next(s for s in case.solids + case.fixed if s.name in ('base', 'table'))
    top = base.position[2] + base.size[2] / 2.0
    inside = _run(f'topple_{on}_inside')
    assert past['turn_1.5s_deg'] > 45.0 and track.com[-1, track.names.index('top'), 2] < top
    assert inside['turn_end_deg'] < 2.0 and inside['drift_mm'] < 5.0


def test_static_friction_holds_a_box_on_a_slope_below_its_friction_angle():
    """20 deg slope, mu 0.6 > tan 20 deg: the box moves less than 5 mm in 2 s."""
    assert _run('incline_mu0.6')['slide_mm'] < 5.0


def test_kinetic_friction_slides_a_box_at_g_sin_minus_mu_cos():
    """20 deg slope, mu 0.2: the box slides at g (sin - mu cos) within 10 %, upright."""
    out = _run('incline_mu0.2')
    assert out['accel_ratio'] == pytest.approx(1.0, abs=0.1)
    assert out['turn_end_deg'] < 2.0


def test_a_finger_pushing_off_centre_yaws_a_box_and_a_low_one_slides_it():
    """A capsule finger 2 cm thick, thinner than nothing the particles see: off the centre
    line it turns the box about the vertical; 3 cm above the ground it slides it (the push
    is 0.3 m) without tipping it."""
    off = _run('push_offcentre')
    low = _run('push_low')
    assert off['yaw_deg'] > 10.0 and off['tilt_max_deg'] < 5.0
    assert low['moved_mm'] > 250.0 and low['tilt_max_deg'] < 5.0 and low['yaw_deg'] < 2.0


def test_a_ball_rolls_down_a_slope_at_five_sevenths_without_slipping():
    """A lattice ball meets the slope as one sphere (``is_round``), not as the polyhedron
    of its outer particles: it rolls at (5/7) g sin 20 deg within 10 %, turned angle x r
    over distance within 10 % of 1."""
    out = _run('incline_ball')
    assert out['accel_ratio'] == pytest.approx(1.0, abs=0.1)
    assert out['slip'] == pytest.approx(1.0, abs=0.1)


def test_a_ball_rolls_across_a_table_body_as_on_a_plane():
    """A ball (radius 0.1 m, 1 kg) rolling at 1 m/s across a box body (a table of 20 kg
    on the ground): it meets the box's top face as a plane, not as a washboard of its
    particles, so after 1 s it still rolls at 0.9 m/s or more, without slipping."""
    table = C.Solid('table', 'box', (1.2, 0.6, 0.1), 20.0, (0.0, 0.0, 0.05))
    ball = C.Solid('ball', 'ball', (0.1,), 1.0, (-0.4, 0.0, 0.2), velocity=(1.0, 0.0, 0.0),
                   spin=(0.0, 10.0, 0.0))
    case = C.Case('ball_on_table', 'a ball rolling on a table body', '', (table, ball),
                  C.measure_dominoes, 1.0)
    track = C.simulate(C.SmRos(case), case)
    end = track.at(1.0)
    speed, spin = track.vel[end, 1, 0], track.spin[end, 1, 1]
    assert speed >= 0.9 and spin * 0.1 == pytest.approx(speed, rel=0.1)


@pytest.mark.parametrize('lift_mm', [0.0, 5.0, 10.0, 15.0, 20.0, 24.0])
def test_an_elastic_ball_never_bounces_higher_wherever_in_a_step_it_lands(lift_mm):
    """Restitution 1 from heights spread over one step's fall at impact (26 mm): the
    bounce reaches the drop height within 0.1 % and never more."""
    import dataclasses
    case = C.case('drop_e1')
    ball = case.solids[0]
    lifted = dataclasses.replace(ball, position=(0.0, 0.0, ball.position[2] + lift_mm / 1e3))
    out = C.run(dataclasses.replace(case, solids=(lifted,)))
    assert 0.999 <= out['bounce_ratio'] <= 1.001


def test_only_a_body_that_fills_a_ball_is_round():
    """A lattice ball (in any orientation) is round to within its particles' radius; a
    cube, a cylinder as tall as wide and a 10 % flattened ball are not."""
    from sm_ros.core.stiff_contact import is_round
    from sm_ros.shapes import sphere_lattice
    ball = sphere_lattice(0.09, 0.02)
    turn = np.linalg.qr(np.random.default_rng(3).normal(size=(3, 3)))[0]
    assert is_round(ball, 0.01) and is_round(ball @ turn.T, 0.01)
    grid = np.arange(-0.09, 0.0901, 0.02)
    cube = np.stack(np.meshgrid(grid, grid, grid, indexing='ij'), -1).reshape(-1, 3)
    cylinder = cube[np.hypot(cube[:, 0], cube[:, 1]) <= 0.09]
    assert not is_round(cube, 0.01) and not is_round(cylinder, 0.01)
    assert not is_round(ball * (1.0, 1.0, 0.8), 0.01)


@pytest.mark.parametrize('e', [0.0, 0.5, 1.0])
def test_a_dropped_ball_bounces_to_e_squared_of_its_drop_and_never_higher(e):
    """Restitution e: the first bounce reaches e^2 of the drop height (within 10 %, or
    0.05 of it for e = 0), never more than the drop."""
    out = _run(f'drop_e{e:g}')
    assert out['bounce_ratio'] == pytest.approx(e * e, rel=0.1, abs=0.05 if e == 0 else 0.0)
    assert out['bounce_ratio'] <= 1.0 + 1e-3


@pytest.mark.parametrize('name', ['pyramid', 'tower'])
def test_a_pyramid_and_a_tower_of_boxes_stand(name):
    """4-3-2-1 boxes and a tower of 10: every centre of mass within 5 mm over 10 s."""
    out = _run(name)
    assert out['moved_mm'] < 5.0 and out['turn_max_deg'] < 2.0


@pytest.mark.parametrize('tilt_deg,falls', [(6.0, False), (9.5, True)])
def test_a_slab_three_particles_thick_tips_over_as_the_solid_slab(tilt_deg, falls):
    """A slab 0.06 x 0.2 x 0.44 m (3 particles thick) tilted about its bottom edge: a
    solid slab of that outline balances at atan(0.03 / 0.22) = 7.8 deg.  The lattice's
    particles meet the ground with their cells, so it tips within 25 % of that: at
    0.77 times it rocks back upright, at 1.22 times it falls flat."""
    th = math.radians(tilt_deg)
    turn = np.array([[math.cos(th), 0.0, math.sin(th)], [0.0, 1.0, 0.0],
                     [-math.sin(th), 0.0, math.cos(th)]])
    pivot = np.array([0.03, 0.0, 0.0])
    centre = pivot + turn @ (np.array([0.0, 0.0, 0.22]) - pivot)
    slab = C.Solid('slab0', 'box', (0.06, 0.2, 0.44), 0.5, tuple(centre),
                   C.quat_about((0.0, 1.0, 0.0), th))
    case = C.Case('slab', 'a tilted slab', '', (slab,), C.measure_dominoes, 3.0)
    from_start = C.turned_deg(C.simulate(C.SmRos(case), case), 0)[-1]
    if falls:
        assert from_start > 80.0 - tilt_deg
    else:
        assert abs(from_start - tilt_deg) < 1.0             # upright again


def test_dominoes_fall_in_sequence_when_pushed_and_stand_when_not():
    pushed = _run('dominoes_pushed')
    still = _run('dominoes_still')
    assert pushed['fallen'] == 6 and pushed['in_sequence']
    assert still['fallen'] == 0 and still['standing_turn_max_deg'] < 2.0


@pytest.mark.parametrize('e', [0.0, 0.5, 1.0])
def test_an_off_centre_hit_keeps_momentum_spins_both_and_adds_no_energy(e):
    """Zero gravity, no friction: momentum to round-off, both boxes spin, the kinetic
    energy never rises, the more restitution, the faster they part.  Angular momentum
    moves only with the position pushes of an overlap (PyBullet: 0.06-0.17 here)."""
    out = _run(f'hit_e{e:g}')
    assert out['momentum_err'] < 1e-12
    assert out['angmom_err'] < 1e-2
    assert out['energy_ratio'] <= 1.0 + 1e-9
    assert out['spin_a'] > 0.5 and out['spin_b'] > 0.5
    if e > 0.0:
        assert out['separation'] > _run('hit_e0')['separation'] + 0.1


# --- the solve on its own ---------------------------------------------------------------

def _box_row(centre, half, mu=0.5, e=0.0):
    row = np.zeros(ROW)
    row[C_KIND] = 1.0
    row[C_POS:C_POS + 3] = centre
    row[C_ROT:C_ROT + 9] = np.eye(3).ravel()
    row[C_DIM:C_DIM + 3] = half
    row[C_MU], row[C_E] = mu, e
    row[C_BOUND] = np.linalg.norm(half)
    return row


def _bodies(rng, count, spread, ball=False):
    from sm_ros.core.stiff_contact import body_lists
    xs, vs, ms = [], [], []
    for k in range(count):
        xs.append(np.asfortranarray(rng.normal(size=(27, 3)) * 0.05 + (spread * k, 0.0, 0.1)))
        vs.append(np.asfortranarray(rng.normal(size=(1, 3)) + 0.3 * rng.normal(size=(27, 3))))
        ms.append(rng.uniform(0.5, 2.0, 27))
    xs, vs, ms = body_lists(xs, vs, ms)
    return SS.StiffBodies(xs, vs, ms, np.full(count, 0.02), np.ones(count, np.bool_),
                          np.ones(count, np.bool_), np.ones(count, np.bool_),
                          np.full(count, ball, np.bool_),
                          np.zeros((count, 3, 3)))


def _energy_momenta(bodies):
    ke, mom, ang = 0.0, np.zeros(3), np.zeros(3)
    for x, v, m in zip(bodies.x, bodies.v, bodies.m):
        ke += 0.5 * float(m @ (v * v).sum(axis=1))
        mom += m @ v
        ang += np.cross(x, v * m[:, None]).sum(axis=0)
    return ke, mom, ang


@pytest.mark.parametrize('ball', [False, True])
@pytest.mark.parametrize('e', [0.0, 0.3, 0.7, 1.0])
@pytest.mark.parametrize('seed', range(4))
def test_no_contact_creates_energy_and_body_pairs_keep_both_momenta(e, seed, ball):
    """Random clumps thrown at one another without gravity or colliders, as particles or
    as round bodies (spheres against particles and spheres): the pass never raises the
    kinetic energy; without friction it keeps linear momentum to round-off."""
    rng = np.random.default_rng(seed)
    bodies = _bodies(rng, 4, 0.12, ball)
    rows = np.zeros((1, ROW))
    scene = SS.StiffScene(rows, 0, False, 0.0, e, np.zeros(3), 1.0 / 120.0, 1e-3, 100, 0.04,
                          1.1)
    before = _energy_momenta(bodies)
    stats = np.zeros((4, 5))
    SS.stiff_step(bodies, scene, (np.zeros(0, np.int64), np.zeros((0, 3))),
                  np.zeros((0, 6)), stats)
    after = _energy_momenta(bodies)
    assert stats[:, 2].sum() > 0                       # they touch
    assert after[0] <= before[0] * (1.0 + 1e-12)
    np.testing.assert_allclose(after[1], before[1], atol=1e-12)


@pytest.mark.parametrize('count', [20, 400])
def test_close_pairs_match_numpy(count):
    """The particle pairs closer than the reach, every pair tried (few) or swept along an
    axis (many: 400 x 400 near particles), against all pairs by NumPy."""
    rng = np.random.default_rng(count)
    xa, xb = rng.uniform(0.0, 0.5, (count + 5, 3)), rng.uniform(0.2, 0.7, (count + 9, 3))
    near_a = np.sort(rng.choice(len(xa), count, replace=False))
    near_b = np.sort(rng.choice(len(xb), count, replace=False))
    got = SP.close_pairs(xa, xb, near_a, near_b, 0.06)
    d = np.linalg.norm(xa[near_a][:, None] - xb[near_b][None], axis=2)
    i, j = np.nonzero(d < 0.06)
    assert len(i) > 0 and (count * count > SP.FEW_PAIRS) == (count == 400)
    assert sorted(map(tuple, got.tolist())) == sorted(zip(near_a[i].tolist(),
                                                          near_b[j].tolist()))


def test_touches_lists_each_body_pair_contact_with_which_lies_above():
    """One row per body-pair contact within the touching distance (colliders' rows and
    a pair 5 mm apart left out; 1.1 times radii of 1 cm reach 2 mm): a, b and the side
    of the normal (from b towards a) against gravity."""
    rows = np.zeros((6, SC.K_ROW))
    rows[:, SC.K_A] = [0, 1, 2, 3, 1, 2]
    rows[:, SC.K_B] = [-1, 0, 0, 2, 3, 3]
    rows[:, SC.K_GAP] = [0.0, 0.0, -0.001, 0.0019, 0.001, 0.005]
    rows[:, SC.K_N:SC.K_N + 3] = [[0, 0, 1], [0, 0.6, 0.8], [0, 0.6, -0.8], [1, 0, 0],
                                  [0, 0, 1], [0, 0, 1]]
    radius = np.full(4, 0.01)
    got = SC.touches(rows, np.array([0.0, 0.0, -9.81]), radius, 1.1)
    np.testing.assert_array_equal(got, [[1, 0, 1], [2, 0, -1], [3, 2, 0], [1, 3, 1]])
    assert SC.touches(rows, np.zeros(3), radius, 1.1)[:, 2].tolist() == [0, 0, 0, 0]


@pytest.mark.parametrize('ball', [False, True])
@pytest.mark.parametrize('e', [0.0, 0.5, 1.0])
def test_no_collider_contact_creates_energy(e, ball):
    """Clumps thrown against a box and the ground, with friction, as particles or as
    round bodies (one sphere each): the kinetic energy after the pass is at most what it
    was."""
    rng = np.random.default_rng(7)
    bodies = _bodies(rng, 3, 0.2, ball)
    rows = np.stack([np.zeros(ROW), _box_row((0.2, 0.0, 0.0), (0.05, 0.3, 0.3), 0.8, e)])
    rows[0, C_MU], rows[0, C_E] = 0.6, e
    scene = SS.StiffScene(rows, 1, True, 0.5, e, np.zeros(3), 1.0 / 60.0, 1e-3, 100, 0.04,
                          1.1)
    before = _energy_momenta(bodies)[0]
    stats = np.zeros((3, 5))
    SS.stiff_step(bodies, scene, (np.zeros(0, np.int64), np.zeros((0, 3))),
                  np.zeros((1, 6)), stats)
    assert stats[:, 0].sum() > 0
    assert _energy_momenta(bodies)[0] <= before * (1.0 + 1e-12)


def _pair_rows(xa, xb, radius, cells, margin):
    """The contact rows ``pair_contacts`` gives two bodies at rest of unit-mass particles
    xa and xb (N, 3), of contact ``radius`` and lattice ``cells`` (2, 3, 3; zeros: none,
    their particles' spheres), within ``margin``."""
    from sm_ros.core.stiff_contact import body_lists
    xs, vs, ms = body_lists([np.asfortranarray(x) for x in (xa, xb)],
                            [np.zeros((len(x), 3), order='F') for x in (xa, xb)],
                            [np.ones(len(x)) for x in (xa, xb)])
    bodies = SS.StiffBodies(xs, vs, ms, np.full(2, radius), np.ones(2, np.bool_),
                            np.ones(2, np.bool_), np.ones(2, np.bool_), np.zeros(2, np.bool_),
                            cells)
    frames = np.zeros((2, SC.F_ROW))
    for b in range(2):
        SC.body_frame(xs[b], vs[b], ms[b], frames[b], np.zeros((3, 3)), np.zeros((3, 3)))
    out = np.zeros((SC.SLOTS, SC.K_ROW))
    count = SP.pair_contacts(bodies, frames, 0, 1, margin, _PAIR_SCENE, out, 0)
    return out[:count]


@pytest.mark.parametrize('seed', range(3))
def test_bodies_apart_at_any_angle_get_no_overlap(seed):
    """Two 3x3x3 lattice cubes (radius 0.02, spacing 0.04), one turned at random, their
    nearest particles 7.6 mm farther apart than touching: no contact row reports more
    overlap than the slop a contact keeps without a push (a face's plane may reach a
    little past its particles).  An edge or a corner in reach gives a handful of
    particles, and any three lie in a plane: they make no face (``FACE_POINTS``), whose
    normal would make gaps of centimetres out of particles that do not touch."""
    cube = lattice(3, 3, 3, 0.04)
    rng = np.random.default_rng(seed)
    for _ in range(40):
        xb = cube @ np.linalg.qr(rng.normal(size=(3, 3)))[0].T
        away = rng.normal(size=3)
        away /= np.linalg.norm(away)
        xa = cube + 0.3 * away
        for _ in range(4):                  # nearest particles 0.0476 m apart
            near = np.sqrt(((xa[:, None] - xb[None]) ** 2).sum(-1)).min()
            xa -= (near - 0.0476) * away
        rows = _pair_rows(xa, xb, 0.02, np.zeros((2, 3, 3)), 0.002)
        assert np.all(rows[:, SC.K_GAP] > -SC.SLOP_SHARE * 0.04)


def test_an_edge_on_a_face_meets_it_with_its_cell_not_its_sphere():
    """A lattice cube turned 45 deg about y rests an edge on another's top face: the
    pair's gaps are along the face's normal between the cells' outlines (the edge reaches
    r (cos 45 + sin 45) below its particles, as the body's outline does), so the closest
    is the 1 mm the test leaves; with spheres (no cells) it is 8.3 mm more."""
    r, cube = 0.02, lattice(3, 3, 3, 0.04)
    c, s = math.cos(math.pi / 4), math.sin(math.pi / 4)
    turn = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
    xa = cube @ turn.T
    xa[:, 2] += (0.04 + r) + r * (c + s) + 0.001 - xa[:, 2].min()   # 1 mm above b's top
    gaps = {}
    for name, cells in (('cells', np.array([r * turn, r * np.eye(3)])),
                        ('spheres', np.zeros((2, 3, 3)))):
        rows = _pair_rows(xa, cube, r, cells, 0.02)
        np.testing.assert_allclose(rows[:, SC.K_N:SC.K_N + 3], [[0.0, 0.0, 1.0]] * len(rows),
                                   atol=1e-9)
        gaps[name] = rows[:, SC.K_GAP].min()
    assert gaps['cells'] == pytest.approx(0.001, abs=1e-9)
    assert gaps['spheres'] == pytest.approx(0.001 + r * (c + s - 1.0), abs=1e-9)


@pytest.mark.parametrize('tilt_deg', [10.0, 30.0, 60.0])
def test_a_box_tipped_over_an_edge_meets_it_with_its_own_face(tilt_deg):
    """A lattice box tipped about y rests its bottom face 1 mm off another box's edge,
    its particles past the edge below that box's top: the contact's normal is the tipped
    face's and its closest gap the 1 mm, not a false overlap along the other box's top or
    side normal (the flatter side's, before: 3-15 mm, which pushed the box off the edge)."""
    r = 0.02
    base = lattice(5, 3, 3, 0.04, (-0.08, 0.0, -0.04))  # top layer at z = 0, edge at x = 0
    c, s = math.cos(math.radians(tilt_deg)), math.sin(math.radians(tilt_deg))
    turn = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
    normal = turn[:, 2]
    off = normal * (0.001 + r * (1 + s + c))           # its outline 1 mm off the edge cell's
    tipped = lattice(7, 3, 3, 0.04, (0.02, 0.0, 0.04)) @ turn.T + off
    rows = _pair_rows(tipped, base, r, np.array([r * turn, r * np.eye(3)]), 0.02)
    assert len(rows) > 0
    np.testing.assert_allclose(rows[:, SC.K_N:SC.K_N + 3], [normal] * len(rows), atol=1e-9)
    assert rows[:, SC.K_GAP].min() == pytest.approx(0.001, abs=1e-9)


def test_a_cell_meets_the_ground_with_its_lowest_corner():
    """``_outline_gap`` of a particle's lattice cell, turned at random, against the ground:
    the height of the lowest of its 8 corners (NumPy), and ``_outline_point`` at that
    corner once the cell tilts; a zero cell is the particle's sphere."""
    rows = np.zeros((1, ROW))
    rng = np.random.default_rng(5)
    for _ in range(20):
        turn = np.linalg.qr(rng.normal(size=(3, 3)))[0]
        cell = 0.01 * turn                       # half edges as columns
        p = np.array([0.1, -0.2, 0.05])
        corners = p + np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1)
                                for sz in (-1, 1)]) @ cell.T
        gap, _, _, nz = SC._outline_gap(rows, -1, p, 0.01, cell)
        assert nz == 1.0 and gap == pytest.approx(corners[:, 2].min(), abs=1e-12)
        point = np.array(SC._outline_point(p, 0.01, cell, 0.0, 0.0, 1.0))
        if np.abs(cell[2]).min() > SC.CORNER_TILT * 0.01:
            np.testing.assert_allclose(point, corners[np.argmin(corners[:, 2])], atol=1e-12)
    assert SC._outline_gap(rows, -1, p, 0.01, np.zeros((3, 3)))[0] == pytest.approx(0.04)


def test_lattice_axes_are_found_in_any_orientation_and_not_in_a_cloud():
    """A box lattice turned at random gives its three axes; a random cloud and a lattice
    with one particle moved off it give none (their particles meet colliders as spheres)."""
    from sm_ros.core.stiff_contact import lattice_axes
    grid = [np.arange(k) * 0.02 for k in (3, 10, 22)]
    slab = np.stack(np.meshgrid(*grid, indexing='ij'), -1).reshape(-1, 3)
    turn = np.linalg.qr(np.random.default_rng(1).normal(size=(3, 3)))[0]
    axes = lattice_axes(slab @ turn.T)
    along = np.abs(axes.T @ turn)              # each found axis along one lattice axis
    np.testing.assert_allclose(np.sort(along, axis=1), [[0.0, 0.0, 1.0]] * 3, atol=1e-9)
    np.testing.assert_allclose(along.sum(axis=0), 1.0, atol=1e-9)
    assert lattice_axes(np.random.default_rng(2).random((300, 3))) is None
    moved = slab.copy()
    moved[0] += 0.004
    assert lattice_axes(moved) is None
    assert lattice_axes(np.zeros((20, 3))) is None      # coincident particles
    moved[0] = np.nan
    assert lattice_axes(moved) is None


def test_body_frame_matches_numpy():
    rng = np.random.default_rng(3)
    x, v, m = rng.normal(size=(50, 3)), rng.normal(size=(50, 3)), rng.uniform(0.1, 1, 50)
    frame, inertia_out, inv = np.zeros(SC.F_ROW), np.zeros((3, 3)), np.zeros((3, 3))
    SC.body_frame(np.asfortranarray(x), np.asfortranarray(v), m, frame, inertia_out, inv)
    com = m @ x / m.sum()
    r = x - com
    inertia = (m * (r * r).sum(axis=1)).sum() * np.eye(3) - (r.T * m) @ r
    spin = np.linalg.solve(inertia, np.cross(r, (v - m @ v / m.sum()) * m[:, None]).sum(0))
    assert frame[SC.F_MASS] == pytest.approx(m.sum())
    np.testing.assert_allclose(frame[SC.F_COM:SC.F_COM + 3], com, atol=1e-12)
    np.testing.assert_allclose(inertia_out, inertia, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(inv, np.linalg.inv(inertia), rtol=1e-9)
    np.testing.assert_allclose(frame[SC.F_SPIN:SC.F_SPIN + 3], spin, rtol=1e-9)
    assert frame[SC.F_REACH] == pytest.approx(np.linalg.norm(r, axis=1).max())


def _gap_numpy(kind, centre, rot, dims, p, radius):
    """Distance between a sphere at p and the collider's surface, by brute force: the
    nearest of many surface samples (outside) or of the faces (inside a box)."""
    q = rot.T @ (p - centre)
    if kind == 0:
        return np.linalg.norm(p - centre) - dims[0] - radius
    if kind == 1:
        outside = np.linalg.norm(q - np.clip(q, -dims, dims))
        inside = np.min(dims - np.abs(q))
        return (outside if outside > 0 else -inside) - radius
    z = np.clip(q[2], -dims[1], dims[1])
    return np.linalg.norm(q - (0.0, 0.0, z)) - dims[0] - radius


@pytest.mark.parametrize('kind', [0, 1, 2])
def test_surface_gap_matches_numpy(kind):
    rng = np.random.default_rng(kind)
    angle = 0.7
    rot = np.array([[math.cos(angle), -math.sin(angle), 0.0],
                    [math.sin(angle), math.cos(angle), 0.0], [0.0, 0.0, 1.0]])
    dims = np.array([0.2, 0.1, 0.3])
    row = np.zeros(ROW)
    row[C_KIND], row[C_POS:C_POS + 3] = kind, (0.1, -0.2, 0.3)
    row[C_ROT:C_ROT + 9], row[C_DIM:C_DIM + 3] = rot.ravel(), dims
    for p in rng.normal(size=(200, 3)) * 0.3 + (0.1, -0.2, 0.3):
        gap, nx, ny, nz = SC.surface_gap(row, p[0], p[1], p[2], 0.01)
        assert gap == pytest.approx(_gap_numpy(kind, row[1:4], rot, dims, p, 0.01), abs=1e-12)
        assert math.isclose(nx * nx + ny * ny + nz * nz, 1.0, rel_tol=1e-12)


def test_a_one_particle_body_takes_the_same_compiled_pass():
    """A body of one particle (its positions C- and F-contiguous at once) is stepped by the
    pass compiled for bodies of many: stepping it compiles no second variant."""
    from sm_ros.core import BodyParams, Ground, World
    lattice = np.stack(np.meshgrid(*[np.arange(3) * 0.02] * 3), -1).reshape(-1, 3)
    shapes = (lattice + (0.0, 0.0, 0.05), np.array([[0.3, 0.0, 0.05]]))
    worlds = []
    for points in shapes:
        world = World(gravity=(0.0, 0.0, -9.81))
        world.set_colliders(ground=Ground(height=0.0))
        world.add_body(points, 0.01, BodyParams('rigid', 0.9))
        worlds.append(world)
    worlds[0].step(1.0 / 120.0)
    compiled = len(SS.stiff_step.signatures)
    worlds[1].step(1.0 / 120.0)
    assert len(SS.stiff_step.signatures) == compiled


def test_the_stiff_pass_runs_only_where_stiff_bodies_can_meet_something(monkeypatch):
    """A lone rigid body with no collider pays nothing for contact (the pass does not run,
    and its free fall is exact); a ground, a second colliding rigid body or a moving
    collider makes it run; a second body that does not collide does not."""
    from sm_ros.bench.common import cube_lattice
    from sm_ros.core import BodyParams, Capsule, Ground, World
    from sm_ros.core.contact import BodyContact
    from sm_ros.core.stiff_contact import StiffContact
    calls = []
    run = StiffContact.run
    monkeypatch.setattr(StiffContact, 'run', lambda self, *a: calls.append(1) or run(self, *a))
    stiff = BodyParams(mode='rigid', alpha=1.0)

    def steps(*, ground=False, second=None, finger=False):
        world = World()
        world.set_colliders(ground=Ground() if ground else None,
                            capsules=[Capsule(center=(0.0, 0.0, -3.0), name='finger',
                                              kinematic=True)] if finger else [])
        body = world.add_body(cube_lattice(4, 0.1, (0.0, 0.0, 1.0)), 0.01, stiff)
        if second is not None:
            world.add_body(cube_lattice(4, 0.1, (0.5, 0.0, 1.0)), 0.01, stiff,
                           contact=BodyContact(collide=second))
        calls.clear()
        start = body.com()[2]
        for _ in range(12):
            world.step(1.0 / 120.0)
        return len(calls), body.com()[2] - start

    count, drop = steps()
    t = 12 / 120.0                    # 12 steps of semi-implicit Euler: g h^2 (1 + ... + 12)
    assert count == 0 and drop == pytest.approx(-0.5 * 9.81 * t * (t + 1.0 / 120.0), rel=1e-12)
    assert steps(second=False)[0] == 0
    assert steps(ground=True)[0] == 12
    assert steps(second=True)[0] == 12
    assert steps(finger=True)[0] == 12


def test_body_frame_equals_its_numpy_twin():
    """``body_frame`` of random bodies (masses, a common velocity, a spin, noise): mass,
    centre, velocity, the spin that keeps the angular momentum, the inertia tensor and its
    inverse, the reach and the bounds, as NumPy computes them."""
    rng = np.random.default_rng(8)
    for n in (1, 7, 300, 4099):
        x = np.asfortranarray(rng.normal(size=(n, 3)) * [0.3, 0.1, 0.2] + [5.0, -2.0, 1.0])
        m = rng.uniform(0.5, 2.0, n)
        spin = rng.normal(size=3)
        v = np.asfortranarray([1.0, -3.0, 0.5] + np.cross(spin, x - x.mean(0))
                              + 0.01 * rng.normal(size=(n, 3)))
        frame, inertia, inverse = np.zeros(SC.F_ROW), np.zeros((3, 3)), np.zeros((3, 3))
        SC.body_frame(x, v, m, frame, inertia, inverse)
        mass = m.sum()
        com, vel = m @ x / mass, m @ v / mass
        r, u = x - com, v - vel
        want = np.einsum('i,ij,ik->jk', m, r, r)
        want = np.trace(want) * np.eye(3) - want
        ang = (m[:, None] * np.cross(r, u)).sum(0)
        np.testing.assert_allclose(inertia, want, rtol=1e-10, atol=1e-12 * mass)
        if n >= 7:
            np.testing.assert_allclose(inverse @ want, np.eye(3), atol=1e-9)
            np.testing.assert_allclose(frame[SC.F_SPIN:SC.F_SPIN + 3],
                                       np.linalg.solve(want, ang), rtol=1e-8, atol=1e-12)
        assert frame[SC.F_MASS] == pytest.approx(mass, rel=1e-14)
        assert frame[SC.F_INV] == pytest.approx(1.0 / mass, rel=1e-14)
        np.testing.assert_allclose(frame[SC.F_COM:SC.F_COM + 3], com, rtol=1e-13)
        np.testing.assert_allclose(frame[SC.F_VEL:SC.F_VEL + 3], vel, rtol=1e-12, atol=1e-14)
        assert frame[SC.F_REACH] == pytest.approx(np.sqrt((r ** 2).sum(1).max()), rel=1e-12)
        np.testing.assert_array_equal(frame[SC.F_LO:SC.F_LO + 3], x.min(0))
        np.testing.assert_array_equal(frame[SC.F_HI:SC.F_HI + 3], x.max(0))


# --- bodies carried as a whole beside stiff ones ---------------------------------------

_MIXED_STACK = """
colliders: {ground: {friction: 0.6}}
contact: {friction: 0.6, sleep: false}
bodies:
  - {name: lower, shape: box, size: [0.2, 0.2, 0.12], spacing: 0.04, mass: 0.6,
     position: [0.0, 0.0, 0.07], mode: linear, alpha: 0.9, beta: 0.2, clusters: 2}
  - {name: upper, shape: box, size: [0.2, 0.2, 0.12], spacing: 0.04, mass: 0.6,
     position: [0.05, 0.0, 0.20], mode: linear, alpha: 0.9, beta: 0.2, clusters: 2}
  - {name: ball, shape: sphere, radius: 0.14, spacing: 0.04, mass: 0.5,
     position: [0.1, 0.0, 0.42], mode: quadratic, alpha: 0.8, beta: 0.5, clusters: 2}
"""


def test_a_soft_ball_on_a_stack_of_stiff_boxes_comes_to_rest():
    """A ball too soft to be stiff but carried as a whole rests on two stiff boxes: its
    contact is solved with theirs, so its weight reaches the ground through both and after
    a second every body is at rest, its velocity that of its motion (no body sinking into
    the one below while another pass pushes it back)."""
    import yaml
    from sm_ros.scene import build_world, parse_scene
    world, _ = build_world(parse_scene(yaml.safe_load(_MIXED_STACK)))
    h = 1.0 / 120.0
    for _ in range(120):
        world.step(h)
    start = {b.name: b.x.mean(axis=0) for b in world.bodies}
    for _ in range(60):
        world.step(h)
    for body in world.bodies:
        assert np.linalg.norm(body.v.mean(axis=0)) < 5e-3, body.name
        assert np.linalg.norm(body.x.mean(axis=0) - start[body.name]) < 1e-3, body.name


_SOFT_LOAD = """
colliders: {ground: {friction: 0.6}}
contact: {friction: 0.6, sleep: false}
bodies:
  - {name: base, shape: box, size: [0.3, 0.3, 0.12], spacing: 0.04, mass: 2.0,
     position: [0.0, 0.0, 0.09], mode: rigid, alpha: 0.9}
  - {name: upper, shape: box, size: [0.24, 0.24, 0.12], spacing: 0.04, mass: 1.0,
     position: [0.0, 0.0, 0.26], mode: rigid, alpha: 0.9}
"""
_SPONGE = """
  - {name: sponge, shape: box, size: [0.24, 0.24, 0.09], spacing: 0.03, mass: MASS,
     position: [0.0, 0.0, 0.42], mode: linear, alpha: 0.3, beta: 0.2, damping: 0.2}
"""


@pytest.mark.parametrize('mass', [0.3, 3.0])
def test_a_soft_load_does_not_sink_a_stiff_box_into_the_one_it_lies_on(mass):
    """A soft block (alpha 0.3: met particle by particle, after the stiff pass) of 0.3 or
    3 kg on a stiff box lying on another: after 3 s the upper box lies as deep in the
    lower one as without the load (within 1 mm), the lower one on the ground, both at
    rest.  The pass that meets the soft block moves the box as a whole; without what it
    lies on there, the load sank it 4 and 11 mm deeper every step, which the stiff pass
    pushed back, and the lower box into the ground."""
    import yaml
    from sm_ros.scene import build_world, parse_scene

    def gap(text):
        world, _ = build_world(parse_scene(yaml.safe_load(text)))
        for _ in range(360):
            world.step(1.0 / 120.0)
        base, upper = world.body('base'), world.body('upper')
        for body in (base, upper):
            assert np.abs(body.v).max() < 5e-3, body.name
        return upper.x[:, 2].min() - base.x[:, 2].max(), base.x[:, 2].min()

    alone, _ = gap(_SOFT_LOAD)
    loaded, lowest = gap(_SOFT_LOAD + _SPONGE.replace('MASS', str(mass)))
    assert loaded == pytest.approx(alone, abs=1e-3)
    assert lowest > 0.02 - 1e-4                     # the ground holds the lower box


def test_a_soft_body_alone_still_lands_on_its_particles():
    """Two soft blocks (alpha 0.5: carried as a whole) dropped apart beside a stiff box:
    they take their contacts with it and each other in the stiff pass, but each meets the
    ground with its own particles while it is near no other body, so it squashes on
    landing, as a soft body does."""
    from sm_ros.core import BodyParams, Ground, World
    world = World()
    world.set_colliders(ground=Ground())
    g = np.stack(np.meshgrid(*[np.arange(7)] * 3, indexing='ij'), -1).reshape(-1, 3) * 0.025
    params = BodyParams(mode='quadratic', alpha=0.5, beta=0.5)
    block = world.add_body(g - g.mean(axis=0) + (0.0, 0.0, 0.5), 0.01, params, 'a')
    world.add_body(g - g.mean(axis=0) + (1.0, 0.0, 0.5), 0.01, params, 'b')
    world.add_body(g - g.mean(axis=0) + (2.0, 0.0, 0.1), 0.01, BodyParams('rigid', 1.0), 'c')
    rest = np.ptp(block.x[:, 2])
    least = rest
    for _ in range(120):
        world.step(1.0 / 120.0)
        least = min(least, np.ptp(block.x[:, 2]))
    assert world.contact.rigid[:3].all()             # the stiff pass's bodies
    assert least < 0.6 * rest


def test_bodies_carried_as_a_whole_keep_their_pass_where_none_is_stiff():
    """A bin of blocks carried as a whole and no stiff body: their contacts stay in the
    contact pass (its pair list holds them), which costs less than the stiff pass for
    many bodies; one stiff body among them takes them all into the stiff pass."""
    from sm_ros.bench.contact_scenes import block_bin
    from sm_ros.core import BodyParams
    world = block_bin(24)
    world.step(1.0 / 120.0)
    assert world.contact.coupling[:24].all() and not world.contact.rigid[:24].any()
    assert world.contact.npairs > 0
    world.body('block0').set_params(BodyParams('rigid', 1.0))
    world.step(1.0 / 120.0)
    assert world.contact.rigid[:24].all()


def test_the_pass_lists_hold_the_bodies_own_arrays_of_any_layout():
    """``body_lists`` (made and filled by cached compiled functions) holds each body's
    positions, velocities and masses themselves, F-ordered, C-ordered or one particle."""
    from sm_ros.core.stiff_contact import body_lists
    blocks = [np.arange(6.0).reshape(3, 2).T, np.arange(6.0).reshape(2, 3), np.ones((1, 3))]
    masses = [np.full(len(b), 0.5) for b in blocks]
    for m in masses:
        m.flags.writeable = False
    xs, vs, ms = body_lists(blocks, blocks, masses)
    assert len(xs) == len(vs) == len(ms) == 3
    for got, want in zip(list(xs) + list(ms), blocks + masses):
        assert np.shares_memory(got, want) and np.array_equal(got, want)
