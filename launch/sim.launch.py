"""
Start sim_node (or N of them in namespaces) and optionally RViz.

    ros2 launch sm_ros sim.launch.py scene:=rope rviz:=true
    ros2 launch sm_ros sim.launch.py count:=2 scenes:=rope,sheet     # /sim_0/..., /sim_1/...
    ros2 launch sm_ros sim.launch.py foxglove_port:=8765             # live view in Foxglove

Arguments: scene, scenes (one per node, comma separated), count, namespace, rviz,
foxglove_port (0 = off; node i gets port + i), params_file (default: the installed
config/sim_node.yaml). The node list comes from sm_ros.launching.node_configs.
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node
from sm_ros.launching import node_configs, rviz_config, rviz_wanted

ARGUMENTS = {
    'scene': ('', 'bundled scene name or YAML path (every node)'),
    'scenes': ('', 'comma-separated scenes, one per node (overrides scene and count)'),
    'count': ('1', 'number of sim_node processes, in namespaces <namespace>_<i>'),
    'namespace': ('', "namespace (count > 1: prefix, default 'sim')"),
    'rviz': ('false', 'also start RViz with config/sim.rviz'),
    'foxglove_port': ('0', 'Foxglove WebSocket port of the first node (0 = off)'),
    'params_file': ('', 'parameter file (default: config/sim_node.yaml)'),
}


def _launch(context):
    share = get_package_share_directory('sm_ros')
    value = {k: LaunchConfiguration(k).perform(context) for k in ARGUMENTS}
    params_file = value['params_file'] or os.path.join(share, 'config', 'sim_node.yaml')
    actions = []
    configs = node_configs(value['scene'], value['count'], value['namespace'],
                           value['scenes'], value['foxglove_port'], params_file)
    for cfg in configs:
        actions.append(Node(package='sm_ros', executable='sim_node', name=cfg['name'],
                            namespace=cfg['namespace'], parameters=cfg['parameters'],
                            output='screen', emulate_tty=True))
    if rviz_wanted(value['rviz']):
        config = os.path.join(share, 'config', 'sim.rviz')
        spaces = [cfg['namespace'] for cfg in configs]
        if any(spaces):              # several nodes: every node's topics in one view
            import tempfile
            with open(config, encoding='utf-8') as f:
                text = rviz_config(f.read(), spaces)
            fd, config = tempfile.mkstemp(prefix='sm_ros_', suffix='.rviz')
            with os.fdopen(fd, 'w', encoding='utf-8') as f:
                f.write(text)
        actions.append(Node(package='rviz2', executable='rviz2', name='rviz2',
                            arguments=['-d', config]))
    return actions


def generate_launch_description():
    """Declare the arguments and start the nodes."""
    return LaunchDescription(
        [DeclareLaunchArgument(k, default_value=d, description=text)
         for k, (d, text) in ARGUMENTS.items()] + [OpaqueFunction(function=_launch)])
