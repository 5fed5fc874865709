"""The ROS names the core must know, said once: a tracker's namespace and node name (the
section of its parameters in a run's parameter file, :func:`~.config_files.to_ros_params`).
Every other name (topics, the other nodes) is :mod:`apf_swarm_nodes.topics`'s."""

from __future__ import annotations

__all__ = ['TRACKER_NODE', 'UAV_PREFIX', 'tracker_node_name', 'uav_namespace']

#: the node name of every tracker (each in its own namespace, :func:`uav_namespace`)
TRACKER_NODE = 'tracker'
#: a tracker's namespace is this prefix and its id
UAV_PREFIX = '/uav_'


def uav_namespace(uav_id: int) -> str:
    """The namespace of tracker ``uav_id``: ``/uav_<i>``."""
    return f'{UAV_PREFIX}{uav_id}'


def tracker_node_name(uav_id: int) -> str:
    """The fully qualified node name of tracker ``uav_id``: ``/uav_<i>/tracker``."""
    return f'{uav_namespace(uav_id)}/{TRACKER_NODE}'
