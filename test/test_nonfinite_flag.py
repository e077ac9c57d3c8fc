"""The integration pass flags a non-finite state itself (``World.state_flagged``).

``kernels.integrate.advance`` returns |g - p|^2 + 0 (v0 + v1 + v2): a non-finite start
position or new velocity makes a body's shape-error sums (``Body._err``) non-finite, so the
node's check after a step reads those few numbers instead of every x and v
(``NonFiniteCheck.bad_bodies(bodies, flagged=True)``). Here a value is poisoned in every
kind of body the solver steps (one cluster, set layout, quadratic, plastic, kinematic
particles, a torque: the per-body step; serial and threaded kernels; the compiled world
step one-threaded and threaded), and the flags must find exactly the bodies a full scan
finds.
"""

import math

import numpy as np
import pytest

from sm_ros.core import BodyParams, Box, Ground, Sphere, World, tuning
from sm_ros.core.contact import BodyContact, ContactParams
from sm_ros import nonfinite
from sm_ros.nonfinite import NonFiniteCheck
from test_core_fused import lattice

BAD = (math.nan, math.inf, -math.inf)


def _world(mode, clusters, plastic, colliders=True, seed=3):
    """Two damped bodies (one grabbed, one under a wrench), over colliders."""
    rng = np.random.default_rng(seed)
    world = World()
    if colliders:
        world.set_colliders(ground=Ground(height=0.0, friction=0.4, restitution=0.2),
                            boxes=[Box(lo=(0.05, -0.1, 0.0), hi=(0.2, 0.1, 0.03))],
                            spheres=[Sphere(center=(-0.05, 0.05, 0.02), radius=0.04)])
    kw = dict(mode=mode, clusters=clusters, alpha=0.3, beta=0.4, damping=0.3)
    if plastic:
        kw.update(plastic_yield=0.01, plastic_creep=20.0, plastic_max=0.3)
    bodies = []
    for b in range(2):
        x0 = lattice(6) + (0.15 * b - 0.05, 0.0, 0.02 + 0.05 * b)
        x0 = x0 + 0.002 * rng.standard_normal(x0.shape)
        v0 = rng.standard_normal(x0.shape)
        body = world.add_body(x0, masses=0.01 + 0.02 * rng.random(len(x0)),
                              params=BodyParams(**kw), velocities=v0, name=f'b{b}')
        bodies.append(body)
    bodies[0].set_kinematic(np.array([0, 5]), bodies[0].x[[0, 5]] + (0.0, 0.0, 0.01))
    bodies[1].set_wrench((0.02, 0.0, 0.1), (0.0, 0.001, 0.002))
    return world, bodies


@pytest.mark.parametrize('mode,clusters,plastic,parallel', [
    ('rigid', 1, False, False), ('linear', 1, True, True), ('quadratic', 1, False, False),
    ('linear', 8, False, True), ('quadratic', 8, True, False), ('linear', 8, False, False)])
@pytest.mark.parametrize('where', ['x', 'v'])
def test_the_pass_flags_a_poisoned_value(monkeypatch, mode, clusters, plastic, parallel,
                                         where):
    monkeypatch.setattr(tuning, 'PARALLEL_MIN_WORK', 0 if parallel else 1 << 40)
    rng = np.random.default_rng(7)
    for bad in BAD:
        world, bodies = _world(mode, clusters, plastic)
        world.contact_params = ContactParams(enabled=False)
        check = NonFiniteCheck()
        for _ in range(2):
            world.step(1.0 / 200.0)
        assert world.state_flagged
        assert check.bad_bodies(bodies, flagged=True) == []
        k = int(rng.integers(2))
        a = bodies[k]._x if where == 'x' else bodies[k]._v
        a[int(rng.integers(len(a))), int(rng.integers(3))] = bad
        world.step(1.0 / 200.0)
        assert world.state_flagged and check.full_scans == 0
        assert not np.isfinite(bodies[k]._err).all()
        assert np.isfinite(bodies[1 - k]._err).all()
        assert check.bad_bodies(bodies, flagged=True) == [bodies[k]]
        assert check.full_scans == 0
        assert check.bad_bodies(bodies) == [bodies[k]] and check.full_scans == 1


@pytest.mark.parametrize('threaded,in_python', [(False, True), (True, False)])
def test_the_compiled_world_step_flags_it(monkeypatch, threaded, in_python):
    """Many small bodies in the compiled world steps (the packed one-cluster bodies and the
    set-layout records): the poisoned ones are found from their flags, whichever thread
    stepped them, the flags read in Python or in one compiled call."""
    monkeypatch.setattr(nonfinite, 'PYTHON_FLAGS_MAX', 10 ** 6 if in_python else 0)
    # the records on the helper threads
    monkeypatch.setattr(tuning, 'RECORDS_PARALLEL_MIN_WORK', 0 if threaded else 1 << 40)
    rng = np.random.default_rng(11)
    world = World()
    world.contact_params = ContactParams(enabled=False)
    for b in range(12):
        world.add_body(lattice(4) + (0.3 * b, 0.0, 0.5), masses=0.01,
                       params=BodyParams(mode='linear', damping=0.05,
                                         clusters=2 if b % 3 == 0 else 1), name=f'b{b}')
    bodies = world.bodies
    check = NonFiniteCheck()
    world.step(1.0 / 240.0)
    pack, records, slow, par = world._split_bodies(1.0 / 240.0)
    # one-cluster bodies in the packed step (core/packed.py), 8-cluster ones as records
    assert len(pack) == 8 and len(records) == 4 and not slow
    for trial in range(6):
        picks = sorted(rng.choice(12, size=int(rng.integers(1, 4)), replace=False))
        for k in picks:
            a = bodies[k]._x if rng.random() < 0.5 else bodies[k]._v
            a[int(rng.integers(len(a))), int(rng.integers(3))] = BAD[trial % 3]
        world.step(1.0 / 240.0)
        assert world.state_flagged
        assert check.bad_bodies(bodies, flagged=True) == [bodies[k] for k in picks]
        for k in picks:
            bodies[k].reset()
        world.step(1.0 / 240.0)
        assert check.bad_bodies(bodies, flagged=True) == []
    assert check.full_scans == 0
    assert isinstance(check._errs, list) == in_python


def test_flags_do_not_cover_what_contact_writes():
    """After a step whose body-body contact moved particles the flags do not say
    everything: ``state_flagged`` is False and the check reads x and v."""
    world = World()
    for b in range(2):
        world.add_body(lattice(4) + (0.05 * b, 0.0, 0.5), masses=0.01,
                       params=BodyParams(mode='linear'), name=f'b{b}',
                       contact=BodyContact())
    world.step(1.0 / 240.0)
    assert world.contact is not None and not world.state_flagged
    world.contact_params = ContactParams(enabled=False)
    world.step(1.0 / 240.0)
    assert world.state_flagged
    assert not World().state_flagged                 # never stepped


def test_an_overflow_is_not_reset():
    """Flags also come from an overflow of finite values (|v| near 1e308): a flagged body
    whose x and v are finite is not reported."""
    world = World(gravity=(0.0, 0.0, 0.0))
    world.contact_params = ContactParams(enabled=False)
    body = world.add_body(lattice(3), masses=0.01, params=BodyParams(mode='linear'))
    world.step(0.01)
    body._v[:] = 1.5e308 / 3 * 2.5                  # finite; v0 + v1 + v2 overflows
    body._err[:] = math.inf                          # what the pass would leave
    check = NonFiniteCheck()
    assert body.is_finite()
    assert check.bad_bodies([body], flagged=True) == []
