"""The recorder node's take loop (:func:`spin`): no executor.

The recorder waits on an rclpy wait set of its subscriptions (as ``rclpy.wait_for_message``
does) and takes every ready message with its MessageInfo: the stamp is the DDS reception time
(taken by the middleware when the sample arrived, not when the recorder got the CPU), and the
publication sequence number shows losses. The events executor cannot hand a callback the
MessageInfo (measured: SystemError in ``spin_once``) and the single-threaded executor costs
~170 us per message (measured: a recorder on it lost 7 % of a lockstep run's messages); the
take loop costs less than either. Its periodic work (discovery, flush, status) runs between
waits.
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from .recorder_node import RecorderNode
    from .recording import RecordedTopic

__all__ = ['never_called', 'spin']


def never_called(_msg: Any) -> None:  # pragma: no cover -- no executor spins the recorder
    """The callback of the recorder's subscriptions, which :func:`spin` takes from."""
    raise AssertionError('the recorder takes its messages in recorder_take.spin')


def _take_all(node: RecorderNode, t: RecordedTopic) -> int:
    """Take every message queued on ``t`` (with its MessageInfo); returns how many."""
    n = 0
    handle = t.sub.handle
    with handle:
        while True:
            got = handle.take_message(t.sub.msg_type, True)
            if got is None:
                return n
            node.on_message(t, got[0], got[1])
            n += 1


def spin(node: RecorderNode, stop: list[int], drain: float) -> None:
    """Wait on the subscriptions, take what is ready, run the periodic work; after a signal
    (``stop`` not empty) take what is still queued until 0.2 s pass without a message (at
    most ``drain`` seconds)."""
    from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy

    ws, ws_topics = None, -1
    by_ptr: dict[int, RecordedTopic] = {}
    while not stop and node.context.ok():
        now = time.monotonic()
        for job in node.periodic:
            if now >= job[1]:
                job[2]()
                job[1] = max(job[1] + job[0], now)
        topics = list(node.topics.values())
        if len(topics) != ws_topics:
            ws_topics = len(topics)
            ws = _rclpy.WaitSet(ws_topics, 0, 0, 0, 0, 0, node.context.handle) if topics else None
            by_ptr = {t.sub.handle.pointer: t for t in topics}
        timeout = min(0.05, max(0.0, min(job[1] for job in node.periodic) - time.monotonic()))
        if ws is None:
            time.sleep(timeout)
            continue
        ws.clear_entities()
        for t in topics:
            ws.add_subscription(t.sub.handle)
        ws.wait(int(timeout * 1e9))
        for ptr in ws.get_ready_entities('subscription'):
            _take_all(node, by_ptr[ptr])
    end = time.monotonic() + drain
    quiet_since = time.monotonic()
    while time.monotonic() < end and time.monotonic() - quiet_since < 0.2:
        if sum(_take_all(node, t) for t in list(node.topics.values())):
            quiet_since = time.monotonic()
        else:
            time.sleep(0.01)
