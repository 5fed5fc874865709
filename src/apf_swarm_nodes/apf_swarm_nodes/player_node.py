"""Player node: republishes a bag's raw CDR messages with their recorded timing.

Message i goes out at ``t0 + (stamp_i - stamp_first) / rate`` (an absolute schedule: lateness
never accumulates), after the ``wait_for`` topics have a subscriber; ``start_offset``,
``loop``, ``topics``, remapping and ``/clock`` as docs/USAGE.md, *Bags*, describes. Each
publisher takes its first recorded publisher's reliability and durability.
``apf-swarm bag play`` runs this node in-process.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.qos import ReliabilityPolicy
from rosgraph_msgs.msg import Clock

from .bags import BagInfo, iter_raw, open_bag
from .dds.qos import replay_profile
from .errors import NodeParameterError
from .node_common import CLOCK_QOS, freeze_startup_heap, msg_class, run_node, running
from .params import EXECUTOR_PARAM, NodeParam, declare_node_params, declare_str_array
from .topics import CLOCK

__all__ = ['PRELOAD_BYTES', 'PlayerNode', 'main', 'run_player']

#: bags up to this size are read into memory before the start (no reading on the schedule)
PRELOAD_BYTES = 256 << 20

NODE_PARAMS = (
    EXECUTOR_PARAM,
    NodeParam('bag', '', 'the bag directory to play'),
    NodeParam('rate', 1.0, 'playback speed factor', lo=1e-3, hi=1e3),
    NodeParam('loop', False, 'play the bag again and again'),
    NodeParam(
        'start_offset', 0.0, 'skip this many seconds from the start of the bag [s]', lo=0.0, hi=1e9
    ),
    NodeParam('clock', 0.0, 'publish /clock at this rate [Hz] (0: no clock)', lo=0.0, hi=10000.0),
    NodeParam('queue_depth', 100, 'minimum keep-last depth of every publisher', lo=1, hi=100000),
    NodeParam(
        'wait_timeout',
        30.0,
        'how long to wait for the wait_for subscribers [s]',
        lo=0.0,
        hi=3600.0,
    ),
    NodeParam(
        'ack_timeout',
        5.0,
        'at the end, how long to wait for reliable acknowledgements [s]',
        lo=0.0,
        hi=600.0,
    ),
    NodeParam('exit_when_done', True, 'exit after the last message (false: stay up)'),
)


class PlayerNode(Node):
    """Publishers for the bag's topics and the timed replay (:meth:`play`)."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('player', **kwargs)
        p = declare_node_params(self, NODE_PARAMS)
        self.p = p
        #: called with ``(topic, raw)`` after each message is out (``bag play --view``)
        self.on_published: Callable[[str, bytes], None] | None = None
        self.topic_filter = declare_str_array(
            self, 'topics', 'play only these topics (empty: all)'
        )
        self.wait_for = declare_str_array(
            self,
            'wait_for',
            'before the start, wait until each of these '
            'topics (as published, after remapping) has a subscriber',
        )
        if not p['bag']:
            raise NodeParameterError(
                'parameter bag: the bag directory to play is required (-p bag:=DIR)'
            )
        self.info: BagInfo = open_bag(Path(p['bag']))
        for t in self.topic_filter:
            self.info.topic(t)
        self.rate = float(p['rate'])
        self.clock_hz = float(p['clock'])
        names = self.topic_filter or [t.name for t in self.info.topics]
        if self.clock_hz > 0:
            names = [n for n in names if n != CLOCK]
        self.pubs: dict[str, Any] = {}
        for name in names:
            t = self.info.topic(name)
            self.pubs[name] = self.create_publisher(
                msg_class(t.type), name, replay_profile(t.offered_qos, p['queue_depth'])
            )
        self.clock_pub = (
            self.create_publisher(Clock, CLOCK, CLOCK_QOS) if self.clock_hz > 0 else None
        )
        self.lateness_ns: list[int] = []
        self.published = 0
        self.get_logger().info(
            f'playing {self.info.path}: {len(self.pubs)} topics, '
            f'{self.info.duration:.2f} s at rate {self.rate:g}'
            + (f', /clock at {self.clock_hz:g} Hz' if self.clock_pub else '')
        )

    # --- the messages ---------------------------------------------------------------------
    def messages(self) -> Any:
        """``(stamp_ns, topic, bytes)`` from ``start_offset`` on, in time order."""
        t_from = self.info.start_ns + int(round(float(self.p['start_offset']) * 1e9))
        for topic, _type, ts, raw in iter_raw(self.info.path, list(self.pubs), info=self.info):
            if ts >= t_from:
                yield ts, topic, raw

    def wait_subscribers(self) -> None:
        topics = [self.resolve_topic_name(t) for t in self.wait_for]
        end = time.monotonic() + float(self.p['wait_timeout'])
        by_name = {pub.topic_name: pub for pub in self.pubs.values()}
        missing = [t for t in topics if t not in by_name]
        if missing:
            raise NodeParameterError(
                f'wait_for {missing}: not topics this player publishes '
                f'({", ".join(sorted(by_name))})'
            )
        while running():
            left = [t for t in topics if by_name[t].get_subscription_count() < 1]
            if not left:
                return
            if time.monotonic() > end:
                raise NodeParameterError(
                    f'no subscriber on {", ".join(left)} after '
                    f'{self.p["wait_timeout"]:g} s (wait_timeout)'
                )
            time.sleep(0.01)

    # --- the schedule ---------------------------------------------------------------------
    def _wait_until(self, due_ns: int, bag_at: Any) -> bool:
        """Sleep until ``due_ns`` (monotonic), publishing /clock on the way; False on shutdown."""
        period = int(1e9 / self.clock_hz) if self.clock_pub is not None else 0
        while True:
            now = time.monotonic_ns()
            if period and now >= self._next_clock:
                assert self.clock_pub is not None  # period > 0: /clock is published
                msg = Clock()
                msg.clock.sec, msg.clock.nanosec = divmod(int(bag_at(now)), 1_000_000_000)
                self.clock_pub.publish(msg)
                self._next_clock += period * max(1, (now - self._next_clock) // period + 1)
            target = min(due_ns, self._next_clock) if period else due_ns
            rem = target - time.monotonic_ns()
            if rem <= 0:
                if time.monotonic_ns() >= due_ns:
                    return True
                continue
            if not running():
                return False
            if rem > 50_000_000:
                time.sleep(0.05)
            elif rem > 300_000:
                time.sleep((rem - 200_000) / 1e9)
            # else: the last 0.3 ms without sleeping (a sleep overshoots its request)

    def _publish(self, topic: str, raw: bytes, due: int | None = None) -> int:
        """Publish, hand to :attr:`on_published`, note the lateness against ``due`` (None:
        the first message, which starts the schedule); returns the time it was out."""
        self.pubs[topic].publish(raw)
        if self.on_published is not None:
            self.on_published(topic, raw)
        now = time.monotonic_ns()
        self.lateness_ns.append(0 if due is None else now - due)
        self.published += 1
        return now

    def play(self) -> int:
        """Play (``loop``: forever); returns the number of messages published."""
        self.wait_subscribers()
        preload = self.info.size <= PRELOAD_BYTES
        cached = list(self.messages()) if preload else None
        freeze_startup_heap()
        t0 = time.monotonic_ns()
        self._next_clock = t0
        started = False
        while running():
            items = cached if cached is not None else self.messages()
            first = None
            last_due = t0
            for ts, topic, raw in items:
                if first is None:
                    first = ts
                    if not started:
                        # the schedule starts when the first message is out: the first
                        # write to a newly matched reader can take tens of ms, which would
                        # make every later one late
                        started = True
                        t0 = last_due = self._next_clock = self._publish(topic, raw)
                        continue

                def bag_at(now: int, first: int = first, t0: int = t0) -> int:
                    return first + int((now - t0) * self.rate)

                due = t0 + int((ts - first) / self.rate)
                if not self._wait_until(due, bag_at):
                    return self.published
                self._publish(topic, raw, due)
                last_due = due
            if not self.p['loop'] or first is None:
                break
            t0 = last_due + int(1e9 / max(self.clock_hz, 100.0))  # next pass right after
        timeout = Duration(seconds=float(self.p['ack_timeout']))
        for pub in self.pubs.values():
            if (
                pub.qos_profile.reliability == ReliabilityPolicy.RELIABLE
                and pub.get_subscription_count()
            ):
                pub.wait_for_all_acked(timeout)
        return self.published

    def report(self) -> str:
        if not self.lateness_ns:
            return 'published nothing'
        late = np.asarray(self.lateness_ns) / 1e6
        return (
            f'published {self.published} messages; lateness against the schedule p50 '
            f'{np.percentile(late, 50):.3f} ms, p99 {np.percentile(late, 99):.3f} ms, max '
            f'{late.max():.3f} ms'
        )


def run_player(node: PlayerNode) -> None:
    node.play()
    node.get_logger().info(node.report())
    if not node.p['exit_when_done']:
        while running():
            time.sleep(0.1)


def main(args: list[str] | None = None) -> None:
    """``player --ros-args -p bag:=DIR [-p rate:=2.0] [-r /a:=/b] ...``"""
    sys.exit(run_node('player', PlayerNode, args, run=run_player))


if __name__ == '__main__':
    main()
