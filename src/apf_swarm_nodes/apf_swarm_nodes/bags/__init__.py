"""Bags of the swarm: rosbag2 directories (metadata.yaml version 9 + MCAP storage), no ROS graph
and no rclpy (the layout: docs/USAGE.md, *Bags*).

:mod:`.write` (:class:`BagWriter`, on mcap's public ``Writer``), :mod:`.types` (definitions and
RIHS01 hashes of the types), :mod:`.info` (``bag info``, from metadata.yaml and the MCAP
summaries), :mod:`.read` (messages, ``bag metrics``), :mod:`.export` and :mod:`.recover`
(``bag reindex``). Every expected problem raises :class:`BagError` with one line that names
it and says what to do.
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
