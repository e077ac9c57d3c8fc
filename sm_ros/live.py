"""
Live view in Foxglove: a WebSocket server inside the node, no ROS installation needed.

``FoxgloveView(port)`` starts the Foxglove SDK's WebSocket server (``pip install
'.[viz]'``) and streams, as Foxglove's own message types (protobuf):

=================  =====================  ==============================================
channel            schema                 content
=================  =====================  ==============================================
``/points``        foxglove.PointCloud    every particle, the bytes of the published
                                          PointCloud2 as they are (x, y, z float32 and
                                          the body index uint32, 16 bytes a point); the
                                          ``body`` field is listed first so that the 3D
                                          panel colours the points by body by default
``/poses``         foxglove.PosesInFrame  one pose (centre of mass, rotation) per body
``/surfaces``      foxglove.SceneUpdate   the deformed mesh surfaces (triangle lists)
``/colliders``     foxglove.SceneUpdate   ground, boxes, spheres, capsules where they
                                          are now (kinematic ones move; a new kind is
                                          one entry in ``COLLIDER_ENTITIES``)
``/contacts``      foxglove.SceneUpdate   forces as arrows (``log_contacts``: the node
                                          sends the collider wrenches at the colliders)
``/diagnostics``   JSON                   the solver's figures as numbers (Plot panel)
=================  =====================  ==============================================

Cost: each ``log_*`` method first asks the channel whether a client is subscribed
(``Channel.has_sinks``) and returns at once when none is, so a node without a connected
Foxglove pays one such question per channel and tick. The point cloud is not
re-encoded: the protobuf message is a small header (stamp, frame, fields) followed by the
cloud's bytes, joined into one ``bytes`` object (the one copy of the cloud the stream
makes; the server queues that object).

The module is ROS-free: it takes NumPy arrays and the cloud's raw bytes.
"""

from __future__ import annotations

import math
from typing import Any, Callable, Dict, Iterable, List, Optional, Sequence, Tuple

import numpy as np

from sm_ros.live_cloud import (CLOUD_FIELDS, CLOUD_POINT_STEP,  # noqa: F401
                               encode_point_cloud, point_cloud_header)

#: Default port of ``foxglove.port``. 0 (off) is the node's default; 8765 is Foxglove's
#: own default port, the one ``make run`` passes and the app's connection dialog proposes.
FOXGLOVE_DEFAULT_PORT = 8765

#: Colour of the surfaces and colliders (RGBA in [0, 1]).
SURFACE_RGBA = (0.85, 0.45, 0.2, 0.9)
COLLIDER_RGBA = (0.55, 0.6, 0.65, 0.5)
GROUND_RGBA = (0.4, 0.4, 0.4, 0.35)
CONTACT_RGBA = (0.9, 0.1, 0.1, 1.0)
#: Side of the square drawn for the (infinite) ground plane (m).
GROUND_SIDE = 20.0


class VizUnavailable(RuntimeError):
    """foxglove-sdk is not installed (``pip install 'sm_ros[viz]'``)."""


def _foxglove():
    try:
        import foxglove
    except ImportError as exc:  # pragma: no cover - depends on the install
        raise VizUnavailable(
            "the Foxglove live view needs foxglove-sdk: pip install -e '.[viz]'") from exc
    return foxglove


# ----------------------------------------------------------------------------------------
# Scene entities
# ----------------------------------------------------------------------------------------

def body_rgba(index: int, count: int) -> Tuple[float, float, float, float]:
    """Return a distinct colour for body ``index`` of ``count`` (hue wheel)."""
    import colorsys
    h = (index / max(count, 1)) % 1.0
    r, g, b = colorsys.hsv_to_rgb(h, 0.65, 0.95)
    return (r, g, b, 1.0)


def _color(sdk, rgba):
    return sdk.messages.Color(r=rgba[0], g=rgba[1], b=rgba[2], a=rgba[3])


def _pose(sdk, centre, quat):
    msgs = sdk.messages
    return msgs.Pose(position=msgs.Vector3(x=float(centre[0]), y=float(centre[1]),
                                           z=float(centre[2])),
                     orientation=msgs.Quaternion(x=float(quat[0]), y=float(quat[1]),
                                                 z=float(quat[2]), w=float(quat[3])))


def _ground_entity(sdk, ground, pose) -> Dict[str, list]:
    msgs = sdk.messages
    centre = (0.0, 0.0, float(ground.height) - 0.0005)
    return {'cubes': [msgs.CubePrimitive(pose=_pose(sdk, centre, (0, 0, 0, 1)),
                                         size=msgs.Vector3(x=GROUND_SIDE, y=GROUND_SIDE,
                                                           z=0.001),
                                         color=_color(sdk, GROUND_RGBA))]}


def _box_entity(sdk, box, pose) -> Dict[str, list]:
    msgs = sdk.messages
    size = np.asarray(box.hi, float) - np.asarray(box.lo, float)
    return {'cubes': [msgs.CubePrimitive(pose=_pose(sdk, *pose),
                                         size=msgs.Vector3(x=size[0], y=size[1], z=size[2]),
                                         color=_color(sdk, COLLIDER_RGBA))]}


def _ball(sdk, centre, quat, diameter):
    msgs = sdk.messages
    return msgs.SpherePrimitive(pose=_pose(sdk, centre, quat),
                                size=msgs.Vector3(x=diameter, y=diameter, z=diameter),
                                color=_color(sdk, COLLIDER_RGBA))


def _sphere_entity(sdk, sphere, pose) -> Dict[str, list]:
    return {'spheres': [_ball(sdk, *pose, 2.0 * float(sphere.radius))]}


def _capsule_entity(sdk, capsule, pose) -> Dict[str, list]:
    """A cylinder along the local z axis and a sphere at each end."""
    msgs = sdk.messages
    centre, quat = np.asarray(pose[0], float), np.asarray(pose[1], float)
    radius, length = float(capsule.radius), float(capsule.length)
    x, y, z, w = quat
    axis = np.array([2 * (x * z + y * w), 2 * (y * z - x * w), 1 - 2 * (x * x + y * y)])
    diameter = 2.0 * radius
    ends = [centre + 0.5 * length * axis, centre - 0.5 * length * axis]
    return {'cylinders': [msgs.CylinderPrimitive(
                pose=_pose(sdk, centre, quat),
                size=msgs.Vector3(x=diameter, y=diameter, z=length),
                bottom_scale=1.0, top_scale=1.0, color=_color(sdk, COLLIDER_RGBA))],
            'spheres': [_ball(sdk, end, quat, diameter) for end in ends]}


#: Collider class name -> function(foxglove, collider, (centre, quaternion x y z w))
#: returning {SceneEntity keyword: [primitives]}. A new collider kind is drawn by adding
#: one entry here (and, if a World keeps it elsewhere than ground/boxes/spheres/capsules,
#: one line in ``world_colliders``).
COLLIDER_ENTITIES: Dict[str, Callable] = {
    'Ground': _ground_entity,
    'Box': _box_entity,
    'Sphere': _sphere_entity,
    'Capsule': _capsule_entity,
}


def _declared_pose(collider) -> Tuple[np.ndarray, np.ndarray]:
    """Return the centre and quaternion a collider was declared with."""
    if hasattr(collider, 'lo'):
        centre = (np.asarray(collider.lo, float) + np.asarray(collider.hi, float)) / 2.0
    else:
        centre = np.asarray(getattr(collider, 'center', (0.0, 0.0, 0.0)), float)
    quat = getattr(collider, 'orientation', None)
    return centre, np.asarray(quat if quat is not None else (0.0, 0.0, 0.0, 1.0), float)


def world_colliders(world) -> List[Tuple[str, Any, Tuple[np.ndarray, np.ndarray]]]:
    """
    Return (id, collider, (centre, quaternion)) for every collider of a core World.

    Named colliders are drawn where they are now (``World.collider_pose``: kinematic ones
    move); the others where they were declared.
    """
    out = []
    ground = getattr(world, 'ground', None)
    if ground is not None:
        out.append(('ground', ground, (np.zeros(3), np.array([0.0, 0.0, 0.0, 1.0]))))
    for kind in ('boxes', 'spheres', 'capsules'):
        for index, collider in enumerate(getattr(world, kind, ()) or ()):
            name = getattr(collider, 'name', None)
            pose = _declared_pose(collider)
            if name and hasattr(world, 'collider_pose'):
                try:
                    pose = world.collider_pose(name)
                except (ValueError, KeyError):
                    pass
            fallback = f'{kind[:-1] if kind != "boxes" else "box"}{index}'
            out.append((name or fallback, collider, pose))
    return out


def _timestamp_msg(sdk, stamp_ns: int):
    sec, nsec = divmod(int(stamp_ns), 1_000_000_000)
    return sdk.messages.Timestamp(sec=sec, nsec=nsec)


class FoxgloveView:
    """
    A Foxglove WebSocket server and its channels (see the module docstring).

    ``port`` 0 picks a free port (tests); ``host`` defaults to the loopback interface
    (pass ``0.0.0.0`` to be reachable from other machines).
    """

    def __init__(self, port: int = FOXGLOVE_DEFAULT_PORT, host: str = '127.0.0.1',
                 name: str = 'sm_ros', frame_id: str = 'world'):
        """Start the server; raises VizUnavailable without foxglove-sdk, OSError if busy."""
        sdk = _foxglove()
        from foxglove.channels import PosesInFrameChannel, SceneUpdateChannel
        from foxglove.messages import PointCloud
        self._sdk = sdk
        self.frame_id = frame_id
        self.context = sdk.Context()
        try:
            self.server = sdk.start_server(name=name, host=host, port=int(port),
                                          context=self.context)
        except Exception as exc:  # noqa: BLE001 - the SDK raises its own error type
            raise OSError(f'Foxglove server on {host}:{port}: {exc}') from exc
        self.host = host
        self.points = sdk.Channel('/points', schema=PointCloud.get_schema(),
                                 message_encoding='protobuf', context=self.context)
        self.poses = PosesInFrameChannel('/poses', context=self.context)
        self.surfaces = SceneUpdateChannel('/surfaces', context=self.context)
        self.colliders = SceneUpdateChannel('/colliders', context=self.context)
        self.contacts = SceneUpdateChannel('/contacts', context=self.context)
        self.diagnostics = sdk.Channel('/diagnostics', context=self.context)
        self.messages_logged = 0
        self._collider_key = None

    # ------------------------------------------------------------------ info

    @property
    def port(self) -> int:
        """Return the port the server listens on."""
        return int(self.server.port)

    @property
    def url(self) -> str:
        """Return the ws:// address to connect Foxglove to."""
        host = 'localhost' if self.host in ('127.0.0.1', '0.0.0.0', '') else self.host
        return f'ws://{host}:{self.port}'

    @property
    def app_url(self) -> str:
        """Return a link that opens the Foxglove web app connected to this server."""
        return self.server.app_url()

    def wants_cloud(self) -> bool:
        """Return True while a client is subscribed to ``/points``."""
        return self.points.has_sinks()

    def wants_any(self) -> bool:
        """Return True while a client is subscribed to any channel."""
        return any(c.has_sinks() for c in (self.points, self.poses, self.surfaces,
                                           self.colliders, self.contacts, self.diagnostics))

    # ------------------------------------------------------------------ logging

    def log_cloud(self, data, stamp_ns: int) -> bool:
        """Send the cloud's raw bytes (16 bytes a point, the published layout)."""
        if not self.points.has_sinks():
            return False
        self.points.log(encode_point_cloud(data, stamp_ns, self.frame_id), log_time=stamp_ns)
        self.messages_logged += 1
        return True

    def log_poses(self, positions: np.ndarray, quaternions: np.ndarray,
                  stamp_ns: int) -> bool:
        """Send one pose per body: positions (B, 3), quaternions (B, 4) as x, y, z, w."""
        if not self.poses.has_sinks():
            return False
        poses = [_pose(self._sdk, centre, quat)
                 for centre, quat in zip(np.asarray(positions), np.asarray(quaternions))]
        message = self._sdk.messages.PosesInFrame(
            timestamp=_timestamp_msg(self._sdk, stamp_ns), frame_id=self.frame_id, poses=poses)
        self.poses.log(message, log_time=stamp_ns)
        self.messages_logged += 1
        return True

    def log_surfaces(self, surfaces: Sequence[Tuple[str, np.ndarray]], stamp_ns: int,
                     count: Optional[int] = None) -> bool:
        """Send the deformed surfaces: [(body name, triangle corners (3F, 3))]."""
        if not self.surfaces.has_sinks():
            return False
        msgs = self._sdk.messages
        stamp = _timestamp_msg(self._sdk, stamp_ns)
        entities = []
        for name, corners in surfaces:
            pts = [msgs.Point3(x=float(x), y=float(y), z=float(z))
                   for x, y, z in np.asarray(corners, dtype=np.float64)]
            tri = msgs.TriangleListPrimitive(
                pose=msgs.Pose(orientation=msgs.Quaternion(w=1.0)), points=pts,
                color=_color(self._sdk, SURFACE_RGBA))
            entities.append(msgs.SceneEntity(timestamp=stamp, frame_id=self.frame_id,
                                             id=f'surface/{name}', triangles=[tri]))
        self.surfaces.log(msgs.SceneUpdate(entities=entities), log_time=stamp_ns)
        self.messages_logged += 1
        return True

    def log_colliders(self, colliders: Iterable[Tuple[str, Any, Any]], stamp_ns: int) -> bool:
        """
        Send the colliders [(id, collider, (centre, quaternion))] (see ``world_colliders``).

        Sent when a client subscribes and whenever a collider moved or changed (the
        entities persist in the client in between).
        """
        if not self.colliders.has_sinks():
            self._collider_key = None
            return False
        colliders = list(colliders)
        key = tuple((cid, repr(collider), tuple(np.round(np.concatenate(
            [np.ravel(pose[0]), np.ravel(pose[1])]), 9))) for cid, collider, pose in colliders)
        if key == self._collider_key:
            return False
        msgs = self._sdk.messages
        stamp = _timestamp_msg(self._sdk, stamp_ns)
        entities = []
        for cid, collider, pose in colliders:
            draw = COLLIDER_ENTITIES.get(type(collider).__name__)
            if draw is None:
                continue
            entities.append(msgs.SceneEntity(timestamp=stamp, frame_id=self.frame_id,
                                             id=f'collider/{cid}',
                                             **draw(self._sdk, collider, pose)))
        deletions = [msgs.SceneEntityDeletion(timestamp=stamp,
                                              type=msgs.SceneEntityDeletionType.All)]
        self.colliders.log(msgs.SceneUpdate(deletions=deletions, entities=entities),
                           log_time=stamp_ns)
        self._collider_key = key
        self.messages_logged += 1
        return True

    def log_contacts(self, points: np.ndarray, forces: np.ndarray, stamp_ns: int,
                     metres_per_newton: float = 0.01) -> bool:
        """Send contact forces as arrows: points (K, 3) where forces (K, 3) act."""
        if not self.contacts.has_sinks():
            return False
        msgs = self._sdk.messages
        stamp = _timestamp_msg(self._sdk, stamp_ns)
        arrows = []
        for point, force in zip(np.asarray(points, float), np.asarray(forces, float)):
            length = float(np.linalg.norm(force)) * metres_per_newton
            if not length > 0.0:
                continue
            arrows.append(msgs.ArrowPrimitive(
                pose=_pose(self._sdk, point, _quaternion_x_to(force)),
                shaft_length=0.8 * length, shaft_diameter=0.1 * length,
                head_length=0.2 * length, head_diameter=0.2 * length,
                color=_color(self._sdk, CONTACT_RGBA)))
        entity = msgs.SceneEntity(timestamp=stamp, frame_id=self.frame_id, id='contacts',
                                  arrows=arrows)
        self.contacts.log(msgs.SceneUpdate(entities=[entity]), log_time=stamp_ns)
        self.messages_logged += 1
        return True

    def log_diagnostics(self, values: Dict[str, Any], stamp_ns: int) -> bool:
        """Send the solver's figures (numbers where they are numbers) as one JSON message."""
        if not self.diagnostics.has_sinks():
            return False
        out: Dict[str, Any] = {}
        for key, value in values.items():
            try:
                number = float(value)
                out[key] = number if math.isfinite(number) else None
            except (TypeError, ValueError):
                out[key] = value
        out['stamp'] = stamp_ns / 1e9
        self.diagnostics.log(out, log_time=stamp_ns)
        self.messages_logged += 1
        return True

    def close(self) -> None:
        """Stop the server (clients are disconnected)."""
        try:
            self.server.stop()
        except Exception:  # noqa: BLE001 - stopping twice is harmless
            pass


#: Where the layout for the Foxglove app is kept (``python -m sm_ros.live --layout``).
LAYOUT_FILE = 'config/foxglove_layout.json'


def layout_json() -> str:
    """
    Return a Foxglove layout (JSON) for the live view and for recordings.

    A 3D panel (frame ``world``; ``/points`` coloured by the ``body`` field, poses, surfaces,
    colliders, contact arrows, a grid) beside a Plot panel of the solver's figures
    (``/diagnostics``: tick and step time, achieved rate). Import it in Foxglove with
    *Layouts -> Import from file*.
    """
    fl = _foxglove_layouts()
    scene = fl.BaseRendererSceneUpdateTopicSettings
    three_d = fl.ThreeDeePanel(title='sm_ros', config=fl.ThreeDeeConfig(
        fixed_frame='world', follow_tf='world',
        topics={
            '/points': fl.BaseRendererPointCloudTopicSettings(
                visible=True, point_size=3.0, color_mode='colormap', color_field='body',
                color_map='turbo'),
            '/poses': fl.BaseRendererPosesTopicSettings(visible=True, type='axis',
                                                        axis_scale=0.5),
            '/surfaces': scene(visible=True),
            '/colliders': scene(visible=True),
            '/contacts': scene(visible=True),
        },
        layers={'grid': fl.BaseRendererGridLayerSettings(visible=True, frame_id='world',
                                                         size=10.0, divisions=20)}))
    plot = fl.PlotPanel(title='solver', config=fl.PlotConfig(paths=[
        fl.PlotSeries(value='/diagnostics.tick_ms_mean', label='tick (ms)'),
        fl.PlotSeries(value='/diagnostics.step_ms_mean', label='step (ms)'),
        fl.PlotSeries(value='/diagnostics.rate_achieved_hz', label='rate (Hz)'),
    ]))
    layout = fl.Layout(content=fl.SplitContainer(direction='row', items=[
        fl.SplitItem(proportion=3, content=three_d), fl.SplitItem(proportion=1, content=plot)]))
    import json
    return json.dumps(json.loads(layout.to_json()), indent=1) + '\n'


def _foxglove_layouts():
    try:
        import foxglove.layouts as fl
    except ImportError as exc:  # pragma: no cover - depends on the install
        raise VizUnavailable('the layout needs foxglove-sdk: pip install -e .[viz]') from exc
    return fl


def main(argv=None) -> int:
    """``python -m sm_ros.live --layout [FILE]``: write the Foxglove layout."""
    import argparse
    import sys
    parser = argparse.ArgumentParser(prog='python -m sm_ros.live', description=layout_json.__doc__)
    parser.add_argument('--layout', nargs='?', const=LAYOUT_FILE, default=None, metavar='FILE',
                    help=f'write the layout to FILE (default {LAYOUT_FILE})')
    args = parser.parse_args(argv)
    if args.layout is None:
        sys.stdout.write(layout_json())
        return 0
    with open(args.layout, 'w', encoding='utf-8') as f:
        f.write(layout_json())
    print(f'wrote {args.layout}')
    return 0


def _quaternion_x_to(v: np.ndarray) -> Tuple[float, float, float, float]:
    """Return the shortest rotation (x, y, z, w) taking +x onto the direction of ``v``."""
    d = np.asarray(v, float) / float(np.linalg.norm(v))
    if d[0] < -0.999999:
        return (0.0, 0.0, 1.0, 0.0)
    q = np.array([0.0, -d[2], d[1], 1.0 + d[0]])      # half-way rotation about x cross d
    q /= np.linalg.norm(q)
    return tuple(float(c) for c in q)


if __name__ == '__main__':
    import sys
    sys.exit(main())
