"""Sleeping bodies (sm_ros.core.sleep): a body at rest in a contact world is not stepped
until a moving body touches it or an input changes it; kernels against NumPy twins."""

import numpy as np
import pytest
from numba.typed import List

from sm_ros.core import BodyParams, Ground, World
from sm_ros.core import sleep as SL
from sm_ros.core.contact import ContactParams

S = 0.02
H = 1 / 120
UP = np.array([0.0, 0.0, 1.0])


def lattice(nx, ny, nz, s=S, center=(0.0, 0.0, 0.0)):
    g = np.stack(np.meshgrid(np.arange(nx), np.arange(ny), np.arange(nz), indexing='ij'),
                 -1).reshape(-1, 3) * s
    return g - g.mean(axis=0) + np.asarray(center, dtype=float)


def _flags(states):
    out = List()
    for s in states:
        f = np.zeros(4)
        f[3] = s
        out.append(f)
    return out


def _update(flat, bodies, state, pi, pj, count):
    """``sleep_update`` with sleep_speed 0.01 m/s, sleep_time 0.5 s, sleeping allowed;
    ``bodies``: (their positions, their flags)."""
    return SL.sleep_update(flat, *bodies, state, SL.Pairs(pi, pj, count),
                           SL.SleepRule(UP, H, 0.01, 0.5, True))


# ---------------------------------------------------------------------------- kernels

def test_body_moves_matches_numpy():
    rng = np.random.default_rng(1)
    off = np.array([0, 5, 9, 16])
    X = rng.normal(size=(3, 16))
    Xp = X + 0.01 * rng.normal(size=(3, 16))
    Xa = X + 0.1 * rng.normal(size=(3, 16))
    Xp0, Xa0 = Xp.copy(), Xa.copy()
    flags = _flags([0.0, 1.0, -1.0])              # awake, asleep, held awake
    step2, drift2 = np.full(3, -1.0), np.full(3, -1.0)
    SL.body_moves(X, Xp, Xa, off, flags, step2, drift2)
    for b in (0, 2):
        sl = slice(off[b], off[b + 1])
        assert step2[b] == pytest.approx(((X[:, sl] - Xp0[:, sl]) ** 2).sum(0).max(),
                                         rel=1e-12)
        assert drift2[b] == pytest.approx(((X[:, sl] - Xa0[:, sl]) ** 2).sum(0).max(),
                                          rel=1e-12)
        assert np.array_equal(Xp[:, sl], X[:, sl])            # the step's positions kept
    assert step2[1] == 0.0 and drift2[1] == 0.0               # asleep: not measured
    assert np.array_equal(Xp[:, 5:9], Xp0[:, 5:9])
    assert np.array_equal(Xa, Xa0)                            # the anchors are not moved


def test_touch_restless_matches_numpy():
    rng = np.random.default_rng(2)
    n, nb = 60, 6
    X = rng.uniform(0, 0.35, size=(3, n))
    R = np.full(n, 0.02)
    B = np.repeat(np.arange(nb, dtype=np.int32), n // nb)
    i, j = np.triu_indices(n, 1)
    pi, pj = i.astype(np.int32), j.astype(np.int32)
    level = np.array([2, 0, 1, 2, 0, 1], dtype=np.uint8)   # restless, settled, unsettled
    near = np.full(nb, 7, dtype=np.uint8)
    off = np.arange(nb + 1) * (n // nb)
    xs = List([X[:, off[b]:off[b + 1]].copy() for b in range(nb)])
    d = np.linalg.norm(X[:, i] - X[:, j], axis=0)
    touch = (d < SL.TOUCH_FACTOR * (R[i] + R[j])) & (B[i] != B[j])
    flat = SL.FlatArrays(x=X, v=X, inv_mass=R, awake_inv_mass=R, radius=R, body=B, offset=off,
                         touched=np.zeros(nb, np.uint8))
    # the stiff pass's body pairs in contact: a, b, a above b (1), below (-1) or neither
    stiff = np.array([[1, 2, 1], [4, 5, -1], [0, 4, 0], [5, 1, 1]], dtype=np.int64)
    for up in (np.zeros(3), np.array([0.0, 0.0, 1.0]), np.array([0.6, 0.0, -0.8])):
        SL.touch_restless(flat, xs, SL.Pairs(pi, pj, len(pi), stiff), level, up, near,
                          SL.TOUCH_FACTOR)
        want = np.zeros(nb, dtype=np.uint8)
        both = zip(np.concatenate([B[i][touch], stiff[:, 0]]),
                   np.concatenate([B[j][touch], stiff[:, 1]]),
                   np.concatenate([(X[:, i] - X[:, j]).T[touch] @ up, stiff[:, 2]]))
        for a, b, above in both:
            # a level 1 counts only from below (any side without gravity); 2 always
            if level[b] == 2 or (level[b] == 1 and (not up.any() or above > 0)):
                want[a] = max(want[a], level[b])
            if level[a] == 2 or (level[a] == 1 and (not up.any() or above < 0)):
                want[b] = max(want[b], level[a])
        assert np.array_equal(near, want)
        assert want.any()


def test_sleep_update_falls_asleep_wakes_and_holds():
    # three one-particle bodies: 0 still for long enough, 1 still but touching 2, which
    # moves fast (restless: in this step and the one before); then 2 touches 0 while 0
    # sleeps
    X = np.array([[0.0, 1.0, 1.03], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    Xp, Xa = X.copy(), X.copy()
    V = np.ones((3, 3))
    W = np.array([1.0, 2.0, 3.0])
    Wa = W.copy()
    R = np.full(3, 0.02)
    B = np.arange(3, dtype=np.int32)
    off = np.arange(4)
    xs = List([X[:, k:k + 1] for k in range(3)])          # views: the same positions
    flags = _flags([0.0, 0.0, 0.0])
    slept = np.zeros(3, dtype=np.uint8)
    calm = np.array([0.5, 0.5, 0.0])
    # fast (body 2 moved fast in the step before too), step2, drift2, level, near
    scratch = [np.array([0, 0, 1], np.uint8), np.zeros(3), np.zeros(3), np.zeros(3, np.uint8),
               np.zeros(3, np.uint8)]
    pi, pj = np.array([0, 1], dtype=np.int32), np.array([2, 2], dtype=np.int32)
    touched = np.zeros(3, dtype=np.uint8)
    flat = SL.FlatArrays(X, V, W, Wa, R, B, off, touched)
    state = SL.SleepArrays(Xp, Xa, slept, calm, *scratch)
    Xp[0, 2] -= 0.01                          # body 2 moved 1 cm in the step: restless
    n = _update(flat, (xs, flags), state, pi, pj, 2)
    assert n == 1
    assert flags[0][3] == 1.0 and slept[0] == 1 and touched[0] == 1    # asleep
    assert W[0] == 0.0 and np.all(V[:, 0] == 0.0)
    assert flags[1][3] == 0.0 and flags[2][3] == 0.0         # 1 touches restless 2
    assert np.all(V[:, 1:] == 1.0) and np.array_equal(W[1:], Wa[1:])
    # body 2 jumps to touch the sleeping body 0: 0 wakes, W restored; body 1, no longer
    # touched by a restless body, falls asleep
    X[0, 2] = 0.03
    n = _update(flat, (xs, flags), state, pi, pj, 2)
    assert n == 2 and flags[0][3] == 0.0 and slept[0] == 0 and W[0] == 1.0
    assert flags[1][3] == 1.0 and W[1] == 0.0
    flags[1][3] = 0.0                         # woken from outside (Body.wake)
    assert SL.sleep_sync(flags, slept, off, W, Wa, calm) == 1
    assert W[1] == 2.0 and slept[1] == 0
    # held awake (-1): never sleeps, and counts as restless
    flags[1][3] = -1.0
    calm[1] = 10.0
    _update(flat, (xs, flags), state, pi, pj, 0)
    assert flags[1][3] == -1.0 and calm[1] == 0.0


def test_no_body_falls_asleep_on_a_support_that_still_moves_slowly():
    # body 0 still for long enough, resting on body 1 below it, which drifts slowly
    # (unsettled: not still for sleep_time, not fast enough to be restless): 0 stays
    # awake; once 1 has been still for sleep_time both fall asleep together; a sleeping
    # body is not woken by an unsettled one; beside (not below) it, an unsettled body
    # does not keep it awake
    X = np.array([[0.0, 0.0], [0.0, 0.0], [0.03, 0.0]])
    Xp, Xa = X.copy(), X.copy()
    Xa[0, 1] -= 0.01                          # 1 cm from where its still spell began
    V = np.zeros((3, 2))
    W = np.ones(2)
    Wa = W.copy()
    R = np.full(2, 0.02)
    B = np.arange(2, dtype=np.int32)
    off = np.arange(3)
    xs = List([X[:, k:k + 1] for k in range(2)])
    flags = _flags([0.0, 0.0])
    slept = np.zeros(2, dtype=np.uint8)
    calm = np.array([1.0, 0.4])
    scratch = [np.zeros(2, np.uint8), np.zeros(2), np.zeros(2), np.zeros(2, np.uint8),
               np.zeros(2, np.uint8)]
    pi, pj = np.array([0], dtype=np.int32), np.array([1], dtype=np.int32)
    touched = np.zeros(2, dtype=np.uint8)
    flat = SL.FlatArrays(X, V, W, Wa, R, B, off, touched)
    state = SL.SleepArrays(Xp, Xa, slept, calm, *scratch)
    assert _update(flat, (xs, flags), state, pi, pj, 1) == 0
    assert calm[1] == 0.0 and scratch[3][1] == 1 and scratch[4][0] == 1     # unsettled
    assert flags[0][3] == 0.0
    for _ in range(int(0.5 / H)):             # 1 now still: settles after sleep_time
        _update(flat, (xs, flags), state, pi, pj, 1)
        assert flags[0][3] == flags[1][3]     # together
    assert flags[0][3] == 1.0 and flags[1][3] == 1.0
    flags[1][3] = 0.0                         # 1 woken from outside, moves slowly
    SL.sleep_sync(flags, slept, off, W, Wa, calm)
    X[0, 1] += 0.0001
    _update(flat, (xs, flags), state, pi, pj, 1)
    assert flags[0][3] == 1.0 and flags[1][3] == 0.0          # 0 sleeps on
    # side by side: 0 wakes from outside, 1 beside it is unsettled; 0 falls asleep
    X[:, 0] = (-0.03, 0.0, 0.0)
    flags[0][3] = 0.0
    SL.sleep_sync(flags, slept, off, W, Wa, calm)
    Xp[:, 0] = Xa[:, 0] = X[:, 0]
    calm[0] = 1.0
    Xa[0, 1] -= 0.01
    _update(flat, (xs, flags), state, pi, pj, 1)
    assert scratch[3][1] == 1 and flags[0][3] == 1.0


# ---------------------------------------------------------------------------- worlds

def _two_boxes(contact=None):
    w = World()
    w.contact_params = contact or ContactParams(sleep_time=0.25)
    w.set_colliders(ground=Ground())
    p = BodyParams(mode='rigid', alpha=0.99, damping=0.5)
    a = w.add_body(lattice(4, 4, 3, center=(0, 0, 0.02)), 0.01, p, 'a')
    b = w.add_body(lattice(4, 4, 3, center=(0, 0, 0.02 + 3 * S)), 0.01, p, 'b')
    return w, a, b


def _until_asleep(w, names, seconds=4.0):
    for _ in range(int(seconds / H)):
        w.step(H)
        if sorted(w.asleep) == sorted(names):
            return True
    return False


def test_a_stack_falls_asleep_and_keeps_its_state_bit_for_bit():
    w, a, b = _two_boxes()
    assert _until_asleep(w, ['a', 'b'])
    assert w.asleep_count == 2 and a.asleep and b.asleep
    assert np.all(a.v == 0.0) and np.all(b.v == 0.0)          # at rest: no momentum
    xa, xb = a.x.copy(), b.x.copy()
    for _ in range(60):
        w.step(H)
    assert np.array_equal(a.x, xa) and np.array_equal(b.x, xb)
    assert np.all(a.v == 0.0) and np.all(b.v == 0.0)
    assert b.com()[2] > a.com()[2] + 2.5 * S                  # it sleeps where it rests


def test_sleep_off_never_sleeps_and_turning_it_off_wakes():
    w, a, b = _two_boxes(ContactParams(sleep=False, sleep_time=0.25))
    for _ in range(180):
        w.step(H)
    assert w.asleep == [] and w.asleep_count == 0
    w.contact_params = ContactParams(sleep_time=0.25)
    assert _until_asleep(w, ['a', 'b'])
    w.contact_params = ContactParams(sleep=False)
    assert w.asleep == []
    w.step(H)
    assert not np.all(a.v == 0.0)                             # stepped again: gravity


def test_a_moving_body_wakes_the_sleeping_body_it_hits():
    w, a, b = _two_boxes()
    p = BodyParams(mode='rigid', alpha=0.99, damping=0.5)
    c = w.add_body(lattice(4, 4, 3, center=(0.15, 0, 0.02)), 0.01, p, 'c')
    assert _until_asleep(w, ['a', 'b', 'c'])
    c.set_state(v=np.tile([-1.5, 0.0, 0.0], (c.n, 1)))       # pushed at the stack
    assert not c.asleep and a.asleep
    xa = a.x.copy()
    woke = False
    for _ in range(60):
        w.step(H)
        woke = woke or not a.asleep
    assert woke
    assert not np.array_equal(a.x, xa)                        # pushed: it moved
    assert (a.x[:, 0].max() < c.x[:, 0].min() + 0.6 * S)      # and did not pass through


@pytest.mark.parametrize('change', ['state', 'params', 'wrench', 'grab', 'reset'])
def test_an_input_wakes_a_sleeping_body(change):
    w, a, b = _two_boxes()
    assert _until_asleep(w, ['a', 'b'])
    if change == 'state':
        b.set_state(x=b.x + [0.0, 0.0, 0.05])
    elif change == 'params':
        b.set_params(alpha=0.9)
    elif change == 'wrench':
        b.set_wrench([0.0, 0.0, 5.0])
    elif change == 'grab':
        b.set_kinematic([0], b.x[:1] + [0.0, 0.0, 0.05])
    else:
        b.reset()
    assert not b.asleep and a.asleep
    x, v = b.x.copy(), b.v.copy()
    w.step(H)
    assert not (np.array_equal(b.x, x) and np.array_equal(b.v, v))     # stepped
    if change in ('wrench', 'grab'):                          # held awake while it acts
        for _ in range(120):
            w.step(H)
        assert not b.asleep
        assert b._flags[3] == -1.0


@pytest.mark.parametrize('change', ['gravity', 'colliders', 'wake'])
def test_a_world_change_wakes_every_body(change):
    w, a, b = _two_boxes()
    assert _until_asleep(w, ['a', 'b'])
    if change == 'gravity':
        w.gravity = (0.0, 0.0, 9.81)
    elif change == 'colliders':
        w.set_colliders(ground=Ground(height=-0.01))
    else:
        w.wake()
    w.step(H)
    assert w.asleep == []
    assert np.all(w.contact.flat.W > 0.0)                     # masses back


def test_one_body_never_sleeps():
    w = World()
    w.contact_params = ContactParams(sleep_time=0.1)
    w.set_colliders(ground=Ground())
    a = w.add_body(lattice(4, 4, 3, center=(0, 0, 0.02)), 0.01,
                   BodyParams(mode='rigid', alpha=0.99, damping=0.5), 'a')
    for _ in range(120):
        w.step(H)
    assert not a.asleep and w.asleep_count == 0 and w._sleep is None


def test_adding_a_body_wakes_every_body():
    w, a, b = _two_boxes()
    assert _until_asleep(w, ['a', 'b'])
    w.add_body(lattice(2, 2, 2, center=(0.5, 0, 0.5)), 0.01, BodyParams(), 'c')
    w.step(H)
    assert w.asleep == []


@pytest.mark.parametrize('key, value', [('sleep', 'yes'), ('sleep_speed', -0.1),
                                        ('sleep_speed', float('nan')),
                                        ('sleep_time', 1e9), ('sleep_time', True)])
def test_bad_sleep_settings_are_refused(key, value):
    w, a, b = _two_boxes()
    before = w.contact_params
    with pytest.raises(ValueError, match=f'contact.{key}'):
        w.contact_params = ContactParams(**{key: value})
    assert w.contact_params == before


def test_scene_contact_keys_set_sleep():
    from sm_ros.scene import SceneError, parse_scene
    spec = parse_scene({'bodies': [{'shape': 'box', 'size': [0.1, 0.1, 0.1]}],
                        'contact': {'sleep': False, 'sleep_speed': 0.05, 'sleep_time': 2}})
    assert spec.contact == {'sleep': False, 'sleep_speed': 0.05, 'sleep_time': 2.0}
    with pytest.raises(SceneError, match='contact.sleep_time'):
        parse_scene({'bodies': [{'shape': 'box', 'size': [0.1, 0.1, 0.1]}],
                     'contact': {'sleep_time': -1}})


def test_a_world_with_pass_colliders_does_not_sleep():
    # a named collider's wrench is published: a sleeping body would not weigh on it
    from sm_ros.core import Box
    w, a, b = _two_boxes()
    assert _until_asleep(w, ['a', 'b'])
    w.set_colliders(ground=Ground(), boxes=[Box(lo=(0.5, 0.5, 0.0), hi=(0.6, 0.6, 0.1),
                                                name='table')])
    for _ in range(120):
        w.step(H)
        assert w.asleep == []


def test_the_node_tick_reports_the_sleeping_bodies(tmp_path):
    from sm_ros.diagnostics import KEYS
    from sm_ros.sim import Simulation
    scene = tmp_path / 'two.yaml'
    scene.write_text(
        'colliders: {ground: {}}\n'
        'contact: {sleep_time: 0.25}\n'
        'bodies:\n'
        '  - {name: a, shape: box, size: [0.1, 0.1, 0.06], spacing: 0.02, mode: rigid,\n'
        '     alpha: 0.99, damping: 0.5, position: [0, 0, 0.03]}\n'
        '  - {name: b, shape: box, size: [0.1, 0.1, 0.06], spacing: 0.02, mode: rigid,\n'
        '     alpha: 0.99, damping: 0.5, position: [0, 0, 0.1]}\n')
    sim = Simulation({'scene': str(scene)})
    assert 'bodies_asleep' in KEYS
    for _ in range(180):
        sim.tick()
        if sim.stats.asleep == 2:
            break
    assert sim.stats.asleep == 2 == sim.world.asleep_count
    assert sorted(sim.world.asleep) == ['a', 'b']
    b = sim.world.body('b')
    b.set_wrench([0.0, 0.0, 1.0])       # a force message: b awake, held awake, and it
    sim.tick()                          # wakes a, which it touches
    assert sim.stats.asleep == 0 and not b.asleep
    b.clear_wrench()
    for _ in range(180):
        sim.tick()
        if sim.stats.asleep == 2:
            break
    assert sorted(sim.world.asleep) == ['a', 'b']


def test_one_fast_step_is_not_restless():
    # a body that moves fast in one step only (the body it rests on just fell asleep and
    # stopped giving way) does not wake its sleeping neighbour; in two steps in a row it does
    X = np.array([[0.0, 0.03], [0.0, 0.0], [0.0, 0.0]])
    Xp, Xa = X.copy(), X.copy()
    V, W = np.zeros((3, 2)), np.array([0.0, 1.0])
    Wa = np.ones(2)
    R = np.full(2, 0.02)
    B = np.arange(2, dtype=np.int32)
    off = np.arange(3)
    xs = List([X[:, k:k + 1] for k in range(2)])
    flags = _flags([1.0, 0.0])
    slept = np.array([1, 0], dtype=np.uint8)
    calm = np.zeros(2)
    scratch = [np.zeros(2, np.uint8), np.zeros(2), np.zeros(2), np.zeros(2, np.uint8),
               np.zeros(2, np.uint8)]
    flat = SL.FlatArrays(X, V, W, Wa, R, B, off, np.zeros(2, np.uint8))
    state = SL.SleepArrays(Xp, Xa, slept, calm, *scratch)
    pi, pj = np.array([0], np.int32), np.array([1], np.int32)
    Xp[0, 1] -= 0.001                         # 1 mm in a step: 0.12 m/s
    _update(flat, (xs, flags), state, pi, pj, 1)
    assert scratch[0][1] == 1 and scratch[3][1] == 1 and flags[0][3] == 1.0
    Xp[0, 1] -= 0.001                         # and again
    _update(flat, (xs, flags), state, pi, pj, 1)
    assert scratch[3][1] == 2 and flags[0][3] == 0.0 and W[0] == 1.0


def test_without_gravity_nothing_sleeps_and_momentum_is_kept():
    # two bodies drifting together slower than sleep_speed, touching, in zero gravity:
    # nothing rests, so nothing sleeps, and the momentum stays what it was
    w = World(gravity=(0.0, 0.0, 0.0))
    w.contact_params = ContactParams(sleep_time=0.1)
    p = BodyParams(mode='rigid', alpha=0.99)
    a = w.add_body(lattice(3, 3, 3, center=(0, 0, 0)), 0.01, p, 'a')
    b = w.add_body(lattice(3, 3, 3, center=(3 * S, 0, 0)), 0.01, p, 'b')
    for body in (a, b):
        body.set_state(v=np.tile([0.004, 0.001, 0.0], (body.n, 1)))
    p0 = a.momentum() + b.momentum()
    for _ in range(120):
        w.step(H)
    assert w.asleep == []
    np.testing.assert_allclose(a.momentum() + b.momentum(), p0, atol=1e-15)
    assert np.linalg.norm(p0) > 0.0


def test_pair_pass_skipped_while_no_body_is_settled_or_asleep():
    # while every body moves (none asleep, none still for sleep_time) nothing can fall
    # asleep or wake: the pass over the pairs is skipped (``near`` is left as it was);
    # once one body has been still for sleep_time it runs and decides
    X = np.array([[0.0, 0.03], [0.0, 0.0], [0.0, 0.0]])
    Xa = X.copy()
    V = np.ones((3, 2))
    W = np.ones(2)
    R = np.full(2, 0.02)
    B = np.arange(2, dtype=np.int32)
    off = np.arange(3)
    xs = List([X[:, k:k + 1] for k in range(2)])
    pi, pj = np.array([0], dtype=np.int32), np.array([1], dtype=np.int32)
    for calm0, decides in ((0.2, False), (0.5, True)):
        flags = _flags([0.0, 0.0])
        near = np.full(2, 7, dtype=np.uint8)
        scratch = [np.zeros(2, np.uint8), np.zeros(2), np.zeros(2), np.zeros(2, np.uint8),
                   near]
        calm = np.array([calm0, 0.0])
        touched = np.zeros(2, dtype=np.uint8)
        flat = SL.FlatArrays(X, V, W, W.copy(), R, B, off, touched)
        state = SL.SleepArrays(X.copy(), Xa, np.zeros(2, np.uint8), calm, *scratch)
        n = _update(flat, (xs, flags), state, pi, pj, 1)
        if decides:
            # body 0 settled; body 1 beside it is unsettled, not below it: 0 sleeps
            assert n == 1 and flags[0][3] == 1.0 and near[0] == 0
        else:
            assert n == 0 and np.all(near == 7) and flags[0][3] == 0.0
            assert calm[0] == pytest.approx(calm0 + H)


def test_error_estimate_of_a_world_asleep_copies_nothing():
    # every body asleep: a step moves nothing, so the live error estimate is 0, given
    # without saving or stepping anything; a real estimate of the same world agrees
    from sm_ros import error_estimate as EE
    w, a, b = _two_boxes()
    assert _until_asleep(w, ['a', 'b'])
    live = EE.LiveEstimate()
    live.before_tick(w, H, 1.0, 0.0, room_s=1.0, period=1 / 60, step_s=1e-3)
    assert live.running is None and live.result['error_m'] == 0.0
    assert live.result['cost_s'] == 0.0
    assert EE.estimate(w, H)['error_m'] == 0.0
    a.wake()                                       # awake: the next one steps for real,
    # two steps a piece (rigid-mode boxes)
    live.before_tick(w, H, 1.0, 1.0, room_s=1.0, period=1 / 60, step_s=1e-3)
    assert live.result['steps'] == EE.PIECES * EE.PIECE_STEPS and live.result['cost_s'] > 0.0
