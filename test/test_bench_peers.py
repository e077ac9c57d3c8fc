"""
``python -m sm_ros.bench peers`` and the cases of ``sm_ros/bench/cases.py``.

The measurement functions are checked on tracks with a known answer (a rotation of known
angle, a parabola of known acceleration, a rolling ball, a bounce of known height), the
cases' geometry against their description, and the command on a tiny subset with sm_ros
alone and with an engine missing.  Nothing here asserts a contact outcome of sm_ros (the
contact tests do) or a speed.
"""

import math
import sys

import numpy as np
import pytest

from sm_ros.bench import cases as cs
from sm_ros.bench import peers
from sm_ros.shapes import quat_to_matrix


def _matrix(axis, angle):
    return quat_to_matrix(cs.quat_about(axis, angle))


def _track(times, com, rot=None, vel=None, spin=None, ke=None, mom=None, angmom=None,
           names=('box',)):
    """A Track of len(names) solids from arrays over time (T, B, ...); zeros elsewhere."""
    t_count, b_count = len(times), len(names)
    com = np.asarray(com, dtype=float).reshape(t_count, b_count, 3)
    zeros = np.zeros((t_count, b_count, 3))
    rot = np.broadcast_to(np.eye(3), (t_count, b_count, 3, 3)) if rot is None else rot
    rot = np.asarray(rot).reshape(t_count, b_count, 3, 3)
    tr = cs.Track(names)
    for k, t in enumerate(times):
        tr.add(t, com=com[k], rot=rot[k],
               vel=zeros[k] if vel is None else vel[k], spin=zeros[k] if spin is None else spin[k],
               ke=np.zeros(b_count) if ke is None else ke[k],
               mom=zeros[k] if mom is None else mom[k],
               angmom=zeros[k] if angmom is None else angmom[k])
    return tr


def test_rotation_measures_a_known_angle():
    a = np.eye(3)
    for deg in (0.0, 1.0, 30.0, 90.0, 179.0):
        for axis in ((1, 0, 0), (0, 1, 0), (1, 2, 3)):
            b = _matrix(axis, math.radians(deg))
            assert cs.rotation_deg(a, b) == pytest.approx(deg, abs=1e-6)
            # relative to a turned start the same turn still measures deg
            c = _matrix((0, 0, 1), 0.7)
            assert cs.rotation_deg(c, c @ b) == pytest.approx(deg, abs=1e-6)


def test_topple_measures_turn_and_drift():
    times = np.arange(0, 2.01, 0.1)
    turn = np.radians(np.minimum(times, 1.0) * 60.0)              # 60 deg at 1 s, held
    rot = np.array([_matrix((0, 1, 0), a) for a in turn])
    com = np.zeros((len(times), 3))
    com[times >= 1.0] = (0.003, 0.0, -0.004)                      # 5 mm after settling
    out = cs.measure_topple(None, _track(times, com, rot, names=('top',)))
    assert out['turn_1.5s_deg'] == pytest.approx(60.0)
    assert out['turn_end_deg'] == pytest.approx(60.0)
    assert out['drift_mm'] == pytest.approx(5.0)


def test_fit_accel_and_slide_on_a_parabola():
    times = np.arange(0, 2.0001, cs.SAMPLE_DT)
    assert cs.fit_accel(times, 0.3 + 0.2 * times + 0.5 * 1.7 * times ** 2) == pytest.approx(1.7)
    case = cs.case('incline_mu0.2')
    th = math.radians(20.0)
    accel = cs.G * (math.sin(th) - 0.2 * math.cos(th))
    down = np.array([math.cos(th), 0.0, -math.sin(th)])
    com = np.outer(0.5 * accel * times ** 2, down) + case.solids[0].position
    out = cs.measure_slide(case, _track(times, com))
    assert out['accel_ratio'] == pytest.approx(1.0)
    assert out['slide_mm'] == pytest.approx(1e3 * 0.5 * accel * 4.0, rel=1e-3)
    assert out['turn_end_deg'] == pytest.approx(0.0)


def test_roll_measures_rolling_without_slip_and_with_it():
    case = cs.case('incline_ball')
    th, r = math.radians(20.0), case.solids[0].size[0]
    times = np.arange(0, 2.0001, cs.SAMPLE_DT)
    dist = 0.5 * 5.0 / 7.0 * cs.G * math.sin(th) * times ** 2
    down = np.array([math.cos(th), 0.0, -math.sin(th)])
    normal = np.array([math.sin(th), 0.0, math.cos(th)])
    com = np.outer(dist, down)
    for slip in (1.0, 0.5):
        rot = np.array([_matrix(np.cross(normal, down), slip * d / r) for d in dist])
        out = cs.measure_roll(case, _track(times, com, rot, names=('ball',)))
        assert out['accel_ratio'] == pytest.approx(1.0)
        assert out['slip'] == pytest.approx(slip, rel=1e-6)


def test_push_measures_yaw_and_tilt():
    times = np.arange(0, 1.01, 0.1)
    rot = np.array([_matrix((0, 0, 1), math.radians(20 * t))
                    for t in times])
    com = np.outer(times, (0.1, 0.0, 0.0))
    out = cs.measure_push(None, _track(times, com, rot))
    assert out['yaw_deg'] == pytest.approx(20.0)
    assert out['tilt_max_deg'] == pytest.approx(0.0, abs=1e-6)
    assert out['moved_mm'] == pytest.approx(100.0)


def test_drop_energy_of_a_semi_implicit_elastic_bounce_is_the_drops():
    """A ball stepped as the engines step it (semi-implicit Euler, 1/120 s: each step's
    velocity is its move over h) falls 0.48 m and rises back the same way (an elastic
    bounce), sampled every second step: read at the top of the bounce its energy is the
    drop's, although kinetic plus potential energy read anywhere in flight swings by 2 %;
    spin energy it leaves with (0.1 J) counts."""
    case, h, m = cs.case('drop_e1'), 1.0 / 120.0, 1.0
    fall = 0.6 - cs.G * h * h * np.cumsum(np.arange(37))      # z_n = z_n-1 + h v_n
    z = np.concatenate([fall, fall[::-1], fall[1:]])
    v = np.concatenate([[0.0], np.diff(z) / h])
    com = np.zeros((len(z[::2]), 3))
    com[:, 2] = z[::2]
    vel = np.zeros((len(com), 1, 3))
    vel[:, 0, 2] = v[::2]
    times = np.arange(len(com)) * 2 * h
    ke = 0.5 * m * vel[:, :, 2] ** 2
    out = cs.measure_drop(case, _track(times, com, vel=vel, ke=ke, names=('ball',)))
    drop = 0.6 - z.min()
    swing = (ke[:, 0] + m * cs.G * (com[:, 2] - 0.6)) / (m * cs.G * drop)
    assert swing.max() > 0.01 and 0.998 <= out['energy_ratio'] <= 1.0   # sampled top: lower
    spun = cs.measure_drop(case, _track(times, com, vel=vel, names=('ball',),
                                        ke=ke + 0.1 * (times[:, None] > 0.35)))
    assert spun['energy_ratio'] - out['energy_ratio'] == pytest.approx(0.1 / (m * cs.G * drop))


@pytest.mark.parametrize('e', [0.0, 0.5, 1.0])
def test_drop_measures_a_known_bounce(e):
    """A ball falling 0.5 m that leaves the ground at e times its impact speed."""
    case = cs.case(f'drop_e{e:g}')
    z0, low, m = 0.6, 0.1, 1.0
    t_hit = math.sqrt(2 * (z0 - low) / cs.G)
    v_up = e * cs.G * t_hit
    times = np.arange(0, 1.2, 1e-4)
    after = times - t_hit
    z = np.where(times < t_hit, z0 - 0.5 * cs.G * times ** 2,
                 low + np.maximum(v_up * after - 0.5 * cs.G * after ** 2, 0.0))
    vz = np.where(times < t_hit, -cs.G * times, np.where(z > low, v_up - cs.G * after, 0.0))
    com = np.stack([np.zeros_like(z), np.zeros_like(z), z], -1)
    ke = (0.5 * m * vz ** 2)[:, None]
    out = cs.measure_drop(case, _track(times, com, ke=ke, names=('ball',)))
    assert out['bounce_ratio'] == pytest.approx(e * e, abs=1e-3)
    assert out['energy_ratio'] == pytest.approx(e * e, abs=1e-3)    # kept after the bounce


def test_stack_measures_the_largest_drift():
    times = np.arange(0, 2.01, 0.1)
    com = np.zeros((len(times), 2, 3))
    com[:, 1, 2] = 0.1
    com[times >= 1.0, 1] += (0.0, 0.004, 0.0)
    out = cs.measure_stack(None, _track(times, com, names=('a', 'b')))
    assert out['drift_mm'] == pytest.approx(4.0)
    assert out['moved_mm'] == pytest.approx(4.0)


def test_dominoes_count_and_order():
    times = np.arange(0, 3.01, 0.1)
    names = tuple(f'slab{k}' for k in range(3))

    def track(fall_times):
        rot = np.zeros((len(times), 3, 3, 3))
        for k, tf in enumerate(fall_times):
            angles = np.radians(np.clip((times - tf) * 90.0, 0.0, 90.0))
            rot[:, k] = [_matrix((0, 1, 0), a) for a in angles]
        return _track(times, np.zeros((len(times), 3, 3)), rot, names=names)
    out = cs.measure_dominoes(None, track([0.0, 0.6, 1.2]))
    assert out['fallen'] == 3 and out['in_sequence']
    out = cs.measure_dominoes(None, track([1.2, 0.6, 0.0]))
    assert out['fallen'] == 3 and not out['in_sequence']
    out = cs.measure_dominoes(None, track([0.0, 10.0, 10.0]))
    assert out['fallen'] == 1 and out['standing_turn_max_deg'] == pytest.approx(0.0)


def test_hit_measures_momentum_energy_and_separation():
    times = np.array([0.0, 0.5, 1.0])
    vel = np.array([[[1, 0, 0], [0, 0, 0]], [[0.5, 0, 0], [0.5, 0, 0]], [[0, 0, 0], [1, 0, 0]]],
                   dtype=float)
    mom = vel.copy()
    mom[2, 0, 1] = 1e-3                                           # a known momentum error
    angmom = np.zeros_like(vel)
    angmom[:, :, 2] = [[-0.05, 0.0], [-0.025, -0.025], [0.0, -0.05]]
    ke = 0.5 * (vel ** 2).sum(axis=2)
    spin = np.zeros_like(vel)
    spin[2, 1, 2] = 3.0
    out = cs.measure_hit(None, _track(times, np.zeros((3, 2, 3)), vel=vel, spin=spin, ke=ke,
                                      mom=mom, angmom=angmom, names=('a', 'b')))
    assert out['momentum_err'] == pytest.approx(1e-3)
    assert out['angmom_err'] == pytest.approx(0.0)
    assert out['energy_ratio'] == pytest.approx(1.0)
    assert out['separation'] == pytest.approx(1.0)
    assert (out['spin_a'], out['spin_b']) == (0.0, 3.0)


def test_cases_are_placed_as_described():
    table = cs.case('topple_table_past')
    top = table.solids[0]
    edge = table.fixed[0].position[0] + table.fixed[0].size[0] / 2
    assert top.position[0] - edge == pytest.approx(0.05)
    assert cs.case('topple_body_inside').solids[1].position[0] - edge == pytest.approx(-0.05)
    # the slope's box rests on its top face: centre half a side above the plank's surface
    case = cs.case('incline_mu0.6')
    plank, box = case.fixed[0], case.solids[0]
    rot = _matrix((0, 1, 0), math.radians(20))
    local = rot.T @ (np.asarray(box.position) - plank.position)
    assert local[2] == pytest.approx(plank.size[2] / 2 + box.size[2] / 2)
    assert np.allclose(quat_to_matrix(box.quat), rot)
    # the pushed domino turns about its front bottom edge
    slab = cs.case('dominoes_pushed').solids[0]
    edge_point = np.asarray(slab.position) + (0.03, 0.0, -0.22)
    assert np.allclose(np.asarray(slab.velocity),
                       np.cross(slab.spin, np.asarray(slab.position) - edge_point))
    assert len({c.name for c in cs.all_cases()}) == len(cs.all_cases()) == 19


def test_lattice_fills_the_outline():
    box = cs.Solid('b', 'box', (0.3, 0.2, 0.1), 1.0, (1.0, 2.0, 3.0),
                   cs.quat_about((0, 0, 1), math.pi / 2))
    x = cs.lattice(box, 0.02)
    assert len(x) == 15 * 10 * 5
    assert np.allclose(x.mean(axis=0), box.position)
    # turned 90 deg about z: the 0.3 m side lies along y, half a spacing inside the faces
    assert np.ptp(x, axis=0) == pytest.approx([0.18, 0.28, 0.08])


def test_sm_ros_state_of_a_spinning_box():
    """The state of a rigidly moving lattice: its velocity, spin and energy as given."""
    solid = cs.Solid('a', 'box', (0.1, 0.1, 0.1), 1.0, (0.0, 0.05, 0.0),
                     velocity=(1.0, 0.0, 0.0), spin=(0.0, 0.0, 2.0))
    case = cs.Case('spin', '', '', (solid,), cs.measure_hit, 0.1, ground=False,
                   gravity=(0, 0, 0))
    st = cs.SmRos(case).state()
    body = cs.SmRos(case).bodies[0]
    r = body.x - body.x.mean(axis=0)
    inertia = (body.m * (r * r).sum(axis=1)).sum() * np.eye(3) - (r.T * body.m) @ r
    assert st['vel'][0] == pytest.approx([1.0, 0.0, 0.0])
    assert st['spin'][0] == pytest.approx([0.0, 0.0, 2.0])
    assert st['ke'][0] == pytest.approx(0.5 + 0.5 * 4.0 * inertia[2, 2])
    assert st['angmom'][0] == pytest.approx([0.0, 0.0, -0.05 + 2.0 * inertia[2, 2]])


def test_peers_runs_with_sm_ros_alone(tmp_path):
    assert peers.main(['--engines', 'sm_ros', '--cases', 'hit_e1', '--time-scale', '0.2',
                       '--pile-times', '', '--soft-seconds', '0', '--out',
                       str(tmp_path)]) == 0
    text = (tmp_path / 'peers.md').read_text()
    assert '| hit_e1 | momentum_err |' in text and '| sm_ros |' in text
    assert 'PyBullet |' not in text.split('Contact cases side by side')[1]


def test_peers_names_a_missing_engine_and_leaves_its_column_empty(tmp_path, monkeypatch,
                                                                   capsys):
    monkeypatch.setitem(sys.modules, 'pybullet', None)        # import pybullet fails
    assert peers.engine_classes(['pybullet', 'sm_ros'])['pybullet'] is None
    assert 'PyBullet is not installed' in capsys.readouterr().err
    assert peers.main(['--engines', 'pybullet,sm_ros', '--cases', 'hit_e0', '--time-scale',
                       '0.2', '--pile-times', '', '--soft-seconds', '0', '--out',
                       str(tmp_path)]) == 0
    row = [line for line in (tmp_path / 'peers.md').read_text().splitlines()
           if line.startswith('| hit_e0 | energy_ratio |')][0]
    assert row.split('|')[4].strip() == '-'                    # PyBullet's cell


def test_peers_refuses_an_unknown_engine_or_case(tmp_path):
    for bad in (['--engines', 'havok'], ['--cases', 'juggling']):
        with pytest.raises(SystemExit):
            peers.main(bad + ['--out', str(tmp_path)])
    assert not (tmp_path / 'peers.md').exists()
