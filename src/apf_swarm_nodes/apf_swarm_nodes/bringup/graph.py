"""What the ROS graph must show before a run starts: every node, every expected publisher
and subscriber (:func:`expected_graph`, :func:`graph_missing`), and the recorder's status."""

from __future__ import annotations

import signal
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from ..topics import (
    CLOCK,
    SWARM_FORCE_CMDS,
    SWARM_ODOM,
    SWARM_STATE,
    TARGET_ODOM,
    TARGET_REQUEST,
    force_topic,
    odom_topic,
    swarm_node_names,
)


@dataclass(frozen=True)
class TopicExpectation:
    """A topic and the publisher / subscriber counts the graph must show.

    ``or_subscribers_of``: subscribers of that other topic count too (a tracker reads its
    inputs either from the per-UAV odometry topics or from the aggregate ``/swarm/odom``).
    ``optional``: only checked when the topic has a subscriber (``/swarm/odom`` when no
    tracker reads it).
    """

    topic: str
    publishers: int
    subscribers: int
    or_subscribers_of: str | None = None
    optional: bool = False


def expected_graph(
    n: int, mode: str, readers: int | None = None, batch_writers: int = 0
) -> tuple[list[str], list[TopicExpectation]]:
    """Fully qualified node names and topic endpoint counts of a swarm of ``n`` trackers.

    A tracker reads its inputs as ``/uav_<j>/odom`` and ``/target/odom`` (``inputs:=odom``)
    or as ``/swarm/odom`` (``inputs:=aggregate``); the counts accept either. ``readers``: how
    many subscribe to each (default n; see :func:`input_readers`). ``batch_writers``: the
    processes that send their commands as one ``/swarm/force_cmds`` message, which the
    plant must read before the start. ``/swarm/start`` and the bring-up's ``/swarm/state``
    subscription are checked on its own endpoints (:meth:`.graph_watch.GraphWatch.missing`).
    """
    nodes = swarm_node_names(n)
    topics = []
    readers = n if readers is None else readers
    for i in range(1, n + 1):
        topics.append(TopicExpectation(odom_topic(i), 1, readers, or_subscribers_of=SWARM_ODOM))
        topics.append(TopicExpectation(force_topic(i), 1, 1))
    topics.append(TopicExpectation(TARGET_ODOM, 1, readers + 1, or_subscribers_of=SWARM_ODOM))
    topics.append(TopicExpectation(SWARM_ODOM, 1, 0, optional=True))
    if mode == 'lockstep':
        topics.append(TopicExpectation(CLOCK, 1, 0))
        topics.append(TopicExpectation(TARGET_REQUEST, 1, 1))
    topics.append(TopicExpectation(SWARM_STATE, 1, 1))
    if batch_writers:
        topics.append(TopicExpectation(SWARM_FORCE_CMDS, batch_writers, 1))
    return nodes, topics


def input_readers(n: int, mode: str, per_process: int, inputs: str = 'aggregate') -> int:
    """How many subscribers read the trackers' inputs: one per tracker, except in realtime
    with the aggregate inputs (the nodes' ``inputs`` parameter), where a process of several
    trackers subscribes to ``/swarm/odom`` once and hands each message to its other nodes
    (the ``trackers`` executable): one per process."""
    if mode == 'realtime' and per_process > 1 and inputs == 'aggregate':
        return -(-n // per_process)
    return n


def graph_missing(
    present_nodes: Iterable[str],
    counts: Mapping[str, tuple[int, int]],
    nodes: Sequence[str],
    topics: Sequence[TopicExpectation],
) -> list[str]:
    """What is not there yet, in words (empty when the graph is complete).

    ``counts`` maps a topic to its (publishers, subscribers) as the graph shows them.
    """
    present = set(present_nodes)
    out = [f'node {name}' for name in nodes if name not in present]
    for t in topics:
        pubs, subs = counts.get(t.topic, (0, 0))
        if t.optional and subs == 0:
            continue
        extra = counts.get(t.or_subscribers_of, (0, 0))[1] if t.or_subscribers_of else 0
        if pubs < t.publishers or subs + extra < t.subscribers:
            sub_text = f'{subs}' + (
                f' + {extra} on {t.or_subscribers_of}' if t.or_subscribers_of else ''
            )
            need = f' (need >= {t.subscribers})' if t.subscribers else ''
            out.append(
                f'topic {t.topic}: publishers {pubs} (need {t.publishers}), '
                f'subscribers {sub_text}{need}'
            )
    return out


#: no fewer entities missing for this long [s], and a process none of whose nodes was ever
#: seen is restarted (:class:`UnseenRestart`)
STALL = 5.0
#: or: every other process has shown a node for this long [s], and this one none (how it
#: was chosen: docs/RELIABILITY.md, "Known fault: a node that is never discovered")
PEER_WAIT = 3.0
#: restarts of one process while the graph comes up
MAX_UNSEEN_RESTARTS = 2


class UnseenRestart:
    """Which node processes to restart while the graph comes up: those none of whose nodes
    the graph shows, once every other process has shown one for ``peer_wait`` seconds, or
    once the count of missing entities has not fallen for ``stall`` seconds; each at most
    ``limit`` times (why: docs/RELIABILITY.md, "Known fault: a node that is never
    discovered"). ``hosted``: each process's node names (:func:`.commands.hosted_nodes`).
    """

    def __init__(
        self,
        hosted: Mapping[str, Sequence[str]],
        stall: float = STALL,
        limit: int = MAX_UNSEEN_RESTARTS,
        peer_wait: float = PEER_WAIT,
    ) -> None:
        self.hosted = {name: list(nodes) for name, nodes in hosted.items() if nodes}
        self.stall, self.limit, self.peer_wait = stall, limit, peer_wait
        self.restarts: dict[str, int] = {}
        self._best: int | None = None
        self._since = 0.0
        self._shown: dict[str, float] = {}  # process -> when a node of it was first seen

    def due(self, now: float, missing: Sequence[str]) -> list[str]:
        """The processes to restart now [names], given the graph's ``missing`` entities (the
        lines of :func:`graph_missing`) at time ``now`` [s]; each one returned is counted
        as restarted."""
        gone = {line[len('node ') :] for line in missing if line.startswith('node ')}
        unseen = [n for n, nodes in self.hosted.items() if all(x in gone for x in nodes)]
        for name in self.hosted:
            if name not in unseen:
                self._shown.setdefault(name, now)
        progress = self._best is None or len(missing) < self._best
        if progress:
            self._best, self._since = len(missing), now
        stalled = not progress and now - self._since >= self.stall
        peers_up = (
            0 < len(unseen) < len(self.hosted)
            and len(self._shown) == len(self.hosted) - len(unseen)
            and now - max(self._shown.values()) >= self.peer_wait
        )
        if not (stalled or peers_up):
            return []
        names = [n for n in unseen if self.restarts.get(n, 0) < self.limit]
        for name in names:
            self.restarts[name] = self.restarts.get(name, 0) + 1
            self._shown.pop(name, None)
        if names:
            # the restarted processes get their own time to come up
            self._best, self._since = None, now
            for name in self._shown:
                self._shown[name] = now
        return names


#: the recorder drains its queues and writes the MCAP summary after SIGINT
RECORDER_STOP_SEQUENCE = ((signal.SIGINT, 20.0), (signal.SIGTERM, 3.0), (signal.SIGKILL, 2.0))


def recorder_missing(status: Mapping[str, Any] | None, topics: Sequence[str]) -> list[str]:
    """What the recorder has not got yet: ``topics`` it does not record, or a publisher it
    has not matched (``status``: its last ``/recorder/status`` document, None before one)."""
    if status is None:
        return ['recorder: no /recorder/status yet']
    rec = status.get('topics', {})
    out = [f'recorder: not recording {t} yet' for t in topics if t not in rec]
    for t, v in sorted(rec.items()):
        if v.get('matched', 0) < v.get('publishers', 0):
            out.append(
                f'recorder: {t} matched {v.get("matched")} of {v.get("publishers")} publishers'
            )
    return out
