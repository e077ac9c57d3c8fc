"""Packs and threads: a pack steps on the calling thread (``packed.step_packed``), bit for
bit as ``Body._step`` steps its body, also for a body built for threads."""

import numpy as np

from sm_ros.core import BodyParams, Ground, World, tuning


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
    world.add_body(x0, masses=0.015, velocities=v,
                   params=BodyParams(mode='linear', clusters=1, damping=damping, alpha=0.4,
                                     beta=0.6, max_speed=max_speed, max_turn=0.0))
    return world


def test_world_of_one_packed_body_steps_as_the_body_does(monkeypatch):
    """A packed body built for threads (``Body._parallel``: its sums per chunk) steps in
    the pack, and its World.step is bit for bit ``Body._step``'s."""
    monkeypatch.setattr(tuning, 'PARALLEL_MIN_WORK', 1000)
    world = _world(0.05, True, 2.0)
    assert world.bodies[0].n >= 1000
    pack, records, slow, helpers = world._split_bodies(0.01)
    assert len(pack) == 1 and not len(records) and not slow and helpers is False
    ref = _world(0.05, True, 2.0)
    ref._collider_radii(0.01)              # what the world gives the body it steps
    for _ in range(10):
        world.step(0.01)
        ref.bodies[0]._step(0.01, ref._gravity, ref._has_col, ref._ground_row,
                            ref._box_rows, ref._sphere_rows, max(1e-3, 2.0 * 9.81 * 0.01))
    assert (world.bodies[0].x == ref.bodies[0].x).all()
    assert (world.bodies[0].v == ref.bodies[0].v).all()
