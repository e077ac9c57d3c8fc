"""The live error estimate (``sm_ros.error_estimate``): step doubling on the running world,
which it leaves bit for bit; its value against the true error of the accuracy scenes; its
schedule in the simulation (age, pieces, a world asleep) and its parameter."""

import math

import numpy as np
import pytest

from sm_ros import error_estimate as EE
from sm_ros.core.snapshot import Snapshot


def _ratios(name, h, points=125, duration=2.0):
    """Estimate / true error every 0.25 s along 2 s of an accuracy scene; the true error
    is the scene's (the largest RMS position error over 2 s against the exact motion or a
    run at h / 16; ``sm_ros.bench.estimate.ratios``)."""
    from sm_ros.bench import accuracy as acc
    from sm_ros.bench.estimate import ratios
    return ratios(acc.make_scenes(points)[name], h, duration)['ratios']


#: Where the local error rate does not add up to the 2 s error (doc/error_estimate.md):
#: after the jaws let go, the press vibrates, and the error of that vibration's phase stops
#: growing at its amplitude (mean 2-10x, single up to 16x).
_KNOWN_OFF = {'plastic_press'}


@pytest.mark.parametrize('h', [1.0 / 120.0, 1.0 / 240.0])
@pytest.mark.parametrize('scene', ['rigid_spin', 'ballistic', 'soft_drop', 'cantilever',
                                   'plastic_press'])
def test_estimates_track_the_true_error_of_the_accuracy_scenes(scene, h, request):
    """Eight estimates along 2 s: their mean within 3x of the true error, each within 10x."""
    if scene in _KNOWN_OFF:
        request.node.add_marker(pytest.mark.xfail(strict=True, reason='doc/error_estimate.md'))
    ratios = _ratios(scene, h)
    assert 1.0 / 3.0 <= ratios.mean() <= 3.0, ratios
    assert np.all((ratios >= 0.1) & (ratios <= 10.0)), ratios


def test_ballistic_estimate_is_the_exact_error():
    """A body under gravity alone: the local error of a step is g h^2 / 4 for each
    particle, whatever its spin, so the estimate is g h T / 2, the exact error."""
    from sm_ros.core import BodyParams, World
    world = World(gravity=(0.0, 0.0, -9.81))
    world.add_body(np.random.default_rng(1).random((30, 3)), 0.1,
                   BodyParams(mode='rigid', alpha=1.0, beta=0.0), velocities=np.ones((30, 3)))
    res = EE.estimate(world, 0.01)
    assert res['error_m'] == pytest.approx(9.81 * 0.01 * EE.HORIZON_S / 2.0, rel=1e-6)
    assert res['local_m'] == pytest.approx(9.81 * 0.01 ** 2 / 2.0, rel=1e-6)


def test_step_difference_keeps_a_rigid_bodys_rigid_motion_halved_and_drops_a_stretch():
    """A linear body counts its first-step difference; a rigid-mode body half the rigid
    motion (a translation plus a small turn) closest to its second-step difference, so a
    stretch of a box's points along an axis counts nothing."""
    from sm_ros.core import BodyParams, World
    rng, world = np.random.default_rng(3), World(gravity=(0.0, 0.0, 0.0))
    soft = world.add_body(rng.random((25, 3)), 0.1, BodyParams(mode='linear'))
    corners = np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).reshape(3, -1).T
    box = world.add_body(2.0 + np.concatenate([corners, np.eye(3), -np.eye(3)]) * [0.2, 0.1, 0.3],
                         0.1, BodyParams(mode='rigid'))
    x = np.concatenate([soft._x, box._x])
    first, moved, stretch = rng.random((39, 3)) * 1e-3, np.zeros((39, 3)), np.zeros((39, 3))
    moved[25:] = [1e-3, -2e-3, 5e-4] + np.cross([0.0, 2e-3, -1e-3], box._x - box._x.mean(0))
    stretch[25:, 0] = 1e-3 * (box._x[:, 0] - box._x[:, 0].mean())
    for second, counted in ((moved, 0.5 * moved[25:]), (stretch, 0.0)):
        d = EE.step_difference(world, [x, x], [x + first, x + second])
        np.testing.assert_allclose(d[:25], first[:25], atol=1e-15)
        np.testing.assert_allclose(d[25:], counted, atol=1e-15)


def test_error_from_positions():
    coarse = np.zeros((4, 3))
    fine = np.array([[3e-4, 4e-4, 0.0]] * 4)           # 0.5 mm apart
    res = EE.error_from(fine - coarse, 0.01, order=1.0, horizon=2.0)
    assert res['local_m'] == pytest.approx(1e-3)
    assert res['rate_m_s'] == pytest.approx(0.1) and res['error_m'] == pytest.approx(0.2)
    assert EE.error_from(fine - coarse, 0.01, order=2.0)['local_m'] == pytest.approx(2e-3 / 3)
    fine[0, 0] = np.nan
    assert EE.error_from(fine - coarse, 0.01)['error_m'] == math.inf


def _sims(scene, **values):
    from sm_ros.sim import Simulation
    now = [0.0]
    on = Simulation({'scene': scene, **values}, clock=lambda: now[0])
    off = Simulation({'scene': scene, 'error_estimate.rate': 0.0}, clock=lambda: now[0])
    return on, off, now


def _worlds(scene, lead):
    from sm_ros.sim import Simulation
    sims = [Simulation({'scene': scene, 'error_estimate.rate': 0.0}) for _ in range(2)]
    h = float(sims[0].params['dt'])
    for sim in sims:
        for _ in range(lead):                            # into contact for 'many'
            sim.world.step(h)
    return sims[0].world, sims[1].world, h


@pytest.mark.parametrize('scene,lead', [('default', 20), ('many', 120)])
def test_pieces_between_ticks_leave_the_world_as_without_estimates(scene, lead):
    """Room for one piece a tick: the estimate's three pieces over three ticks, the world
    stepped in between, give what the state it started from gives in one go, and the
    world steps bit for bit as one without estimates; with room for three, one tick."""
    world, twin, h = _worlds(scene, lead)
    whole = EE.estimate(world, h)                        # leaves the world as it was
    live = EE.LiveEstimate()
    live.piece_s = 1.0
    for k in range(3):
        live.before_tick(world, h, 1.0, 0.01 * k, room_s=1.5, period=0.01, step_s=1.0)
        assert (live.result is None) == (k < 2)
        live.piece_s = 1.0
        for w in (world, twin):
            w.step(h)
    assert live.result['error_m'] == whole['error_m'] > 0.0
    assert live.age(0.05) == pytest.approx(0.05)
    live.before_tick(world, h, 1.0, 0.5, room_s=3.5, period=0.01, step_s=1.0)
    assert live.result_at == 0.0                         # not due before 1 s
    live.before_tick(world, h, 1.0, 1.0, room_s=3.5, period=0.01, step_s=1.0)
    assert live.result_at == 1.0 and live.running is None
    for w in (world, twin):
        w.step(h)
    for a, b in zip(world.bodies, twin.bodies):
        assert a.x.tobytes() == b.x.tobytes() and a.v.tobytes() == b.v.tobytes()


def test_a_simulation_with_estimates_ticks_as_one_without():
    on, off, now = _sims('default', **{'error_estimate.rate': 10.0})
    for _ in range(60):
        on.tick()
        off.tick()
        now[0] += 1.0 / 60.0
    assert on.error_estimate['error_m'] > 0.0 and on._estimates.age(now[0]) <= 0.2
    for a, b in zip(on.world.bodies, off.world.bodies):
        assert a.x.tobytes() == b.x.tobytes() and a.v.tobytes() == b.v.tobytes()
    running = on._estimates
    on.set_params({'alpha': 0.6})                        # a physics change: anew, at once
    on.tick()
    assert running.result_at == now[0] and running.running is None


def test_estimate_is_never_older_than_two_periods_and_is_counted():
    """Heavy ticks that leave no room: the pieces wait, and run all at once in the tick
    before the next estimate is due, so the age stays within 2 / rate."""
    on, off, now = _sims('default', **{'error_estimate.rate': 2.0})
    ages = []
    for k in range(400):
        on._estimates.piece_s = 1e9
        on.tick()
        now[0] += 1.0 / 60.0
        age = on.status_values()['error_estimate_age_s']
        if k > 60:
            ages.append(age)
    assert max(ages) <= 2.0 / 2.0 + 1e-9 and min(ages) >= 0.0
    assert on.stats.estimate_s_sum > 0.0 and on.status_values()['error_estimate_m'] > 0.0
    off.tick()
    assert off.error_estimate is None and off.status_values()['error_estimate_age_s'] is None


def test_ticks_without_room_share_the_pieces_one_each_before_the_deadline(monkeypatch):
    """No tick leaves room: an estimate waits, then its three pieces run one a tick in the
    last three ticks before the last would be 2 / rate old (none takes all three), and
    the world steps on as one without estimates."""
    world, twin, h = _worlds('default', 20)
    live, period, ran, tick = EE.LiveEstimate(), 0.01, [], [0]
    run = EE.Estimate.run

    def counted(est, pieces):
        first = len(est.runs)
        spent = run(est, pieces)
        ran.append((tick[0], len(est.runs) - first))
        return spent

    monkeypatch.setattr(EE.Estimate, 'run', counted)
    for k in range(420):                                  # rate 1 Hz: 2 s at most
        tick[0] = k
        live.piece_s = 1e9                                # no piece ever fits the room
        live.before_tick(world, h, 1.0, k * period, room_s=0.005, period=period, step_s=1e9)
        for w in (world, twin):
            w.step(h)
        assert live.age(k * period) is None or live.age(k * period) <= 2.0 + 1e-9
    assert [n for _, n in ran] == [1] * 6                 # two estimates, a piece a tick
    assert [k for k, _ in ran] == [97, 98, 99, 294, 295, 296]
    for a, b in zip(world.bodies, twin.bodies):
        assert a.x.tobytes() == b.x.tobytes() and a.v.tobytes() == b.v.tobytes()


def test_a_heap_asleep_estimates_zero_without_copying(monkeypatch):
    from test_snapshot import _stack
    world = _stack()
    for _ in range(400):
        world.step(1.0 / 120.0)
        if world.all_asleep:
            break
    assert world.all_asleep
    saves = []
    monkeypatch.setattr(Snapshot, 'save', lambda self, w: saves.append(w))
    live = EE.LiveEstimate()
    live.before_tick(world, 1.0 / 120.0, 1.0, 5.0, room_s=1.0, period=1 / 60, step_s=1e-3)
    assert live.result['error_m'] == 0.0 and live.running is None and saves == []
    assert live.age(5.5) == 0.5


def test_rate_is_checked_and_a_refused_value_changes_nothing():
    from sm_ros.sim import ParameterError, Simulation
    sim = Simulation({'scene': 'default'})
    for bad in (-1.0, 10.5, float('nan'), float('inf')):
        with pytest.raises(ParameterError):
            sim.set_params({'error_estimate.rate': bad})
    assert sim.pending == {} and sim.params['error_estimate.rate'] == 0.2
    sim.set_params({'error_estimate.rate': 0.0})
    sim.tick()
    assert sim.error_estimate is None


@pytest.mark.parametrize('scene', ['default', 'grasp', 'many', 'mesh', 'paper_384',
                                   'paper_8_clusters', 'plastic', 'rope', 'sheet',
                                   'sheet_rod'])
def test_every_bundled_scene_has_a_fresh_estimate_and_ticks_as_without(scene):
    """Every bundled scene at 10 Hz: after the first 0.2 s the estimate is never older
    than 2 / rate, and the world ticks bit for bit as one without estimates."""
    on, off, now = _sims(scene, **{'error_estimate.rate': 10.0})
    for k in range(40):
        on.tick()
        off.tick()
        now[0] += 1.0 / 60.0
        age = on.status_values()['error_estimate_age_s']
        assert k < 12 or 0.0 <= age <= 0.2 + 1e-9, (k, age)
    rigid = any(body.params.mode == 'rigid' for body in on.world.bodies)
    assert on.error_estimate['steps'] in (0, EE.PIECES * (EE.PIECE_STEPS if rigid else 1))
    for a, b in zip(on.world.bodies, off.world.bodies):
        assert a.x.tobytes() == b.x.tobytes() and a.v.tobytes() == b.v.tobytes(), a.name


def test_a_new_rate_applies_to_the_next_estimate():
    on, _, now = _sims('default', **{'error_estimate.rate': 0.2})
    for _ in range(3):
        on.tick()
        now[0] += 1.0 / 60.0
    first = on._estimates.result_at
    on.set_params({'error_estimate.rate': 10.0})
    for _ in range(8):                                   # 0.13 s: due after 0.1 s at 10 Hz
        on.tick()
        now[0] += 1.0 / 60.0
    assert on._estimates.result_at > first
