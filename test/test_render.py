"""The headless render command: GIF and PNG strip, small files, clear errors."""

import os
import subprocess
import sys

import numpy as np
import pytest

pytest.importorskip('matplotlib')
Image = pytest.importorskip('PIL.Image')

from sm_ros import render  # noqa: E402


def test_gif_frames_and_size(tmp_path):
    out = tmp_path / 'run.gif'
    figures = render.render('rope', str(out), seconds=0.5, fps=10)
    assert out.is_file() and figures['bytes'] == out.stat().st_size
    assert out.stat().st_size < 300 * 1024
    with Image.open(out) as im:
        assert im.format == 'GIF' and im.size == (400, 300)
        assert im.n_frames == 6
    assert figures['points'] == 76 and figures['bodies'] == 1


def test_png_strip(tmp_path):
    out = tmp_path / 'strip.png'
    render.render('mesh', str(out), seconds=0.4, fps=10, params={'alpha': 0.9},
                  view=render.View(panels=3))
    with Image.open(out) as im:
        assert im.format == 'PNG' and im.size == (720, 220)


def test_simulate_records_frames_and_surfaces():
    rec = render.simulate('mesh', seconds=0.2, fps=10, max_draw=500)
    assert len(rec.frames) == 3 and rec.times[-1] == pytest.approx(0.2)
    assert sum(len(p) for p in rec.frames[0]) <= 500 + len(rec.frames[0])
    assert all(s is not None for s in rec.surfaces[-1])


def test_cli_errors(tmp_path, capsys):
    assert render.main(['default', '--out', str(tmp_path / 'x.jpg')]) == 2
    assert 'gif or .png' in capsys.readouterr().err
    assert render.main(['no_such_scene', '--out', str(tmp_path / 'x.gif')]) == 2
    assert 'bundled' in capsys.readouterr().err
    with pytest.raises(SystemExit):
        render.main(['default', '--set', 'speed=3'])


def test_module_runs_headless(tmp_path):
    out = tmp_path / 'cli.png'
    env = {k: v for k, v in os.environ.items() if k not in ('DISPLAY', 'MPLBACKEND')}
    res = subprocess.run([sys.executable, '-m', 'sm_ros.render', 'rope', '--seconds', '0.2',
                          '--out', str(out), '--set', 'mode=quadratic'],
                         capture_output=True, text=True, env=env, timeout=300)
    assert res.returncode == 0, res.stderr
    assert out.is_file() and 'points in 1 bodies' in res.stdout


def test_gif_from_a_recording(tmp_path):
    """A recorded run (rosbag2 MCAP) is drawn from its clouds: frames at --fps of the stamps."""
    pytest.importorskip('mcap_ros2', reason="reading recordings needs the 'record' extra")
    pytest.importorskip('rclpy', reason='the test serialises clouds with rclpy')
    from rclpy.serialization import serialize_message
    from sm_ros.cloud import CloudBuffer
    from sm_ros.record import BagRecorder
    buf = CloudBuffer('world')
    bag = tmp_path / 'run'
    with BagRecorder(bag, split_s=0.2) as rec:      # three files, read in order
        for i in range(31):        # 60 Hz for 0.5 s: a box falling, a sphere at rest
            t = i / 60.0
            box = np.stack(np.meshgrid(*[np.linspace(0, 0.1, 5)] * 3), -1).reshape(-1, 3)
            box[:, 2] += 1.0 - 4.9 * t * t
            rec.write('/points', 'sensor_msgs/msg/PointCloud2',
                      serialize_message(buf.fill([box, np.zeros((10, 3))])),
                      1_000_000_000 + round(t * 1e9))
    assert len(list(bag.glob('*.mcap'))) == 3
    out = tmp_path / 'rec.gif'
    assert render.main([str(bag), '--out', str(out), '--fps', '10']) == 0
    from PIL import Image
    with Image.open(out) as im:
        assert im.n_frames == 6          # t = 0, 0.1, ..., 0.5 s
    loaded = render.load_recording(str(bag), fps=10.0, max_draw=50)
    assert [round(t, 3) for t in loaded.times] == [0.0, 0.1, 0.2, 0.3, 0.4, 0.5]
    assert [len(b) for b in loaded.frames[0]] == [46, 4]     # shared fairly: 125 + 10 -> 50
    top = max(loaded.frames[3][0][:, 2])
    assert top == pytest.approx(1.1 - 4.9 * 0.3 ** 2, abs=1e-6)
    assert render.main([str(bag), '--out', str(out), '--topic', '/none']) == 2
