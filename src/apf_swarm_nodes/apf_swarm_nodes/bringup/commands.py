"""The run's plan (:class:`Plan`: what to start, where, with which parameters) and the
command lines of its node processes."""

from __future__ import annotations

import argparse
import fnmatch
from collections.abc import Sequence
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

from apf_swarm_core.command_hold import STALE_AFTER
from apf_swarm_core.config import SwarmConfig

from ..topics import (
    PLANT_NODE,
    RECORDER_NODE,
    TARGET_NAMESPACE,
    TARGET_NODE,
    TRACKER_NODE,
    tracker_node_name,
    uav_namespace,
)
from .errors import BringupError

__all__ = [
    'PACKAGE',
    'Plan',
    'executable_path',
    'hosted_nodes',
    'node_commands',
    'node_netns',
    'package_prefix',
    'recorder_command',
    'ros_command',
]

PACKAGE = 'apf_swarm_nodes'


@dataclass(frozen=True)
class Plan:
    """One run as asked: the configuration and the options of ``apf-swarm up``, each field
    named as its option."""

    cfg: SwarmConfig
    out: Path
    mode: str = 'lockstep'
    trackers_per_process: int = 1
    #: ``NAME:=VALUE`` for every node
    node_params: Sequence[str] = ()
    record: bool = False
    on_recorder_death: str = 'stop'
    respawn: bool = False
    max_respawns: int = 3
    ready_timeout: float = 30.0
    stall_timeout: float = 20.0
    domain_id: int | None = None
    discovery_range: str = 'LOCALHOST'
    spawn: str = 'fork'
    #: ``PATTERN=NETNS``: the simulated host of the node processes a pattern matches
    node_netns: Sequence[str] = ()
    secure: bool = False
    secure_host: Sequence[str] = ()
    secure_address: str | None = None
    secure_pki: Path | None = None
    keep_keys: bool = False
    gains: str = 'auto'
    no_plots: bool = False
    #: the live view's port, None without ``--view``
    view: int | None = None
    view_host: str = '127.0.0.1'

    @classmethod
    def from_args(cls, args: argparse.Namespace, **given: Any) -> Plan:
        """The options in ``args``, then ``given``."""
        options = {f.name: getattr(args, f.name) for f in fields(cls) if hasattr(args, f.name)}
        return cls(**{**options, **given})

    @property
    def n(self) -> int:
        """The number of trackers."""
        return self.cfg.n_trackers

    def node_value(self, name: str, default: str) -> str:
        """A node parameter's value as given (the last one wins, as for ROS), else ``default``."""
        return dict(p.split(':=', 1) for p in self.node_params).get(name, default)

    @property
    def batch_commands(self) -> bool:
        """Whether a process of several trackers sends its commands as one message (realtime,
        aggregate inputs): the ``batch_commands`` node parameter, by default ``--secure``."""
        several = (
            self.mode == 'realtime'
            and self.trackers_per_process > 1
            and self.node_value('inputs', 'aggregate') == 'aggregate'
        )
        given = self.node_value('batch_commands', '')
        if given:
            return several and given.strip().lower() == 'true'
        return several and self.secure

    @property
    def stale_after(self) -> float:
        """The plant's: a tracker whose command answers an older state gets zero force."""
        return float(self.node_value('stale_after', str(STALE_AFTER)))


def executable_path(prefix: Path, name: str) -> Path:
    """The path of the package's executable ``name`` under the install ``prefix``."""
    return prefix / 'lib' / PACKAGE / name


def package_prefix() -> Path:
    """The package's install prefix (BringupError if it is not built)."""
    from ament_index_python.packages import PackageNotFoundError, get_package_prefix

    try:
        return Path(get_package_prefix(PACKAGE))
    except (PackageNotFoundError, KeyError, ValueError) as exc:
        raise BringupError(
            f'package {PACKAGE} is not in the ament index ({exc}); build with '
            '`make setup` and `source scripts/activate.sh`'
        ) from None


def ros_command(
    prefix: Path,
    exe: str,
    ros_args: Sequence[str],
    params: Sequence[str],
    args: Sequence[str] = (),
) -> list[str]:
    """``EXE ARGS --ros-args ROS_ARGS -p P...`` of the package's executable ``exe``."""
    ps = [a for p in params for a in ('-p', p)]
    return [str(executable_path(prefix, exe)), *args, '--ros-args', *ros_args, *ps]


def node_commands(
    prefix: Path,
    config_file: Path,
    n: int,
    mode: str,
    node_params: Sequence[str] = (),
    per_process: int = 1,
) -> list[tuple[str, list[str]]]:
    """(log name, argv) of every node process of the swarm; ``node_params`` go to every
    node; ``per_process`` > 1: that many trackers to a process (``trackers_<first>-<last>``)."""
    files = ['--params-file', str(config_file)]
    mine = f'mode:={mode}'
    started = [mine, 'wait_for_start:=true', *node_params]
    target = ['-r', f'__ns:={TARGET_NAMESPACE}', '-r', f'__node:={TARGET_NODE}']
    cmds = [
        ('target', ros_command(prefix, 'target', [*files, *target], started)),
        ('plant', ros_command(prefix, 'plant', [*files, '-r', f'__node:={PLANT_NODE}'], started)),
    ]
    if per_process > 1:
        for first in range(1, n + 1, per_process):
            ids = f'{first}-{min(n, first + per_process - 1)}'
            argv = ros_command(prefix, 'trackers', files, [mine, *node_params], ['--uav-ids', ids])
            cmds.append((f'trackers_{ids}', argv))
        return cmds
    for i in range(1, n + 1):
        names = ['-r', f'__ns:={uav_namespace(i)}', '-r', f'__node:={TRACKER_NODE}']
        params = [f'uav_id:={i}', mine, *node_params]
        cmds.append((f'tracker_{i}', ros_command(prefix, 'tracker', [*files, *names], params)))
    return cmds


def recorder_command(
    prefix: Path, mode: str, bag: Path, config_file: Path, node_params: Sequence[str]
) -> list[str]:
    """The recorder's argv: it records into ``bag`` (which must not exist)."""
    params = [f'mode:={mode}', f'output:={bag}', f'config_file:={config_file}', *node_params]
    return ros_command(prefix, 'recorder', ['-r', f'__node:={RECORDER_NODE}'], params)


def hosted_nodes(name: str) -> list[str]:
    """The fully qualified names of the nodes a process hosts, from its log name
    (``plant``, ``target``, ``tracker_3``, ``trackers_1-16``); [] for another."""
    if name == 'plant':
        return [f'/{PLANT_NODE}']
    if name == 'target':
        return [f'{TARGET_NAMESPACE}/{TARGET_NODE}']
    kind, _, ids = name.partition('_')
    first, _, last = ids.partition('-')
    if kind == 'tracker' and first.isdigit() and not last:
        return [tracker_node_name(int(first))]
    if kind == 'trackers' and first.isdigit() and last.isdigit():
        return [tracker_node_name(i) for i in range(int(first), int(last) + 1)]
    return []


def node_netns(name: str, rules: Sequence[str]) -> str | None:
    """The network namespace of node process ``name``: the first ``PATTERN=NETNS`` rule
    whose shell pattern matches it, or None."""
    for rule in rules:
        pattern, _, ns = rule.partition('=')
        if fnmatch.fnmatchcase(name, pattern):
            return ns
    return None
