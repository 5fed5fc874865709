"""Every ROS name of the swarm, said once: the topics (absolute, and relative to the node's
namespace where a node names its own), the nodes' names and namespaces, and the channels of
the Foxglove view. Plain strings, no rclpy: the bag tools use them too. Their QoS profiles
are :mod:`.node_common`'s; the table is in docs/ROS.md, section "Topics and QoS".

The core knows one name only, a tracker's (its parameter-file section):
:mod:`apf_swarm_core.names`.
"""

from __future__ import annotations

import re

from apf_swarm_core.names import TRACKER_NODE, UAV_PREFIX, tracker_node_name, uav_namespace

__all__ = [
    'ACCEL_CMD',
    'CLOCK',
    'DISCOVERY_INFO',
    'FORCE_CMD',
    'FOXGLOVE_FRAMES',
    'FOXGLOVE_METRICS',
    'FOXGLOVE_SCENE',
    'ODOM',
    'PLANT_NODE',
    'PRIVATE_STATUS',
    'RECORDER_NODE',
    'RECORDER_STATUS',
    'REQUEST',
    'STATUS',
    'SWARM_FORCE_CMDS',
    'SWARM_MARKERS',
    'SWARM_ODOM',
    'SWARM_PUBLISHED',
    'SWARM_START',
    'SWARM_STATE',
    'TARGET_NAMESPACE',
    'TARGET_NODE',
    'TARGET_ODOM',
    'TARGET_REQUEST',
    'TRACKER_NODE',
    'UAV_PREFIX',
    'UAV_TOPIC',
    'VELOCITY_CMD',
    'force_topic',
    'odom_topic',
    'swarm_node_names',
    'tracker_node_name',
    'uav_namespace',
]

# --- nodes ------------------------------------------------------------------------------------
PLANT_NODE = 'plant'
TARGET_NODE = 'target'
TARGET_NAMESPACE = '/target'
RECORDER_NODE = 'recorder'

# --- topics relative to a node's namespace ---------------------------------------------------
#: a tracker's (``/uav_<i>``) and the target's (``/target``) odometry
ODOM = 'odom'
#: a tracker's outputs: the force command the plant integrates, and the setpoints
FORCE_CMD = 'force_cmd'
ACCEL_CMD = 'accel_cmd'
VELOCITY_CMD = 'velocity_cmd'
#: the target's lockstep requests (``/target/request``)
REQUEST = 'request'
#: the recorder's status, published on its private name ``~/status``
STATUS = 'status'
PRIVATE_STATUS = f'~/{STATUS}'

# --- absolute topics --------------------------------------------------------------------------
TARGET_ODOM = f'{TARGET_NAMESPACE}/{ODOM}'
TARGET_REQUEST = f'{TARGET_NAMESPACE}/{REQUEST}'
SWARM_STATE = '/swarm/state'
SWARM_ODOM = '/swarm/odom'
SWARM_START = '/swarm/start'
#: the force commands of a process's trackers as one message (``batch_commands``)
SWARM_FORCE_CMDS = '/swarm/force_cmds'
SWARM_MARKERS = '/swarm/markers'
CLOCK = '/clock'
RECORDER_STATUS = f'/{RECORDER_NODE}/{STATUS}'
#: rmw's topic of each participant's node names (unmangled; the domain probe counts its writers)
DISCOVERY_INFO = 'ros_discovery_info'

#: topics only a swarm publishes (its nodes, a bring-up, a bag played into the domain): a
#: publisher of one of them means another swarm; the per-UAV topics match :data:`UAV_TOPIC`
SWARM_PUBLISHED = (
    SWARM_STATE,
    SWARM_ODOM,
    SWARM_START,
    SWARM_FORCE_CMDS,
    SWARM_MARKERS,
    TARGET_ODOM,
    TARGET_REQUEST,
)
#: a tracker's topics: ``/uav_<i>/force_cmd``, ``accel_cmd``, ``velocity_cmd``, ``odom``
UAV_TOPIC = re.compile(
    rf'^{re.escape(UAV_PREFIX)}\d+/({FORCE_CMD}|{ACCEL_CMD}|{VELOCITY_CMD}|{ODOM})$'
)

# --- the Foxglove view's channels (not ROS topics) --------------------------------------------
FOXGLOVE_SCENE = '/swarm/scene'
FOXGLOVE_FRAMES = '/swarm/frames'
FOXGLOVE_METRICS = '/swarm/metrics'


def odom_topic(uav_id: int) -> str:
    """Absolute odometry topic of tracker ``uav_id``: ``/uav_<i>/odom``."""
    return f'{uav_namespace(uav_id)}/{ODOM}'


def force_topic(uav_id: int) -> str:
    """Absolute force-command topic of tracker ``uav_id``: ``/uav_<i>/force_cmd``."""
    return f'{uav_namespace(uav_id)}/{FORCE_CMD}'


def swarm_node_names(n: int) -> list[str]:
    """Fully qualified names of the nodes of a swarm of ``n`` trackers."""
    return [f'{TARGET_NAMESPACE}/{TARGET_NODE}', f'/{PLANT_NODE}'] + [
        tracker_node_name(i) for i in range(1, n + 1)
    ]
