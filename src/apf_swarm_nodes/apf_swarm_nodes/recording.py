"""What the recorder node decides and counts, without ROS: which topics it records
(:class:`TopicSelection`), what each recorded topic received, wrote and lost
(:class:`RecordedTopic`), and the counts and status it reports (:func:`recording_counts`,
:func:`recording_status`).

Counts: ``received`` (callbacks), ``written``, ``lost`` (gaps in the publication sequence
numbers of single-publisher topics: lost before the recorder took them, e.g. overwritten in a
keep-last publisher history while the recorder was starved) and ``dropped`` = received -
written + lost.
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from .errors import NodeParameterError

__all__ = ['RecordedTopic', 'TopicSelection', 'recording_counts', 'recording_status']


class TopicSelection:
    """The topics to record: those listed in ``wanted`` (empty: all), matching ``regex``
    (empty: all), never those matching ``exclude`` nor the recorder's ``own``;
    NodeParameterError when ``regex`` or ``exclude`` is not a regular expression."""

    def __init__(self, wanted: Sequence[str], regex: str, exclude: str) -> None:
        self.wanted = list(wanted)
        self.own: set[str] = set()
        try:
            self.regex = re.compile(regex) if regex else None
            self.exclude = re.compile(exclude) if exclude else None
        except re.error as exc:
            raise NodeParameterError(
                f'regex / exclude: not a regular expression ({exc})'
            ) from None

    def __call__(self, topic: str) -> bool:
        """Whether ``topic`` is recorded."""
        return not (
            topic in self.own
            or (self.wanted and topic not in self.wanted)
            or (self.regex is not None and not self.regex.search(topic))
            or (self.exclude is not None and self.exclude.search(topic))
        )

    def describe(self) -> str:
        """The selection in words, for the log."""
        return (
            ('topics ' + ', '.join(self.wanted) if self.wanted else 'all topics')
            + (f', regex {self.regex.pattern!r}' if self.regex is not None else '')
            + (f', exclude {self.exclude.pattern!r}' if self.exclude is not None else '')
        )


@dataclass(slots=True, eq=False)
class RecordedTopic:
    """One recorded topic: its bag connection ``conn``, its subscription ``sub`` (set by the
    node) and its counts."""

    name: str
    type: str
    conn: Any
    sub: Any = None
    received: int = 0
    written: int = 0
    lost: int = 0
    last_seq: int = 0
    single_pub: bool = False

    def take(self, seq: int | None) -> None:
        """A message received with publication sequence number ``seq`` (None or 0: not
        known): a gap after the previous one of a single publisher counts as lost."""
        self.received += 1
        if seq:
            if self.single_pub and self.last_seq and seq > self.last_seq + 1:
                self.lost += seq - self.last_seq - 1
            self.last_seq = seq


def recording_counts(
    topics: Iterable[RecordedTopic], skipped: Mapping[str, str]
) -> dict[str, Any]:
    """The totals and per-topic counts, and the topics not recorded with why."""
    topics = list(topics)
    rec = sum(t.received for t in topics)
    wr = sum(t.written for t in topics)
    lost = sum(t.lost for t in topics)
    return {
        'received': rec,
        'written': wr,
        'lost': lost,
        'dropped': rec - wr + lost,
        'topics': {
            t.name: {'received': t.received, 'written': t.written, 'lost': t.lost} for t in topics
        },
        'skipped': dict(skipped),
    }


def recording_status(
    bag: Path, links: Mapping[str, tuple[int, int]], counts: Mapping[str, Any]
) -> dict[str, Any]:
    """The ``~/status`` of a recorder writing ``bag``: per topic its (matched, publishers)
    from ``links``, ``ready`` when every publisher is matched, and the totals of
    :func:`recording_counts`."""
    topics = {name: {'matched': m, 'publishers': p} for name, (m, p) in links.items()}
    return {
        'bag': str(bag),
        'ready': all(v['matched'] >= v['publishers'] for v in topics.values()),
        'topics': topics,
        'received': counts['received'],
        'written': counts['written'],
        'dropped': counts['dropped'],
    }
