"""Packs and threads: a pack runs on the threads only with several bodies (chunks of
bodies); one body, however big, steps on the calling thread without a parallel region
(``packed.step_packed_one``), bit for bit as the threaded call would step it."""

import numpy as np

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


def test_world_of_one_packed_body_steps_it_on_one_thread(monkeypatch):
    """A world of one packed body does not run its pack on the threads, however big the
    body (a body's particle pass is not split over threads: ``packed.step_packed``), and
    its World.step is bit for bit ``Body._step``'s."""
    monkeypatch.setattr(world_mod, 'WORLD_PARALLEL_MIN_WORK', 1000)
    world = _world(0.05, True, 2.0)
    assert world.bodies[0].n >= 1000
    assert world._split_bodies(0.01)[3] is False
    ref = _world(0.05, True, 2.0)
    for _ in range(10):
        world.step(0.01)
        ref.bodies[0]._step(0.01, ref._gravity, ref._has_col, ref._ground_row,
                            ref._box_rows, ref._sphere_rows, max(1e-3, 2.0 * 9.81 * 0.01))
    assert (world.bodies[0].x == ref.bodies[0].x).all()
    assert (world.bodies[0].v == ref.bodies[0].v).all()


def test_pack_of_one_body_steps_on_one_thread_when_asked_for_threads(monkeypatch):
    """``Pack.step(parallel=True)`` of one body (a body built for threads, stepped by
    ``Body._step``) steps it on one thread: bit for bit the states of ``parallel=False``,
    both through ``step_packed_one`` (no parallel region), never ``step_packed``."""
    h = 1.0 / 240.0
    a, b = _world(0.05, True, 2.0), _world(0.05, True, 2.0)
    pa, pb = a._split_bodies(h)[0], b._split_bodies(h)[0]
    calls = []
    real_one, real_par = packed.step_packed_one, packed.step_packed

    def spy_one(*args):
        calls.append('one')
        return real_one(*args)

    def spy_par(*args):
        calls.append('threads')
        return real_par(*args)

    monkeypatch.setattr(packed, 'step_packed_one', spy_one)
    monkeypatch.setattr(packed, 'step_packed', spy_par)
    for _ in range(5):
        for w, p, par in ((a, pa, True), (b, pb, False)):
            p.step(h, w._gravity, w._has_col, w._ground_row, w._box_rows, w._sphere_rows,
                   0.05, par)
    assert calls == ['one'] * 10
    assert (a.bodies[0].x == b.bodies[0].x).all() and (a.bodies[0].v == b.bodies[0].v).all()
