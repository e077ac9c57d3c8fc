"""
Recordings: rosbag2 folders with MCAP storage, checked with an independent reader.

The messages are serialised by rclpy (as the node does), written by ``sm_ros.record`` and
read back with ``rosbags`` (its own MCAP reader and CDR decoder) and with
``mcap_ros2``'s decoder (which uses the message definitions stored in the file).
"""

import os
from pathlib import Path
import signal
import subprocess
import sys
import textwrap
import threading
import time

import numpy as np
import pytest
import yaml

pytest.importorskip('mcap', reason="recording needs the 'record' extra (mcap)")
rosbags = pytest.importorskip('rosbags', reason="the independent reader 'rosbags' is missing")
pytest.importorskip('rclpy', reason='messages are serialised with rclpy')

from rclpy.serialization import serialize_message  # noqa: E402
from sm_ros import record  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent


def _typestore():
    from rosbags.typesys import get_typestore, Stores
    return get_typestore(Stores.ROS2_JAZZY)


def read_with_rosbags(bag):
    """Return [(topic, msgtype, timestamp, message)] read by rosbags."""
    from rosbags.rosbag2 import Reader
    store = _typestore()
    out = []
    with Reader(bag) as reader:
        for conn, stamp, raw in reader.messages():
            out.append((conn.topic, conn.msgtype, stamp,
                        store.deserialize_cdr(raw, conn.msgtype)))
    return out


def sample_messages(n_points=500, bodies=3, seed=0):
    """Return (cloud, poses, diagnostics) messages like the node publishes."""
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
    from geometry_msgs.msg import Pose, PoseArray
    from sm_ros.cloud import CloudBuffer
    rng = np.random.default_rng(seed)
    blocks = [rng.normal(size=(n_points // bodies, 3)) for _ in range(bodies)]
    cloud = CloudBuffer('world').fill(blocks)
    cloud.header.stamp.sec, cloud.header.stamp.nanosec = 12, 345
    poses = PoseArray()
    poses.header.frame_id = 'world'
    for b in blocks:
        p = Pose()
        p.position.x, p.position.y, p.position.z = (float(v) for v in b.mean(axis=0))
        p.orientation.w = 1.0
        poses.poses.append(p)
    diag = DiagnosticArray(status=[DiagnosticStatus(
        name='sim_node: solver', level=DiagnosticStatus.OK, message='running',
        values=[KeyValue(key='points', value=str(n_points)),
                KeyValue(key='step_ms_mean', value='0.25')])])
    return cloud, poses, diag, np.concatenate(blocks).astype(np.float32)


def test_message_definition_has_every_nested_type_once():
    text = record.message_definition('sensor_msgs/msg/PointCloud2')
    names = [line[5:] for line in text.splitlines() if line.startswith('MSG: ')]
    assert names == ['std_msgs/Header', 'builtin_interfaces/Time', 'sensor_msgs/PointField']
    assert text.startswith('# This message holds a collection of N-dimensional points')
    with pytest.raises(FileNotFoundError, match='no sensor_msgs/msg/NoSuch.msg'):
        record.message_definition('sensor_msgs/msg/NoSuch')
    with pytest.raises(ValueError, match="'pkg/msg/Type'"):
        record.message_definition('PointCloud2')


def test_recording_reads_back_equal_with_rosbags(tmp_path):
    cloud, poses, diag, xyz = sample_messages()
    bag = tmp_path / 'run'
    stamps = [1_000_000_000 + 16_666_667 * i for i in range(5)]
    with record.BagRecorder(bag) as rec:
        for t in stamps:
            rec.write('/points', 'sensor_msgs/msg/PointCloud2', serialize_message(cloud), t)
            rec.write('/poses', 'geometry_msgs/msg/PoseArray', serialize_message(poses), t)
        rec.write('/diagnostics', 'diagnostic_msgs/msg/DiagnosticArray',
                  serialize_message(diag), stamps[-1])
    assert rec.dropped == 0 and rec.error is None
    assert sorted(p.name for p in bag.iterdir()) == ['metadata.yaml', 'run_0.mcap']
    info = yaml.safe_load((bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert info['storage_identifier'] == 'mcap' and info['message_count'] == 11
    assert info['starting_time']['nanoseconds_since_epoch'] == stamps[0]
    assert info['duration']['nanoseconds'] == stamps[-1] - stamps[0]
    counts = {t['topic_metadata']['name']: t['message_count']
              for t in info['topics_with_message_count']}
    assert counts == {'/points': 5, '/poses': 5, '/diagnostics': 1}

    msgs = read_with_rosbags(bag)
    assert len(msgs) == 11
    clouds = [m for m in msgs if m[0] == '/points']
    assert [m[2] for m in clouds] == stamps
    for _, msgtype, _, m in clouds:
        assert msgtype == 'sensor_msgs/msg/PointCloud2'
        assert (m.width, m.point_step, m.header.frame_id) == (cloud.width, 16, 'world')
        assert [f.name for f in m.fields] == ['x', 'y', 'z', 'body']
        got = np.frombuffer(m.data.tobytes(), dtype=np.float32).reshape(-1, 4)[:, :3]
        np.testing.assert_array_equal(got, xyz)
        body = np.frombuffer(m.data.tobytes(), dtype=np.uint32).reshape(-1, 4)[:, 3]
        np.testing.assert_array_equal(np.bincount(body), [166, 166, 166])
    pose_msgs = [m[3] for m in msgs if m[0] == '/poses']
    assert [p.position.x for p in pose_msgs[0].poses] == [p.position.x for p in poses.poses]
    (d,) = [m[3] for m in msgs if m[0] == '/diagnostics']
    assert [(kv.key, kv.value) for kv in d.status[0].values] == [('points', '500'),
                                                                  ('step_ms_mean', '0.25')]


def test_schemas_in_the_file_decode_with_mcap_ros2(tmp_path):
    """The ros2msg definitions written into the file are complete (mcap_ros2 uses them)."""
    pytest.importorskip('mcap_ros2', reason="the 'record' extra's mcap-ros2-support")
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
    cloud, poses, diag, xyz = sample_messages(n_points=30)
    bag = tmp_path / 'b'
    with record.BagRecorder(bag, compression='zstd') as rec:
        rec.write('/points', 'sensor_msgs/msg/PointCloud2', serialize_message(cloud), 5)
        rec.write('/diagnostics', 'diagnostic_msgs/msg/DiagnosticArray',
                  serialize_message(diag), 6)
    with open(record.mcap_path(bag), 'rb') as f:
        decoded = list(make_reader(f, decoder_factories=[DecoderFactory()])
                       .iter_decoded_messages())
    assert [c.topic for _, c, _, _ in decoded] == ['/points', '/diagnostics']
    m = decoded[0][3]
    got = np.frombuffer(bytes(m.data), dtype=np.float32).reshape(-1, 4)[:, :3]
    np.testing.assert_array_equal(got, xyz)
    assert decoded[1][3].status[0].values[1].value == '0.25'


def test_full_queue_drops_and_counts_without_blocking(tmp_path):
    """While the disk is stuck, write() returns at once and counts what it dropped."""
    cloud, _, _, _ = sample_messages(n_points=30)
    data = serialize_message(cloud)
    rec = record.BagRecorder(tmp_path / 'q', max_queue=2)
    gate = threading.Event()
    real_add = rec._writer.add_message

    def stuck(*args, **kwargs):
        gate.wait(10.0)
        return real_add(*args, **kwargs)

    rec._writer.add_message = stuck
    assert rec.write('/points', 'sensor_msgs/msg/PointCloud2', data, 1)
    deadline = time.monotonic() + 5.0
    while rec.queued and time.monotonic() < deadline:   # the thread holds message 1
        time.sleep(0.005)
    t0 = time.perf_counter()
    accepted = [rec.write('/points', 'sensor_msgs/msg/PointCloud2', data, t)
                for t in range(2, 12)]
    elapsed = time.perf_counter() - t0
    assert accepted == [True, True] + [False] * 8
    assert rec.dropped == 8
    assert elapsed < 1.0   # a stuck disk never holds a tick (the gate holds 10 s)
    gate.set()
    rec.close()
    msgs = read_with_rosbags(tmp_path / 'q')
    assert [m[2] for m in msgs] == [1, 2, 3]


def test_refuses_to_overwrite(tmp_path):
    (tmp_path / 'x').mkdir()
    with pytest.raises(FileExistsError, match='never overwritten'):
        record.BagRecorder(tmp_path / 'x')


CHILD = textwrap.dedent('''
    import sys, time
    from rclpy.serialization import serialize_message
    from std_msgs.msg import String
    from sm_ros.record import BagRecorder
    rec = BagRecorder(sys.argv[1], flush_s=0.05, chunk_bytes=256, split_s=1.0)
    i = 0
    while True:
        rec.write('/chatter', 'std_msgs/msg/String', serialize_message(String(data=f'm{i}')),
                  10**9 + i * 10**7)
        i += 1
        time.sleep(0.002)
''')


def read_with_mcap(path):
    """The message count in the summary of a finished MCAP file (the indexed reader)."""
    from mcap.reader import make_reader
    with open(path, 'rb') as f:
        stats = make_reader(f).get_summary().statistics
    return stats.message_count


def test_killed_recorder_leaves_every_finished_file_readable_without_repair(tmp_path):
    """SIGKILL mid-recording (log time 10 ms a message, a file a second): rosbags and the
    mcap indexed reader open every file metadata.yaml lists as it is, and those hold the
    first messages in order; the streaming reader reads on into the cut file, and repair
    finishes that one too."""
    bag = tmp_path / 'killed'
    env = dict(os.environ, PYTHONPATH=f"{ROOT}{os.pathsep}{os.environ.get('PYTHONPATH', '')}")
    proc = subprocess.Popen([sys.executable, '-c', CHILD, str(bag)], env=env)
    try:
        deadline = time.monotonic() + 60.0
        listed, flushed = [], 0
        while time.monotonic() < deadline and (len(listed) < 2 or flushed < 10):
            time.sleep(0.05)
            try:
                meta = yaml.safe_load((bag / 'metadata.yaml').read_text())
                listed = meta['rosbag2_bagfile_information']['relative_file_paths']
                custom = meta['rosbag2_bagfile_information']['custom_data']
                flushed = int(custom['open_file_messages']) if len(listed) >= 2 else 0
            except (OSError, TypeError, KeyError, ValueError):
                pass
        assert len(listed) >= 2 and flushed >= 10, 'the recorder never finished a file'
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait(10)
    info = yaml.safe_load((bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    listed = info['relative_file_paths']
    assert listed == [f'killed_{i}.mcap' for i in range(len(listed))]
    assert [f['message_count'] for f in info['files']] == [100] * len(listed)
    assert info['message_count'] == 100 * len(listed)
    cut = bag / f'killed_{len(listed)}.mcap'         # the open file, if the kill let it be
    assert set(bag.glob('*.mcap')) - {bag / name for name in listed} <= {cut}
    msgs = read_with_rosbags(bag)                                # no repair
    assert [m[3].data for m in msgs] == [f'm{i}' for i in range(100 * len(listed))]
    assert [m[2] for m in msgs] == [10**9 + i * 10**7 for i in range(len(msgs))]
    assert [read_with_mcap(bag / name) for name in listed] == [100] * len(listed)
    raw = list(record.iter_raw(bag))
    assert len(raw) >= len(msgs)
    from std_msgs.msg import String
    from rclpy.serialization import deserialize_message
    assert [deserialize_message(d, String).data for _, _, _, d in raw] == \
        [f'm{i}' for i in range(len(raw))]
    meta = record.repair(bag)['rosbag2_bagfile_information']
    assert meta['message_count'] == len(raw)
    assert len(meta['relative_file_paths']) == len(listed) + cut.exists()
    assert [m[3].data for m in read_with_rosbags(bag)] == [f'm{i}' for i in range(len(raw))]


def test_files_split_by_log_time(tmp_path):
    """split_s of log time per file, each file's messages and span in metadata.yaml;
    split_s=0: one file; a negative split_s is refused before anything is created."""
    from std_msgs.msg import String
    data = serialize_message(String(data='x'))
    bag = tmp_path / 's'
    with record.BagRecorder(bag, split_s=2.0) as rec:
        for i in range(7):                 # log times 0, 1, ..., 6 s
            rec.write('/a', 'std_msgs/msg/String', data, i * 10**9)
    info = yaml.safe_load((bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert info['relative_file_paths'] == ['s_0.mcap', 's_1.mcap', 's_2.mcap', 's_3.mcap']
    assert [f['message_count'] for f in info['files']] == [2, 2, 2, 1]
    assert [f['starting_time']['nanoseconds_since_epoch'] for f in info['files']] == \
        [0, 2 * 10**9, 4 * 10**9, 6 * 10**9]
    assert [f['duration']['nanoseconds'] for f in info['files']] == [10**9] * 3 + [0]
    assert info['message_count'] == 7 and info['duration']['nanoseconds'] == 6 * 10**9
    assert sorted(p.name for p in bag.glob('*.mcap')) == info['relative_file_paths']
    assert len(read_with_rosbags(bag)) == 7
    one = tmp_path / 'one'
    with record.BagRecorder(one, split_s=0.0) as rec:
        for i in range(7):
            rec.write('/a', 'std_msgs/msg/String', data, i * 10**9)
    info = yaml.safe_load((one / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert info['relative_file_paths'] == ['one_0.mcap'] and info['message_count'] == 7
    with pytest.raises(ValueError, match='split_s'):
        record.BagRecorder(tmp_path / 'neg', split_s=-1.0)
    assert not (tmp_path / 'neg').exists()


def test_cli_info_and_repair(tmp_path, capsys):
    from std_msgs.msg import String
    bag = tmp_path / 'c'
    with record.BagRecorder(bag) as rec:
        for i in range(3):
            rec.write('/chatter', 'std_msgs/msg/String', serialize_message(String(data='a')),
                      i * 500_000_000)
    assert record.main(['info', str(bag)]) == 0
    out = capsys.readouterr().out
    assert '3 messages over 1.000 s' in out and 'std_msgs/msg/String' in out
    assert record.main(['repair', str(bag)]) == 0
    assert len(read_with_rosbags(bag)) == 3
    assert record.main(['info', str(tmp_path / 'none')]) == 2
