"""Recorder node: every selected topic, as received (raw CDR), into a rosbag2 bag (MCAP).

New topics are found by polling the graph; each gets a raw subscription whose QoS follows its
publishers and a connection in the bag (:class:`~apf_swarm_nodes.bags.BagWriter`), flushed
every ``flush_period``. ``~/status`` (JSON) says which topics are recorded and matched and
the counts (:mod:`.recording`). SIGINT / SIGTERM: take what is queued, close the bag, exit 0.
docs/USAGE.md, *Bags*, tells the rest (stamps, losses, spinning).
"""

from __future__ import annotations

import json
import signal
import sys
import time
from functools import partial
from pathlib import Path
from typing import Any

import rclpy
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, ReliabilityPolicy
from std_msgs.msg import String

from .bags import CUSTOM_CONFIG, CUSTOM_MODE, CUSTOM_RECORDER, BagError, BagWriter
from .dds.qos import profile_to_dict, qos_from_dict, recording_profile
from .errors import NodeParameterError
from .node_common import START_QOS, environment_refused, freeze_startup_heap, msg_class
from .params import MODES, NodeParam, declare_node_params, declare_str_array
from .recording import RecordedTopic, TopicSelection, recording_counts, recording_status
from .stop_watchdog import NODE_STOP_BOUND, StopWatchdog
from .topics import PRIVATE_STATUS

__all__ = ['RecorderNode', 'main', 'spin']

NODE_PARAMS = (
    NodeParam(
        'output',
        '',
        'bag directory to create (must not exist); empty: '
        'rosbag2_<date>-<time> in the working directory',
    ),
    NodeParam('regex', '', 'record only topics matching this regular expression (empty: all)'),
    NodeParam('exclude', '', 'never record topics matching this regular expression'),
    NodeParam('compress', False, 'zstd-compress the MCAP chunks'),
    NodeParam('chunk_size', 1 << 20, 'uncompressed chunk size [bytes]', lo=1024, hi=1 << 30),
    NodeParam(
        'flush_period',
        1.0,
        'close and flush the pending chunk this often [s]: what a SIGKILL can lose',
        lo=0.01,
        hi=3600.0,
    ),
    NodeParam(
        'split_size', 0, 'start a new MCAP file after this many bytes (0: never)', lo=0, hi=1 << 50
    ),
    NodeParam(
        'split_duration',
        0.0,
        'start a new MCAP file after this many seconds (0: never)',
        lo=0.0,
        hi=1e9,
    ),
    NodeParam('queue_depth', 1000, 'depth of every subscription (keep last)', lo=1, hi=100000),
    NodeParam(
        'discovery_period',
        0.1,
        'how often the graph is polled for new topics [s]',
        lo=0.01,
        hi=60.0,
    ),
    NodeParam(
        'drain_timeout',
        2.0,
        'at shutdown, take queued messages for at most this long [s]',
        lo=0.0,
        hi=60.0,
    ),
    NodeParam('mode', 'lockstep', 'timing mode of the run (stored in the bag)', choices=MODES),
    NodeParam(
        'config_file',
        '',
        "the run's parameter file, stored in the bag (custom_data) so "
        'that `apf-swarm bag metrics` needs nothing else',
    ),
)


#: the pause after each turn of the executor [s], so that the next turn takes at once what
#: arrived meanwhile (the stamps are the middleware's reception times, which it does not change)
TURN_PAUSE = 0.005
#: no QoS event handlers on the subscriptions (see RecorderNode.__init__)
NO_EVENTS = SubscriptionEventCallbacks(use_default_callbacks=False)


class RecorderNode(Node):
    """Raw subscriptions to the selected topics, written as received into a bag."""

    def __init__(self, **kwargs: Any) -> None:
        # parameter services and QoS event handlers would be waited on at every turn of the
        # executor, whose cost is per message here (a recorder never served them)
        kwargs.setdefault('start_parameter_services', False)
        super().__init__('recorder', **kwargs)
        wanted = declare_str_array(
            self,
            'topics',
            'record exactly these topics (empty list: all, subject to regex and exclude)',
        )
        p = declare_node_params(self, NODE_PARAMS)
        self.p = p
        self.selected = TopicSelection(wanted, p['regex'], p['exclude'])
        out = p['output'] or time.strftime('rosbag2_%Y_%m_%d-%H_%M_%S')
        self.output = Path(out).expanduser().resolve()
        self.writer = BagWriter(
            self.output,
            compress=p['compress'],
            chunk_size=p['chunk_size'],
            split_size=p['split_size'],
            split_duration=p['split_duration'],
        )
        self.writer.open()
        self.writer.set_custom_data(CUSTOM_MODE, p['mode'], early=True)
        if p['config_file']:
            try:
                text = Path(p['config_file']).read_text()
            except OSError as exc:
                raise NodeParameterError(
                    f'config_file {p["config_file"]}: {exc.strerror}'
                ) from None
            self.writer.set_custom_data(CUSTOM_CONFIG, text, early=True)
        self.topics: dict[str, RecordedTopic] = {}
        self.skipped: dict[str, str] = {}
        self.closed = False
        self.status_pub = self.create_publisher(String, PRIVATE_STATUS, START_QOS)
        self.selected.own.add(self.status_pub.topic_name)
        self._last_status = ''
        #: [period, next due (monotonic), what]: run by :func:`spin` between waits
        now = time.monotonic()
        self.periodic: list[list[Any]] = [
            [float(p['discovery_period']), now, self._discover],
            [float(p['flush_period']), now + float(p['flush_period']), self.writer.flush],
            [0.5, now + 0.5, self._publish_status],
        ]
        self.get_logger().info(
            f'recording into {self.output} ({self.selected.describe()}'
            + (', zstd' if p['compress'] else '')
            + ')'
        )
        self._discover()

    # --- subscriptions ---------------------------------------------------------------------
    def _skip(self, topic: str, why: str) -> None:
        if self.skipped.get(topic) != why:
            self.skipped[topic] = why
            self.get_logger().warn(f'not recording {topic}: {why}')

    def _discover(self) -> None:
        if self.closed:
            return
        changed = False
        me = (self.get_name(), self.get_namespace())
        for topic, types in self.get_topic_names_and_types():
            if topic in self.topics or not self.selected(topic):
                continue
            infos = self.get_publishers_info_by_topic(topic)
            pubs = [i for i in infos if (i.node_name, i.node_namespace) != me]
            if not pubs:
                continue  # QoS and type come from a publisher: wait for one
            if len(types) != 1:
                self._skip(topic, f'several types {types}')
                continue
            msgtype = types[0]
            try:
                cls = msg_class(msgtype)
            except NodeParameterError:
                self._skip(
                    topic,
                    f'type {msgtype} is not installed (no Python module); build '
                    'and source the package that defines it',
                )
                continue
            offered = [profile_to_dict(i.qos_profile) for i in pubs]
            try:
                conn = self.writer.add_topic(
                    topic, msgtype, offered_qos=[qos_from_dict(o) for o in offered]
                )
            except BagError as exc:
                self._skip(topic, str(exc))
                continue
            qos = recording_profile(offered, int(self.p['queue_depth']))
            rel = qos.reliability == ReliabilityPolicy.RELIABLE
            tl = qos.durability == DurabilityPolicy.TRANSIENT_LOCAL
            t = RecordedTopic(topic, msgtype, conn)
            t.single_pub = len(pubs) == 1
            # two arguments: the executor hands the callback the MessageInfo too
            t.sub = self.create_subscription(
                cls, topic, partial(self.on_message, t), qos, raw=True, event_callbacks=NO_EVENTS
            )
            self.topics[topic] = t
            changed = True
            self.get_logger().info(
                f'recording {topic} [{msgtype}] '
                f'({"reliable" if rel else "best effort"}'
                f'{", transient local" if tl else ""}, {len(pubs)} '
                f'publisher{"s" if len(pubs) > 1 else ""})'
            )
        for t in self.topics.values():
            t.single_pub = self.count_publishers(t.name) <= 1
        if changed:
            self._publish_status()

    def take_all(self, t: RecordedTopic) -> int:
        """Take every message queued on ``t`` (with its MessageInfo); returns how many
        (``take_message`` on the subscription's handle: docs/PERFORMANCE.md, Bags, ``take_all``,
        compares it with ``spin_once``)."""
        n = 0
        handle = t.sub.handle
        with handle:
            while (got := handle.take_message(t.sub.msg_type, True)) is not None:
                self.on_message(t, got[0], got[1])
                n += 1
        return n

    def on_message(self, t: RecordedTopic, raw: bytes, info: dict[str, Any]) -> None:
        """A message taken from ``t`` with its MessageInfo: counted, and written with its
        reception time."""
        t.take(info.get('publication_sequence_number'))
        ts = info.get('received_timestamp') or time.time_ns()
        if self.closed:
            return
        self.writer.write(t.conn, int(ts), raw)
        t.written += 1

    # --- status and counts ----------------------------------------------------------------
    def counts(self) -> dict[str, Any]:
        return recording_counts(self.topics.values(), self.skipped)

    def status(self) -> dict[str, Any]:
        links = {
            t.name: (t.sub.get_publisher_count(), self.count_publishers(t.name))
            for t in self.topics.values()
        }
        return recording_status(self.output, links, self.counts())

    def _publish_status(self) -> None:
        if self.closed:
            return
        text = json.dumps(self.status(), sort_keys=True)
        if text != self._last_status:
            self._last_status = text
            self.status_pub.publish(String(data=text))

    def close(self) -> dict[str, Any]:
        """Stop writing, close the bag (summaries, metadata.yaml); returns the counts."""
        if self.closed:
            return self.counts()
        c = self.counts()
        self.writer.set_custom_data(CUSTOM_RECORDER, json.dumps(c, sort_keys=True))
        self.closed = True
        self.writer.close()
        return c


def spin(node: RecorderNode, stop: list[int], drain: float) -> None:
    """Run the subscriptions' callbacks and, between them, the periodic work; after a signal
    (``stop`` not empty) take what is still queued until 0.2 s pass without a message (at
    most ``drain`` seconds)."""
    from rclpy.executors import SingleThreadedExecutor

    executor = SingleThreadedExecutor(context=node.context)
    executor.add_node(node)
    try:
        while not stop and node.context.ok():
            now = time.monotonic()
            for job in node.periodic:
                if now >= job[1]:
                    job[2]()
                    job[1] = max(job[1] + job[0], now)
            timeout = min(0.05, max(0.0, min(job[1] for job in node.periodic) - time.monotonic()))
            # a turn runs one callback (one message): take every queue's others too
            executor.spin_once(timeout_sec=timeout)
            for t in list(node.topics.values()):
                node.take_all(t)
            time.sleep(TURN_PAUSE)
        end = time.monotonic() + drain
        quiet_since = time.monotonic()
        while time.monotonic() < end and time.monotonic() - quiet_since < 0.2:
            if sum(node.take_all(t) for t in list(node.topics.values())):
                quiet_since = time.monotonic()
            else:
                time.sleep(0.01)
    finally:
        executor.shutdown()


def main(args: list[str] | None = None) -> None:
    """Jazzy main: own SIGINT / SIGTERM handling so that the bag is closed after a drain."""
    from apf_swarm_core.errors import ApfSwarmError
    from rclpy.executors import ExternalShutdownException
    from rclpy.signals import SignalHandlerOptions

    stop: list[int] = []
    if environment_refused('recorder'):
        sys.exit(2)
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda signum, _frame: stop.append(signum))
    # the stop bounded even when the main thread is blocked in DDS: the drain, the bag's
    # close and leaving DDS (the bound grows with the drain once the parameter is read)
    watchdog = StopWatchdog(NODE_STOP_BOUND, who='recorder').install()
    node: RecorderNode | None = None
    code = 0
    try:
        node = RecorderNode()
        watchdog.bound = NODE_STOP_BOUND + float(node.p['drain_timeout'])
        freeze_startup_heap()
        spin(node, stop, float(node.p['drain_timeout']))
    except (ApfSwarmError, ValueError) as exc:
        print(f'recorder: error: {exc}', file=sys.stderr)
        code = 2
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        watchdog.arm()
        if node is not None:
            try:
                c = node.close()
                msg = (
                    f'closed {node.output}: received {c["received"]}, written {c["written"]}, '
                    f'lost in transport {c["lost"]}, dropped {c["dropped"]} on '
                    f'{len(c["topics"])} topics'
                )
                print(
                    f'recorder: {msg}' if not c['dropped'] else f'recorder: warning: {msg}',
                    file=sys.stderr,
                    flush=True,
                )
            except Exception as exc:
                print(f'recorder: error: closing {node.output}: {exc}', file=sys.stderr)
                code = code or 1
            node.destroy_node()
        rclpy.try_shutdown()
        watchdog.close()
    sys.exit(code)


if __name__ == '__main__':
    main()
