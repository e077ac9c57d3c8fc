"""The packed pass of a big one-cluster body split over threads (``packed._pass_threads``)
gives the serial pass's states to round-off, and runs only where it pays."""

import numpy as np
import pytest

import sm_ros.core.packed as packed
import sm_ros.core.world as world_mod
from sm_ros.core import BodyParams, Ground, World


def lattice(n, spacing=0.02):
    g = np.arange(n) * spacing
    return np.stack(np.meshgrid(g, g, g, indexing='ij'), axis=-1).reshape(-1, 3)


def _world(damping, ground, max_speed):
    """One one-cluster linear body of 9,261 particles (3 blocks of the threaded split),
    spinning, falling onto a ground or not, fast enough to hit the speed cap."""
    world = World()
    if ground:
        world.set_colliders(ground=Ground(height=0.0, friction=0.5, restitution=0.3))
    x0 = lattice(21) + (0.0, 0.0, 0.02)
    rng = np.random.default_rng(5)
    c = x0.mean(axis=0)
    v = np.cross((0.0, 0.0, 8.0), x0 - c) + rng.standard_normal(x0.shape)
    world.add_body(x0, masses=0.01 + 0.01 * rng.random(len(x0)), velocities=v,
                   params=BodyParams(mode='linear', clusters=1, damping=damping, alpha=0.4,
                                     beta=0.6, max_speed=max_speed, max_turn=0.0))
    return world


def _step_pack(world, threads, pass_min, steps, h=1.0 / 240.0):
    """``steps`` steps of the world's pack through ``step_packed`` with ``threads`` chunks
    (run on however many threads Numba has: the chunks, not the threads, set the sums)."""
    body = world.bodies[0]
    pack = world._split_bodies(h)[0]
    assert pack is not None and pack.bodies == [body]
    thresh = max(1e-3, 2.0 * 9.81 * h)
    for _ in range(steps):
        scratch = np.zeros((threads, packed.SCRATCH))
        packed.step_packed(pack.P, pack.counts, pack.parts, scratch, threads, pass_min, h,
                           world._gravity, world._has_col, world._ground_row,
                           world._box_rows, world._sphere_rows, thresh)
    return body


@pytest.mark.parametrize('damping,ground,max_speed', [(0.0, False, 0.0), (0.1, False, 2.0),
                                                      (0.05, True, 2.0), (0.0, True, 0.0)])
def test_threaded_pass_gives_the_serial_states(damping, ground, max_speed):
    """3 runs of whole blocks, their sums added in run order: positions, velocities, the
    shape-error sums and the cap counts of the serial pass to round-off, through the
    speed cap, the damping, the ground."""
    serial = _step_pack(_world(damping, ground, max_speed), 1, 0, 20)
    split = _step_pack(_world(damping, ground, max_speed), 3, 1, 20)
    scale = np.abs(serial.x).max()
    assert np.abs(split.x - serial.x).max() <= 1e-12 * scale
    assert np.abs(split.v - serial.v).max() <= 1e-9 * np.abs(serial.v).max()
    assert split._err.sum() == pytest.approx(serial._err.sum(), rel=1e-9)
    assert split._part.shape == serial._part.shape == (1, 1, 12)
    np.testing.assert_allclose(split._part, serial._part, rtol=1e-9, atol=1e-12)
    assert (split._limit_counts == serial._limit_counts).all()
    if max_speed:
        assert serial._limit_counts[0] > 0                      # the cap was hit


def test_small_body_never_takes_the_threaded_pass():
    """Below ``pass_min`` particles ``step_packed`` on several threads steps the body on
    one (bit for bit the serial states), and a world of one body below the thresholds
    steps it on one thread."""
    serial = _step_pack(_world(0.05, True, 2.0), 1, 0, 10)
    threads = _step_pack(_world(0.05, True, 2.0), 4, 10 ** 6, 10)
    assert (threads.x == serial.x).all() and (threads.v == serial.v).all()
    world = _world(0.05, False, 0.0)
    assert world._split_bodies(0.01)[3] is False
    assert world.bodies[0].n < packed.PASS_PARALLEL_MIN


def test_world_threads_one_big_body_only_from_the_threshold(monkeypatch):
    """A world of one packed body runs its pack on the threads only when the body has at
    least ``PASS_PARALLEL_MIN`` particles (and the world ``WORLD_PARALLEL_MIN_WORK``) and
    Numba has more than one thread; World.step then gives the serial states to round-off."""
    import numba
    monkeypatch.setattr(world_mod, 'WORLD_PARALLEL_MIN_WORK', 1000)
    monkeypatch.setattr(packed, 'PASS_PARALLEL_MIN', 10 ** 6)
    assert _world(0.0, False, 0.0)._split_bodies(0.01)[3] is False
    monkeypatch.setattr(packed, 'PASS_PARALLEL_MIN', 1000)
    world = _world(0.05, True, 2.0)
    assert world._split_bodies(0.01)[3] is (numba.get_num_threads() > 1)
    assert world.bodies[0].n >= packed.PASS_PARALLEL_MIN
    ref = _world(0.05, True, 2.0)
    ref.compiled_step = True
    for _ in range(10):
        world.step(0.01)
    for _ in range(10):
        ref._split_bodies(0.01)
        _step_pack(ref, 1, 0, 1, h=0.01)
    np.testing.assert_allclose(world.bodies[0].x, ref.bodies[0].x, rtol=0, atol=1e-12)


def test_pack_of_one_body_below_the_threshold_steps_serially_when_asked_for_threads(
        monkeypatch):
    """``Pack.step(parallel=True)`` of one body below ``PASS_PARALLEL_MIN`` (a body built
    for threads, stepped by ``Body._step``) takes the serial entry: bit for bit the states
    of ``parallel=False``, and ``step_packed`` is called with one thread only."""
    h = 1.0 / 240.0
    a, b = _world(0.05, True, 2.0), _world(0.05, True, 2.0)
    pa, pb = a._split_bodies(h)[0], b._split_bodies(h)[0]
    calls = []
    real = packed.step_packed

    def spy(*args):
        calls.append(args[4])
        return real(*args)

    monkeypatch.setattr(packed, 'step_packed', spy)
    for _ in range(5):
        for w, p, par in ((a, pa, True), (b, pb, False)):
            p.step(h, w._gravity, w._has_col, w._ground_row, w._box_rows, w._sphere_rows,
                   0.05, par)
    assert calls == [1] * 10
    assert (a.bodies[0].x == b.bodies[0].x).all() and (a.bodies[0].v == b.bodies[0].v).all()
