"""
sm_ros: deformable objects for ROS 2 with meshless shape matching (Mueller et al. 2005).

Subpackages and modules: ``sm_ros.core`` (the solver, no rclpy), ``sm_ros.params`` (the
parameter table), ``sm_ros.scene`` (scene files), ``sm_ros.sim`` (the simulation without
ROS), ``sm_ros.node`` (the ``sim_node`` executable, a ROS adapter of ``sm_ros.sim``),
``sm_ros.cloud`` (PointCloud2 with NumPy).
"""

__version__ = '0.1.0'
