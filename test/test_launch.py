"""
What a ROS package ships: the launch file and the RViz configuration.

The RViz file is parsed as YAML in every run; the launch file's node list
(``sm_ros.launching``) is checked everywhere, and the launch file itself is loaded where
the ``launch`` and ``launch_ros`` packages are importable (they are not on PyPI).
"""

import ast
import importlib.util
from pathlib import Path

import pytest
import yaml

from sm_ros.launching import node_configs, rviz_config, rviz_wanted

ROOT = Path(__file__).resolve().parent.parent
LAUNCH_FILE = ROOT / 'launch' / 'sim.launch.py'


def displays():
    data = yaml.safe_load((ROOT / 'config' / 'sim.rviz').read_text())
    return data, {d['Class'].split('/')[-1]: d for d in data['Visualization Manager']['Displays']}


def test_rviz_config_shows_the_node_topics():
    data, shown = displays()
    assert data['Visualization Manager']['Global Options']['Fixed Frame'] == 'world'
    cloud = shown['PointCloud2']
    assert cloud['Topic']['Value'] == '/points'
    assert (cloud['Color Transformer'], cloud['Channel Name']) == ('Intensity', 'body')
    assert shown['PoseArray']['Topic']['Value'] == '/poses'
    assert shown['MarkerArray']['Topic']['Value'] == '/markers'


def test_one_node_by_default():
    (cfg,) = node_configs(scene='rope', params_file='/p.yaml')
    assert cfg == {'namespace': '', 'name': 'sim_node',
                   'parameters': ['/p.yaml', {'scene': 'rope', 'foxglove.port': 0}]}


def test_n_nodes_in_namespaces_with_their_own_scenes_and_ports():
    cfgs = node_configs(count=3, scenes='rope,sheet,many', foxglove_port=8765)
    assert [c['namespace'] for c in cfgs] == ['sim_0', 'sim_1', 'sim_2']
    assert [c['parameters'][-1] for c in cfgs] == [
        {'scene': 'rope', 'foxglove.port': 8765}, {'scene': 'sheet', 'foxglove.port': 8766},
        {'scene': 'many', 'foxglove.port': 8767}]
    assert [c['namespace'] for c in node_configs(count=2, namespace='lab')] == \
        ['lab_0', 'lab_1']
    assert len(node_configs(scenes='a,b')) == 2        # scenes alone sets the count


@pytest.mark.parametrize('kwargs, match', [
    ({'count': 0}, 'count must be >= 1'),
    ({'count': 2, 'scenes': 'a,b,c'}, 'lists 3 scenes for count 2'),
    ({'foxglove_port': 70000}, 'foxglove_port must be in'),
])
def test_bad_arguments_are_refused(kwargs, match):
    with pytest.raises(ValueError, match=match):
        node_configs(**kwargs)


def test_rviz_flag():
    assert [rviz_wanted(v) for v in ('true', 'True', '1', 'false', '', 'no')] == \
        [True, True, True, False, False, False]


def test_launch_file_declares_what_node_configs_takes():
    """The launch arguments are the keyword arguments of node_configs (+ rviz)."""
    tree = ast.parse(LAUNCH_FILE.read_text())
    args = next(n.value for n in tree.body if isinstance(n, ast.Assign)
                and getattr(n.targets[0], 'id', '') == 'ARGUMENTS')
    names = {ast.literal_eval(k) for k in args.keys}
    code = node_configs.__code__
    assert names == set(code.co_varnames[:code.co_argcount]) | {'rviz'}


def test_launch_file_loads_with_launch(tmp_path, monkeypatch):
    try:
        import launch  # noqa: F401
        import launch_ros  # noqa: F401
        from launch import LaunchContext
    except ImportError:
        pytest.skip('the ROS 2 launch packages (launch, launch_ros) are not importable: '
                    'they are not on PyPI; the node list is tested through '
                    'sm_ros.launching instead')
    share = tmp_path / 'share' / 'sm_ros'
    (share / 'config').mkdir(parents=True)
    (share / 'config' / 'sim.rviz').write_text((ROOT / 'config' / 'sim.rviz').read_text())
    monkeypatch.setenv('AMENT_PREFIX_PATH', str(tmp_path))
    (tmp_path / 'share' / 'ament_index' / 'resource_index' / 'packages').mkdir(parents=True)
    (tmp_path / 'share' / 'ament_index' / 'resource_index' / 'packages' / 'sm_ros').touch()
    spec = importlib.util.spec_from_file_location('sim_launch', LAUNCH_FILE)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    desc = mod.generate_launch_description()
    context = LaunchContext()
    for name, value in (('count', '2'), ('rviz', 'true')):
        context.launch_configurations[name] = value
    for entity in desc.entities:
        if hasattr(entity, 'default_value') and entity.name not in context.launch_configurations:
            context.launch_configurations[entity.name] = ''.join(
                s.perform(context) for s in entity.default_value)
    opaque = desc.entities[-1]
    nodes = opaque.execute(context)
    assert [n.node_executable for n in nodes] == ['sim_node', 'sim_node', 'rviz2']


def test_rviz_shows_every_node_of_a_multi_node_launch():
    base = (ROOT / 'config' / 'sim.rviz').read_text()
    assert rviz_config(base, ['']) == base
    data = yaml.safe_load(rviz_config(base, ['sim_0', '/sim_1']))
    shown = [(d['Class'].split('/')[-1], d['Topic']['Value'])
             for d in data['Visualization Manager']['Displays'] if 'Topic' in d]
    assert shown == [('PointCloud2', '/sim_0/points'), ('PointCloud2', '/sim_1/points'),
                     ('PoseArray', '/sim_0/poses'), ('PoseArray', '/sim_1/poses'),
                     ('MarkerArray', '/sim_0/markers'), ('MarkerArray', '/sim_1/markers')]
    grid = data['Visualization Manager']['Displays'][0]
    assert grid['Class'] == 'rviz_default_plugins/Grid'
    assert data['Visualization Manager']['Global Options']['Fixed Frame'] == 'world'
