"""Reading a bag's messages: raw records, the run's configuration, its trajectory and
summary (``apf-swarm bag metrics``)."""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterable, Iterator
from functools import partial
from pathlib import Path
from typing import Any

from ..topics import SWARM_STATE
from .errors import BagError
from .info import BagInfo, open_bag, reindex_hint
from .types import CUSTOM_CONFIG, CUSTOM_MODE, SWARM_STATE_TYPE, one_line, typestore

__all__ = [
    'bag_config',
    'bag_metrics',
    'bag_trajectory',
    'iter_raw',
    'messages',
    'swarm_state_decoder',
]


@contextlib.contextmanager
def _damaged(path: Path, what: str) -> Iterator[None]:
    """Errors of rosbags and mcap (ReaderError, AnyReaderError...) as BagError: a damaged file."""
    try:
        yield
    except Exception as exc:
        raise BagError(
            f'{path}: cannot read {what}, the file is damaged ({one_line(exc)}); '
            f'{reindex_hint(path)}'
        ) from None


def messages(
    info: BagInfo, topics: Iterable[str] | None = None, what: str = 'the messages'
) -> Iterator[tuple[Any, Any, int, bytes]]:
    """``(reader, connection, timestamp_ns, cdr)`` of every message on ``topics`` (None: all)
    in time order, with rosbags' AnyReader and the types of the bag's own definitions.

    The bag is opened at once: a definition that does not parse raises here; a damaged file
    is a BagError that says ``cannot read {what}``.
    """
    from rosbags.highlevel import AnyReader

    with _damaged(info.path, what):
        reader = AnyReader([info.path], default_typestore=typestore())
    try:
        reader.open()
    except Exception as exc:
        raise BagError(
            f'{info.path}: cannot load the type definitions stored in the bag '
            f'({one_line(exc)}); it was not written with full, valid ros2msg definitions'
        ) from None

    def read() -> Iterator[tuple[Any, Any, int, bytes]]:
        with _damaged(info.path, what), contextlib.closing(reader):
            conns = [c for c in reader.connections if topics is None or c.topic in topics]
            for conn, ts, raw in reader.messages(connections=conns):
                yield reader, conn, int(ts), raw

    return read()


def iter_raw(
    path: Path | str, topics: Iterable[str] | None = None, *, info: BagInfo | None = None
) -> Iterator[tuple[str, str, int, bytes]]:
    """``(topic, type, timestamp_ns, cdr bytes)`` of every message, in time order.

    ``topics``: only these (BagError for a topic that is not in the bag).
    """
    info = info or open_bag(path)
    wanted = None if topics is None else set(topics)
    for t in wanted or ():
        info.topic(t)
    for _reader, conn, ts, raw in messages(info, wanted):
        yield conn.topic, conn.msgtype, ts, bytes(raw)


def bag_config(info: BagInfo, config: Path | None = None) -> tuple[Any, str]:
    """The run's SwarmConfig and timing mode: from ``config`` (a parameter file) or from the
    bag's ``custom_data`` (the bring-up's recorder stores both)."""
    import tempfile

    from apf_swarm_core.config_files import load_config

    mode = info.custom_data.get(CUSTOM_MODE, 'lockstep')
    if config is not None:
        return load_config(config), mode
    text = info.custom_data.get(CUSTOM_CONFIG)
    if not text:
        raise BagError(
            f'{info.path} has no apf_swarm configuration in its custom_data (not '
            'recorded by `apf-swarm up --record`?); pass --config FILE'
        )
    with tempfile.TemporaryDirectory() as tmp:
        p = Path(tmp) / 'config.yaml'
        p.write_text(text)
        return load_config(p), mode


def swarm_state_decoder() -> Callable[[bytes], Any]:
    """A function that deserializes ``/swarm/state`` CDR bytes with rosbags (no rclpy)."""
    return partial(typestore().deserialize_cdr, typename=SWARM_STATE_TYPE)


def bag_trajectory(
    path: Path | str, config: Path | None = None, *, quiet: bool = True
) -> tuple[dict[str, Any], Any, str, Any]:
    """``(trajectory, cfg, mode, accumulator)`` of a bag's ``/swarm/state``: every message
    through the bring-up's StateAccumulator (the CDR decoded by rosbags, so that the bag tools
    need no rclpy). ``quiet=False``: a progress bar on stderr."""
    from ..analysis.samples import StateAccumulator
    from ..progress import progress_iter

    info = open_bag(path)
    cfg, mode = bag_config(info, config)
    count = info.topic(SWARM_STATE).count
    acc = StateAccumulator(mode, cfg.steps, cfg.record_every, swarm_state_decoder())
    messages = iter_raw(info.path, [SWARM_STATE], info=info)
    for _topic, _type, _ts, raw in progress_iter(messages, SWARM_STATE, total=count, quiet=quiet):
        acc.add_raw(raw)
    traj = acc.trajectory()
    if traj is None:
        raise BagError(f'{info.path}: /swarm/state has no message; nothing to compute')
    return traj, cfg, mode, acc


def bag_metrics(
    path: Path | str, config: Path | None = None, *, quiet: bool = True
) -> dict[str, Any]:
    """summary.json of the run from the bag's ``/swarm/state`` (:func:`runio.run_summary`, the
    function the bring-up uses), plus ``messages`` and ``mode``."""
    from ..analysis.runio import run_summary

    traj, cfg, mode, acc = bag_trajectory(path, config, quiet=quiet)
    status = 'completed' if mode == 'realtime' or acc.complete else 'incomplete'
    summary = run_summary(
        traj, cfg, status=status, n_samples=len(acc.samples), dropped=acc.dropped
    )
    summary['mode'] = mode
    summary['messages'] = acc.messages()
    return summary
