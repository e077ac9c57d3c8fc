"""
Check sim_node as a process.

Exit code 2 and one line for a bad scene or parameter file, a clean Ctrl-C (no
traceback), and the first cloud seen by another process.
"""

import contextlib
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from conftest import spare_domain

pytest.importorskip('rclpy', reason='ROS 2 wheels not installed (pip install -e .[ros])')

SIM_NODE = os.path.join(os.path.dirname(sys.executable), 'sim_node')


def sim_node_cmd(*args):
    """Return the command: the console script when installed, else the module."""
    if os.path.exists(SIM_NODE):
        return [SIM_NODE, *args]
    return [sys.executable, '-m', 'sm_ros.node', *args]


def run_fail(*args, timeout=120):
    """Run sim_node expecting it to stop by itself; return (code, stderr lines)."""
    env = dict(os.environ, ROS_DOMAIN_ID=str(spare_domain()))
    proc = subprocess.run(sim_node_cmd(*args), env=env, capture_output=True, text=True,
                          timeout=timeout)
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    return proc.returncode, lines


@pytest.mark.parametrize('make_args, expected', [
    (lambda tmp: ['--ros-args', '--params-file', str(tmp / 'missing.yaml')], 'no such file'),
    (lambda tmp: ['--ros-args', '--params-file', _write(tmp / 'bad.yaml', 'a: [\n')],
     'invalid YAML'),
    (lambda tmp: ['--ros-args', '-p', f'scene:={tmp / "nope.yaml"}'], 'no such scene'),
    (lambda tmp: ['--ros-args', '-p', 'scene:=' + _write(
        tmp / 's.yaml', 'bodies:\n  - {name: sponge, shape: box, spacing: -1}\n')],
     "body 'sponge'"),
    (lambda tmp: ['--ros-args', '-p', 'alpha:=3.0'], 'alpha'),
    (lambda tmp: ['--ros-args', '-p', 'mode:=cubic'], 'mode'),
    (lambda tmp: ['--ros-args', '--params-file', _write(
        tmp / 'p.yaml', 'sim_node:\n  ros__parameters:\n    rate: "fast"\n')], 'rate'),
], ids=['missing params file', 'invalid params file', 'missing scene', 'invalid scene',
        'alpha out of range', 'unknown mode', 'wrong type in params file'])
def test_bad_configuration_exits_2_with_one_line(tmp_path, make_args, expected):
    code, lines = run_fail(*make_args(tmp_path))
    errors = [ln for ln in lines if ln.startswith('sim_node: error:')]
    assert code == 2, lines
    assert len(errors) == 1 and expected in errors[0], lines
    assert not any('Traceback' in ln for ln in lines)


def _write(path, text):
    path.write_text(text)
    return str(path)


@contextlib.contextmanager
def _cloud_probe(domain):
    """A subscriber to /points in a context of its own on ``domain``: yields the executor
    to spin and the list the clouds arrive in; shut down on leaving."""
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from sensor_msgs.msg import PointCloud2
    ctx = Context()
    rclpy.init(context=ctx, domain_id=domain)
    node = Node('probe', context=ctx)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(node)
    got = []
    node.create_subscription(PointCloud2, '/points', got.append, 10)
    try:
        yield ex, got
    finally:
        ex.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=ctx)


def _reap(proc):
    """Kill ``proc`` if it still runs, and collect it."""
    if proc.poll() is None:
        proc.kill()
        proc.communicate()


def test_first_cloud_then_clean_ctrl_c(warm, tmp_path):
    domain = spare_domain()
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    with _cloud_probe(domain) as (ex, got):
        proc = subprocess.Popen(sim_node_cmd('--ros-args', '-p', 'rate:=30.0'), env=env,
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            deadline = time.monotonic() + 120
            while not got and time.monotonic() < deadline and proc.poll() is None:
                ex.spin_once(timeout_sec=0.05)
            assert got, 'no cloud from sim_node'
            assert got[0].width > 100 and got[0].header.frame_id == 'world'
            proc.send_signal(signal.SIGINT)
            out, err = proc.communicate(timeout=30)
        finally:
            _reap(proc)
    assert proc.returncode == 0, err
    assert 'Traceback' not in err and 'Traceback' not in out


@pytest.mark.parametrize('delay, cold', [(4.0, True), (2.5, False)], ids=['cold', 'warm'])
def test_ctrl_c_during_start_up_is_clean(tmp_path, delay, cold):
    # cold: an empty Numba cache makes the warm-up last far longer than the delay, so the
    # signal lands in it; warm: somewhere in scene building, warm-up or the first ticks.
    # (Ctrl-C in the first fraction of a second, while Python imports rclpy, prints a
    # KeyboardInterrupt traceback like any rclpy node.)
    env = dict(os.environ, ROS_DOMAIN_ID=str(spare_domain()))
    if cold:
        env['NUMBA_CACHE_DIR'] = str(tmp_path)
    proc = subprocess.Popen(sim_node_cmd(), env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        proc.wait(timeout=delay)
    except subprocess.TimeoutExpired:
        proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 0, err
    assert 'Traceback' not in err + out


def test_only_the_echoes_of_a_start_up_ctrl_c_are_kept_quiet():
    from types import SimpleNamespace
    from llvmlite.binding import ffi
    from sm_ros.startup import interrupt_noise
    ctypes_drop = SimpleNamespace(exc_value=KeyboardInterrupt(), object=None)
    half_built = SimpleNamespace(exc_value=AttributeError('_as_parameter_'),
                                 object=ffi.ObjectRef.__del__)
    ours = SimpleNamespace(exc_value=AttributeError('x'), object=interrupt_noise)
    assert interrupt_noise(ctypes_drop, False)
    assert interrupt_noise(half_built, True)        # llvmlite's __del__ after a Ctrl-C
    assert not interrupt_noise(half_built, False)   # without one: reported
    assert not interrupt_noise(ours, True)          # anything else: reported


def test_an_interrupted_warm_up_stops_its_helper_processes(monkeypatch):
    from sm_ros import warmup
    procs = []

    def start(args, env_extra=None):
        import tempfile
        p = subprocess.Popen([sys.executable, '-c', 'import time; time.sleep(60)'])
        procs.append(p)
        return p, tempfile.TemporaryFile()

    def interrupted(*_):
        raise KeyboardInterrupt

    monkeypatch.setattr(warmup, '_spawn', start)
    monkeypatch.setattr(warmup, 'cold_kernels', lambda: 5)
    monkeypatch.setattr(warmup, '_cpus', lambda: 2)
    monkeypatch.setattr(warmup, '_warm_up', interrupted)
    with pytest.raises(KeyboardInterrupt):
        warmup.warm_up()
    assert len(procs) == 2 and all(p.poll() is not None for p in procs)   # killed, reaped


def test_the_start_up_watchdog_stops_running_warm_up_helpers(monkeypatch):
    """A Ctrl-C while the node starts ends the process from ``startup.run``'s watchdog,
    without unwinding the warm-up; ``warmup.stop_helpers`` (what the watchdog calls
    first) kills and reaps the warm-up helper processes that are running, and a finished
    warm-up leaves none behind."""
    from sm_ros import warmup
    procs = []

    def start(args, env_extra=None):
        import tempfile
        p = subprocess.Popen([sys.executable, '-c', 'import time; time.sleep(60)'])
        procs.append(p)
        return p, tempfile.TemporaryFile()

    def body(on_stage, helpers, t0):
        assert warmup._HELPERS == list(helpers) and len(helpers) == 2
        assert all(p.poll() is None for p in procs)
        warmup.stop_helpers()                 # the watchdog, on a Ctrl-C
        assert all(p.poll() is not None for p in procs)    # killed and reaped
        return 0.0

    monkeypatch.setattr(warmup, '_spawn', start)
    monkeypatch.setattr(warmup, 'cold_kernels', lambda: 5)
    monkeypatch.setattr(warmup, '_cpus', lambda: 2)
    monkeypatch.setattr(warmup, '_warm_up', body)
    assert warmup.warm_up() >= 0.0
    assert len(procs) == 2 and warmup._HELPERS == []


BIG_SCENE = """
bodies:
  - name: slab
    shape: box
    size: [0.975, 0.975, 0.85]     # 40 x 40 x 35 = 56,000 particles: a 896 KB cloud
    spacing: 0.025
    mass: 2.0
    position: [0.0, 0.0, 0.5]
"""


def _shm_segments(pid):
    """Sizes of the Fast DDS shared-memory segments mapped by process ``pid``."""
    sizes = {}
    with open(f'/proc/{pid}/maps') as f:
        for line in f:
            path = line.split()[-1]
            if path.startswith('/dev/shm/fastrtps_') and not path.endswith('_el'):
                sizes[path] = os.stat(path).st_size
    return sorted(sizes.values())


@pytest.mark.slow
@pytest.mark.skipif(not os.path.isdir('/dev/shm'), reason='Fast DDS shared memory needs '
                    '/dev/shm (Linux)')
def test_a_large_cloud_goes_out_over_the_packaged_profile_to_a_plain_subscriber(warm,
                                                                                tmp_path):
    """With no DDS profile chosen, sim_node's participant takes config/fastdds_shm.xml (its
    256 MiB shared-memory segment, mapped by the node) and says so; a subscriber in this
    process, which sets nothing, receives the 56,000-point (896 KB) cloud whole."""
    scene = _write(tmp_path / 'big.yaml', BIG_SCENE)
    domain = spare_domain()
    env = {k: v for k, v in os.environ.items()
           if k not in ('FASTRTPS_DEFAULT_PROFILES_FILE', 'FASTDDS_DEFAULT_PROFILES_FILE',
                        'FASTDDS_BUILTIN_TRANSPORTS')}
    env.update(ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    with _cloud_probe(domain) as (ex, got):
        proc = subprocess.Popen(sim_node_cmd('--ros-args', '-p', f'scene:={scene}', '-p',
                                             'rate:=10.0'), env=env, cwd=tmp_path,
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            deadline = time.monotonic() + 180
            while len(got) < 3 and time.monotonic() < deadline and proc.poll() is None:
                ex.spin_once(timeout_sec=0.05)
            segments = _shm_segments(proc.pid) if proc.poll() is None else []
            proc.send_signal(signal.SIGINT)
            out, err = proc.communicate(timeout=30)
        finally:
            _reap(proc)
    assert got, f'no cloud from sim_node: {err[-2000:]}'
    assert got[-1].width * got[-1].height == 56_000
    assert len(got[-1].data) == 56_000 * got[-1].point_step > 512 * 1024
    assert segments and segments[-1] >= 64 * 1024 * 1024, segments     # the packaged one
    assert 'DDS: the packaged Fast DDS profile' in out + err
    assert 'fastdds_shm.xml' in out + err


def test_the_packaged_profile_never_overrides_a_users_choice(tmp_path, monkeypatch):
    """A profile variable, a transport choice, a default profile file in the working
    directory or another RMW: the environment is left as it is."""
    from sm_ros.startup import packaged_dds_profile, use_packaged_dds_profile
    monkeypatch.chdir(tmp_path)
    path = packaged_dds_profile()
    assert path is not None and path.endswith('fastdds_shm.xml') and os.path.isfile(path)
    env = {}
    assert use_packaged_dds_profile(env) == path
    assert env == {'FASTRTPS_DEFAULT_PROFILES_FILE': path}
    env = {'RMW_IMPLEMENTATION': 'rmw_fastrtps_cpp'}
    assert use_packaged_dds_profile(env) == path
    for chosen in ({'FASTRTPS_DEFAULT_PROFILES_FILE': '/mine.xml'},
                   {'FASTDDS_DEFAULT_PROFILES_FILE': '/mine.xml'},
                   {'FASTDDS_BUILTIN_TRANSPORTS': 'UDPv4'},
                   {'RMW_IMPLEMENTATION': 'rmw_cyclonedds_cpp'}):
        env = dict(chosen)
        assert use_packaged_dds_profile(env) is None
        assert env == chosen
    (tmp_path / 'DEFAULT_FASTRTPS_PROFILES.xml').write_text('<profiles/>')
    env = {}
    assert use_packaged_dds_profile(env) is None and env == {}


@pytest.mark.slow
def test_node_killed_mid_recording_leaves_files_every_reader_opens_unrepaired(warm, tmp_path):
    """SIGKILL sim_node while it records (record.split_s 1 s): rosbags reads the files
    metadata.yaml lists as they are, every tick's cloud once and in order, and the mcap
    reader finds each file's summary; only the file open at the kill is left out."""
    pytest.importorskip('mcap', reason="recording needs the 'record' extra")
    pytest.importorskip('rosbags', reason='the recording is read with rosbags')
    import yaml
    from mcap.reader import make_reader
    from test_node_outputs import NODE_SCENE, rosbags_messages
    scene = _write(tmp_path / 'box.yaml', NODE_SCENE)
    bag = tmp_path / 'killed'
    env = dict(os.environ, ROS_DOMAIN_ID=str(spare_domain()))
    proc = subprocess.Popen(sim_node_cmd('--ros-args', '-p', f'scene:={scene}', '-p',
                                         f'record.path:={bag}', '-p', 'record.split_s:=1.0'),
                            env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        deadline = time.monotonic() + 90.0
        listed = []
        while time.monotonic() < deadline and len(listed) < 3:
            time.sleep(0.1)
            assert proc.poll() is None, proc.stderr.read().decode()
            try:
                info = yaml.safe_load((bag / 'metadata.yaml').read_text())
                listed = info['rosbag2_bagfile_information']['relative_file_paths']
            except (OSError, TypeError, KeyError):
                pass
        assert len(listed) >= 3, 'the node finished no recording file'
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait(10)
    info = yaml.safe_load((bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    # the file open at the kill is not listed (nor made, if the kill fell between two files)
    assert len(list(bag.glob('*.mcap'))) - len(info['relative_file_paths']) in (0, 1)
    msgs = rosbags_messages(bag)
    assert len(msgs) == info['message_count']
    clouds = [m for t, _, m in msgs if t == '/points']
    assert len(clouds) >= 60 and all(c.width == 216 for c in clouds)
    stamps = [c.header.stamp.sec * 10 ** 9 + c.header.stamp.nanosec for c in clouds]
    assert stamps == sorted(stamps) and len(set(np.diff(stamps))) == 1   # every tick, once
    for entry in info['files']:
        with open(bag / entry['path'], 'rb') as f:
            summary = make_reader(f).get_summary()
        assert summary.statistics.message_count == entry['message_count'] > 0


def test_a_scene_switch_on_a_cold_cache_says_it_compiles_and_how_long_it_took(
        ros, monkeypatch, tmp_path):
    """While the cache is not warm yet, switching scenes logs that the new scene's kernels
    compile, then how long the scene took to build; on a warm cache only the second."""
    from rcl_interfaces.msg import Log
    from rclpy.parameter import Parameter
    from sm_ros import warmup
    node = ros.start(_write(tmp_path / 'a.yaml', BIG_SCENE.replace('0.975, 0.975, 0.85',
                                                                   '0.1, 0.1, 0.1')))
    logs = ros.subscribe(Log, '/rosout')
    for cold, name in ((5, 'b'), (0, 'c')):
        monkeypatch.setattr(warmup, 'cold_kernels', lambda answer=cold: answer)
        path = _write(tmp_path / f'{name}.yaml', BIG_SCENE.replace('0.975, 0.975, 0.85',
                                                                   '0.2, 0.1, 0.1'))
        assert node.set_parameters([Parameter('scene', value=path)])[0].successful
        assert ros.spin_until(lambda p=path: any(f"scene '{p}' built in" in m.msg
                                                 for m in logs))
        compiling = [m.msg for m in logs if f"scene '{path}': compiling the kernels it needs"
                     in m.msg]
        assert len(compiling) == (1 if cold else 0)


def test_the_scene_at_rest_is_published_while_the_solver_compiles(ros, monkeypatch, tmp_path):
    """On a cold cache the node publishes its scene's particles at rest (stamp 0) on
    ``points`` while the simulation is built (here a build held 1.5 s, as a compile), then
    removes that publisher: the simulation's own one is the only one left."""
    from sensor_msgs.msg import PointCloud2
    from sm_ros import node as node_module, warmup
    from sm_ros.cloud import read_xyz
    from sm_ros.scene import load_scene
    monkeypatch.setattr(warmup, 'cold_kernels', lambda: 5)
    monkeypatch.setattr(warmup, 'start_background', lambda: None)
    real = node_module.Simulation

    def compiling(*args, **kwargs):
        time.sleep(1.5)
        return real(*args, **kwargs)
    monkeypatch.setattr(node_module, 'Simulation', compiling)
    scene = _write(tmp_path / 'a.yaml', BIG_SCENE.replace('0.975, 0.975, 0.85',
                                                          '0.1, 0.1, 0.1'))
    got = ros.subscribe(PointCloud2, 'points')
    node = ros.start(scene)
    assert ros.spin_until(lambda: len(got) >= 2)
    want = np.concatenate([b.points for b in load_scene(scene).bodies]).astype(np.float32)
    for msg in got:
        assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (0, 0)
        assert np.array_equal(read_xyz(msg).astype(np.float32), want)
    assert node.count_publishers(f'{ros.namespace}/points') == 1
