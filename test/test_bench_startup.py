"""``python -m sm_ros.bench startup`` on something small: one warm start of sim_node on a
27-particle scene, timed to its first cloud (the figures are the benchmark's, not the
test's: it checks that a cloud was seen and the result written)."""

import json
import os
from pathlib import Path
import re
import subprocess
import sys

import pytest

pytest.importorskip('rclpy', reason='ROS 2 wheels not installed (pip install -e .[ros])')

ROOT = Path(__file__).resolve().parent.parent

SCENE = """
bodies:
  - name: cube
    shape: box
    size: [0.1, 0.1, 0.1]
    spacing: 0.05
    position: [0.0, 0.0, 0.5]
"""


@pytest.mark.slow
def test_startup_benchmark_times_a_warm_first_cloud(warm, tmp_path):
    scene = tmp_path / 'cube.yaml'
    scene.write_text(SCENE)
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(
        p for p in (str(ROOT), os.environ.get('PYTHONPATH')) if p))
    out = subprocess.run([sys.executable, '-m', 'sm_ros.bench', 'startup', '--warm-only',
                          '--runs', '1', '--timeout', '120', '--out', str(tmp_path / 'out'),
                          '--', '--ros-args', '-p', f'scene:={scene}'],
                         env=env, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stdout + out.stderr
    line = re.search(r'^warm: first cloud after [0-9.]+ s, first simulated cloud after '
                     r'([0-9.]+) s \(exit code 0; the node had used ([0-9.]+) CPU s\)$',
                     out.stdout, re.M)
    assert line, out.stdout
    result = json.loads((tmp_path / 'out' / 'startup.json').read_text())
    assert result['seconds']['warm'] == [pytest.approx(float(line.group(1)), abs=0.01)]
    assert 0.0 < result['seconds']['warm'][0] < 120.0
    assert result['seconds']['warm cpu'] == [pytest.approx(float(line.group(2)), abs=0.1)]
