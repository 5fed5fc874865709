"""The command lines of a run's node processes, and the network namespaces of simulated
hosts."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from ..topics import (
    PLANT_NODE,
    TARGET_NAMESPACE,
    TARGET_NODE,
    TRACKER_NODE,
    tracker_node_name,
    uav_namespace,
)
from .errors import BringupError
from .processes import PACKAGE


def executable_path(prefix: Path, name: str) -> Path:
    return prefix / 'lib' / PACKAGE / name


def package_prefix() -> Path:
    from ament_index_python.packages import PackageNotFoundError, get_package_prefix

    try:
        return Path(get_package_prefix(PACKAGE))
    except (PackageNotFoundError, KeyError, ValueError) as exc:
        raise BringupError(
            f'package {PACKAGE} is not in the ament index ({exc}); build with '
            '`make setup` and `source scripts/activate.sh`'
        ) from None


def node_commands(
    prefix: Path,
    config_file: Path,
    n: int,
    mode: str,
    node_params: Sequence[str] = (),
    per_process: int = 1,
) -> list[tuple[str, list[str]]]:
    """(log name, argv) of every node process of the swarm.

    ``node_params`` (``NAME:=VALUE``) go to every node, e.g. ``executor:=events``.
    ``per_process`` > 1: the trackers are hosted that many to a process (executable
    ``trackers``, log names ``trackers_<first>-<last>``), each still its own node
    ``/uav_<i>/tracker`` with its own parameters.
    """
    cfg = str(config_file)
    extra = [a for p in node_params for a in ('-p', p)]

    def exe(name: str) -> str:
        return str(executable_path(prefix, name))

    cmds = [
        (
            'target',
            [
                exe('target'),
                '--ros-args',
                '--params-file',
                cfg,
                '-r',
                f'__ns:={TARGET_NAMESPACE}',
                '-r',
                f'__node:={TARGET_NODE}',
                '-p',
                f'mode:={mode}',
                '-p',
                'wait_for_start:=true',
                *extra,
            ],
        ),
        (
            'plant',
            [
                exe('plant'),
                '--ros-args',
                '--params-file',
                cfg,
                '-r',
                f'__node:={PLANT_NODE}',
                '-p',
                f'mode:={mode}',
                '-p',
                'wait_for_start:=true',
                *extra,
            ],
        ),
    ]
    if per_process > 1:
        for first in range(1, n + 1, per_process):
            last = min(n, first + per_process - 1)
            cmds.append(
                (
                    f'trackers_{first}-{last}',
                    [
                        exe('trackers'),
                        '--uav-ids',
                        f'{first}-{last}',
                        '--ros-args',
                        '--params-file',
                        cfg,
                        '-p',
                        f'mode:={mode}',
                        *extra,
                    ],
                )
            )
        return cmds
    for i in range(1, n + 1):
        cmds.append(
            (
                f'tracker_{i}',
                [
                    exe('tracker'),
                    '--ros-args',
                    '--params-file',
                    cfg,
                    '-r',
                    f'__ns:={uav_namespace(i)}',
                    '-r',
                    f'__node:={TRACKER_NODE}',
                    '-p',
                    f'uav_id:={i}',
                    '-p',
                    f'mode:={mode}',
                    *extra,
                ],
            )
        )
    return cmds


def hosted_nodes(name: str) -> list[str]:
    """The fully qualified names of the nodes a process of :func:`node_commands` hosts, from
    its log name (``plant``, ``target``, ``tracker_3``, ``trackers_1-16``); [] for another."""
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


def node_netns(name: str, rules: Sequence[str] | None) -> str | None:
    """The network namespace a node process runs in: the first ``PATTERN=NETNS`` rule whose
    shell pattern matches its log name (``tracker_3``, ``trackers_1-2``, ``plant``), or None."""
    import fnmatch

    for rule in rules or ():
        pattern, _, ns = rule.partition('=')
        if fnmatch.fnmatchcase(name, pattern):
            return ns
    return None
