"""
The Foxglove live view, checked from the outside with a plain WebSocket client.

The client speaks the Foxglove WebSocket protocol (subprotocol ``foxglove.sdk.v1``:
``advertise`` JSON, ``subscribe``, binary message frames) and decodes the protobuf
messages with Google's protobuf library from the schema the server advertises, so
nothing of sm_ros is used to decode what sm_ros sent.
"""

import base64
import json
import struct
import time

import numpy as np
import pytest

pytest.importorskip('foxglove', reason="the live view needs the 'viz' extra (foxglove-sdk)")
ws_client = pytest.importorskip('websockets.sync.client', reason='websockets is missing')
pytest.importorskip('google.protobuf', reason='protobuf decodes the messages in the test')

from sm_ros import live  # noqa: E402


class FoxgloveClient:
    """A minimal Foxglove WebSocket client: channels by topic, subscribe, receive."""

    def __init__(self, url, timeout=5.0):
        """Connect and read the server's advertisements."""
        self._conn = ws_client.connect(url, subprotocols=['foxglove.sdk.v1'], max_size=None,
                                       open_timeout=timeout)
        self.ws = self._conn.__enter__()
        self.channels = {}
        self.subs = {}
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline and '/points' not in self.channels:
            self._handle(self.ws.recv(timeout=timeout))

    def _handle(self, frame):
        if isinstance(frame, str):
            msg = json.loads(frame)
            if msg['op'] == 'advertise':
                for c in msg['channels']:
                    self.channels[c['topic']] = c
            return None
        opcode, sub_id, log_time = struct.unpack('<BIQ', frame[:13])
        assert opcode == 1
        return self.subs[sub_id], log_time, frame[13:]

    def subscribe(self, *topics):
        """Subscribe to ``topics``."""
        subs = []
        for t in topics:
            sub_id = len(self.subs) + 1
            self.subs[sub_id] = t
            subs.append({'id': sub_id, 'channelId': self.channels[t]['id']})
        self.ws.send(json.dumps({'op': 'subscribe', 'subscriptions': subs}))

    def receive(self, topic, timeout=5.0):
        """Return (log_time, payload) of the next message on ``topic``."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            got = self._handle(self.ws.recv(timeout=max(0.01, deadline - time.monotonic())))
            if got is not None and got[0] == topic:
                return got[1], got[2]
        raise TimeoutError(topic)

    def decoder(self, topic):
        """Return a protobuf message class built from the advertised schema of ``topic``."""
        from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
        c = self.channels[topic]
        assert c['encoding'] == 'protobuf' and c['schemaEncoding'] == 'protobuf'
        fds = descriptor_pb2.FileDescriptorSet.FromString(base64.b64decode(c['schema']))
        pool = descriptor_pool.DescriptorPool()
        for f in fds.file:
            pool.Add(f)
        return message_factory.GetMessageClass(pool.FindMessageTypeByName(c['schemaName']))

    def close(self):
        """Disconnect."""
        self._conn.__exit__(None, None, None)


def wait_until(cond, timeout=5.0):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if cond():
            return True
        time.sleep(0.01)
    return False


@pytest.fixture
def view():
    v = live.FoxgloveView(port=0)
    yield v
    v.close()


@pytest.fixture
def client(view):
    c = FoxgloveClient(view.url)
    yield c
    c.close()


def test_header_matches_the_sdk_encoding():
    """The hand-written protobuf header plus the raw bytes equals the SDK's own encoding."""
    from foxglove.messages import (PackedElementField, PackedElementFieldNumericType as T,
                                   PointCloud, Pose, Quaternion, Timestamp, Vector3)
    data = np.arange(48, dtype=np.uint8).tobytes()
    kinds = {5: T.Uint32, 7: T.Float32}
    for ns in (0, 7, 1_500_000_000, 3_000_000_007):
        sec, nsec = divmod(ns, 10 ** 9)
        sdk = PointCloud(timestamp=Timestamp(sec=sec, nsec=nsec), frame_id='world',
                         pose=Pose(position=Vector3(), orientation=Quaternion(w=1.0)),
                         point_stride=16, data=data,
                         fields=[PackedElementField(name=n, offset=o, type=kinds[t])
                                 for n, o, t in live.CLOUD_FIELDS]).encode()
        assert live.encode_point_cloud(data, ns, 'world') == sdk


def test_client_receives_the_published_cloud(view, client):
    pytest.importorskip('rclpy', reason='the PointCloud2 is built by sm_ros.cloud (rclpy)')
    from sm_ros.cloud import CloudBuffer, read_xyz, structured_view
    rng = np.random.default_rng(3)
    blocks = [rng.normal(size=(n, 3)) for n in (40, 25, 7)]
    msg = CloudBuffer('world').fill(blocks)
    assert not view.wants_cloud()
    client.subscribe('/points')
    assert wait_until(view.wants_cloud)
    assert view.log_cloud(msg.data, 2_000_000_123)
    log_time, payload = client.receive('/points')
    assert log_time == 2_000_000_123
    pc = client.decoder('/points').FromString(payload)
    assert (pc.timestamp.seconds, pc.timestamp.nanos) == (2, 123)
    assert pc.frame_id == 'world' and pc.point_stride == msg.point_step
    assert pc.fields[0].name == 'body'     # Foxglove colours by the first field
    layout = {f.name: f.offset for f in pc.fields}
    dtype = np.dtype({'names': ['x', 'y', 'z', 'body'],
                      'formats': ['<f4', '<f4', '<f4', '<u4'],
                      'offsets': [layout['x'], layout['y'], layout['z'], layout['body']],
                      'itemsize': pc.point_stride})
    pts = np.frombuffer(pc.data, dtype=dtype)
    np.testing.assert_array_equal(np.stack([pts['x'], pts['y'], pts['z']], axis=1),
                                  read_xyz(msg))
    np.testing.assert_array_equal(pts['body'], structured_view(msg)['body'])
    np.testing.assert_array_equal(np.bincount(pts['body']), [40, 25, 7])


def test_nothing_is_built_without_a_subscriber(view, monkeypatch):
    """No client: log_* return at once without encoding anything."""
    def boom(*a, **k):
        raise AssertionError('encoded without a subscriber')
    monkeypatch.setattr(live, 'encode_point_cloud', boom)
    assert not view.log_cloud(b'\0' * 32, 1)
    assert not view.log_poses(np.zeros((1, 3)), np.array([[0, 0, 0, 1.0]]), 1)
    assert not view.log_surfaces([('a', np.zeros((3, 3)))], 1)
    assert not view.log_diagnostics({'points': 1}, 1)
    assert not view.log_contacts(np.zeros((1, 3)), np.ones((1, 3)), 1)
    assert view.messages_logged == 0


def test_colliders_poses_contacts_and_diagnostics(view, client):
    from sm_ros.core import Box, Capsule, Ground, Sphere, World
    client.subscribe('/colliders', '/poses', '/contacts', '/diagnostics', '/surfaces')
    assert wait_until(lambda: view.colliders.has_sinks() and view.surfaces.has_sinks())
    world = World(gravity=(0.0, 0.0, -9.81))
    h = np.sqrt(0.5)
    world.set_colliders(ground=Ground(height=0.25),
                        boxes=[Box(lo=(1, 2, 3), hi=(2, 4, 7)),
                               Box(lo=(0, 0, 0), hi=(1, 1, 1), name='lid',
                                   orientation=(0, 0, h, h), kinematic=True)],
                        spheres=[Sphere(center=(0, 0, 1), radius=0.5)],
                        capsules=[Capsule(center=(0, 0, 2), radius=0.1, length=0.4,
                                          orientation=(h, 0, 0, h))])
    assert view.log_colliders(live.world_colliders(world), 10)
    assert not view.log_colliders(live.world_colliders(world), 11)   # unchanged: not again
    upd = client.decoder('/colliders').FromString(client.receive('/colliders')[1])
    ents = {e.id: e for e in upd.entities}
    assert set(ents) == {'collider/ground', 'collider/box0', 'collider/lid',
                         'collider/sphere0', 'collider/capsule0'}
    cube = ents['collider/box0'].cubes[0]
    assert (cube.pose.position.x, cube.pose.position.y, cube.pose.position.z) == (1.5, 3, 5)
    assert (cube.size.x, cube.size.y, cube.size.z) == (1, 2, 4)
    assert ents['collider/lid'].cubes[0].pose.orientation.z == pytest.approx(h)
    assert ents['collider/sphere0'].spheres[0].size.x == 1.0
    assert ents['collider/ground'].cubes[0].pose.position.z == pytest.approx(0.25, abs=1e-3)
    cap = ents['collider/capsule0']
    assert cap.cylinders[0].size.z == pytest.approx(0.4) and len(cap.spheres) == 2
    # turned 90 degrees about x: the capsule's axis is -y, its end caps at y = -+0.2
    assert sorted(round(sp.pose.position.y, 9) for sp in cap.spheres) == [-0.2, 0.2]
    world.move_collider('lid', (3.0, 0.0, 0.5))
    world.step(1.0 / 120.0)
    assert view.log_colliders(live.world_colliders(world), 12)       # it moved: sent again
    upd = client.decoder('/colliders').FromString(client.receive('/colliders')[1])
    lid = {e.id: e for e in upd.entities}['collider/lid'].cubes[0]
    assert (lid.pose.position.x, lid.pose.position.z) == (3.0, 0.5)

    q = np.array([[0.0, 0.0, np.sin(0.3), np.cos(0.3)]])
    assert view.log_poses(np.array([[1.0, 2.0, 3.0]]), q, 12)
    poses = client.decoder('/poses').FromString(client.receive('/poses')[1])
    assert poses.frame_id == 'world' and len(poses.poses) == 1
    assert poses.poses[0].orientation.z == pytest.approx(np.sin(0.3))

    assert view.log_contacts(np.array([[0.0, 0, 0]]), np.array([[0.0, 0, 50.0]]), 13)
    arrows = client.decoder('/contacts').FromString(client.receive('/contacts')[1])
    (arrow,) = arrows.entities[0].arrows
    assert arrow.shaft_length + arrow.head_length == pytest.approx(0.5)   # 50 N x 0.01 m/N
    o = arrow.pose.orientation    # +x turned onto +z
    rot_x = np.array([1 - 2 * (o.y ** 2 + o.z ** 2), 2 * (o.x * o.y + o.z * o.w),
                      2 * (o.x * o.z - o.y * o.w)])
    np.testing.assert_allclose(rot_x, [0, 0, 1], atol=1e-12)

    tri = np.arange(18, dtype=float).reshape(6, 3)
    assert view.log_surfaces([('cow', tri)], 14)
    surf = client.decoder('/surfaces').FromString(client.receive('/surfaces')[1])
    pts = surf.entities[0].triangles[0].points
    assert surf.entities[0].id == 'surface/cow' and len(pts) == 6 and pts[5].z == 17.0

    assert view.log_diagnostics({'points': '1000', 'mode': 'linear', 'step_ms_mean': 0.5}, 15)
    data = json.loads(client.receive('/diagnostics')[1])
    assert data == {'points': 1000.0, 'mode': 'linear', 'step_ms_mean': 0.5, 'stamp': 15 / 1e9}


def test_busy_port_is_a_clear_error(view):
    with pytest.raises(OSError, match=f'Foxglove server on 127.0.0.1:{view.port}'):
        live.FoxgloveView(port=view.port)


def test_layout_file_is_current_and_names_the_channels(view):
    import json
    from pathlib import Path
    path = Path(__file__).resolve().parent.parent / live.LAYOUT_FILE
    assert path.read_text() == live.layout_json(), \
        'config/foxglove_layout.json is stale: python -m sm_ros.live --layout'
    data = json.loads(path.read_text())
    three_d, plot = (item['content'] for item in data['content']['items'])
    channels = {c.topic() for c in (view.points, view.poses, view.surfaces, view.colliders,
                                    view.contacts)}
    assert set(three_d['config']['topics']) == channels
    points = three_d['config']['topics']['/points']
    assert (points['colorMode'], points['colorField']) == ('colormap', 'body')
    assert three_d['config']['fixedFrame'] == 'world'
    from sm_ros.diagnostics import KEYS
    for series in plot['config']['paths']:
        topic, _, key = series['value'].partition('.')
        assert topic == view.diagnostics.topic() and key in KEYS
