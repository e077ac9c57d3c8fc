"""
The simulation without ROS: a world, its scene and everything that changes it.

:class:`Simulation` owns the ``sm_ros.core.World`` built from a scene, the parameter values
(checked with the table in ``sm_ros.params``), the changes waiting for the next tick, the
forces and their timeouts, the grippers, the recovery of bodies that went non-finite and the
tick statistics. ``sm_ros.node`` is a thin ROS adapter around it; tests and scripts drive it
directly::

    sim = Simulation({'scene': 'rope', 'alpha': 0.9})
    sim.set_params({'gravity': [0.0, 0.0, -1.0]})    # checked now, applied at the next tick
    sim.set_force('rope', force=[1, 0, 0], torque=[0, 0, 0])
    sim.tick()                                        # substeps x world.step(dt)

Extension points (keep them small and documented when you add one):

* ``add_tick_listener(fn)``: ``fn(sim)`` runs after every tick's steps (the node publishes
  there; its time counts as ``publish_ms``). Recorders and other consumers hook in here.
* ``on_change(names, fn)``: ``fn(changes)`` runs when ``apply_pending`` applies a change to
  one of ``names`` (the node retimes its timers there). A new parameter's code goes here.
* ``status_values()``: the figures of the ``/diagnostics`` solver status.

Timing: ``clock`` (default ``time.monotonic``) dates forces for ``force_timeout``; tests
pass their own.
"""

from dataclasses import dataclass
import logging
import math
import time
from typing import Any, Callable, Dict, Iterable, List, Mapping, Optional, Tuple

import numpy as np

from sm_ros import params as table
from sm_ros.inputs import checked_points, checked_wrench, Forces, Grippers, InputError
from sm_ros.params import MAX_COORDINATE
from sm_ros.error_estimate import LiveEstimate
from sm_ros.stats import MomentumDrift, TickStats, solver_figures

#: Seconds between two log lines about bodies that went non-finite.
NONFINITE_LOG_PERIOD = 1.0
#: Parameters whose change abandons the live error estimate in progress (it estimates the
#: error of the configuration it started from; a new world or dt drops it too).
ESTIMATE_KEYS = frozenset(table.SCENE_DEFAULT_KEYS + ('substeps', 'scene'))


class ConfigError(Exception):
    """A configuration the simulation cannot run with (bad scene or parameter value)."""


class ParameterError(ValueError):
    """A parameter change refused by :meth:`Simulation.set_params`; nothing changed."""


def _scene_api():
    from sm_ros import scene
    return scene


@dataclass
class PreparedScene:
    """A scene built and ready to swap in, with the values it was built with."""

    world: Any
    metas: List[Any]
    spec: Any
    values: Dict[str, Any]


def scene_values(values: Mapping[str, Any]) -> Dict[str, Any]:
    """Return the values a scene is built with (body parameters, gravity, ground)."""
    return {k: values[k] for k in table.SCENE_DEFAULT_KEYS}


def build_scene(name: str, values: Mapping[str, Any], log=None) -> PreparedScene:
    """
    Load and build a scene; raise ConfigError with the loader's message.

    The scene is built twice: the first world takes one step and is dropped, so that every
    kernel specialisation the real world needs is compiled or loaded from the cache before
    the first tick (a copy would not do: its arrays' types differ).
    """
    scene = _scene_api()
    defaults = scene_values(values)
    try:
        spec = scene.load_scene(name)
        throwaway, _ = scene.build_world(spec, defaults)
        world, metas = scene.build_world(spec, defaults)
    except ValueError as exc:
        raise ConfigError(f'scene: {exc}') from None
    try:
        throwaway.step(float(values['dt']))
    except Exception as exc:  # noqa: B902 - warming must never stop a good scene
        (log or logging.getLogger(__name__)).warning(f'scene warm-up step failed: {exc}')
    return PreparedScene(world, list(metas), spec, defaults)


def body_params_refusal(values: Mapping[str, Any]) -> Optional[str]:
    """Return why the core refuses the body parameters in ``values``, or None."""
    try:
        _scene_api().params_from(scene_values(values), None)
    except ValueError as exc:
        return str(exc)
    return None


def empty_world_like(world):
    """Return a World with ``world``'s gravity and colliders and no bodies."""
    from sm_ros.core import World
    new = World(gravity=tuple(float(g) for g in world.gravity))
    new.set_colliders(ground=world.ground, boxes=world.boxes, spheres=world.spheres,
                      capsules=world.capsules)
    return new


def cloud_body(world, points: np.ndarray, values: Mapping[str, Any]):
    """
    Make the ``cloud_in`` body of ``points``; return (name, BodySpec, BodyMeta, its world).

    In ``add`` mode the body joins ``world`` (named ``cloud_in_2``, ... if taken); in
    ``replace`` mode it is the only body of a new world with the same colliders. Raises
    InputError for points that make no body.
    """
    scene = _scene_api()
    mode = values['cloud_in_mode']
    existing = {b.name for b in world.bodies}
    name = 'cloud_in'
    if mode == 'add':
        k = 1
        while name in existing:
            k += 1
            name = f'cloud_in_{k}'
    defaults = scene_values(values)
    try:
        spec = scene.cloud_body_spec(points, int(values['max_points']), name)
        # a throwaway copy takes one step first, so the first tick pays no compilation
        scratch = empty_world_like(world)
        scene.add_spec_body(scratch, spec, defaults, 'cloud_in')
        scratch.step(float(values['dt']))
        target = empty_world_like(world) if mode == 'replace' else world
        meta = scene.add_spec_body(target, spec, defaults, 'cloud_in')
    except ValueError as exc:
        raise InputError(str(exc)) from None
    return name, spec, meta, target


def apply_body_params(world, metas, changes: Mapping[str, Any], log) -> None:
    """Set changed body parameters on every body of ``world`` that does not override them
    (``metas``: the bodies' scene metadata); log the ones a body refuses."""
    for body, meta in zip(world.bodies, metas):
        fields = {table.BODY_FIELDS[k]: v for k, v in changes.items()
                  if k not in meta.overrides}
        if not fields:
            continue
        try:
            body.set_params(**fields)
        except ValueError as exc:
            log.error(f"body '{body.name}': parameters not applied: {exc}")


def carry_state(old_world, new_world) -> None:
    """Give every body of ``new_world`` the state (x, v) of the body of ``old_world`` with
    its name, where that one has the same rest shape and masses."""
    old = {b.name: b for b in old_world.bodies}
    for b in new_world.bodies:
        o = old.get(b.name)
        if o is None or o.n != b.n:
            continue
        if np.array_equal(o.x_init, b.x_init) and np.array_equal(o.m, b.m):
            b.set_state(x=o.x, v=o.v)


class Simulation:
    """
    A world, its scene, pending parameter changes, forces, grippers and tick statistics.

    ``values`` are node parameters by name (``sm_ros.params``); missing ones take their
    defaults. Raises ConfigError for a value or scene it cannot run with. Attributes read
    by the node and the tests: ``world``, ``metas`` (per-body scene metadata), ``spec``
    (the scene), ``params`` (applied values), ``pending`` (accepted, not yet applied),
    ``forces`` (body name -> clock time of its last force), ``grippers``, ``stats``.
    """

    def __init__(self, values: Optional[Mapping[str, Any]] = None, *,
                 clock: Callable[[], float] = time.monotonic, log=None):
        """Check the values, load and build the scene."""
        self.clock = clock
        self.log = log or logging.getLogger(__name__)
        self.params: Dict[str, Any] = table.defaults()
        self.params.update(values or {})
        for p in table.NODE_PARAMS:
            reason = p.check(self.params[p.name])
            if reason:
                raise ConfigError(f'parameter {reason}')
        reason = body_params_refusal(self.params)
        if reason:
            raise ConfigError(f'parameter {reason}')
        try:
            scene = build_scene(self.params['scene'], self.params, self.log)
        except ImportError as exc:
            raise ConfigError(f'the solver core cannot be imported: {exc}') from None
        self.world, self.metas, self.spec = scene.world, scene.metas, scene.spec
        self.pending: Dict[str, Any] = {}
        self.pending_scene: Optional[PreparedScene] = None
        self._prepared: Optional[PreparedScene] = None
        self.forces = Forces()
        self.grippers = Grippers()
        #: {collider name: (force, torque)} the bodies exerted on each named collider,
        #: averaged over the last tick (world frame, torque about the collider's centre)
        self.collider_wrenches: Dict[str, Tuple[np.ndarray, np.ndarray]] = {}
        self.sim_ns = 0
        self.cloud_count = 0
        self.momentum = MomentumDrift(lambda: self.world)
        self._estimates = LiveEstimate()
        self._own_s = 0.0           # the last tick's time without the estimate's pieces
        self._tick_at = clock()     # when the last tick started (the estimate's clock)
        self.stats = TickStats(clock())
        self._nonfinite_logged = -math.inf
        self._nonfinite = None      # sm_ros.nonfinite.NonFiniteCheck (Numba), made when used
        self._tick_listeners: List[Callable[['Simulation'], None]] = []
        self._change_handlers: List[Tuple[frozenset, Callable[[Dict[str, Any]], None]]] = []
        # an estimate in progress describes the old configuration: drop it
        self.on_change(ESTIMATE_KEYS, lambda changes: self._estimates.drop())

    # ------------------------------------------------------------------ read-outs

    @property
    def num_points(self) -> int:
        """Return the total number of particles of all bodies."""
        return int(sum(b.n for b in self.world.bodies))

    @property
    def sim_time(self) -> float:
        """Return the simulation time in seconds (monotonic across resets and scenes)."""
        return self.sim_ns * 1e-9

    @property
    def error_estimate(self) -> Optional[Dict[str, Any]]:
        """Return the last finished live error estimate (``sm_ros.error_estimate``) or None."""
        return self._estimates.result

    @property
    def _estimator(self):
        """The live error estimate in progress, or None."""
        return self._estimates.running

    def status_values(self) -> Dict[str, Any]:
        """Return the figures of the solver status (``sm_ros.diagnostics.solver_status``)."""
        return solver_figures(self.world, self.params, self.momentum, self.error_estimate,
                              self._estimates.age(self.clock()))

    # ------------------------------------------------------------------ hooks

    def add_tick_listener(self, fn: Callable[['Simulation'], None]) -> None:
        """Call ``fn(sim)`` after every tick's steps (timed as publishing)."""
        self._tick_listeners.append(fn)

    def on_change(self, names: Iterable[str], fn: Callable[[Dict[str, Any]], None]) -> None:
        """Call ``fn(changes)`` whenever ``apply_pending`` applies one of ``names``."""
        self._change_handlers.append((frozenset(names), fn))

    # ------------------------------------------------------------------ parameters

    def latest(self) -> Dict[str, Any]:
        """Return the newest accepted values: applied ones updated by the pending ones."""
        return {**self.params, **self.pending}

    def check(self, changes: Mapping[str, Any]) -> Optional[str]:
        """
        Return why ``changes`` are refused, or None; nothing is applied.

        A new scene is loaded and built here (so a bad one is refused at once); ``queue``
        keeps it for the next tick.
        """
        values = self.latest()
        for name, value in changes.items():
            reason = table.BY_NAME[name].check(value)
            if reason:
                return reason
            values[name] = value
        if any(k in table.BODY_FIELDS for k in changes):
            reason = body_params_refusal(values)
            if reason:
                return reason
        self._prepared = None
        if 'scene' in changes:
            try:
                self._prepared = build_scene(changes['scene'], values, self.log)
            except ConfigError as exc:
                return str(exc)
        return None

    def queue(self, changes: Mapping[str, Any]) -> None:
        """Queue changes that ``check`` accepted; the next tick applies them."""
        for name, value in changes.items():
            if name == 'scene':
                self.pending_scene, self._prepared = self._prepared, None
            self.pending[name] = value

    def set_params(self, changes: Mapping[str, Any]) -> None:
        """Check and queue ``changes`` (raise ParameterError if refused; nothing changes)."""
        reason = self.check(changes)
        if reason:
            raise ParameterError(reason)
        self.queue(changes)

    def apply_pending(self) -> Dict[str, Any]:
        """Apply the queued changes (between two steps); return them."""
        if not self.pending and self.pending_scene is None:
            return {}
        pending, self.pending = self.pending, {}
        scene, self.pending_scene = self.pending_scene, None
        self.params.update(pending)
        if scene is not None:
            self.install_world(scene.world, scene.metas, scene.spec)
            # the scene was built with the values of its check: later changes still apply
            body_changes = {k: self.params[k] for k in scene.values
                            if k in table.BODY_FIELDS and self.params[k] != scene.values[k]}
        else:
            body_changes = {k: v for k, v in pending.items() if k in table.BODY_FIELDS}
        if body_changes:
            apply_body_params(self.world, self.metas, body_changes, self.log)
        if 'gravity' in pending:
            self.world.gravity = np.asarray(pending['gravity'], dtype=np.float64)
        if any(k in pending for k in table.GROUND_KEYS):
            self.world.set_colliders(
                ground=_scene_api().ground_from(self.spec.colliders.get('ground'),
                                                scene_values(self.params)),
                boxes=self.world.boxes, spheres=self.world.spheres,
                capsules=self.world.capsules)
        if any(k in pending for k in table.CONTACT_KEYS):
            self.world.contact_params = _scene_api().contact_from(
                self.spec.contact, scene_values(self.params))
        for names, fn in self._change_handlers:
            changed = {k: v for k, v in pending.items() if k in names}
            if changed:
                fn(changed)
        return pending

    def install_world(self, world, metas, spec=None, keep_state: bool = True) -> None:
        """Swap in a new world; bodies unchanged by name and rest shape keep their state."""
        if keep_state:
            carry_state(self.world, world)
        self.world = world
        self.metas = list(metas)
        if spec is not None:
            self.spec = spec
        self.forces.clear()
        self.grippers.clear()
        self.momentum.forget()

    # ------------------------------------------------------------------ inputs

    def body(self, name: str):
        """Return the body called ``name``; raise InputError naming the known ones."""
        try:
            return self.world.body(name)
        except KeyError:
            known = ', '.join(b.name for b in self.world.bodies)
            raise InputError(f"unknown body '{name}' (bodies: {known})") from None

    def set_force(self, body: str, force, torque) -> None:
        """Hold a wrench on one body ('' = every body); a zero wrench clears it."""
        f, t = checked_wrench(force, torque)
        targets = [self.body(body)] if body else list(self.world.bodies)
        self.forces.hold(targets, f, t, self.clock())

    def expire_forces(self) -> None:
        """Clear the forces not renewed within ``force_timeout`` seconds (0: never)."""
        self.forces.expire(self.world, self.params['force_timeout'], self.clock)

    def grab(self, gripper: str, position, quaternion) -> None:
        """Attach particles to a gripper (first pose) or move them with it."""
        self.grippers.grab(self.world, gripper, position, quaternion,
                           self.params['grab_radius'])

    def release(self, gripper: str) -> None:
        """Release one gripper by name, or every gripper for ''."""
        self.grippers.release(self.world, gripper)

    def move_collider(self, name: str, position, quaternion) -> None:
        """Move kinematic collider ``name`` to a pose by the end of the next tick.

        It gets there over the tick's ``substeps`` steps (position linearly, orientation by
        slerp) at the linear and angular velocity that implies, which friction and
        restitution see. Raises InputError (nothing changes) for an unknown or static
        collider, NaN/Inf, a position beyond the coordinate range, or a zero or non-unit
        quaternion.
        """
        pos = np.asarray(position, dtype=np.float64).reshape(-1)
        if pos.shape == (3,) and np.isfinite(pos).all() and np.abs(pos).max() > MAX_COORDINATE:
            raise InputError(f"position of collider '{name}' beyond +-{MAX_COORDINATE:g} m")
        duration = float(self.params['dt']) * int(self.params['substeps'])
        try:
            self.world.move_collider(name, position, quaternion, duration)
        except ValueError as exc:
            raise InputError(str(exc)) from None

    def add_cloud(self, points) -> Tuple[str, int]:
        """Add a body made from points (N, 3) as ``cloud_in_mode`` says; return its name, n."""
        mode = self.params['cloud_in_mode']
        name, spec, meta, world = cloud_body(self.world, checked_points(points), self.params)
        if mode == 'replace':
            self.install_world(world, [meta], keep_state=False)
        else:
            self.metas.append(meta)
        self.cloud_count += 1
        return name, spec.n

    def reset(self) -> None:
        """Every body back to its initial state; grippers and forces released."""
        self.world.reset()
        self.forces.clear()
        self.grippers.clear()
        self.momentum.forget()

    # ------------------------------------------------------------------ ticks

    def tick(self) -> None:
        """Apply pending changes, step ``substeps`` x ``dt``, recover, call the listeners."""
        t0 = time.perf_counter()
        self.apply_pending()
        world, stats = self.world, self.stats
        dt = float(self.params['dt'])
        substeps = int(self.params['substeps'])
        self.expire_forces()
        # the live error estimate (error_estimate.LiveEstimate): one every 1 / rate s, its
        # pieces in what the last tick left of the period (all that are left when the next
        # is due by the next tick, as far away as the last); the world is left bit for bit
        period = 1.0 / float(self.params['rate'])
        now = self.clock()
        estimate_s = self._estimates.before_tick(
            world, dt, float(self.params['error_estimate.rate']), now,
            room_s=period - self._own_s, period=max(period, now - self._tick_at),
            step_s=stats.step_s_max or 0.0)
        self._tick_at = now
        measure = MomentumDrift.conservative(world, bool(self.forces or self.grippers))
        # the momentum is summed once when a conservative run starts, then only when the
        # drift is read (diagnostics), not twice every tick
        before = self.momentum.measure(world) \
            if measure and self.momentum.needs_reference() else None
        for _ in range(substeps):
            s = time.perf_counter()
            world.step(dt)
            stats.add_step(time.perf_counter() - s)
        self.sim_ns += substeps * int(round(dt * 1e9))
        self.collider_wrenches = world.take_collider_wrenches()
        contact = world.contact
        if contact is not None:
            stats.add_contact(contact.found, int(contact.fast_particles(dt).sum()))
        stats.asleep = world.asleep_count
        reset = self.reset_nonfinite()
        if measure and not reset:
            self.momentum.track(world, before)
        else:
            self.momentum.forget()
        tp = time.perf_counter()
        for fn in self._tick_listeners:
            fn(self)
        stats.add_publish(time.perf_counter() - tp)
        tick_s = time.perf_counter() - t0
        self._own_s = tick_s - estimate_s
        stats.add_tick(tick_s, substeps * dt, period, estimate_s=estimate_s)

    def reset_nonfinite(self) -> List[str]:
        """Reset every body whose state is no longer finite; return their names."""
        if self._nonfinite is None:
            from sm_ros.nonfinite import NonFiniteCheck   # one compiled pass over all bodies
            self._nonfinite = NonFiniteCheck()
        world = self.world
        # right after the steps: the integration passes flagged a non-finite state already
        # unless contact or pass colliders wrote after them (World.state_flagged)
        names = [b.name for b in self._nonfinite.bad_bodies(world.bodies, world.state_flagged)]
        for name in names:
            self.world.body(name).reset()
            self.forces.pop(name, None)
            self.grippers.drop_body(name)
        if names:
            self.stats.add_nonfinite(names)
            now = time.monotonic()
            if now - self._nonfinite_logged >= NONFINITE_LOG_PERIOD:
                self._nonfinite_logged = now
                for name in names:
                    self.log.error(f"body '{name}' went non-finite and was reset")
        return names
