"""
sim_node: a ROS 2 node that runs a shape-matching world and publishes it.

The contract is shared/docs/interface.md (topics, services, parameters, diagnostics, bad
input). Data path: scene file -> ``sm_ros.scene`` (bodies) -> ``sm_ros.core`` (World,
steps) -> this module (messages). This module holds no physics.

Threading: every callback is in the node's default (mutually exclusive) callback group, so
a message, a service request or a parameter change is never handled in the middle of a
tick. Parameter changes are validated when they are set and applied at the start of the
next tick (between two steps); inputs are validated completely before they touch the
state.
"""

from dataclasses import dataclass
import functools
import math
import os
import signal
import sys
import threading
import time
from typing import Any, Dict, List, Optional, Sequence, Tuple

from builtin_interfaces.msg import Time as TimeMsg
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import Pose, PoseArray, PoseStamped, WrenchStamped
import numpy as np
from rcl_interfaces.msg import (FloatingPointRange, IntegerRange, ParameterDescriptor,
                                ParameterType, SetParametersResult)
import rclpy
from rclpy.clock import Clock, ClockType
from rclpy.exceptions import (InvalidParameterTypeException, InvalidParameterValueException,
                              ParameterException)
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import qos_profile_sensor_data, QoSProfile, ReliabilityPolicy
from rclpy.qos_overriding_options import QoSOverridingOptions
from rclpy.signals import install_signal_handlers, SignalHandlerOptions
from rosgraph_msgs.msg import Clock as ClockMsg
from sensor_msgs.msg import PointCloud2
from sm_ros.cloud import CloudBuffer, CloudError, read_xyz
from sm_ros.diagnostics import diagnostic_array, solver_status, TickStats
from sm_ros.markers import MarkerBuffer
from sm_ros.params import (BODY_FIELDS, BY_NAME, GROUND_KEYS, MAX_COORDINATE, Param,
                           SCENE_DEFAULT_KEYS)
from sm_ros.params import NODE_PARAMS as PARAMS
from sm_ros.warmup import warm_up
from std_msgs.msg import String
from std_srvs.srv import SetBool, Trigger
from visualization_msgs.msg import MarkerArray

NODE_NAME = 'sim_node'

#: Inputs larger than this (N, N*m) are refused as out of range.
MAX_WRENCH = 1e9

# How often the same topic's refusal is logged (seconds).
REFUSAL_LOG_PERIOD = 1.0


class ConfigError(Exception):
    """A start-up configuration the node cannot run with (bad scene or parameter file)."""


def descriptor(p: Param) -> ParameterDescriptor:
    """Return the ParameterDescriptor of a table row (what ``ros2 param describe`` shows)."""
    text = p.description
    if p.choices:
        text += ' (one of: ' + ', '.join(p.choices) + ')'
    if p.positive:
        text += f' (must be > {p.lo:g})'
    d = ParameterDescriptor(name=p.name, type=p.ros_type, description=text,
                            read_only=p.read_only)
    if p.lo is not None and p.ros_type == ParameterType.PARAMETER_DOUBLE:
        d.floating_point_range = [FloatingPointRange(
            from_value=float(p.lo), to_value=float(p.hi), step=0.0)]
    elif p.lo is not None and p.ros_type == ParameterType.PARAMETER_INTEGER:
        d.integer_range = [IntegerRange(from_value=int(p.lo), to_value=int(p.hi), step=1)]
    return d


# ----------------------------------------------------------------------------------------
# Small pure helpers
# ----------------------------------------------------------------------------------------

def stamp_from_ns(ns: int) -> TimeMsg:
    """Return a builtin_interfaces/Time for ``ns`` nanoseconds."""
    return TimeMsg(sec=int(ns // 1_000_000_000), nanosec=int(ns % 1_000_000_000))


def quaternion_from_matrix(r: np.ndarray) -> Tuple[float, float, float, float]:
    """Return the unit quaternion (x, y, z, w) of a proper rotation matrix (Shepperd)."""
    m = np.asarray(r, dtype=np.float64)
    t = m[0, 0] + m[1, 1] + m[2, 2]
    if t > 0.0:
        s = 2.0 * math.sqrt(t + 1.0)
        q = (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, s / 4
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = 2.0 * math.sqrt(max(1.0 + m[0, 0] - m[1, 1] - m[2, 2], 1e-300))
        q = s / 4, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s, (m[2, 1] - m[1, 2]) / s
    elif m[1, 1] > m[2, 2]:
        s = 2.0 * math.sqrt(max(1.0 + m[1, 1] - m[0, 0] - m[2, 2], 1e-300))
        q = (m[0, 1] + m[1, 0]) / s, s / 4, (m[1, 2] + m[2, 1]) / s, (m[0, 2] - m[2, 0]) / s
    else:
        s = 2.0 * math.sqrt(max(1.0 + m[2, 2] - m[0, 0] - m[1, 1], 1e-300))
        q = (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, s / 4, (m[1, 0] - m[0, 1]) / s
    n = math.sqrt(sum(c * c for c in q)) or 1.0
    x, y, z, w = (float(c) / n for c in q)
    return (x, y, z, w) if w >= 0.0 else (-x, -y, -z, -w)


def matrix_from_quaternion(x: float, y: float, z: float, w: float) -> np.ndarray:
    """Return the rotation matrix of the quaternion (x, y, z, w); it is normalised first."""
    n = math.sqrt(x * x + y * y + z * z + w * w)
    x, y, z, w = x / n, y / n, z / n, w / n
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def scene_api():
    """Return the scene module (kept behind a function so the node imports it lazily)."""
    from sm_ros import scene
    return scene


def check_params_files(argv: Sequence[str]) -> Optional[str]:
    """
    Return why a ``--params-file`` in ``argv`` cannot be used, or None.

    Checked before rclpy.init so that a missing or broken file gives one clear line
    instead of rcl's multi-line error.
    """
    import yaml
    args = list(argv)
    for i, a in enumerate(args):
        if a != '--params-file':
            continue
        if i + 1 >= len(args):
            return '--params-file needs a file name'
        path = args[i + 1]
        if not os.path.isfile(path):
            return f'params file {path}: no such file'
        try:
            with open(path, encoding='utf-8') as f:
                data = yaml.safe_load(f)
        except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
            first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            return f'params file {path}: invalid YAML: {first}'
        if not isinstance(data, dict):
            return f'params file {path}: expected a mapping of node names to ros__parameters'
    return None


def _short_error(exc: BaseException) -> str:
    """Return the first line of an exception's message without rcl's source locations."""
    text = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
    return text.split(', at /')[0]


def guarded(topic: str):
    """
    Wrap a message callback so that no input can raise out of it.

    The checks in the callbacks refuse every bad input the node knows of; anything else
    that raises (a bug, or a case nobody foresaw) is refused the same way, logged with its
    type, and the node goes on.
    """
    def wrap(callback):
        @functools.wraps(callback)
        def safe(self, msg):
            try:
                callback(self, msg)
            except Exception as exc:  # noqa: B902 - a message must never stop the node
                self.refuse(topic, f'unexpected {type(exc).__name__}: {exc}')
        return safe
    return wrap


@dataclass
class _Attachment:
    """The particles of one body held by one gripper, in the gripper's frame."""

    body: str
    indices: np.ndarray
    local: np.ndarray
    targets: Optional[np.ndarray] = None


# ----------------------------------------------------------------------------------------
# The node
# ----------------------------------------------------------------------------------------

class SimNode(Node):
    """
    The simulation node (interface.md).

    Keyword arguments go to ``rclpy.node.Node`` (``context``, ``parameter_overrides``,
    ``namespace``, ...). ``paused=True`` starts with the simulation paused (for tests and
    embedding; the ``pause`` service does the same at run time).
    """

    def __init__(self, node_name: str = NODE_NAME, *, paused: bool = False, **kwargs):
        """Declare the parameters, load the scene, create the interfaces, warm up."""
        super().__init__(node_name, **kwargs)
        self.paused = paused
        self.timer_calls = 0
        self.refused: Dict[str, int] = {}
        self.last_refusal: Dict[str, str] = {}
        self._refusal_logged: Dict[str, float] = {}
        self._refusal_suppressed: Dict[str, int] = {}
        self._pending: Dict[str, Any] = {}
        self._pending_scene = None
        self._prepared_scene = None
        self._forces: Dict[str, float] = {}
        self._grippers: Dict[str, List[_Attachment]] = {}
        self._sim_ns = 0
        self._momentum_ref = None
        self._momentum_drift: Optional[float] = None
        self._cloud_count = 0
        self._steady = Clock(clock_type=ClockType.STEADY_TIME)

        for p in PARAMS:
            self.declare_parameter(p.name, p.default, descriptor(p))
        self._p: Dict[str, Any] = {p.name: self._param_value(p.name) for p in PARAMS}
        for p in PARAMS:
            reason = p.check(self._p[p.name])
            if reason:
                raise ConfigError(f'parameter {reason}')
        reason = self._check_body_params(self._p)
        if reason:
            raise ConfigError(f'parameter {reason}')

        try:
            self.world, self.metas, self.spec = self._build_scene(self._p['scene'], self._p)
            self.warm_up_s = warm_up()
        except ImportError as exc:
            raise ConfigError(f'the solver core cannot be imported: {exc}') from None

        self.cloud = CloudBuffer(self._p['frame_id'])
        self._poses = PoseArray()
        self._markers = MarkerBuffer()
        self._stats = TickStats(time.monotonic())

        qos = QoSProfile(depth=5, reliability=ReliabilityPolicy.RELIABLE)
        overrides = QoSOverridingOptions.with_default_policies()
        self.pub_points = self.create_publisher(PointCloud2, 'points', qos,
                                                qos_overriding_options=overrides)
        self.pub_poses = self.create_publisher(PoseArray, 'poses', QoSProfile(depth=10),
                                               qos_overriding_options=overrides)
        self.pub_diagnostics = self.create_publisher(
            DiagnosticArray, '/diagnostics', QoSProfile(depth=10),
            qos_overriding_options=overrides)
        self.pub_markers = self.create_publisher(MarkerArray, 'markers', qos,
                                                 qos_overriding_options=overrides)
        self.pub_clock = None
        self._set_publish_clock(self._p['publish_clock'])

        self.create_subscription(WrenchStamped, 'force', self.force_callback, 10)
        self.create_subscription(PoseStamped, 'grab', self.grab_callback, 10)
        self.create_subscription(String, 'release', self.release_callback, 10)
        self.create_subscription(PointCloud2, 'cloud_in', self.cloud_in_callback,
                                 qos_profile_sensor_data)

        self.create_service(Trigger, '~/reset', self.reset_callback)
        self.create_service(SetBool, '~/pause', self.pause_callback)
        self.create_service(Trigger, '~/step', self.step_callback)

        self.add_on_set_parameters_callback(self.validate_parameters_callback)
        self.add_post_set_parameters_callback(self.parameters_set_callback)

        self.tick_timer = self.create_timer(1.0 / self._p['rate'], self.timer_callback,
                                            clock=self._steady)
        self.diagnostics_timer = None
        self._set_diagnostics_rate(self._p['diagnostics_rate'])
        self._stats.reset_window(time.monotonic())
        self.get_logger().info(
            f"scene '{self._p['scene'] or 'default'}': {len(self.world.bodies)} bodies, "
            f'{self.num_points} points; {self._p["rate"]:g} Hz x {self._p["substeps"]} '
            f'steps of {self._p["dt"]:g} s; warm-up {self.warm_up_s:.2f} s')

    # ------------------------------------------------------------------ properties

    @property
    def num_points(self) -> int:
        """Return the total number of particles of all bodies."""
        return int(sum(b.n for b in self.world.bodies))

    @property
    def sim_time(self) -> float:
        """Return the simulation time in seconds (monotonic across resets and scenes)."""
        return self._sim_ns * 1e-9

    @property
    def grippers(self) -> Dict[str, List[_Attachment]]:
        """Return the attached grippers: name -> attachments per body."""
        return self._grippers

    def _param_value(self, name: str) -> Any:
        value = self.get_parameter(name).value
        if BY_NAME[name].ros_type == ParameterType.PARAMETER_DOUBLE_ARRAY:
            value = [float(v) for v in value]
        return value

    # ------------------------------------------------------------------ scenes

    def _scene_defaults(self, values: Dict[str, Any]) -> Dict[str, Any]:
        return {k: values[k] for k in SCENE_DEFAULT_KEYS}

    def _build_scene(self, name: str, values: Dict[str, Any]):
        """
        Load and build a scene; raise ConfigError with the loader's message.

        The scene is built twice: the first world takes one step and is dropped, so that
        every kernel specialisation the real world needs is compiled or loaded from the
        cache before the first tick (a copy would not do: its arrays' types differ).
        """
        scene = scene_api()
        defaults = self._scene_defaults(values)
        try:
            spec = scene.load_scene(name)
            throwaway, _ = scene.build_world(spec, defaults)
            world, metas = scene.build_world(spec, defaults)
        except ValueError as exc:
            raise ConfigError(f'scene: {exc}') from None
        try:
            throwaway.step(float(values['dt']))
        except Exception as exc:  # noqa: B902 - warming must never stop a good scene
            self.get_logger().warn(f'scene warm-up step failed: {exc}')
        return world, metas, spec

    def _check_body_params(self, values: Dict[str, Any]) -> Optional[str]:
        """Return why the body parameters in ``values`` are refused by the core, or None."""
        try:
            scene_api().params_from(self._scene_defaults(values), None)
        except ValueError as exc:
            return str(exc)
        return None

    def _install_world(self, world, metas, spec=None, keep_state: bool = True) -> None:
        """Swap in a new world; bodies unchanged by name and rest shape keep their state."""
        if keep_state:
            old = {b.name: b for b in self.world.bodies}
            for b in world.bodies:
                o = old.get(b.name)
                if (o is not None and o.n == b.n and np.array_equal(o.x_init, b.x_init)
                        and np.array_equal(o.m, b.m)):
                    b.set_state(x=o.x, v=o.v)
        self.world = world
        self.metas = list(metas)
        if spec is not None:
            self.spec = spec
        self._forces.clear()
        self._grippers.clear()
        self._momentum_ref = None

    # ------------------------------------------------------------------ parameters

    def validate_parameters_callback(self, params: List[Parameter]) -> SetParametersResult:
        """Refuse bad values with a reason; prepare a scene reload (nothing is applied)."""
        result = SetParametersResult(successful=True)
        values = {p.name: self._param_value(p.name) for p in PARAMS}
        changed = {}
        for param in params:
            spec = BY_NAME.get(param.name)
            if spec is None or not spec.node:
                continue
            value = param.value
            if spec.ros_type == ParameterType.PARAMETER_DOUBLE_ARRAY:
                value = [float(v) for v in value]
            reason = spec.check(value)
            if reason:
                return SetParametersResult(successful=False, reason=reason)
            values[param.name] = value
            changed[param.name] = value
        if any(k in BODY_FIELDS for k in changed):
            reason = self._check_body_params(values)
            if reason:
                return SetParametersResult(successful=False, reason=reason)
        self._prepared_scene = None
        if 'scene' in changed:
            try:
                self._prepared_scene = self._build_scene(changed['scene'], values)
            except ConfigError as exc:
                return SetParametersResult(successful=False, reason=str(exc))
        return result

    def parameters_set_callback(self, params: List[Parameter]) -> None:
        """Queue accepted changes; the next tick applies them between two steps."""
        for param in params:
            if param.name not in BY_NAME or not BY_NAME[param.name].node:
                continue
            if param.name == 'scene':
                self._pending_scene = self._prepared_scene
                self._prepared_scene = None
            value = param.value
            if BY_NAME[param.name].ros_type == ParameterType.PARAMETER_DOUBLE_ARRAY:
                value = [float(v) for v in value]
            self._pending[param.name] = value

    def apply_pending(self) -> None:
        """Apply queued parameter changes (called at the start of a tick)."""
        if not self._pending and self._pending_scene is None:
            return
        pending, self._pending = self._pending, {}
        scene, self._pending_scene = self._pending_scene, None
        self._p.update(pending)
        if scene is not None:
            self._install_world(*scene)
            body_changes = {}
        else:
            body_changes = {k: v for k, v in pending.items() if k in BODY_FIELDS}
        if body_changes:
            self._apply_body_params(body_changes)
        if 'gravity' in pending:
            self.world.gravity = np.asarray(pending['gravity'], dtype=np.float64)
        if any(k in pending for k in GROUND_KEYS):
            self.world.set_colliders(
                ground=scene_api().ground_from(self.spec.colliders.get('ground'),
                                               self._scene_defaults(self._p)),
                boxes=self.world.boxes, spheres=self.world.spheres)
        if 'rate' in pending:
            self.tick_timer.timer_period_ns = int(round(1e9 / self._p['rate']))
        if 'diagnostics_rate' in pending:
            self._set_diagnostics_rate(self._p['diagnostics_rate'])
        if 'publish_clock' in pending:
            self._set_publish_clock(self._p['publish_clock'])
        if 'frame_id' in pending:
            self.cloud.frame_id = self._p['frame_id']

    def _apply_body_params(self, changes: Dict[str, Any]) -> None:
        """Set changed body parameters on every body that does not override them."""
        for body, meta in zip(self.world.bodies, self.metas):
            fields = {BODY_FIELDS[k]: v for k, v in changes.items()
                      if k not in meta.overrides}
            if not fields:
                continue
            try:
                body.set_params(**fields)
            except ValueError as exc:
                self.get_logger().error(f"body '{body.name}': parameters not applied: {exc}")

    def _set_diagnostics_rate(self, rate: float) -> None:
        if rate <= 0.0:
            if self.diagnostics_timer is not None:
                self.destroy_timer(self.diagnostics_timer)
                self.diagnostics_timer = None
            return
        if self.diagnostics_timer is None:
            self.diagnostics_timer = self.create_timer(1.0 / rate, self.diagnostics_callback,
                                                       clock=self._steady)
        else:
            self.diagnostics_timer.timer_period_ns = int(round(1e9 / rate))

    def _set_publish_clock(self, on: bool) -> None:
        if on and self.pub_clock is None:
            self.pub_clock = self.create_publisher(
                ClockMsg, '/clock', QoSProfile(depth=10),
                qos_overriding_options=QoSOverridingOptions.with_default_policies())
        elif not on and self.pub_clock is not None:
            self.destroy_publisher(self.pub_clock)
            self.pub_clock = None

    # ------------------------------------------------------------------ ticks

    def timer_callback(self) -> None:
        """Apply pending changes, then (unless paused) advance one tick and publish."""
        self.timer_calls += 1
        if self.paused:
            self.apply_pending()
        else:
            self.tick()

    def tick(self) -> None:
        """Apply pending changes, advance ``substeps`` steps of ``dt``, check, publish once."""
        t0 = time.perf_counter()
        self.apply_pending()
        world = self.world
        stats = self._stats
        dt = float(self._p['dt'])
        substeps = int(self._p['substeps'])
        self._expire_forces()
        measure = self._conservative()
        if measure:
            p_before, scale_before = self._momentum()
        for _ in range(substeps):
            s = time.perf_counter()
            world.step(dt)
            stats.add_step(time.perf_counter() - s)
        self._sim_ns += substeps * int(round(dt * 1e9))
        reset = self._reset_nonfinite()
        if measure and not reset:
            self._track_momentum(p_before, scale_before)
        else:
            self._momentum_ref = None
        tp = time.perf_counter()
        self.publish()
        stats.add_publish(time.perf_counter() - tp)
        stats.add_tick(time.perf_counter() - t0, substeps * dt, 1.0 / self._p['rate'])

    def _reset_nonfinite(self) -> List[str]:
        """Reset every body whose state is no longer finite; return their names."""
        names = [b.name for b in self.world.bodies if not b.is_finite()]
        for name in names:
            self.world.body(name).reset()
            self._forces.pop(name, None)
            self._drop_body_from_grippers(name)
            self.get_logger().error(f"body '{name}' went non-finite and was reset",
                                    throttle_duration_sec=1.0)
        if names:
            self._stats.add_nonfinite(names)
        return names

    def publish(self) -> None:
        """Publish the cloud, poses, clock and markers of the current state."""
        stamp = stamp_from_ns(self._sim_ns)
        bodies = self.world.bodies
        self.pub_points.publish(self.cloud.fill([b.x for b in bodies], stamp))
        poses = self._poses
        if len(poses.poses) != len(bodies):
            poses.poses = [Pose() for _ in bodies]
        poses.header.stamp = stamp
        poses.header.frame_id = self._p['frame_id']
        for pose, body in zip(poses.poses, bodies):
            c = body.com()
            pose.position.x, pose.position.y, pose.position.z = (float(c[0]), float(c[1]),
                                                                 float(c[2]))
            o = pose.orientation
            o.x, o.y, o.z, o.w = quaternion_from_matrix(body.rotation())
        self.pub_poses.publish(poses)
        if self.pub_clock is not None:
            self.pub_clock.publish(ClockMsg(clock=stamp))
        if self.pub_markers.get_subscription_count() > 0:
            markers = self._build_markers(stamp)
            if markers is not None:
                self.pub_markers.publish(markers)

    def _build_markers(self, stamp) -> Optional[bytes]:
        """Return the serialised MarkerArray of the bodies with a surface, or None."""
        surfaces = []
        for i, (body, meta) in enumerate(zip(self.world.bodies, self.metas)):
            surface = getattr(meta, 'surface', None)
            if surface is None or len(surface.faces) == 0:
                continue
            verts = np.asarray(surface.vertices(body.x), dtype=np.float64)
            surfaces.append((body.name, i, verts[surface.faces].reshape(-1, 3)))
        if not surfaces and self._markers.key in (None, ()):
            return None            # nothing to show, and nothing shown that must go
        return self._markers.fill(surfaces, self._p['frame_id'], stamp.sec, stamp.nanosec)

    # ------------------------------------------------------------------ momentum

    def _conservative(self) -> bool:
        """Whether no external force acts this tick (then momentum must be conserved)."""
        world = self.world
        if np.any(np.asarray(world.gravity) != 0.0) or self._forces or self._grippers:
            return False
        if world.boxes or world.spheres:
            return False
        if any(len(b.pinned) for b in world.bodies):
            return False                                  # pins hold bodies in place
        if world.ground is not None:
            h = world.ground.height
            for b in world.bodies:
                if b.n and float(b.x[:, 2].min()) <= h + 1e-6:
                    return False
        return True

    def _momentum(self) -> Tuple[np.ndarray, float]:
        p = np.zeros(3)
        scale = 0.0
        for b in self.world.bodies:
            p += b.momentum()
            scale += float(np.dot(b.m, np.linalg.norm(b.v, axis=1)))
        return p, scale

    def _track_momentum(self, p_before: np.ndarray, scale_before: float) -> None:
        if self._momentum_ref is None:
            self._momentum_ref = (p_before, scale_before)
        p_ref, s_ref = self._momentum_ref
        p_now, s_now = self._momentum()
        denom = max(s_ref, s_now, 1e-300)
        self._momentum_drift = float(np.linalg.norm(p_now - p_ref)) / denom \
            if denom > 1e-300 else 0.0

    # ------------------------------------------------------------------ diagnostics

    def diagnostics_callback(self) -> None:
        """Publish the solver status and start a new measurement window."""
        self.pub_diagnostics.publish(diagnostic_array(self.solver_status(),
                                                      stamp_from_ns(self._sim_ns)))
        self._stats.reset_window(time.monotonic())

    def solver_status(self):
        """Return the '<node name>: solver' DiagnosticStatus of the current window."""
        bodies = self.world.bodies
        n = self.num_points
        err2 = sum(b.n * float(b.shape_error_rms()) ** 2 for b in bodies)
        modes = sorted({b.params.mode for b in bodies}) or [self._p['mode']]
        return solver_status(
            self.get_name(), self._stats, time.monotonic(), points=n, bodies=len(bodies),
            clusters=sum(int(b.num_clusters) for b in bodies), mode=','.join(modes),
            rate_target_hz=self._p['rate'],
            shape_error_rms_m=math.sqrt(err2 / n) if n else 0.0,
            momentum_drift=self._momentum_drift if self._momentum_ref is not None else None,
            refused_messages=sum(self.refused.values()), paused=self.paused)

    # ------------------------------------------------------------------ bad input

    def refuse(self, topic: str, reason: str) -> None:
        """Count a refused input and log it (warn, at most once a second per topic)."""
        self.refused[topic] = self.refused.get(topic, 0) + 1
        self.last_refusal[topic] = reason
        now = time.monotonic()
        last = self._refusal_logged.get(topic)
        if last is not None and now - last < REFUSAL_LOG_PERIOD:
            self._refusal_suppressed[topic] = self._refusal_suppressed.get(topic, 0) + 1
            return
        more = self._refusal_suppressed.pop(topic, 0)
        tail = f' ({more} more refused since the last report)' if more else ''
        self._refusal_logged[topic] = now
        self.get_logger().warn(f'{topic}: refused: {reason}{tail}')

    def _body_or_refuse(self, topic: str, name: str):
        try:
            return self.world.body(name)
        except KeyError:
            known = ', '.join(b.name for b in self.world.bodies)
            self.refuse(topic, f"unknown body '{name}' (bodies: {known})")
            return None

    # ------------------------------------------------------------------ force

    @guarded('force')
    def force_callback(self, msg: WrenchStamped) -> None:
        """Hold a wrench on one body (frame_id) or every body (empty); zero clears it."""
        w = msg.wrench
        f = np.array([w.force.x, w.force.y, w.force.z], dtype=np.float64)
        t = np.array([w.torque.x, w.torque.y, w.torque.z], dtype=np.float64)
        if not (np.isfinite(f).all() and np.isfinite(t).all()):
            self.refuse('force', 'NaN or Inf in the wrench')
            return
        if np.abs(f).max() > MAX_WRENCH or np.abs(t).max() > MAX_WRENCH:
            self.refuse('force', f'wrench component beyond +-{MAX_WRENCH:g} (out of range)')
            return
        name = msg.header.frame_id
        if name:
            body = self._body_or_refuse('force', name)
            if body is None:
                return
            targets = [body]
        else:
            targets = list(self.world.bodies)
        clear = not f.any() and not t.any()
        now = time.monotonic()
        for body in targets:
            if clear:
                body.clear_wrench()
                self._forces.pop(body.name, None)
            else:
                body.set_wrench(f, t)
                self._forces[body.name] = now

    def _expire_forces(self) -> None:
        timeout = self._p['force_timeout']
        if timeout <= 0.0 or not self._forces:
            return
        now = time.monotonic()
        for name in [n for n, t in self._forces.items() if now - t > timeout]:
            del self._forces[name]
            self.world.body(name).clear_wrench()

    # ------------------------------------------------------------------ grab / release

    @guarded('grab')
    def grab_callback(self, msg: PoseStamped) -> None:
        """Attach particles to a named gripper (first pose) or move them with it."""
        name = msg.header.frame_id
        if not name:
            self.refuse('grab', 'empty gripper name (header.frame_id)')
            return
        p = msg.pose.position
        q = msg.pose.orientation
        pos = np.array([p.x, p.y, p.z], dtype=np.float64)
        quat = np.array([q.x, q.y, q.z, q.w], dtype=np.float64)
        if not (np.isfinite(pos).all() and np.isfinite(quat).all()):
            self.refuse('grab', f"NaN or Inf in the pose of gripper '{name}'")
            return
        if np.abs(pos).max() > MAX_COORDINATE:
            self.refuse('grab', f"position of gripper '{name}' beyond +-{MAX_COORDINATE:g} m")
            return
        norm = float(np.linalg.norm(quat))
        if not 1e-6 < norm < 1e6:
            self.refuse('grab', f"orientation of gripper '{name}' is not a rotation "
                        f'(quaternion norm {norm:g})')
            return
        rot = matrix_from_quaternion(*quat)
        attachments = self._grippers.get(name)
        if attachments is None:
            radius = self._p['grab_radius']
            attachments = []
            for body in self.world.bodies:
                d = body.x - pos
                idx = np.flatnonzero(np.einsum('ij,ij->i', d, d) <= radius * radius)
                if idx.size:
                    attachments.append(_Attachment(body.name, idx, d[idx] @ rot))
            if not attachments:
                self.refuse('grab', f'no particle within grab_radius {radius:g} m of gripper '
                            f"'{name}' at ({pos[0]:g}, {pos[1]:g}, {pos[2]:g})")
                return
            self._grippers[name] = attachments
        self._apply_kinematics({a.body for a in attachments}, pose=(name, pos, rot))

    def _apply_kinematics(self, body_names, pose=None) -> None:
        """Give each named body the kinematic targets of all grippers holding it."""
        if pose is not None:
            name, pos, rot = pose
            for a in self._grippers[name]:
                a.targets = pos + a.local @ rot.T
        for body_name in body_names:
            body = self.world.body(body_name)
            held = [a for atts in self._grippers.values() for a in atts if a.body == body_name]
            if not held:
                body.clear_kinematic()
                continue
            idx = np.concatenate([a.indices for a in held])
            targets = np.concatenate([a.targets for a in held])
            idx, first = np.unique(idx, return_index=True)
            body.set_kinematic(idx, targets[first])

    @guarded('release')
    def release_callback(self, msg: String) -> None:
        """Release one gripper by name, or all of them on an empty name."""
        name = msg.data
        if name and name not in self._grippers:
            known = ', '.join(self._grippers) or 'none'
            self.refuse('release', f"unknown gripper '{name}' (grippers: {known})")
            return
        names = [name] if name else list(self._grippers)
        bodies = {a.body for n in names for a in self._grippers[n]}
        for n in names:
            del self._grippers[n]
        self._apply_kinematics(bodies)

    def _drop_body_from_grippers(self, body_name: str) -> None:
        for name in list(self._grippers):
            kept = [a for a in self._grippers[name] if a.body != body_name]
            if kept:
                self._grippers[name] = kept
            else:
                del self._grippers[name]

    # ------------------------------------------------------------------ cloud_in

    @guarded('cloud_in')
    def cloud_in_callback(self, msg: PointCloud2) -> None:
        """Build a body from a cloud; it replaces the scene's bodies or joins them."""
        try:
            points = read_xyz(msg)
        except CloudError as exc:
            self.refuse('cloud_in', str(exc))
            return
        if np.abs(points).max() > MAX_COORDINATE:
            self.refuse('cloud_in', f'coordinates beyond +-{MAX_COORDINATE:g} m')
            return
        frame = msg.header.frame_id
        if frame and frame != self._p['frame_id']:
            self.get_logger().warn(
                f"cloud_in: frame '{frame}' taken as '{self._p['frame_id']}' (no tf lookup)",
                throttle_duration_sec=10.0)
        scene = scene_api()
        mode = self._p['cloud_in_mode']
        existing = {b.name for b in self.world.bodies}
        name = 'cloud_in'
        if mode == 'add':
            k = 1
            while name in existing:
                k += 1
                name = f'cloud_in_{k}'
        defaults = self._scene_defaults(self._p)
        from sm_ros.core import World
        try:
            body_spec = scene.cloud_body_spec(points, int(self._p['max_points']), name)
            # a throwaway copy takes one step first, so the first tick pays no compilation
            scratch = World(gravity=tuple(float(g) for g in self.world.gravity))
            scratch.set_colliders(ground=self.world.ground, boxes=self.world.boxes,
                                  spheres=self.world.spheres)
            scene.add_spec_body(scratch, body_spec, defaults, 'cloud_in')
            scratch.step(float(self._p['dt']))
            if mode == 'replace':
                world = World(gravity=tuple(float(g) for g in self.world.gravity))
                world.set_colliders(ground=self.world.ground, boxes=self.world.boxes,
                                    spheres=self.world.spheres)
                meta = scene.add_spec_body(world, body_spec, defaults, 'cloud_in')
                self._install_world(world, [meta], keep_state=False)
            else:
                meta = scene.add_spec_body(self.world, body_spec, defaults, 'cloud_in')
                self.metas.append(meta)
        except ValueError as exc:
            self.refuse('cloud_in', str(exc))
            return
        self._cloud_count += 1
        self.get_logger().info(f"cloud_in: body '{name}' from {points.shape[0]} points "
                               f'({body_spec.n} particles), mode {mode}')

    # ------------------------------------------------------------------ services

    def reset_callback(self, request: Trigger.Request, response: Trigger.Response):
        """Every body back to its initial state; grabs and forces released."""
        self.world.reset()
        self._forces.clear()
        self._grippers.clear()
        self._momentum_ref = None
        response.success = True
        response.message = f'reset {len(self.world.bodies)} bodies'
        return response

    def pause_callback(self, request: SetBool.Request, response: SetBool.Response):
        """Pause (true) or resume (false) the simulation clock."""
        self.paused = bool(request.data)
        response.success = True
        response.message = 'paused' if self.paused else 'running'
        return response

    def step_callback(self, request: Trigger.Request, response: Trigger.Response):
        """While paused: advance exactly one tick and publish."""
        if not self.paused:
            response.success = False
            response.message = 'not paused: call ~/pause with data: true first'
            return response
        self.tick()
        response.success = True
        response.message = f'sim time {self.sim_time:.6f} s'
        return response


# ----------------------------------------------------------------------------------------
# Entry point
# ----------------------------------------------------------------------------------------

def _fail(message: str) -> int:
    print(f'sim_node: error: {message}', file=sys.stderr)
    return 2


def main(args=None) -> int:
    """Run sim_node until Ctrl-C; exit code 2 for a bad scene or parameter file."""
    argv = sys.argv if args is None else args
    reason = check_params_files(argv)
    if reason:
        return _fail(reason)
    try:
        # No rclpy signal handlers while starting: Ctrl-C during the (possibly long, cold
        # Numba cache) warm-up raises KeyboardInterrupt right away; rclpy's handlers take
        # over once the node exists, for a clean shutdown of the spinning node.
        rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    except Exception as exc:  # noqa: B902 - rcl reports bad arguments as RCLError
        return _fail(_short_error(exc))
    node = None
    code = 0
    starting = threading.Event()
    starting.set()
    interrupted = threading.Event()

    def on_sigint(signum, frame):
        interrupted.set()
        raise KeyboardInterrupt

    def start_up_watchdog():
        # A Ctrl-C during the cold warm-up can be raised where it is dropped (inside an
        # LLVM -> ctypes callback while Numba writes its cache): if the start-up is still
        # running a little after the Ctrl-C, leave at once (nothing is spinning yet).
        interrupted.wait()
        time.sleep(2.0)
        if starting.is_set():
            os._exit(0)

    def quiet_dropped_interrupt(unraisable):
        # ctypes reports the dropped KeyboardInterrupt with a traceback: not for a Ctrl-C
        if not isinstance(unraisable.exc_value, KeyboardInterrupt):
            sys.__unraisablehook__(unraisable)

    signal.signal(signal.SIGINT, on_sigint)
    sys.unraisablehook = quiet_dropped_interrupt
    threading.Thread(target=start_up_watchdog, daemon=True).start()
    try:
        try:
            node = SimNode()
        except Exception:  # noqa: B902 - a dropped Ctrl-C can leave Numba mid-compile
            if interrupted.is_set():
                raise KeyboardInterrupt from None
            raise
        starting.clear()
        sys.unraisablehook = sys.__unraisablehook__
        signal.signal(signal.SIGINT, signal.default_int_handler)
        if interrupted.is_set():
            raise KeyboardInterrupt
        install_signal_handlers(SignalHandlerOptions.ALL)
        try:
            rclpy.spin(node)
        except Exception:  # noqa: B902 - the executor may fail once Ctrl-C shut rcl down
            if rclpy.ok():
                raise
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except ConfigError as exc:
        code = _fail(str(exc))
    except (InvalidParameterTypeException, InvalidParameterValueException,
            ParameterException) as exc:
        code = _fail(f'parameter: {_short_error(exc)}')
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return code


if __name__ == '__main__':
    sys.exit(main())
