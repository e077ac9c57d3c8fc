"""Packaging for sm_ros: a ROS 2 Jazzy node simulating deformable objects (shape matching)."""

import os

from setuptools import find_packages
from setuptools import setup

package_name = 'sm_ros'

ROS_WHEELS = [
    'ros-jazzy-rclpy[fastrtps]',
    'ros-jazzy-sensor-msgs',
    'ros-jazzy-std-msgs',
    'ros-jazzy-geometry-msgs',
    'ros-jazzy-diagnostic-msgs',
    'ros-jazzy-std-srvs',
    'ros-jazzy-visualization-msgs',
    'ros-jazzy-rosgraph-msgs',
]


def config_data_files():
    """Return data_files entries for everything under config/ and launch/ (per folder)."""
    entries = []
    walked = [w for top in ('config', 'launch') for w in sorted(os.walk(top))]
    for folder, _, files in walked:
        if '__pycache__' in folder:
            continue
        paths = sorted(os.path.join(folder, f) for f in files)
        if paths:
            entries.append((os.path.join('share', package_name, folder), paths))
    return entries


setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'test.*']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
    ] + config_data_files(),
    install_requires=['setuptools', 'numpy', 'numba', 'pyyaml'],
    extras_require={
        'ros': ROS_WHEELS,
        'mesh': ['trimesh'],
        'plot': ['matplotlib'],
        # live view in Foxglove (sm_ros.live, parameter foxglove.port)
        'viz': ['foxglove-sdk'],
        # rosbag2 MCAP recordings (sm_ros.record, ~/record service, record.path parameter)
        'record': ['mcap', 'mcap-ros2-support'],
        # progress bars of warmup, bench and render (quiet when not a terminal)
        'progress': ['tqdm'],
        # linear-elastic FEM reference of `python -m sm_ros.bench material` (issue 12 part 6)
        'fem': ['scikit-fem'],
        'test': [
            'pytest', 'pytest-xdist', 'hypothesis', 'psutil', 'trimesh', 'matplotlib',
            'foxglove-sdk', 'mcap', 'mcap-ros2-support', 'tqdm',
            'rosbags', 'websockets', 'protobuf', 'scikit-fem',
            'colcon-core', 'colcon-python-setup-py', 'colcon-ros', 'catkin_pkg',
            'ruff',
        ],
        # scipy: contact baseline (cKDTree); pybullet, mujoco: `python -m sm_ros.bench peers`
        'bench': ['matplotlib', 'psutil', 'pypbd', 'scipy', 'pybullet>=3.2.7', 'mujoco>=4.0'],
    },
    zip_safe=True,
    maintainer='sm_ros maintainers',
    maintainer_email='sm-ros@example.org',
    description='Meshless shape matching (Mueller et al. 2005) deformable bodies as a ROS 2 node',
    license='Apache-2.0',
    tests_require=['pytest'],
    entry_points={
        'console_scripts': [
            'sim_node = sm_ros.node:main',
            'warmup = sm_ros.warmup:main',
        ],
    },
)
