"""Bags of the swarm: rosbag2 directories (metadata.yaml version 9 + MCAP storage), no ROS graph.

A bag written here is an ordinary rosbag2 bag: rosbags' ``AnyReader``, the ``mcap`` readers,
Foxglove and ``ros2 bag`` on a full ROS install open it. Layout of a bag directory ``BAG/``::

    BAG/metadata.yaml        rosbag2 metadata, version 9 (topics, types, offered QoS, counts,
                             files, custom_data: apf_swarm.recorder / .config / .mode)
    BAG/BAG_0.mcap           MCAP storage: one schema (ros2msg, full definition) per type, one
    BAG/BAG_1.mcap ...       channel per topic (offered_qos_profiles in its metadata), chunked
                             messages (zstd-compressed chunks with ``compress``); more files
                             only when split by size or duration

:mod:`.write` (:class:`BagWriter`, on mcap's public ``Writer``), :mod:`.types` (definitions and
RIHS01 hashes of the types), :mod:`.info` (``bag info``: metadata.yaml and the MCAP summaries,
never every message), :mod:`.read` (messages, ``bag metrics``), :mod:`.export` and
:mod:`.recover` (``bag reindex``). Nothing here imports rclpy. Every expected problem (no such
path, not a bag, missing metadata.yaml, truncated or corrupt MCAP, unknown topic or type)
raises :class:`BagError` with one line that names it and says what to do (the command line
prints it, exit code 2).
"""

from .errors import BagError
from .export import export_csv, flatten
from .info import BagInfo, bag_files, format_info, info_dict, open_bag
from .read import bag_config, bag_metrics, bag_trajectory, iter_raw
from .recover import reindex
from .types import CUSTOM_CONFIG, CUSTOM_MODE, CUSTOM_RECORDER, type_definition
from .write import BagWriter

__all__ = [
    'CUSTOM_CONFIG',
    'CUSTOM_MODE',
    'CUSTOM_RECORDER',
    'BagError',
    'BagInfo',
    'BagWriter',
    'bag_config',
    'bag_files',
    'bag_metrics',
    'bag_trajectory',
    'export_csv',
    'flatten',
    'format_info',
    'info_dict',
    'iter_raw',
    'open_bag',
    'reindex',
    'type_definition',
]
