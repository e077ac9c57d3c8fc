"""The throwaway worlds whose steps compile the solver's kernels (``sm_ros.warmup``).

Each stage builds a small world that reaches a group of kernels and steps it; a cold
warm-up runs ``MAIN_STAGES`` in its own process and the others in two helper processes.
"""

import time

import numpy as np


def _stiff_world():
    """Two rigid cubes on the ground beside the moving colliders."""
    from sm_ros.core import BodyParams, World
    world = World(gravity=(0.0, 0.0, -9.81))
    _colliders(world, 0.3)
    for i in range(2):
        world.add_body(_cube() + (0.0, 0.0, 0.05 + 0.11 * i), 0.01, BodyParams('rigid', 0.9))
    return world


def _stiff_pass() -> None:
    """The stiff bodies' contact pass alone (``World._stiff_pass``), without the bodies'
    own step, which the other warm-up processes compile meanwhile."""
    world = _stiff_world()
    world._ensure_flat()
    world._stiff_pass(1.0 / 120.0, 1e-3)


def _cube(n: int = 3, half: float = 0.05) -> np.ndarray:
    g = np.linspace(-half, half, n)
    return np.stack(np.meshgrid(g, g, g, indexing='ij'), axis=-1).reshape(-1, 3)


def _colliders(world, finger_x: float) -> None:
    """The ground, a box, a sphere and a kinematic capsule finger that moves."""
    from sm_ros.core import Box, Capsule, Ground, Sphere
    world.set_colliders(ground=Ground(height=0.0, friction=0.5, restitution=0.0),
                        boxes=[Box(lo=(1.0, 1.0, 0.0), hi=(2.0, 2.0, 1.0))],
                        spheres=[Sphere(center=(-1.0, -1.0, 0.0), radius=0.5)],
                        capsules=[Capsule(center=(finger_x, 0.0, 0.0), radius=0.05,
                                          length=0.2, name='warm_finger', kinematic=True)])
    world.move_collider('warm_finger', (finger_x, 0.0, 0.05), (0.0, 0.0, 0.0, 1.0), 1.0 / 60.0)


_PLASTIC = dict(plastic_yield=0.01, plastic_creep=1.0, plastic_max=0.5)


def _modes() -> None:
    """Every deformation mode, clusters and plasticity, a wrench and a grabbed particle
    under the colliders (body-body contact off), and the bodies' read-outs."""
    from sm_ros.core import BodyParams, World
    from sm_ros.core.contact import ContactParams
    cube = _cube()
    world = World(gravity=(0.0, 0.0, -9.81))
    world.contact_params = ContactParams(enabled=False)
    _colliders(world, 0.3)
    configs = [BodyParams(mode='rigid'), BodyParams(mode='linear'),
               BodyParams(mode='quadratic', clusters=2, plastic_yield=0.01,
                          plastic_creep=1.0, plastic_max=0.5),
               BodyParams(mode='linear', clusters=2, plastic_creep=1.0, plastic_max=0.5)]
    bodies = [world.add_body(cube + (0.3 * i, 0.0, 0.1), masses=0.01, params=p,
                             name=f'warm{i}') for i, p in enumerate(configs)]
    bodies[0].set_wrench((0.0, 0.0, 1.0), (0.0, 0.0, 0.1))
    bodies[1].set_kinematic(np.array([0]), cube[:1] + (0.3, 0.0, 0.12))
    for _ in range(2):
        world.step(1.0 / 120.0)
    for b in bodies:
        b.com(), b.rotation(), b.shape_error_rms(), b.momentum(), b.is_finite()


def _damped() -> None:
    """Damping inside the particle pass, of bodies of one and of several clusters."""
    from sm_ros.core import BodyParams, Ground, World
    from sm_ros.core.contact import ContactParams
    big = _cube(11)
    damped = World(gravity=(0.0, 0.0, -9.81))
    damped.contact_params = ContactParams(enabled=False)
    damped.set_colliders(ground=Ground(height=0.0))
    for i, (mode, k) in enumerate((('linear', 1), ('linear', 2), ('quadratic', 2))):
        damped.add_body(big + (0.3 * i, 0.0, 0.1), masses=0.01,
                        params=BodyParams(mode=mode, clusters=k, damping=0.05))
    damped.bodies[0].set_kinematic(np.array([0]), big[:1] + (0.0, 0.0, 0.12))
    for _ in range(2):
        damped.step(1.0 / 120.0)


def warm_packed() -> None:
    """Step the one-cluster rigid and linear bodies (the packed step, ``core/packed.py``)
    under the static and moving colliders, several at once with contact under gravity
    (``solve_bodies``)."""
    from sm_ros.core import BodyParams, World
    cube = _cube()
    world = World(gravity=(0.0, 0.0, -9.81))
    _colliders(world, 0.6)
    for i, p in enumerate((BodyParams(mode='rigid', alpha=0.9), BodyParams(mode='linear'),
                           BodyParams(damping=0.05))):
        world.add_body(cube + (0.0, 0.0, 0.06 + 0.099 * i), masses=0.01, params=p)
    for _ in range(2):
        world.step(1.0 / 120.0)


def _packed_alone() -> None:
    """Sleeping bodies (``core/sleep.py``), a packed body alone (the collider pass on its
    own buffers) and one spinning past its turn limit (``Pack._limit_turn``)."""
    from sm_ros.core import BodyParams, Capsule, Ground, World
    cube = _cube()
    pile = World(gravity=(0.0, 0.0, -9.81))
    pile.set_colliders(ground=Ground(height=0.0, friction=0.5))
    for i in range(2):
        pile.add_body(cube + (0.0, 0.0, 0.06 + 0.099 * i), masses=0.01,
                      params=BodyParams(mode='rigid', alpha=0.9))
    pile.step(1.0 / 120.0)
    sl = pile._sleep
    sl.all_asleep()
    sl.slept[0] = 1                            # as if body 0 was woken from outside
    sl.sync()
    solo = World(gravity=(0.0, 0.0, -9.81))
    solo.set_colliders(capsules=[Capsule(center=(0.0, 0.0, 0.0), radius=0.05, length=0.1)])
    solo.add_body(cube + (0.0, 0.0, 0.1), masses=0.01)
    solo.step(1.0 / 120.0)
    spin = World(gravity=(0.0, 0.0, 0.0))
    spin.add_body(cube, masses=0.01, velocities=np.cross((0.0, 0.0, 300.0), cube))
    for _ in range(2):
        spin.step(1.0 / 120.0)


def _free_contact() -> None:
    """Body-body contact without gravity (``solve_pairs``)."""
    from sm_ros.core import World
    cube = _cube()
    free = World(gravity=(0.0, 0.0, 0.0))
    for i in range(2):
        free.add_body(cube + (0.099 * i, 0.0, 0.0), masses=0.01,
                      velocities=np.tile(((1.0 - 2.0 * i) * 0.1, 0.0, 0.0), (len(cube), 1)))
    free.step(1.0 / 120.0)


def _points() -> None:
    """Bodies of one particle in every mode (the compiled world step's records)."""
    from sm_ros.core import BodyParams, Ground, World
    one = World(gravity=(0.0, 0.0, -9.81))
    one.set_colliders(ground=Ground(height=0.0))
    for i, p in enumerate((BodyParams(mode='rigid', damping=0.05, **_PLASTIC),
                           BodyParams(mode='linear', clusters=2, **_PLASTIC),
                           BodyParams(mode='quadratic', **_PLASTIC),
                           BodyParams(mode='quadratic', clusters=2, **_PLASTIC),
                           BodyParams(mode='quadratic', clusters=2, damping=0.05))):
        one.add_body(np.array([[0.5 * i, 0.0, 0.1]]), masses=0.01, params=p)
    one.step(1.0 / 120.0)


def _default_scene() -> None:
    """The scene ``sim_node`` starts with (one soft block on the ground)."""
    warm_scene('default')


#: What a cold warm-up compiles, split between this process (``MAIN_STAGES``: the packed
#: step's bodies), a second one (``EXTRA_STAGES``: the set layout's and the compiled
#: records') and a third (:func:`warm_stiff`: contact) so that each takes about as long.
MAIN_STAGES = (_default_scene, warm_packed, _modes, _packed_alone)
EXTRA_STAGES = (_damped, _points)


def warm_extra() -> float:
    """A helper process of a cold warm-up (``warmup.warm_up``): ``EXTRA_STAGES``.
    Return the seconds spent."""
    t0 = time.perf_counter()
    for stage in EXTRA_STAGES:
        run_soft(stage)
    return time.perf_counter() - t0


def warm_stiff() -> None:
    """The third process of a cold warm-up: the stiff bodies' contact pass, then contact
    without gravity."""
    _stiff_pass()
    run_soft(_free_contact)


def run_soft(stage) -> None:
    """Run a stage with no body stiff: the stiff bodies' pass compiles on its own."""
    from unittest import mock
    from sm_ros.core import tuning
    with mock.patch.object(tuning, 'STIFF_SHARE', float('inf')):
        stage()


def warm_scene(name: str) -> float:
    """Build a scene with the node's default parameters and step it (its own variants)."""
    from sm_ros.scene import build_world, load_scene
    t0 = time.perf_counter()
    world, _ = build_world(load_scene(name))
    world.step(1.0 / 120.0)
    return time.perf_counter() - t0
