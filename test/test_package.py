"""
Check the package.

package.xml and setup.py agree, doc/interface.md and config/sim_node.yaml match the
node, the Fast DDS profile is valid, and colcon builds an installable tree.
"""

import ast
import os
from pathlib import Path
import re
import shutil
import subprocess
import sys
from xml.etree import ElementTree

import pytest
import yaml

ROOT = Path(__file__).resolve().parent.parent
#: Services every rclpy node has (parameters, type descriptions): not in the README.
STANDARD_SERVICES = ('describe_parameters', 'get_parameter_types', 'get_parameters',
                     'list_parameters', 'set_parameters', 'set_parameters_atomically',
                     'get_type_description')
ROS_MSG_PACKAGES = ('rclpy', 'std_msgs', 'std_srvs', 'geometry_msgs', 'sensor_msgs',
                    'diagnostic_msgs', 'visualization_msgs', 'rosgraph_msgs')


def setup_kwargs():
    """Return the keyword arguments of setup() in setup.py, without running it."""
    tree = ast.parse((ROOT / 'setup.py').read_text())
    names = {}
    for node in tree.body:
        if isinstance(node, ast.Assign) and isinstance(node.targets[0], ast.Name):
            try:
                names[node.targets[0].id] = ast.literal_eval(node.value)
            except ValueError:
                pass
    call = next(n.value for n in tree.body if isinstance(n, ast.Expr)
                and isinstance(n.value, ast.Call) and getattr(n.value.func, 'id', '') == 'setup')
    out = {}
    for kw in call.keywords:
        try:
            out[kw.arg] = ast.literal_eval(kw.value)
        except ValueError:
            if isinstance(kw.value, ast.Name):
                out[kw.arg] = names.get(kw.value.id)
            elif isinstance(kw.value, ast.Dict):
                out[kw.arg] = {ast.literal_eval(k): (names[v.id] if isinstance(v, ast.Name)
                                                     else ast.literal_eval(v))
                               for k, v in zip(kw.value.keys, kw.value.values)}
    return out


# ----------------------------------------------------------------------------------------
# package.xml and setup.py
# ----------------------------------------------------------------------------------------

def test_package_xml_is_valid_format_3():
    catkin_pkg = pytest.importorskip('catkin_pkg.package')
    pkg = catkin_pkg.parse_package(str(ROOT / 'package.xml'))
    pkg.validate()
    assert pkg.name == 'sm_ros' and pkg.package_format == 3
    assert pkg.licenses == ['Apache-2.0']
    assert pkg.get_build_type() == 'ament_python'
    assert re.match(r'[^@\s]+@[^@\s]+\.[a-z]+$', pkg.maintainers[0].email)
    depends = {d.name for d in pkg.exec_depends}
    assert set(ROS_MSG_PACKAGES) <= depends
    assert {'python3-numpy', 'python3-numba', 'python3-yaml'} <= depends
    assert {'python3-pytest', 'python3-hypothesis'} <= {d.name for d in pkg.test_depends}


def test_setup_py_dependencies_and_entry_point():
    kw = setup_kwargs()
    assert kw['name'] == 'sm_ros'
    assert set(kw['install_requires']) >= {'numpy', 'numba', 'pyyaml'}
    assert not any(r.startswith('ros-') for r in kw['install_requires'])
    extras = kw['extras_require']
    wheels = {'ros-jazzy-' + p.replace('_', '-') for p in ROS_MSG_PACKAGES} - {'ros-jazzy-rclpy'}
    assert wheels | {'ros-jazzy-rclpy[fastrtps]'} == set(extras['ros'])
    assert set(extras['test']) >= {'pytest', 'hypothesis', 'psutil', 'trimesh', 'matplotlib'}
    assert extras['mesh'] == ['trimesh'] and extras['plot'] == ['matplotlib']
    assert set(extras['bench']) == {'matplotlib', 'psutil', 'pypbd', 'scipy', 'pybullet>=3.2.7',
                                   'mujoco>=4.0'}
    assert kw['entry_points']['console_scripts'] == ['sim_node = sm_ros.node:main',
                                                     'warmup = sm_ros.warmup:main']
    assert kw['license'] == 'Apache-2.0'


def test_package_versions_agree():
    catkin_pkg = pytest.importorskip('catkin_pkg.package')
    import sm_ros
    pkg = catkin_pkg.parse_package(str(ROOT / 'package.xml'))
    assert pkg.version == setup_kwargs()['version'] == sm_ros.__version__


def test_setup_cfg_puts_scripts_in_lib_sm_ros():
    text = (ROOT / 'setup.cfg').read_text()
    assert 'script_dir=$base/lib/sm_ros' in text
    assert 'install_scripts=$base/lib/sm_ros' in text
    assert (ROOT / 'resource' / 'sm_ros').exists()


def test_ci_runs_make_test():
    ci = (ROOT / '.ci' / 'run').read_text()
    assert ci.startswith('#!/usr/bin/env bash\n') and 'set -euo pipefail' in ci
    assert 'make test' in ci
    assert os.access(ROOT / '.ci' / 'run', os.X_OK)
    mk = (ROOT / 'Makefile').read_text()
    assert "pip install --quiet -e '.[ros,viz,record,progress,test]'" in mk
    assert '$(VENV)/bin/python -m pytest -q test' in mk
    # make run starts the live view and prints where to connect
    assert '$(VENV)/bin/sim_node --ros-args -p foxglove.port:=$(FOXGLOVE_PORT) $(ARGS)' in mk
    assert 'FOXGLOVE_PORT ?= 8765' in mk and 'ws://localhost:$(FOXGLOVE_PORT)' in mk
    assert '$(VENV)/bin/python -m sm_ros.warmup' in mk   # kernels compiled at set-up


# ----------------------------------------------------------------------------------------
# doc/interface.md, the README and config/sim_node.yaml against the node
# ----------------------------------------------------------------------------------------

def readme_table(heading):
    """Rows (cells, backticks stripped) of the first table after ``heading`` in the contract.

    The contract is doc/interface.md (the README links to it and sums it up).
    """
    text = (ROOT / 'doc' / 'interface.md').read_text()
    start = text.index(heading)
    rows = []
    for line in text[start:].splitlines()[1:]:
        if line.startswith('|'):
            cells = line.strip().strip('|').split('|')
            rows.append([c.strip().strip('`') for c in cells])
        elif rows:
            break
    return rows[2:]


def _value_text(value):
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, str):
        return f"'{value}'"
    if isinstance(value, list):
        return '[' + ', '.join(_value_text(v) for v in value) + ']'
    if isinstance(value, float):
        return f'{value:g}' if value != 1.0 / 120.0 else '1/120'
    return str(value)


def _range_text(p):
    if p.choices:
        return ', '.join(p.choices)
    if p.lo is None:
        return ''
    lo = '(' if p.positive else '['
    return f'{lo}{p.lo:g}, {p.hi:g}]'


def test_readme_parameter_table_matches_the_node():
    from sm_ros.params import NODE_PARAMS as PARAMS
    rows = readme_table('## Parameters')
    assert [r[0] for r in rows] == [p.name for p in PARAMS]
    for row, p in zip(rows, PARAMS):
        assert row[1] == p.type_name, p.name
        assert row[2] == _value_text(p.default), p.name
        assert row[3] == _range_text(p), p.name
        assert row[4], p.name


@pytest.fixture
def graph(ros, cube_scene):
    """Return the topics and services of a running node, relative to its namespace."""
    node = ros.start(cube_scene, publish_clock=True)
    ns = ros.namespace + '/'

    def rel(name):
        return name[len(ns):] if name.startswith(ns) else name
    pubs = {rel(name): types[0] for name, types in node.get_topic_names_and_types()
            if node.count_publishers(name) and name not in ('/rosout', '/parameter_events')
            and any(i.node_name == 'sim_node' for i in node.get_publishers_info_by_topic(name))}
    subs = {rel(name): types[0] for name, types in node.get_topic_names_and_types()
            if any(i.node_name == 'sim_node'
                   for i in node.get_subscriptions_info_by_topic(name))
            and name != '/parameter_events'}
    srvs = {rel(name).replace('sim_node/', '~/'): types[0]
            for name, types in node.get_service_names_and_types_by_node('sim_node',
                                                                        ros.namespace)
            if name.rsplit('/', 1)[-1] not in STANDARD_SERVICES}
    return pubs, subs, srvs


def test_readme_topic_and_service_tables_match_the_node(graph):
    pubs, subs, srvs = graph
    assert {r[0]: r[1] for r in readme_table('## Topics published')} == {
        k: v.replace('/msg/', '/') for k, v in pubs.items()}
    assert {r[0]: r[1] for r in readme_table('## Topics subscribed')} == {
        k: v.replace('/msg/', '/') for k, v in subs.items()}
    assert {r[0]: r[1] for r in readme_table('## Services')} == {
        k: v.replace('/srv/', '/') for k, v in srvs.items()}


def test_readme_starts_with_the_two_commands():
    text = (ROOT / 'README.md').read_text()
    first_block = text[text.index('```'):text.index('```', text.index('```') + 3)]
    assert 'make run' in first_block and 'make test' in first_block
    for doc in ('doc/interface.md', 'doc/architecture.md', 'doc/core_api.md',
                'doc/scenes.md', 'doc/benchmarks.md'):
        assert doc in text
    for phrase in ('colcon build', 'source install/setup.bash', 'ros2 run sm_ros sim_node',
                   'ros2 param set /sim_node alpha 0.9', 'FASTRTPS_DEFAULT_PROFILES_FILE'):
        assert phrase in text, phrase


def test_interface_lists_every_diagnostics_key():
    pytest.importorskip('diagnostic_msgs')
    from sm_ros.diagnostics import KEYS
    text = (ROOT / 'doc' / 'interface.md').read_text()
    assert [k for k in KEYS if f'`{k}`' not in text] == []


def test_config_sim_node_yaml_has_every_parameter_at_its_default():
    from sm_ros.params import NODE_PARAMS as PARAMS
    data = yaml.safe_load((ROOT / 'config' / 'sim_node.yaml').read_text())
    params = data['/**']['ros__parameters']
    assert list(params) == [p.name for p in PARAMS]
    for p in PARAMS:
        assert params[p.name] == p.default, p.name
        assert type(params[p.name]) is type(p.default), p.name
    text = (ROOT / 'config' / 'sim_node.yaml').read_text().splitlines()
    for p in PARAMS:
        i = next(k for k, ln in enumerate(text) if ln.strip().startswith(p.name + ':'))
        assert text[i - 1].strip().startswith('#'), f'{p.name} has no comment'


def test_no_file_points_outside_the_repository():
    outside = ('shared' '/', '..' '/shared')            # split so that this file passes
    found = []
    paths = []
    for folder, dirs, names in os.walk(ROOT):
        dirs[:] = [d for d in dirs if d not in ('.venv', '.git', 'build', 'install', 'log',
                                                '__pycache__', '.pytest_cache')]
        paths += [Path(folder) / n for n in names]
    for path in paths:
        if path.suffix not in ('.py', '.md', '.yaml', '.cfg', '.toml', '.xml'):
            continue
        for number, line in enumerate(path.read_text(errors='replace').splitlines(), 1):
            if any(o in line for o in outside):
                found.append(f'{path.relative_to(ROOT)}:{number}: {line.strip()}')
    assert found == []


def test_fastdds_profile_gives_large_shm_segments():
    root = ElementTree.parse(ROOT / 'config' / 'fastdds_shm.xml').getroot()
    ns = {'f': 'http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles'}
    shm = [t for t in root.iterfind('.//f:transport_descriptor', ns)
           if t.findtext('f:type', namespaces=ns) == 'SHM']
    assert len(shm) == 1
    segment = int(shm[0].findtext('f:segment_size', namespaces=ns))
    assert segment >= 4 * 16 * 1_000_000            # several 1M-point clouds (16 MB each)
    assert int(shm[0].findtext('f:maxMessageSize', namespaces=ns)) <= segment
    part = root.find('f:participant', ns)
    assert part.get('is_default_profile') == 'true'
    ids = [e.text for e in part.iterfind('.//f:userTransports/f:transport_id', ns)]
    assert shm[0].findtext('f:transport_id', namespaces=ns) in ids
    assert part.findtext('.//f:useBuiltinTransports', namespaces=ns) == 'false'


def test_fastdds_profile_loads_in_a_participant(tmp_path):
    pytest.importorskip('rclpy')
    code = ('import rclpy; from rclpy.node import Node; rclpy.init(); '
            "n = Node('profile_check'); print('ok'); n.destroy_node(); rclpy.shutdown()")
    env = dict(os.environ, FASTRTPS_DEFAULT_PROFILES_FILE=str(ROOT / 'config' /
                                                              'fastdds_shm.xml'),
               RMW_IMPLEMENTATION='rmw_fastrtps_cpp', ROS_DOMAIN_ID='231')
    proc = subprocess.run([sys.executable, '-c', code], env=env, capture_output=True,
                          text=True, timeout=60)
    assert proc.returncode == 0 and 'ok' in proc.stdout, proc.stderr
    assert 'Error' not in proc.stderr and 'error' not in proc.stderr.lower(), proc.stderr


# ----------------------------------------------------------------------------------------
# colcon
# ----------------------------------------------------------------------------------------

def test_colcon_build_install_tree(tmp_path):
    try:
        import colcon_core  # noqa: F401
        import colcon_ros  # noqa: F401
    except ImportError:
        pytest.skip('colcon is not installed (pip install colcon-core colcon-ros '
                    'colcon-python-setup-py): the colcon build is not checked')
    src = tmp_path / 'src' / 'sm_ros'
    shutil.copytree(ROOT, src, ignore=shutil.ignore_patterns(
        '.venv', '.git', 'build', 'install', 'log', '__pycache__', '*.egg-info',
        '.pytest_cache', '.hypothesis'))
    colcon = [sys.executable, '-m', 'colcon']
    if shutil.which('colcon', path=os.path.dirname(sys.executable)):
        colcon = [os.path.join(os.path.dirname(sys.executable), 'colcon')]
    proc = subprocess.run(colcon + ['build', '--base-paths', 'src', '--build-base', 'build',
                                    '--install-base', 'install', '--event-handlers',
                                    'console_direct-'],
                          cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    prefix = tmp_path / 'install' / 'sm_ros'
    exe = prefix / 'lib' / 'sm_ros' / 'sim_node'
    assert exe.is_file() and os.access(exe, os.X_OK)
    assert os.access(prefix / 'lib' / 'sm_ros' / 'warmup', os.X_OK)   # ros2 run sm_ros warmup
    assert (prefix / 'share' / 'ament_index' / 'resource_index' / 'packages' /
            'sm_ros').is_file()
    assert (prefix / 'share' / 'sm_ros' / 'package.xml').is_file()
    assert (prefix / 'share' / 'sm_ros' / 'config' / 'sim_node.yaml').is_file()
    assert (prefix / 'share' / 'sm_ros' / 'config' / 'scenes' / 'default.yaml').is_file()
    assert (prefix / 'share' / 'sm_ros' / 'config' / 'sim.rviz').is_file()
    assert (prefix / 'share' / 'sm_ros' / 'launch' / 'sim.launch.py').is_file()
    # the installed executable imports the installed package and finds the bundled scenes
    site = next((prefix / 'lib').glob('python3*/site-packages'))
    env = dict(os.environ, PYTHONPATH=f'{site}{os.pathsep}' + os.environ.get('PYTHONPATH', ''),
               AMENT_PREFIX_PATH=str(prefix), ROS_DOMAIN_ID='232')
    run = subprocess.run([sys.executable, str(exe), '--ros-args', '-p', 'scene:=no_such'],
                         cwd=tmp_path, env=env, capture_output=True, text=True, timeout=120)
    assert run.returncode == 2, run.stderr
    assert 'bundled: ' in run.stderr and 'default' in run.stderr, run.stderr
    assert str(site) in subprocess.run(
        [sys.executable, '-c', 'import sm_ros, sys; print(sm_ros.__file__)'], env=env,
        cwd=tmp_path, capture_output=True, text=True).stdout
