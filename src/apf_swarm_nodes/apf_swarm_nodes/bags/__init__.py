"""Bags of the swarm: rosbag2 directories (metadata.yaml version 9 + MCAP storage), no ROS graph.

A bag written here is an ordinary rosbag2 bag: rosbags' ``AnyReader``, the ``mcap`` readers,
Foxglove and ``ros2 bag`` on a full ROS install open it. Layout of a bag directory ``BAG/``::

    BAG/metadata.yaml        rosbag2 metadata, version 9 (topics, types, offered QoS, counts,
                             files, custom_data: apf_swarm.recorder / .config / .mode)
    BAG/BAG_0.mcap           MCAP storage: one schema (ros2msg, full definition) per type, one
    BAG/BAG_1.mcap ...       channel per topic (offered_qos_profiles in its metadata), chunked
                             messages (zstd-compressed chunks with ``compress``); more files
                             only when split by size or duration

What is here (all of it without rclpy, except :func:`swarm_state_accumulator`, which reuses
the bring-up's deserialization so that ``bag metrics`` equals the live ``summary.json``):

* :class:`BagWriter` (:mod:`.write`) -- raw CDR bytes into a bag, on mcap's public
  ``Writer``; chunks are flushed to the file on :meth:`BagWriter.flush` so that a killed writer
  leaves every flushed chunk recoverable; optional zstd chunk compression and splitting;
* :func:`type_definition` -- the full ``ros2msg`` definition and RIHS01 hash of a type (the
  rosbags Jazzy type store plus the ``.msg`` files of the ament index, custom types included);
* :func:`open_bag` / :func:`format_info` -- what ``apf-swarm bag info`` prints, from
  metadata.yaml and the MCAP summaries (never every message);
* :func:`iter_raw`, :func:`bag_metrics`, :func:`bag_trajectory`, :func:`export_csv`,
  :func:`reindex` -- the other ``apf-swarm bag`` commands.

Every expected problem (no such path, not a bag, missing metadata.yaml, truncated or corrupt
MCAP, unknown topic or type) raises :class:`BagError` with one line that names it
and says what to do (the command line prints it, exit code 2).
"""

from .errors import BagError
from .export import export_csv, flatten
from .info import BagInfo, FileInfo, TopicInfo, bag_files, format_info, info_dict, open_bag
from .read import bag_config, bag_metrics, bag_trajectory, iter_raw, swarm_state_accumulator
from .recover import reindex
from .types import (
    BAG_VERSION,
    CUSTOM_CONFIG,
    CUSTOM_MODE,
    CUSTOM_RECORDER,
    type_definition,
    typestore,
)
from .write import BagWriter, Topic

__all__ = [
    'BAG_VERSION',
    'CUSTOM_CONFIG',
    'CUSTOM_MODE',
    'CUSTOM_RECORDER',
    'BagError',
    'BagInfo',
    'BagWriter',
    'FileInfo',
    'Topic',
    'TopicInfo',
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
    'swarm_state_accumulator',
    'type_definition',
    'typestore',
]
