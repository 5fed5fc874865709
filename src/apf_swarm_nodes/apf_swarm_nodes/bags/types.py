"""Message types and QoS text of a bag: the full ``ros2msg`` definition and RIHS01 hash
of a type (the rosbags Jazzy type store plus the ``.msg`` files of the ament index), and the
constants of the bag layout."""

from __future__ import annotations

import os
import re
from collections.abc import Sequence
from functools import cache
from pathlib import Path
from typing import Any

import yaml

from .errors import BagError

__all__ = [
    'BAG_VERSION',
    'CUSTOM_CONFIG',
    'CUSTOM_MODE',
    'CUSTOM_RECORDER',
    'DEFAULT_CHUNK_SIZE',
    'FILE_RE',
    'MCAP_METADATA_NAME',
    'ROS_DISTRO',
    'SWARM_STATE_TYPE',
    'one_line',
    'qos_text',
    'type_definition',
    'typestore',
]

BAG_VERSION = 9
#: the distribution the bags are written for, as rosbag2 names it (metadata.yaml and MCAP)
ROS_DISTRO = 'jazzy'
#: custom_data keys (metadata.yaml) and the MCAP metadata record the recorder writes first
CUSTOM_RECORDER = 'apf_swarm.recorder'  # JSON: received / written / dropped counts
CUSTOM_CONFIG = 'apf_swarm.config'  # the run's ROS 2 parameter file (YAML text)
CUSTOM_MODE = 'apf_swarm.mode'  # lockstep | realtime
MCAP_METADATA_NAME = 'apf_swarm'
DEFAULT_CHUNK_SIZE = 1 << 20
SWARM_STATE_TYPE = 'apf_swarm_msgs/msg/SwarmState'
FILE_RE = re.compile(r'^(?P<stem>.*?)(?:_(?P<index>\d+))?\.mcap$')


def _find_msg_file(msgtype: str) -> Path | None:
    """``msgtype``'s ``.msg`` file in a ``share/`` directory of the ament index, else in the
    repository's ``src/`` (a fresh checkout before ``make``)."""
    pkg, _, name = msgtype.partition('/msg/')
    prefixes = os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep)
    dirs = [Path(p) / 'share' for p in prefixes if p] + [Path(__file__).resolve().parents[2]]
    for d in dirs if name else ():
        for cand in (d / pkg / 'msg' / f'{name}.msg', d / pkg / pkg / 'msg' / f'{name}.msg'):
            if cand.is_file():
                return cand
    return None


@cache
def typestore() -> Any:
    """The rosbags Jazzy type store with apf_swarm_msgs registered from their ``.msg`` files."""
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    for name in ('ForceCommand', 'ForceCommands', 'SwarmOdometry', 'SwarmState'):
        _register_from_index(store, f'apf_swarm_msgs/msg/{name}')
    return store


def _register_from_index(store: Any, msgtype: str) -> bool:
    """Register ``msgtype`` from its ``.msg`` file in the ament index; False without one."""
    from rosbags.typesys import get_types_from_msg

    path = _find_msg_file(msgtype)
    if path is not None:
        store.register(get_types_from_msg(path.read_text(), msgtype))
    return msgtype in store.fielddefs


@cache
def type_definition(msgtype: str) -> tuple[str, str]:
    """The full ``ros2msg`` definition text (dependencies included) and the RIHS01 hash.

    Raises BagError for a type that is neither in the Jazzy type store nor in a ``.msg`` file
    of the ament index.
    """
    store = typestore()
    try:
        if msgtype not in store.fielddefs and not _register_from_index(store, msgtype):
            raise KeyError(msgtype)
        msgdef, _ = store.generate_msgdef(msgtype, ros_version=2)
        return msgdef, store.hash_rihs01(msgtype)
    except Exception as exc:  # rosbags raises TypesysError / KeyError for missing dependencies
        raise BagError(
            f'message type {msgtype} is unknown: it is not a ROS 2 Jazzy type and no '
            f'{msgtype}.msg is in the ament index ({one_line(exc)}); build and '
            'source the package that defines it'
        ) from None


def qos_text(qos: Sequence[Any]) -> str:
    """offered_qos_profiles as the YAML string stored in an MCAP channel (as rosbags does)."""
    from rosbags.rosbag2.metadata import dump_qos_v9

    return yaml.safe_dump(dump_qos_v9(list(qos)), default_flow_style=False).strip()


def one_line(exc: BaseException) -> str:
    """``Type: message`` of an exception on one line (parsers report over several)."""
    text = ' '.join(str(exc).split())
    if len(text) > 300:
        text = text[:297] + '...'
    return f'{type(exc).__name__}: {text}' if text else type(exc).__name__
