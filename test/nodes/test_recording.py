"""What the recorder decides and counts without ROS (apf_swarm_nodes.recording): the topic
selection, losses from publication sequence numbers, the counts and the status."""

from __future__ import annotations

from pathlib import Path

import pytest
from apf_swarm_nodes.errors import NodeParameterError
from apf_swarm_nodes.recording import (
    RecordedTopic,
    TopicSelection,
    recording_counts,
    recording_status,
)


def test_the_selection_lists_matches_and_excludes() -> None:
    every = TopicSelection([], '', '')
    every.own.add('/recorder/status')
    assert every('/swarm/state') and not every('/recorder/status')
    assert every.describe() == 'all topics'
    some = TopicSelection(['/a', '/b/c'], '^/b', 'c$')
    assert not some('/a') and not some('/b/c') and not some('/b')
    assert some.describe() == "topics /a, /b/c, regex '^/b', exclude 'c$'"
    with pytest.raises(NodeParameterError, match='not a regular expression'):
        TopicSelection([], '(', '')


def test_gaps_in_a_single_publishers_sequence_are_lost() -> None:
    t = RecordedTopic('/x', 'std_msgs/msg/Empty', None)
    t.single_pub = True
    for seq in (1, 2, 5, None, 6):
        t.take(seq)
    assert (t.received, t.lost, t.last_seq) == (5, 2, 6)
    many = RecordedTopic('/y', 'std_msgs/msg/Empty', None)
    for seq in (1, 7):
        many.take(seq)
    assert many.lost == 0  # several publishers: sequences interleave


def test_counts_and_status() -> None:
    a, b = RecordedTopic('/a', 't', None), RecordedTopic('/b', 't', None)
    a.received, a.written, a.lost = 10, 9, 2
    b.received = b.written = 3
    c = recording_counts([a, b], {'/c': 'several types'})
    assert (c['received'], c['written'], c['lost'], c['dropped']) == (13, 12, 2, 3)
    assert c['topics']['/a'] == {'received': 10, 'written': 9, 'lost': 2}
    assert c['skipped'] == {'/c': 'several types'}
    s = recording_status(Path('/bag'), {'/a': (1, 1), '/b': (0, 1)}, c)
    assert s['bag'] == '/bag' and not s['ready'] and s['dropped'] == 3
    assert s['topics']['/b'] == {'matched': 0, 'publishers': 1}
    assert recording_status(Path('/bag'), {'/a': (2, 1)}, c)['ready']
