"""The bring-up's own ROS node: its subscription to ``/swarm/state`` and the ``/swarm/start``
publisher, the wait until the graph shows every node and matched endpoint, and the drain
and shutdown at the end."""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable
from typing import Any

from ..analysis.samples import StateAccumulator
from ..topics import RECORDER_NODE, RECORDER_STATUS
from .commands import Plan, hosted_nodes
from .graph import (
    UnseenRestart,
    expected_graph,
    graph_missing,
    input_readers,
    recorder_missing,
)
from .processes import EXIT_BAD_INPUT, StopRun

__all__ = ['GraphWatch']


class GraphWatch:
    """The bring-up's node on the graph; ``acc`` takes the ``/swarm/state`` samples."""

    def __init__(self, plan: Plan, acc: StateAccumulator, say: Callable[[str], None]) -> None:
        self.plan, self.acc, self.say = plan, acc, say
        #: the topics whose extra publishers were warned of
        self.warned: set[str] = set()
        #: the recorder's last ``/recorder/status`` document (``--record``), None before one
        self.rec_status: dict[str, Any] | None = None
        # rclpy objects, made by init_ros() once rclpy is imported (this module does not)
        self.node: Any = None
        self.executor: Any = None
        self.state_sub: Any = None
        self.start_pub: Any = None

    def init_ros(self) -> None:
        """rclpy, the node (its own UDP-only participant), its executor and endpoints."""
        import rclpy
        from rclpy.experimental import EventsExecutor
        from rclpy.signals import SignalHandlerOptions
        from std_msgs.msg import Empty

        from apf_swarm_msgs.msg import SwarmState

        from ..dds.participant import own_participant
        from ..node_common import START_QOS, STATE_QOS
        from ..topics import SWARM_START, SWARM_STATE

        # args=[]: --node-param NAME:=VALUE would read as a remapping rule; UDP only: no call
        # can block on a shared-memory mutex a killed node held
        with own_participant():
            rclpy.init(args=[], signal_handler_options=SignalHandlerOptions.NO)
            self.node = rclpy.create_node('swarm_up')
        # the events executor costs less CPU per sample (bench/bench_scale.py --only lockstep)
        self.executor = EventsExecutor()
        self.executor.add_node(self.node)
        self.state_sub = self.node.create_subscription(
            SwarmState, SWARM_STATE, self.acc.add_raw, STATE_QOS, raw=True
        )
        if self.plan.record:
            import json

            from std_msgs.msg import String

            def on_status(msg: Any) -> None:
                with contextlib.suppress(ValueError):
                    self.rec_status = json.loads(msg.data)

            self.node.create_subscription(String, RECORDER_STATUS, on_status, START_QOS)
        self.start_pub = self.node.create_publisher(Empty, SWARM_START, START_QOS)
        self._empty_msg = Empty

    def spin(self, timeout: float) -> None:
        """Handle what arrived, waiting at most ``timeout`` s."""
        self.executor.spin_once(timeout_sec=timeout)

    def missing(self, domain_id: int | None) -> list[str]:
        """What the graph does not show yet, in words (:func:`.graph.graph_missing`, and this
        node's own matched endpoints); extra publishers warned of once."""
        node = self.node
        present = {
            (ns.rstrip('/') + '/' + name) for name, ns in node.get_node_names_and_namespaces()
        }
        plan = self.plan
        inputs = plan.node_value('inputs', 'aggregate')
        readers = input_readers(plan.n, plan.mode, plan.trackers_per_process, inputs)
        # a batching process is one that reads /swarm/odom for its trackers
        nodes, topics = expected_graph(
            plan.n, plan.mode, readers, readers if plan.batch_commands else 0
        )
        if plan.record:
            nodes = [*nodes, f'/{RECORDER_NODE}']
        counts = {
            t.topic: (node.count_publishers(t.topic), node.count_subscribers(t.topic))
            for t in topics
        }
        miss = graph_missing(present, counts, nodes, topics)
        for t in topics:
            if counts[t.topic][0] > t.publishers and t.topic not in self.warned:
                self.warned.add(t.topic)
                self.say(
                    f'warning: {t.topic} has {counts[t.topic][0]} publishers (expected '
                    f'{t.publishers}): another graph on ROS_DOMAIN_ID='
                    f'{domain_id}, or a respawned node not yet forgotten?'
                )
        # our own endpoints: matched counts, not mere discovery
        nstate = self.state_sub.get_publisher_count()
        if nstate < 1:
            miss.append(
                f"topic /swarm/state: this bring-up's subscription matched to "
                f'{nstate} publishers (need 1: the plant)'
            )
        # the plant waits for the start; the target only in realtime
        nstart = self.start_pub.get_subscription_count()
        want, who = (2, 'plant, target') if plan.mode == 'realtime' else (1, 'plant')
        if nstart < want:
            miss.append(
                f'topic /swarm/start: matched subscribers {nstart} (need >= {want}: {who})'
            )
        if plan.record:
            miss += recorder_missing(
                self.rec_status, [t.topic for t in topics if t.publishers and not t.optional]
            )
        return miss

    def publish_start(self) -> None:
        """``/swarm/start``: the run begins."""
        self.start_pub.publish(self._empty_msg())

    def wait_ready(
        self,
        between: Callable[[], None],
        domain_id: int | None,
        processes: list[str],
        restart: Callable[[list[str], str], None],
    ) -> None:
        """Spin until :meth:`missing` finds nothing, calling ``between`` each turn; StopRun
        after ``--ready-timeout``. ``restart``: the ``processes`` (log names)
        :class:`~.graph.UnseenRestart` picks."""
        unseen = UnseenRestart({p: hosted_nodes(p) for p in processes})
        t0 = time.monotonic()
        deadline = t0 + self.plan.ready_timeout
        last_check, last_report = 0.0, t0
        miss = ['(not checked yet)']
        while True:
            self.spin(0.05)
            between()
            now = time.monotonic()
            if now - last_check >= 0.1:
                last_check = now
                miss = self.missing(domain_id)
                if not miss:
                    return
                names = unseen.due(now, miss)
                if names:
                    times = max(unseen.restarts[n] for n in names)
                    restart(
                        names,
                        f'none of its nodes appeared in {now - t0:.1f} s, while its peers '
                        f'did or the graph stalled (restart {times} of at most '
                        f'{unseen.limit})',
                    )
            if now - last_report >= 5.0:
                last_report = now
                self.say(
                    f'waiting for the graph ({now - t0:.0f} s of '
                    f'{self.plan.ready_timeout:g}): {len(miss)} missing, e.g. {miss[0]}'
                )
            if now >= deadline:
                raise StopRun(
                    EXIT_BAD_INPUT,
                    'not_ready',
                    f'the ROS graph was not complete after {self.plan.ready_timeout:g} s '
                    f'(--ready-timeout, ROS_DOMAIN_ID={domain_id}); '
                    f'{len(miss)} never appeared:\n'
                    + ''.join(f'    {m}\n' for m in miss)
                    + f'  node logs: {self.plan.out / "logs"}',
                )

    def drain(self) -> None:
        """Take what is already queued (realtime end), for at most 0.2 s."""
        end = time.monotonic() + 0.2
        before = -1
        while time.monotonic() < end and before != self.acc.received:
            before = self.acc.received
            self.spin(0.02)

    def shutdown_ros(self) -> None:
        """Destroy the executor and the node, shut rclpy down."""
        import rclpy

        if self.executor is not None:
            self.executor.shutdown(timeout_sec=1.0)
            self.executor = None
        if self.node is not None:
            self.node.destroy_node()
            self.node = None
        rclpy.try_shutdown()
