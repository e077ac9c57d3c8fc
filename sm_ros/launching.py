"""
What ``launch/sim.launch.py`` starts, computed without the ``launch`` package.

The launch file is a thin shell over :func:`node_configs` (so its logic is tested where
``launch`` is not installed, as with the PyPI wheels of ROS 2): one ``sim_node`` per
namespace, each with its own scene, optional Foxglove port and the package's parameter
file, plus RViz when asked.

``count`` > 1 starts ``sim_0``, ``sim_1``, ... (or ``<namespace>_<i>``): each node's
topics are then ``/sim_0/points``, ``/sim_1/points``, ... and its services
``/sim_0/sim_node/reset``, ...; DDS carries them between processes and machines like any
other topics. ``scenes`` (comma separated) gives each node its own scene; otherwise all
run ``scene``. Foxglove ports count up from ``foxglove_port`` (0: off).
"""

import copy
from typing import Dict, List, Sequence


def _truthy(text) -> bool:
    return str(text).strip().lower() in ('1', 'true', 'yes', 'on')


def node_configs(scene: str = '', count=1, namespace: str = '', scenes: str = '',
                 foxglove_port=0, params_file: str = '') -> List[Dict]:
    """
    Return one dict per sim_node: ``namespace``, ``name`` and ``parameters`` (a list for
    launch_ros: the parameter file first, then the overrides).

    Raises ValueError for a count below 1, a scene list whose length is not the count, or
    a port outside 0..65535.
    """
    count = int(count)
    if count < 1:
        raise ValueError(f'count must be >= 1, got {count}')
    names = [s.strip() for s in str(scenes).split(',')] if str(scenes).strip() else []
    if names and len(names) != count:
        if count == 1:
            count = len(names)
        else:
            raise ValueError(f'scenes lists {len(names)} scenes for count {count}')
    port = int(foxglove_port)
    if not 0 <= port <= 65535 - count:
        raise ValueError(f'foxglove_port must be in 0..{65535 - count}, got {port}')
    out = []
    for i in range(count):
        if count == 1:
            ns = namespace
        else:
            ns = f'{namespace or "sim"}_{i}'
        overrides = {'scene': names[i] if names else scene,
                     'foxglove.port': port + i if port else 0}
        params = ([params_file] if params_file else []) + [overrides]
        out.append({'namespace': ns, 'name': 'sim_node', 'parameters': params})
    return out


def rviz_wanted(flag) -> bool:
    """Return True for the launch argument values that ask for RViz."""
    return _truthy(flag)


#: The displays of config/sim.rviz that show one node's topics.
_NODE_DISPLAYS = ('rviz_default_plugins/PointCloud2', 'rviz_default_plugins/PoseArray',
                  'rviz_default_plugins/MarkerArray')


def rviz_config(base_text: str, namespaces: Sequence[str]) -> str:
    """
    Return an RViz configuration showing every node: the per-node displays of
    ``base_text`` (config/sim.rviz) repeated for each namespace, their topics prefixed.

    One node in the root namespace gets the file unchanged.
    """
    import yaml
    spaces = [ns.strip('/') for ns in namespaces]
    if spaces in ([], ['']):
        return base_text
    data = yaml.safe_load(base_text)
    manager = data['Visualization Manager']
    out = []
    for display in manager['Displays']:
        if display.get('Class') not in _NODE_DISPLAYS:
            out.append(display)
            continue
        for ns in spaces:
            d = copy.deepcopy(display)
            d['Name'] = f"{display['Name']} /{ns}" if ns else display['Name']
            topic = d['Topic']['Value']
            d['Topic']['Value'] = f"/{ns}/{topic.lstrip('/')}" if ns else topic
            out.append(d)
    manager['Displays'] = out
    return yaml.safe_dump(data, default_flow_style=False, sort_keys=False)
