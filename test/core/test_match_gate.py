"""The lockstep match gate's decisions, without ROS: the first publication waits for every
reader it must reach, later ones for the plant's alone, and only the newest held one goes."""

from __future__ import annotations

from apf_swarm_core.match_gate import MatchGate


def test_the_first_waits_for_the_recorder_later_ones_for_the_plant_alone() -> None:
    gate, sent = MatchGate(1, first=2), []
    assert gate.offer(lambda: sent.append(0), matched=1) is None
    assert gate.offer(lambda: sent.append(1), matched=1) is None  # replaces the held one
    assert gate.holding and gate.retry(matched=1) is None
    action = gate.retry(matched=2)
    assert action is not None and not gate.holding
    action()
    assert sent == [1]
    # the recorder gone: the run goes on with the plant alone
    go = gate.offer(lambda: sent.append(2), matched=1)
    assert go is not None and not gate.holding
    # no plant: held until one matches
    assert gate.offer(lambda: sent.append(3), matched=0) is None
    assert gate.retry(matched=1) is not None and gate.retry(matched=1) is None


def test_without_a_first_count_every_publication_needs_the_same_readers() -> None:
    gate = MatchGate(2)
    assert gate.offer(lambda: None, matched=1) is None
    assert gate.retry(matched=2) is not None
    assert gate.offer(lambda: None, matched=2) is not None
