"""A body and its NumPy reference twin on a ground, started alike: the setting of the
tests that compare the compiled step with ``sm_ros.core.reference``."""

from sm_ros.core import World
from sm_ros.core.reference import ReferenceBody


def on_ground(x0, masses, params, v0, ground):
    """(world under gravity with ``ground``, its body of rest positions ``x0``, the
    reference twin), both starting at ``x0`` with velocities ``v0``."""
    world = World(gravity=(0.0, 0.0, -9.81))
    world.set_colliders(ground=ground)
    body = world.add_body(x0, masses, params)
    ref = ReferenceBody(x0, masses, params)
    body.set_state(v=v0)
    ref.v = v0.copy()
    return world, body, ref
