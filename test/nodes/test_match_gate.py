"""The lockstep MatchGate: a first message waits for every reader it must reach (the plant's
and the recorder's), later ones only for the plant's; the newest held one goes out once."""

from __future__ import annotations

from typing import Any

from apf_swarm_nodes.node_common import MatchGate


class FakeTimer:
    def __init__(self, callback: Any) -> None:
        self.callback, self.running = callback, False

    def cancel(self) -> None:
        self.running = False

    def reset(self) -> None:
        self.running = True


class FakeNode:
    def __init__(self) -> None:
        self.timers: list[FakeTimer] = []

    def create_timer(self, _period: float, callback: Any) -> FakeTimer:
        self.timers.append(FakeTimer(callback))
        return self.timers[-1]


class FakePublisher:
    """Counts the readers it has matched, as the writer side sees them."""

    def __init__(self, matched: int) -> None:
        self.matched = matched

    def get_subscription_count(self) -> int:
        return self.matched


def tick(node: FakeNode) -> None:
    for t in node.timers:
        if t.running:
            t.callback()


def test_first_message_waits_for_the_recorder_then_only_for_the_plant() -> None:
    node, pub, sent = FakeNode(), FakePublisher(matched=1), []
    gate = MatchGate(node, pub, 1, first=2)
    gate(lambda: sent.append(0))  # plant matched, recorder not yet: held
    gate(lambda: sent.append(1))  # replaces the held one
    tick(node)
    assert sent == [] and node.timers[0].running
    pub.matched = 2
    tick(node)
    assert sent == [1] and not node.timers[0].running
    # the recorder gone: the run goes on with the plant alone
    pub.matched = 1
    gate(lambda: sent.append(2))
    assert sent == [1, 2]
    # no plant: held again until one matches
    pub.matched = 0
    gate(lambda: sent.append(3))
    tick(node)
    assert sent == [1, 2]
    pub.matched = 1
    tick(node)
    assert sent == [1, 2, 3]


def test_a_matched_publisher_sends_at_once_and_never_twice() -> None:
    node, pub, sent = FakeNode(), FakePublisher(matched=3), []
    gate = MatchGate(node, pub, 1, first=2)
    gate(lambda: sent.append(0))
    tick(node)
    tick(node)
    assert sent == [0] and not node.timers[0].running
