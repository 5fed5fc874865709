"""What the ROS graph must show before a run starts (:func:`expected_graph`,
:func:`graph_missing`, :func:`recorder_missing`), and which processes to restart meanwhile."""

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

__all__ = [
    'MAX_UNSEEN_RESTARTS',
    'RECORDER_STOP_SEQUENCE',
    'TopicExpectation',
    'UnseenRestart',
    'expected_graph',
    'graph_missing',
    'input_readers',
    'recorder_missing',
]


@dataclass(frozen=True)
class TopicExpectation:
    """A topic and the publisher / subscriber counts the graph must show; subscribers of
    ``or_subscribers_of`` count too; ``optional``: checked only when it has a subscriber."""

    topic: str
    publishers: int
    subscribers: int
    or_subscribers_of: str | None = None
    optional: bool = False


def expected_graph(
    n: int, mode: str, readers: int | None = None, batch_writers: int = 0
) -> tuple[list[str], list[TopicExpectation]]:
    """Fully qualified node names and topic endpoint counts of a swarm of ``n`` trackers.

    Inputs are read per UAV (``inputs:=odom``) or from ``/swarm/odom``; the counts accept
    either. ``readers``: subscribers of each (default n; :func:`input_readers`).
    ``batch_writers``: processes that send one ``/swarm/force_cmds`` message."""
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
    """How many subscribers read the trackers' inputs: one per tracker, or one per process
    in realtime with aggregate inputs and several trackers to a process."""
    if mode == 'realtime' and per_process > 1 and inputs == 'aggregate':
        return -(-n // per_process)
    return n


def graph_missing(
    present_nodes: Iterable[str],
    counts: Mapping[str, tuple[int, int]],
    nodes: Sequence[str],
    topics: Sequence[TopicExpectation],
) -> list[str]:
    """What is not there yet, in words (empty when complete); ``counts``: topic ->
    (publishers, subscribers) as the graph shows them."""
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


#: :class:`UnseenRestart`'s waits [s] (docs/RELIABILITY.md, "Known fault: a node that is
#: never discovered"): no fewer entities missing, every other process shown
STALL, PEER_WAIT = 5.0, 3.0
#: restarts of one process while the graph comes up
MAX_UNSEEN_RESTARTS = 2


class UnseenRestart:
    """Which node processes to restart while the graph comes up: those none of whose nodes
    it shows, once every other has shown one for ``peer_wait`` s or the missing count has
    not fallen for ``stall`` s; each at most ``limit`` times. ``hosted``: process -> its node
    names (:func:`.commands.hosted_nodes`)."""

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
        """The processes to restart at ``now`` [s] (counted as restarted), given the lines of
        :func:`graph_missing`."""
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
    """What the recorder has not got yet, from its last ``/recorder/status`` (or None)."""
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
