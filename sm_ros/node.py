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
import time
from typing import Any, Dict, List, Optional, Tuple

from builtin_interfaces.msg import Time as TimeMsg
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import Pose, PoseArray, PoseStamped, WrenchStamped
import numpy as np
from rcl_interfaces.msg import (FloatingPointRange, IntegerRange, ParameterDescriptor,
                                ParameterEvent, ParameterType, SetParametersResult)
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import qos_profile_sensor_data, QoSProfile, ReliabilityPolicy
from rclpy.qos_overriding_options import QoSOverridingOptions
from rclpy.serialization import serialize_message
from rosgraph_msgs.msg import Clock as ClockMsg
from sensor_msgs.msg import PointCloud2
from sm_ros.cloud import CloudBuffer, CloudError, read_xyz
from sm_ros.core.pose import BodyPose
from sm_ros.diagnostics import contact_status, diagnostic_array, solver_status
from sm_ros.inputs import checked_points, InputError
from sm_ros.markers import MarkerBuffer
from sm_ros.params import BY_NAME, NODE_PARAMS, Param
from sm_ros.rotations import quaternion_from_matrix
from sm_ros.sim import ConfigError, Simulation  # noqa: F401 - ConfigError: for start-up
from sm_ros.warmup import cold_start_note, warm_up
from std_msgs.msg import String
from std_srvs.srv import SetBool, Trigger
from visualization_msgs.msg import MarkerArray

NODE_NAME = 'sim_node'
#: Message types as recordings name them.
POINTS_TYPE = 'sensor_msgs/msg/PointCloud2'
POSES_TYPE = 'geometry_msgs/msg/PoseArray'
MARKERS_TYPE = 'visualization_msgs/msg/MarkerArray'
DIAGNOSTICS_TYPE = 'diagnostic_msgs/msg/DiagnosticArray'
WRENCH_TYPE = 'geometry_msgs/msg/WrenchStamped'
EVENTS_TYPE = 'rcl_interfaces/msg/ParameterEvent'
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


def stamp_from_ns(ns: int) -> TimeMsg:
    """Return a builtin_interfaces/Time for ``ns`` nanoseconds."""
    return TimeMsg(sec=int(ns // 1_000_000_000), nanosec=int(ns % 1_000_000_000))


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


class SimNode(Node):
    """
    The simulation node (doc/interface.md).

    Keyword arguments go to ``rclpy.node.Node`` (``context``, ``parameter_overrides``,
    ``namespace``, ...). ``paused=True`` starts with the simulation paused (the ``pause``
    service does the same at run time). ``self.sim`` is the :class:`Simulation`.
    """

    def __init__(self, node_name: str = NODE_NAME, *, paused: bool = False, **kwargs):
        """Declare the parameters, build the simulation, create the interfaces, warm up."""
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
        self.sim = Simulation(values, log=self.get_logger())
        note = cold_start_note()
        if note:
            self.get_logger().info(note)
        self.warm_up_s = warm_up()
        self.live = None          # sm_ros.live.FoxgloveView while foxglove.port != 0
        self.recorder = None      # sm_ros.record.BagRecorder while recording
        self._recorder_dropped_reported = 0
        self._poser = BodyPose()
        self._pose_key: Tuple[int, ...] = ()

        self.cloud = CloudBuffer(values['frame_id'])
        self._poses = PoseArray()
        self._markers = MarkerBuffer()
        qos = QoSProfile(depth=5, reliability=ReliabilityPolicy.RELIABLE)
        self.pub_points = self._publisher(PointCloud2, 'points', qos)
        self.pub_poses = self._publisher(PoseArray, 'poses', QoSProfile(depth=10))
        self.pub_diagnostics = self._publisher(DiagnosticArray, '/diagnostics',
                                               QoSProfile(depth=10))
        self.pub_markers = self._publisher(MarkerArray, 'markers', qos)
        self.pub_collider_wrench = self._publisher(WrenchStamped, 'collider_wrench',
                                                   QoSProfile(depth=10))
        self.pub_clock = None
        self._set_publish_clock(values['publish_clock'])

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
        self.sim.add_tick_listener(lambda sim: self.publish())
        self.sim.on_change(['rate'], lambda c: setattr(
            self.tick_timer, 'timer_period_ns', int(round(1e9 / c['rate']))))
        self.sim.on_change(['diagnostics_rate'],
                           lambda c: self._set_diagnostics_rate(c['diagnostics_rate']))
        self.sim.on_change(['publish_clock'],
                           lambda c: self._set_publish_clock(c['publish_clock']))
        self.sim.on_change(['frame_id'], lambda c: setattr(self.cloud, 'frame_id',
                                                           c['frame_id']))
        self.sim.on_change(['foxglove.port', 'foxglove.host'], lambda c: self._start_live())
        self.sim.on_change(['frame_id'], lambda c: self.live is not None and setattr(
            self.live, 'frame_id', c['frame_id']))
        self.sim.on_change(['record.path'], lambda c: self._record_path_changed())
        self._start_live()
        if values['record.path']:
            self._start_recording(values['record.path'])
        self.sim.stats.reset_window(time.monotonic())
        self.get_logger().info(
            f"scene '{values['scene'] or 'default'}': {len(self.world.bodies)} bodies, "
            f'{self.num_points} points; {values["rate"]:g} Hz x {values["substeps"]} '
            f'steps of {values["dt"]:g} s; warm-up {self.warm_up_s:.2f} s')

    def _publisher(self, msg_type, topic: str, qos: QoSProfile):
        return self.create_publisher(
            msg_type, topic, qos,
            qos_overriding_options=QoSOverridingOptions.with_default_policies())

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

    # ------------------------------------------------------------------ parameters

    def validate_parameters_callback(self, params: List[Parameter]) -> SetParametersResult:
        """Refuse bad values with a reason; prepare a scene reload (nothing is applied)."""
        changes = {p.name: _plain(p.value) for p in params
                   if p.name in BY_NAME and BY_NAME[p.name].node}
        path = changes.get('record.path')
        if path and os.path.exists(path):
            return SetParametersResult(successful=False, reason=(
                f"record.path: '{path}' exists already (recordings are never overwritten)"))
        reason = self.sim.check(changes)
        if reason:
            return SetParametersResult(successful=False, reason=reason)
        return SetParametersResult(successful=True)

    def parameters_set_callback(self, params: List[Parameter]) -> None:
        """Queue accepted changes; the next tick applies them between two steps."""
        self.sim.queue({p.name: _plain(p.value) for p in params
                        if p.name in BY_NAME and BY_NAME[p.name].node})
        if self.recorder is not None:
            event = ParameterEvent(node=self.get_fully_qualified_name(),
                                   changed_parameters=[p.to_parameter_msg() for p in params])
            event.stamp = self.get_clock().now().to_msg()
            self.recorder.write('/parameter_events', EVENTS_TYPE, serialize_message(event),
                                time.time_ns(), self.sim.sim_ns)

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

    def _set_publish_clock(self, on: bool) -> None:
        if on and self.pub_clock is None:
            self.pub_clock = self._publisher(ClockMsg, '/clock', QoSProfile(depth=10))
        elif not on and self.pub_clock is not None:
            self.destroy_publisher(self.pub_clock)
            self.pub_clock = None

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

    def publish(self) -> None:
        """
        Send what is consumed (cloud, poses, markers, clock, live view).

        Each output is built only when a ROS subscriber, the Foxglove view or the
        recorder takes it (``get_subscription_count``, ``Channel.has_sinks``). While
        recording, a message is serialised once and the same bytes go to the publisher
        and the recorder.
        """
        ns = self.sim.sim_ns
        stamp = stamp_from_ns(ns)
        bodies = self.world.bodies
        live, rec = self.live, self.recorder
        wall = time.time_ns() if rec is not None else 0
        ros_points = self.pub_points.get_subscription_count() > 0
        live_points = live is not None and live.wants_cloud()
        if ros_points or live_points or rec is not None:
            msg = self.cloud.fill([b.x for b in bodies], stamp)
            self._send(self.pub_points, msg, ros_points, POINTS_TYPE, wall, ns)
            if live_points:
                live.log_cloud(self.cloud.msg.data, ns)
        ros_poses = self.pub_poses.get_subscription_count() > 0
        live_poses = live is not None and live.poses.has_sinks()
        if ros_poses or live_poses or rec is not None:
            coms, quats = self.body_poses()
            if ros_poses or rec is not None:
                self._send(self.pub_poses, self._pose_array(coms, quats, stamp), ros_poses,
                           POSES_TYPE, wall, ns)
            if live_poses:
                live.log_poses(coms, quats, ns)
        if self.pub_clock is not None:
            self.pub_clock.publish(ClockMsg(clock=stamp))
        ros_markers = self.pub_markers.get_subscription_count() > 0
        live_surfaces = live is not None and live.surfaces.has_sinks()
        if ros_markers or live_surfaces or rec is not None:
            surfaces = self._surfaces()
            if ros_markers or rec is not None:
                markers = self._build_markers(stamp, surfaces)
                if markers is not None:
                    if ros_markers:
                        self.pub_markers.publish(markers)
                    if rec is not None:
                        rec.write(self.pub_markers.topic_name, MARKERS_TYPE, markers, wall, ns)
            if live_surfaces:
                live.log_surfaces([(name, corners) for name, _, corners in surfaces], ns)
        wrenches = self.sim.collider_wrenches
        ros_wrench = bool(wrenches) and self.pub_collider_wrench.get_subscription_count() > 0
        if ros_wrench or (wrenches and rec is not None):
            for name, (force, torque) in wrenches.items():
                msg = WrenchStamped()
                msg.header.stamp = stamp
                msg.header.frame_id = name
                f, t = msg.wrench.force, msg.wrench.torque
                f.x, f.y, f.z = (float(v) for v in force)
                t.x, t.y, t.z = (float(v) for v in torque)
                self._send(self.pub_collider_wrench, msg, ros_wrench, WRENCH_TYPE, wall, ns)
        if live is not None:
            from sm_ros.live import world_colliders
            live.log_colliders(world_colliders(self.world), ns)

    def _send(self, pub, msg, to_ros: bool, msgtype: str, wall: int, ns: int) -> None:
        """Publish ``msg`` if ``to_ros``; record it (serialised once for both) if recording."""
        if self.recorder is None:
            if to_ros:
                pub.publish(msg)
            return
        data = serialize_message(msg)
        if to_ros:
            pub.publish(data)
        self.recorder.write(pub.topic_name, msgtype, data, wall, ns)

    def body_poses(self) -> Tuple[np.ndarray, np.ndarray]:
        """Return every body's centre of mass (B, 3) and rotation as quaternions (B, 4)."""
        bodies = self.world.bodies
        key = tuple(id(b) for b in bodies)
        if key != self._pose_key:
            self._poser.forget(keep=bodies)
            self._pose_key = key
        coms = np.empty((len(bodies), 3))
        quats = np.empty((len(bodies), 4))
        for i, body in enumerate(bodies):
            com, rot = self._poser.pose(body)
            coms[i] = com
            quats[i] = quaternion_from_matrix(rot)
        return coms, quats

    def _pose_array(self, coms: np.ndarray, quats: np.ndarray, stamp) -> PoseArray:
        poses = self._poses
        if len(poses.poses) != len(coms):
            poses.poses = [Pose() for _ in coms]
        poses.header.stamp = stamp
        poses.header.frame_id = self.sim.params['frame_id']
        for pose, c, q in zip(poses.poses, coms, quats):
            p = pose.position
            p.x, p.y, p.z = float(c[0]), float(c[1]), float(c[2])
            o = pose.orientation
            o.x, o.y, o.z, o.w = float(q[0]), float(q[1]), float(q[2]), float(q[3])
        return poses

    def _surfaces(self) -> List[Tuple[str, int, np.ndarray]]:
        """Return (body name, body index, triangle corners (3F, 3)) of the mesh bodies."""
        surfaces = []
        for i, (body, meta) in enumerate(zip(self.world.bodies, self.metas)):
            surface = getattr(meta, 'surface', None)
            if surface is None or len(surface.faces) == 0:
                continue
            verts = np.asarray(surface.vertices(body.x), dtype=np.float64)
            surfaces.append((body.name, i, verts[surface.faces].reshape(-1, 3)))
        return surfaces

    def _build_markers(self, stamp, surfaces=None) -> Optional[bytes]:
        """Return the serialised MarkerArray of the bodies with a surface, or None."""
        if surfaces is None:
            surfaces = self._surfaces()
        if not surfaces and self._markers.key in (None, ()):
            return None            # nothing to show, and nothing shown that must go
        return self._markers.fill(surfaces, self.sim.params['frame_id'], stamp.sec,
                                  stamp.nanosec)

    # ------------------------------------------------------------------ diagnostics

    def diagnostics_callback(self) -> None:
        """Publish the solver status and start a new measurement window."""
        status = self.solver_status()
        ns = self.sim.sim_ns
        wall = time.time_ns()
        statuses = [status]
        contacts = self.world.contact_stats()
        if any(n for n, _ in contacts.values()):
            statuses.append(contact_status(self.get_name(), contacts))
        self._send(self.pub_diagnostics, diagnostic_array(statuses, stamp_from_ns(ns)), True,
                   DIAGNOSTICS_TYPE, wall, ns)
        if self.live is not None:
            self.live.log_diagnostics({kv.key: kv.value for kv in status.values}, ns)
        rec = self.recorder
        if rec is not None:
            self._recorder_dropped_reported = rec.dropped
            if rec.error:
                self.get_logger().error(f'recording into {rec.path} failed: {rec.error}; '
                                        'stopped', throttle_duration_sec=60.0)
        self.sim.stats.reset_window(time.monotonic())

    def solver_status(self):
        """Return the '<node name>: solver' DiagnosticStatus of the current window."""
        rec = self.recorder
        recorder = {} if rec is None else {
            'recording': str(rec.path), 'recorder_messages': rec.written,
            'recorder_dropped': rec.dropped,
            'recorder_dropped_window': rec.dropped - self._recorder_dropped_reported}
        return solver_status(self.get_name(), self.sim.stats, time.monotonic(),
                             refused_messages=sum(self.refused.values()), paused=self.paused,
                             **recorder, **self.sim.status_values())

    # ------------------------------------------------------------------ live view, recording

    def _start_live(self) -> None:
        """(Re)start the Foxglove live view on ``foxglove.port`` (0: stop it)."""
        if self.live is not None:
            self.live.close()
            self.live = None
        port = int(self.sim.params['foxglove.port'])
        if port == 0:
            return
        try:
            from sm_ros.live import FoxgloveView
            self.live = FoxgloveView(port=port, host=self.sim.params['foxglove.host'],
                                     name=self.get_fully_qualified_name(),
                                     frame_id=self.sim.params['frame_id'])
        except (ImportError, RuntimeError, OSError) as exc:
            self.get_logger().error(f'foxglove.port {port}: no live view: {exc}')
            return
        self.get_logger().info(f'Foxglove live view on {self.live.url}: open Foxglove '
                               f'(app or {self.live.app_url}) and connect to it')

    def _start_recording(self, path: str) -> str:
        """Start recording into ``path``; raise (FileExistsError, ...) with a reason."""
        from sm_ros.record import BagRecorder
        self.recorder = BagRecorder(path)
        self._recorder_dropped_reported = 0
        self.get_logger().info(f'recording into {path} (rosbag2, MCAP)')
        return path

    def stop_recording(self) -> Optional[dict]:
        """Stop recording (close the file, write metadata.yaml); return the metadata."""
        rec, self.recorder = self.recorder, None
        if rec is None:
            return None
        meta = rec.close()['rosbag2_bagfile_information']
        self.get_logger().info(f"recorded {meta['message_count']} messages into {rec.path}"
                               + (f' ({rec.dropped} dropped)' if rec.dropped else ''))
        return meta

    def _record_path_changed(self) -> None:
        self.stop_recording()
        path = self.sim.params['record.path']
        if path:
            try:
                self._start_recording(path)
            except Exception as exc:  # noqa: B902 - any failure: log it, keep running
                self.get_logger().error(f'record.path: not recording: {exc}')

    def record_callback(self, request: SetBool.Request, response: SetBool.Response):
        """Start (true: into record.path, or sm_ros_<date>_<time>) or stop recording."""
        if not request.data:
            meta = self.stop_recording()
            response.success = meta is not None
            response.message = 'not recording' if meta is None else \
                f"stopped: {meta['message_count']} messages"
            return response
        if self.recorder is not None:
            response.success = False
            response.message = f'already recording into {self.recorder.path}'
            return response
        path = self.sim.params['record.path'] or time.strftime('sm_ros_%Y%m%d_%H%M%S')
        if not self.sim.params['record.path']:
            base, k = path, 1
            while os.path.exists(path):
                k += 1
                path = f'{base}_{k}'
        try:
            self._start_recording(path)
        except Exception as exc:  # noqa: B902 - the reason goes back to the caller
            response.success = False
            response.message = f'not recording: {exc}'
            return response
        response.success = True
        response.message = f'recording into {os.path.abspath(path)}'
        return response

    def destroy_node(self):
        """Close the recording (a readable file) and the live view, then the node."""
        try:
            self.stop_recording()
        finally:
            if self.live is not None:
                self.live.close()
                self.live = None
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
