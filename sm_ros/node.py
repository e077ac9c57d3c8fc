"""
sim_node: the ROS 2 adapter of :class:`sm_ros.sim.Simulation`.

The contract is doc/interface.md (topics, services, parameters, diagnostics, bad input).
This module declares the parameters from the table in ``sm_ros.params``, turns messages
into calls of the simulation and its state into messages; it holds no physics and no
simulation state of its own. Start-up and Ctrl-C handling are in ``sm_ros.startup``.

Threading: every callback is in the node's default (mutually exclusive) callback group, so
a message, a service request or a parameter change is never handled in the middle of a
tick. Parameter changes are validated when they are set and applied at the start of the
next tick (between two steps); inputs are validated completely before they touch the
state.
"""

import functools
import os
import sys
import threading
import time
from typing import Any, Dict, List, Optional

from geometry_msgs.msg import PoseStamped, WrenchStamped
import numpy as np
from rcl_interfaces.msg import (FloatingPointRange, IntegerRange, ParameterDescriptor,
                                ParameterType, SetParametersResult)
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import PointCloud2
from sm_ros.cloud import CloudError, read_xyz
from sm_ros.diagnostics import SolverFigures, solver_status
from sm_ros.inputs import checked_points, InputError
from sm_ros.outputs import Outputs
from sm_ros.params import BY_NAME, NODE_PARAMS, Param
from sm_ros.sim import ConfigError, Simulation  # noqa: F401 - ConfigError: for start-up
from sm_ros import warmup
from std_msgs.msg import String
from std_srvs.srv import SetBool, Trigger

NODE_NAME = 'sim_node'
#: How often the same topic's refusal is logged (seconds).
REFUSAL_LOG_PERIOD = 1.0


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


def _plain(value: Any) -> Any:
    """Return a parameter value as plain Python (double arrays as lists of floats)."""
    return [float(v) for v in value] if isinstance(value, (list, tuple, np.ndarray)) \
        else value


def guarded(topic: str):
    """
    Wrap a message callback so that no input can raise out of it.

    A refused input (InputError) is counted and logged with its reason; anything else that
    raises (a bug, or a case nobody foresaw) is refused the same way, logged with its type,
    and the node goes on.
    """
    def wrap(callback):
        @functools.wraps(callback)
        def safe(self, msg):
            try:
                callback(self, msg)
            except InputError as exc:
                self.refuse(topic, str(exc))
            except Exception as exc:  # noqa: B902 - a message must never stop the node
                self.refuse(topic, f'unexpected {type(exc).__name__}: {exc}')
        return safe
    return wrap


def _dds_note() -> str:
    """The start-up line's note on the packaged DDS profile, when ``startup.run`` set it."""
    from sm_ros import startup
    if startup.DDS_PROFILE is None:
        return ''
    return (f'; DDS: the packaged Fast DDS profile {startup.DDS_PROFILE} (large clouds over '
            'shared memory; FASTRTPS_DEFAULT_PROFILES_FILE was unset)')


class InitialCloud:
    """
    The scene's particles at rest, published on ``points`` a few times a second while the
    solver compiles what the scene needs (a cold Numba cache: tens of seconds), so that a
    new user sees the scene at once; the simulation's own publisher takes over when it is
    built. Its stamp is simulation time 0; the first simulated cloud comes after it.
    """

    PERIOD_S = 0.25

    def __init__(self, node: Node, cloud: PointCloud2):
        """Publish ``cloud`` from a thread until :meth:`stop`."""
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        self.node = node
        self.cloud = cloud
        self.publisher = node.create_publisher(
            PointCloud2, 'points', QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE))
        self.sent = 0
        self._done = threading.Event()
        self._thread = threading.Thread(target=self._run, name='sm_ros initial cloud',
                                        daemon=True)
        self._thread.start()

    @classmethod
    def start(cls, node: Node, values: Dict[str, Any]) -> Optional['InitialCloud']:
        """Load the scene and start publishing it; None when it cannot be loaded (the
        simulation then reports why)."""
        try:
            from sm_ros.cloud import CloudBuffer
            from sm_ros.scene import load_scene
            spec = load_scene(values['scene'])
            cloud = CloudBuffer(values['frame_id']).fill([b.points for b in spec.bodies])
        except Exception:  # noqa: B902 - the simulation's build reports a bad scene
            return None
        node.get_logger().info(f"publishing scene '{values['scene'] or 'default'}' at rest "
                               'on points until the solver is compiled')
        return cls(node, cloud)

    def _run(self) -> None:
        while True:
            try:
                self.publisher.publish(self.cloud)
                self.sent += 1
            except Exception:  # noqa: B902 - a context shut down by Ctrl-C: stop quietly
                return
            if self._done.wait(self.PERIOD_S):
                return

    def stop(self) -> None:
        """Stop publishing and remove the publisher."""
        self._done.set()
        self._thread.join()
        self.node.destroy_publisher(self.publisher)


class SimNode(Node):
    """
    The simulation node (doc/interface.md).

    Keyword arguments go to ``rclpy.node.Node`` (``context``, ``parameter_overrides``,
    ``namespace``, ...). ``paused=True`` starts with the simulation paused (the ``pause``
    service does the same at run time). ``self.sim`` is the :class:`Simulation`.
    """

    def __init__(self, node_name: str = NODE_NAME, *, paused: bool = False, **kwargs):
        """Declare the parameters, build the simulation (compiling what its scene needs),
        start the background warm-up on a cold cache, create the interfaces."""
        super().__init__(node_name, **kwargs)
        self.paused = paused
        self.timer_calls = 0
        self.refused: Dict[str, int] = {}
        self.last_refusal: Dict[str, str] = {}
        self._refusal_logged: Dict[str, float] = {}
        self._refusal_suppressed: Dict[str, int] = {}
        self._steady = Clock(clock_type=ClockType.STEADY_TIME)
        for p in NODE_PARAMS:
            self.declare_parameter(p.name, p.default, descriptor(p))
        values = {p.name: _plain(self.get_parameter(p.name).value) for p in NODE_PARAMS}
        # Numba compiles a kernel on its first call: building the scene steps a throwaway
        # copy of it, which compiles (or loads) what this scene needs and nothing more
        note = warmup.scene_start_note(values['scene'])
        initial = None
        if note:
            self.get_logger().info(note)
            initial = InitialCloud.start(self, values)
        start = time.perf_counter()
        try:
            self.sim = Simulation(values, log=self.get_logger())
        finally:
            if initial is not None:
                initial.stop()
        self.warm_up_s = time.perf_counter() - start
        self.background_warmup = None
        if note:
            self._start_background_warmup()
        self.outputs = Outputs(self, self.sim)      # publishers, live view, recorder

        self.create_subscription(WrenchStamped, 'force', self.force_callback, 10)
        self.create_subscription(PoseStamped, 'grab', self.grab_callback, 10)
        self.create_subscription(String, 'release', self.release_callback, 10)
        self.create_subscription(PoseStamped, 'collider_pose', self.collider_pose_callback,
                                 10)
        self.create_subscription(PointCloud2, 'cloud_in', self.cloud_in_callback,
                                 qos_profile_sensor_data)
        self.create_service(Trigger, '~/reset', self.reset_callback)
        self.create_service(SetBool, '~/pause', self.pause_callback)
        self.create_service(Trigger, '~/step', self.step_callback)
        self.create_service(SetBool, '~/record', self.record_callback)
        self.add_on_set_parameters_callback(self.validate_parameters_callback)
        self.add_post_set_parameters_callback(self.parameters_set_callback)

        self.tick_timer = self.create_timer(1.0 / values['rate'], self.timer_callback,
                                            clock=self._steady)
        self.diagnostics_timer = None
        self._set_diagnostics_rate(values['diagnostics_rate'])
        self.sim.add_tick_listener(lambda sim: self.outputs.publish())
        self.sim.on_change(['rate'], lambda c: setattr(
            self.tick_timer, 'timer_period_ns', int(round(1e9 / c['rate']))))
        self.sim.on_change(['diagnostics_rate'],
                           lambda c: self._set_diagnostics_rate(c['diagnostics_rate']))
        self.sim.stats.reset_window(time.monotonic())
        self.get_logger().info(
            f"scene '{values['scene'] or 'default'}': {len(self.world.bodies)} bodies, "
            f'{self.num_points} points; {values["rate"]:g} Hz x {values["substeps"]} '
            f'steps of {values["dt"]:g} s; built in {self.warm_up_s:.2f} s' + _dds_note())

    def _start_background_warmup(self) -> None:
        """Compile the kernels this scene did not need in a niced process on one core
        (``warmup.start_background``); log when it is done."""
        extra = warmup.start_background()
        if extra is None:
            return
        self.background_warmup = extra
        start = time.monotonic()

        def wait():
            code = warmup.finish_background(extra)
            if code == 0:
                self.get_logger().info(
                    f'background warm-up done in {time.monotonic() - start:.0f} s: every '
                    'solver kernel is in the Numba cache')
            elif code is not None:
                self.get_logger().warn(
                    f'background warm-up failed (exit status {code}): kernels compile when '
                    'first used')
        threading.Thread(target=wait, name='sm_ros warm-up', daemon=True).start()

    # ------------------------------------------------------------------ the simulation's state

    world = property(lambda self: self.sim.world, doc='The sm_ros.core.World.')
    metas = property(lambda self: self.sim.metas, doc='Per-body scene metadata.')
    grippers = property(lambda self: self.sim.grippers, doc='Gripper name -> attachments.')
    num_points = property(lambda self: self.sim.num_points, doc='Particles of all bodies.')
    sim_time = property(lambda self: self.sim.sim_time, doc='Simulation time (s).')
    _p = property(lambda self: self.sim.params, doc='Applied parameter values.')
    _pending = property(lambda self: self.sim.pending, doc='Accepted, not yet applied.')
    _pending_scene = property(lambda self: self.sim.pending_scene, doc='Scene to swap in.')
    _forces = property(lambda self: self.sim.forces, doc='Body -> time of its last force.')
    _cloud_count = property(lambda self: self.sim.cloud_count, doc='cloud_in bodies made.')
    # what it sends (sm_ros.outputs)
    cloud = property(lambda self: self.outputs.cloud, doc='The CloudBuffer of points.')
    pub_points = property(lambda self: self.outputs.pub_points)
    pub_poses = property(lambda self: self.outputs.pub_poses)
    pub_markers = property(lambda self: self.outputs.pub_markers)
    pub_diagnostics = property(lambda self: self.outputs.pub_diagnostics)
    pub_collider_wrench = property(lambda self: self.outputs.pub_collider_wrench)
    pub_clock = property(lambda self: self.outputs.pub_clock, doc='None unless publish_clock.')
    live = property(lambda self: self.outputs.live, doc='The Foxglove view, or None.')
    recorder = property(lambda self: self.outputs.recorder, doc='The recorder, or None.')
    _poses = property(lambda self: self.outputs.poses)

    # ------------------------------------------------------------------ parameters

    def validate_parameters_callback(self, params: List[Parameter]) -> SetParametersResult:
        """Refuse bad values with a reason; prepare a scene reload (nothing is applied)."""
        changes = {p.name: _plain(p.value) for p in params
                   if p.name in BY_NAME and BY_NAME[p.name].node}
        path = changes.get('record.path')
        if path and os.path.exists(path):
            return SetParametersResult(successful=False, reason=(
                f"record.path: '{path}' exists already (recordings are never overwritten)"))
        scene = changes.get('scene')
        if scene is not None and warmup.cold_kernels():
            self.get_logger().info(f"scene '{scene or 'default'}': compiling the kernels it "
                                   'needs (Numba cache not warm yet): this takes seconds')
        start = time.perf_counter()
        reason = self.sim.check(changes)
        if scene is not None and not reason:
            self.get_logger().info(f"scene '{scene or 'default'}' built in "
                                   f'{time.perf_counter() - start:.1f} s')
        if reason:
            return SetParametersResult(successful=False, reason=reason)
        return SetParametersResult(successful=True)

    def parameters_set_callback(self, params: List[Parameter]) -> None:
        """Queue accepted changes; the next tick applies them between two steps."""
        self.sim.queue({p.name: _plain(p.value) for p in params
                        if p.name in BY_NAME and BY_NAME[p.name].node})
        self.outputs.record_parameters(params)

    def apply_pending(self) -> None:
        """Apply queued parameter changes (the start of every tick does this)."""
        self.sim.apply_pending()

    def _set_diagnostics_rate(self, rate: float) -> None:
        if rate <= 0.0:
            if self.diagnostics_timer is not None:
                self.destroy_timer(self.diagnostics_timer)
                self.diagnostics_timer = None
        elif self.diagnostics_timer is None:
            self.diagnostics_timer = self.create_timer(1.0 / rate, self.diagnostics_callback,
                                                       clock=self._steady)
        else:
            self.diagnostics_timer.timer_period_ns = int(round(1e9 / rate))

    # ------------------------------------------------------------------ ticks

    def timer_callback(self) -> None:
        """Apply pending changes, then (unless paused) advance one tick and publish."""
        self.timer_calls += 1
        if self.paused:
            self.sim.apply_pending()
        else:
            self.tick()

    def tick(self) -> None:
        """Apply pending changes, advance ``substeps`` steps of ``dt``, check, publish once."""
        self.sim.tick()

    # ------------------------------------------------------------------ diagnostics

    def diagnostics_callback(self) -> None:
        """Publish the solver status and start a new measurement window."""
        self.outputs.send_diagnostics(self.solver_status())
        self.sim.stats.reset_window(time.monotonic())

    def solver_status(self):
        """Return the '<node name>: solver' DiagnosticStatus of the current window."""
        figures = SolverFigures(refused_messages=sum(self.refused.values()),
                                paused=self.paused, **self.outputs.recorder_status(),
                                **self.sim.status_values())
        return solver_status(self.get_name(), self.sim.stats, time.monotonic(), figures)

    # ------------------------------------------------------------------ live view, recording

    def record_callback(self, request: SetBool.Request, response: SetBool.Response):
        """Start (true: into record.path, or sm_ros_<date>_<time>) or stop recording."""
        response.success, response.message = self.outputs.record(bool(request.data))
        return response

    def stop_recording(self) -> Optional[dict]:
        """Stop recording (close the file, write metadata.yaml); return the metadata."""
        return self.outputs.stop_recording()

    def destroy_node(self):
        """Close the recording (a readable file) and the live view, stop a background
        warm-up (the cache keeps what it compiled), then the node."""
        self.outputs.close()
        if self.background_warmup is not None:
            warmup.stop_background(self.background_warmup)
        return super().destroy_node()

    # ------------------------------------------------------------------ inputs

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

    @guarded('force')
    def force_callback(self, msg: WrenchStamped) -> None:
        """Hold a wrench on one body (frame_id) or every body (empty); zero clears it."""
        f, t = msg.wrench.force, msg.wrench.torque
        self.sim.set_force(msg.header.frame_id, (f.x, f.y, f.z), (t.x, t.y, t.z))

    @guarded('grab')
    def grab_callback(self, msg: PoseStamped) -> None:
        """Attach particles to a named gripper (first pose) or move them with it."""
        p, q = msg.pose.position, msg.pose.orientation
        self.sim.grab(msg.header.frame_id, (p.x, p.y, p.z), (q.x, q.y, q.z, q.w))

    @guarded('collider_pose')
    def collider_pose_callback(self, msg: PoseStamped) -> None:
        """Move the kinematic collider named by frame_id to the pose by the next tick's end."""
        p, q = msg.pose.position, msg.pose.orientation
        self.sim.move_collider(msg.header.frame_id, (p.x, p.y, p.z), (q.x, q.y, q.z, q.w))

    @guarded('release')
    def release_callback(self, msg: String) -> None:
        """Release one gripper by name, or all of them on an empty name."""
        self.sim.release(msg.data)

    @guarded('cloud_in')
    def cloud_in_callback(self, msg: PointCloud2) -> None:
        """Build a body from a cloud; it replaces the scene's bodies or joins them."""
        try:
            points = read_xyz(msg)
        except CloudError as exc:
            raise InputError(str(exc)) from None
        points = checked_points(points)
        frame, own = msg.header.frame_id, self.sim.params['frame_id']
        if frame and frame != own:
            self.get_logger().warn(f"cloud_in: frame '{frame}' taken as '{own}' (no tf lookup)",
                                   throttle_duration_sec=10.0)
        name, n = self.sim.add_cloud(points)
        self.get_logger().info(f"cloud_in: body '{name}' from {points.shape[0]} points "
                               f"({n} particles), mode {self.sim.params['cloud_in_mode']}")

    # ------------------------------------------------------------------ services

    def reset_callback(self, request: Trigger.Request, response: Trigger.Response):
        """Every body back to its initial state; grabs and forces released."""
        self.sim.reset()
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


def main(args=None) -> int:
    """Run sim_node until Ctrl-C; exit code 2 for a bad scene or parameter file."""
    from sm_ros.startup import run
    return run(SimNode, args)


if __name__ == '__main__':
    sys.exit(main())
