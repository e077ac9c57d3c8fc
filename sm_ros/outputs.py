"""
What sim_node sends: points, poses, markers, clock, diagnostics, live view and recording.

:class:`Outputs` owns the publishers and the message buffers of a :class:`SimNode` and
builds each output only when it is consumed (a ROS subscriber, the Foxglove live view of
``sm_ros.live`` or the recorder of ``sm_ros.record``). While recording, a message is
serialised once and the same bytes go to the publisher and the recorder. The node calls
:meth:`Outputs.publish` after every tick (a tick listener of the Simulation).
"""

import os
import sys
import time
from typing import List, Optional, Tuple

from builtin_interfaces.msg import Time as TimeMsg
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import Pose, PoseArray, WrenchStamped
import numpy as np
from rcl_interfaces.msg import ParameterEvent
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.qos_overriding_options import QoSOverridingOptions
from rclpy.serialization import serialize_message
from rosgraph_msgs.msg import Clock as ClockMsg
from sensor_msgs.msg import PointCloud2
from sm_ros.cloud import CloudBuffer
from sm_ros.core.pose import BodyPose
from sm_ros.diagnostics import contact_status, diagnostic_array
from sm_ros.markers import MarkerBuffer
from sm_ros.rotations import quaternion_from_matrix
from visualization_msgs.msg import MarkerArray

#: Message types as recordings name them.
POINTS_TYPE = 'sensor_msgs/msg/PointCloud2'
POSES_TYPE = 'geometry_msgs/msg/PoseArray'
MARKERS_TYPE = 'visualization_msgs/msg/MarkerArray'
DIAGNOSTICS_TYPE = 'diagnostic_msgs/msg/DiagnosticArray'
WRENCH_TYPE = 'geometry_msgs/msg/WrenchStamped'
EVENTS_TYPE = 'rcl_interfaces/msg/ParameterEvent'


def stamp_from_ns(ns: int) -> TimeMsg:
    """Return a builtin_interfaces/Time for ``ns`` nanoseconds."""
    return TimeMsg(sec=int(ns // 1_000_000_000), nanosec=int(ns % 1_000_000_000))


class Outputs:
    """The publishers, buffers, live view and recorder of one node."""

    def __init__(self, node, sim):
        """Create the publishers of ``node``; start the live view and recording if asked."""
        self.node = node
        self.sim = sim
        self.live = None          # sm_ros.live.FoxgloveView while foxglove.port != 0
        self.recorder = None      # sm_ros.record.BagRecorder while recording
        self.recorder_dropped_reported = 0
        self._poser = BodyPose()
        self._pose_key: Tuple[int, ...] = ()
        params = sim.params
        self.cloud = CloudBuffer(params['frame_id'])
        self.poses = PoseArray()
        self.markers = MarkerBuffer()
        qos = QoSProfile(depth=5, reliability=ReliabilityPolicy.RELIABLE)
        self.pub_points = self._publisher(PointCloud2, 'points', qos)
        self.pub_poses = self._publisher(PoseArray, 'poses', QoSProfile(depth=10))
        self.pub_diagnostics = self._publisher(DiagnosticArray, '/diagnostics',
                                               QoSProfile(depth=10))
        self.pub_markers = self._publisher(MarkerArray, 'markers', qos)
        self.pub_collider_wrench = self._publisher(WrenchStamped, 'collider_wrench',
                                                   QoSProfile(depth=10))
        self.pub_clock = None
        self.set_publish_clock(params['publish_clock'])
        sim.on_change(['publish_clock'], lambda c: self.set_publish_clock(c['publish_clock']))
        sim.on_change(['frame_id'], self._frame_changed)
        sim.on_change(['foxglove.port', 'foxglove.host'], lambda c: self.start_live())
        sim.on_change(['record.path'], lambda c: self.record_path_changed())
        self.start_live()
        if params['record.path']:
            try:
                self.start_recording(params['record.path'])
            except Exception as exc:  # noqa: B902 - a start-up setting: one clear line
                from sm_ros.sim import ConfigError
                raise ConfigError(f'record.path: {exc}') from None

    def _publisher(self, msg_type, topic: str, qos: QoSProfile):
        return self.node.create_publisher(
            msg_type, topic, qos,
            qos_overriding_options=QoSOverridingOptions.with_default_policies())

    def _frame_changed(self, changes) -> None:
        self.cloud.frame_id = changes['frame_id']
        if self.live is not None:
            self.live.frame_id = changes['frame_id']

    def set_publish_clock(self, on: bool) -> None:
        """Create (True) or destroy (False) the /clock publisher."""
        if on and self.pub_clock is None:
            self.pub_clock = self._publisher(ClockMsg, '/clock', QoSProfile(depth=10))
        elif not on and self.pub_clock is not None:
            self.node.destroy_publisher(self.pub_clock)
            self.pub_clock = None

    # ------------------------------------------------------------------ every tick

    def publish(self) -> None:
        """
        Send what is consumed (cloud, poses, markers, clock, live view).

        Each output is built only when a ROS subscriber, the Foxglove view or the
        recorder takes it (``get_subscription_count``, ``Channel.has_sinks``). While
        recording, a message is serialised once and the same bytes go to the publisher
        and the recorder.
        """
        ns = self.sim.sim_ns
        stamps = []

        def stamp():
            # making a Time message is not free: only when something is sent
            if not stamps:
                stamps.append(stamp_from_ns(ns))
            return stamps[0]
        bodies = self.sim.world.bodies
        live, rec = self.live, self.recorder
        wall = time.time_ns() if rec is not None else 0
        ros_points = self.pub_points.get_subscription_count() > 0
        live_points = live is not None and live.wants_cloud()
        if ros_points or live_points or rec is not None:
            msg = self.cloud.fill([b.x for b in bodies], stamp())
            self._send(self.pub_points, msg, ros_points, POINTS_TYPE, wall, ns)
            if live_points:
                live.log_cloud(self.cloud.msg.data, ns)
        ros_poses = self.pub_poses.get_subscription_count() > 0
        live_poses = live is not None and live.poses.has_sinks()
        if ros_poses or live_poses or rec is not None:
            coms, quats = self.body_poses()
            if ros_poses or rec is not None:
                self._send(self.pub_poses, self._pose_array(coms, quats, stamp()), ros_poses,
                           POSES_TYPE, wall, ns)
            if live_poses:
                live.log_poses(coms, quats, ns)
        if self.pub_clock is not None:
            self.pub_clock.publish(ClockMsg(clock=stamp()))
        ros_markers = self.pub_markers.get_subscription_count() > 0
        live_surfaces = live is not None and live.surfaces.has_sinks()
        if ros_markers or live_surfaces or rec is not None:
            surfaces = self._surfaces()
            if ros_markers or rec is not None:
                markers = self._build_markers(stamp(), surfaces)
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
                msg.header.stamp = stamp()
                msg.header.frame_id = name
                f, t = msg.wrench.force, msg.wrench.torque
                f.x, f.y, f.z = (float(v) for v in force)
                t.x, t.y, t.z = (float(v) for v in torque)
                self._send(self.pub_collider_wrench, msg, ros_wrench, WRENCH_TYPE, wall, ns)
        if live is not None:
            from sm_ros.live import world_colliders
            live.log_colliders(world_colliders(self.sim.world), ns)
            if wrenches and live.contacts.has_sinks():
                # the force on each named collider, as an arrow at its centre
                names = list(wrenches)
                live.log_contacts(
                    np.array([self.sim.world.collider_pose(n)[0] for n in names]),
                    np.array([wrenches[n][0] for n in names], dtype=np.float64), ns)

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
        bodies = self.sim.world.bodies
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
        poses = self.poses
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
        for i, (body, meta) in enumerate(zip(self.sim.world.bodies, self.sim.metas)):
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
        if not surfaces and self.markers.key in (None, ()):
            return None            # nothing to show, and nothing shown that must go
        return self.markers.fill(surfaces, self.sim.params['frame_id'], stamp.sec,
                                  stamp.nanosec)

    # ------------------------------------------------------------------ diagnostics

    def send_diagnostics(self, status) -> None:
        """Publish (and record, and show live) one solver status."""
        ns = self.sim.sim_ns
        statuses = [status]
        contacts = self.sim.world.contact_stats()
        if any(n for n, _ in contacts.values()):
            statuses.append(contact_status(self.node.get_name(), contacts))
        self._send(self.pub_diagnostics, diagnostic_array(statuses, stamp_from_ns(ns)), True,
                   DIAGNOSTICS_TYPE, time.time_ns(), ns)
        if self.live is not None:
            self.live.log_diagnostics({kv.key: kv.value for kv in status.values}, ns)
        rec = self.recorder
        if rec is not None:
            self.recorder_dropped_reported = rec.dropped
            if rec.error:
                self.node.get_logger().error(f'recording into {rec.path} failed: '
                                             f'{rec.error}; stopped',
                                             throttle_duration_sec=60.0)

    def recorder_status(self) -> dict:
        """Return the recorder's diagnostics values ({} while not recording)."""
        rec = self.recorder
        return {} if rec is None else {
            'recording': str(rec.path), 'recorder_messages': rec.written,
            'recorder_dropped': rec.dropped,
            'recorder_dropped_window': rec.dropped - self.recorder_dropped_reported}

    def record_parameters(self, params) -> None:
        """Record accepted parameter changes as a /parameter_events message."""
        if self.recorder is None:
            return
        event = ParameterEvent(node=self.node.get_fully_qualified_name(),
                               changed_parameters=[p.to_parameter_msg() for p in params])
        event.stamp = self.node.get_clock().now().to_msg()
        self.recorder.write('/parameter_events', EVENTS_TYPE, serialize_message(event),
                            time.time_ns(), self.sim.sim_ns)

    # ------------------------------------------------------------------ live view, recording

    def start_live(self) -> None:
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
                                     name=self.node.get_fully_qualified_name(),
                                     frame_id=self.sim.params['frame_id'])
        except (ImportError, RuntimeError, OSError) as exc:
            self.node.get_logger().error(f'foxglove.port {port}: no live view: {exc}')
            return
        self.node.get_logger().info(f'Foxglove live view on {self.live.url}: open Foxglove '
                               f'(app or {self.live.app_url}) and connect to it')

    def start_recording(self, path: str) -> str:
        """Start recording into ``path``; raise (FileExistsError, ...) with a reason."""
        from sm_ros.record import BagRecorder
        self.recorder = BagRecorder(path, split_s=self.sim.params['record.split_s'])
        self._recorder_dropped_reported = 0
        self.node.get_logger().info(f'recording into {path} (rosbag2, MCAP)')
        return path

    def stop_recording(self) -> Optional[dict]:
        """Stop recording (close the file, write metadata.yaml); return the metadata."""
        rec, self.recorder = self.recorder, None
        if rec is None:
            return None
        meta = rec.close()['rosbag2_bagfile_information']
        text = (f"recorded {meta['message_count']} messages into {rec.path}"
                + (f' ({rec.dropped} dropped)' if rec.dropped else ''))
        if self.node.context.ok():
            self.node.get_logger().info(text)
        else:                       # after Ctrl-C: rosout is gone, the console is not
            print(f'[{self.node.get_name()}] {text}', file=sys.stderr)
        return meta

    def record_path_changed(self) -> None:
        """Stop recording, and start again into the new record.path (if not empty)."""
        self.stop_recording()
        path = self.sim.params['record.path']
        if path:
            try:
                self.start_recording(path)
            except Exception as exc:  # noqa: B902 - any failure: log it, keep running
                self.node.get_logger().error(f'record.path: not recording: {exc}')

    def record(self, on: bool) -> Tuple[bool, str]:
        """Start (into record.path, or sm_ros_<date>_<time>) or stop; return (ok, message)."""
        if not on:
            meta = self.stop_recording()
            return meta is not None, ('not recording' if meta is None else
                                      f"stopped: {meta['message_count']} messages")
        if self.recorder is not None:
            return False, f'already recording into {self.recorder.path}'
        path = self.sim.params['record.path'] or time.strftime('sm_ros_%Y%m%d_%H%M%S')
        if not self.sim.params['record.path']:
            base, k = path, 1
            while os.path.exists(path):
                k += 1
                path = f'{base}_{k}'
        try:
            self.start_recording(path)
        except Exception as exc:  # noqa: B902 - the reason goes back to the caller
            return False, f'not recording: {exc}'
        return True, f'recording into {os.path.abspath(path)}'

    def close(self) -> None:
        """Close the recording (a readable file) and the live view."""
        try:
            self.stop_recording()
        finally:
            if self.live is not None:
                self.live.close()
                self.live = None
