"""Recorder node: every selected topic, as received (raw CDR), into a rosbag2 bag (MCAP).

The graph is polled every ``discovery_period``; each new topic that matches the selection
(``topics`` list, ``regex``, minus ``exclude``) and has a publisher gets a raw subscription
whose QoS follows its publishers (reliable only if every publisher is, transient local only if
every publisher is, keep last ``queue_depth``), and a connection in the bag with the full type
definition and the publishers' offered QoS (:class:`~apf_swarm_nodes.bags.BagWriter`). Messages
are stamped with their reception time and written without deserializing; the pending
chunk is flushed every ``flush_period`` so that a recorder killed by SIGKILL loses at most
that much (``apf-swarm bag reindex`` recovers the rest).

``~/status`` (std_msgs/String, JSON, reliable, transient local) says which topics are
recorded and whether every one of their publishers is matched (``ready``), and the counts;
the bring-up waits on it before it starts the clock. Counts: ``received`` (callbacks),
``written``, ``lost`` (gaps in the publication sequence numbers of single-publisher topics:
lost before the recorder took them, e.g. overwritten in a keep-last publisher history while
the recorder was starved) and ``dropped`` = received - written + lost; they go
into metadata.yaml ``custom_data`` (``apf_swarm.recorder``) and the last log line.

Spinning: no executor. The recorder waits on an rclpy wait set of its subscriptions (as
``rclpy.wait_for_message`` does) and takes every ready message with its MessageInfo: the stamp
is the DDS reception time (taken by the middleware when the sample arrived, not when the
recorder got the CPU), and the publication sequence number shows losses. The events
executor cannot hand a callback the MessageInfo (measured: SystemError in ``spin_once``) and
the single-threaded executor costs ~170 us per message (measured: a recorder on it lost 7 %
of a lockstep run's messages); the take loop costs less than either. Its periodic work
(discovery, flush, status) runs between waits.

SIGINT / SIGTERM: stop, take what is still queued (bounded ``drain_timeout``), close the bag
(summary, metadata.yaml), exit 0.
"""

from __future__ import annotations

import importlib
import json
import re
import signal
import sys
import time
from pathlib import Path
from typing import Any

import rclpy
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, ReliabilityPolicy
from std_msgs.msg import String

from .bags import CUSTOM_CONFIG, CUSTOM_MODE, CUSTOM_RECORDER, BagWriter
from .errors import CliError
from .node_common import START_QOS
from .params import MODES, NodeParam, declare_node_params
from .qos import profile_to_dict, qos_from_dict, recording_profile

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


def _msg_class(msgtype: str) -> Any:
    pkg, _, name = msgtype.partition('/msg/')
    try:
        return getattr(importlib.import_module(f'{pkg}.msg'), name)
    except (ImportError, AttributeError):
        return None


class _Topic:
    __slots__ = (
        'conn',
        'last_seq',
        'lost',
        'name',
        'received',
        'single_pub',
        'sub',
        'type',
        'written',
    )

    def __init__(self, name: str, msgtype: str, conn: Any) -> None:
        self.name, self.type, self.conn = name, msgtype, conn
        self.sub: Any = None
        self.received = self.written = self.lost = 0
        self.last_seq = 0
        self.single_pub = False


class RecorderNode(Node):
    """Raw subscriptions to the selected topics, written as received into a bag."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('recorder', **kwargs)
        self.declare_parameter(
            'topics',
            [''],
            descriptor=_str_array_descriptor(
                'topics',
                'record exactly these topics (empty list: all, subject to regex and exclude)',
            ),
        )
        p = declare_node_params(self, NODE_PARAMS)
        self.p = p
        self.wanted = [t for t in self.get_parameter('topics').value if t]
        try:
            self.regex = re.compile(p['regex']) if p['regex'] else None
            self.exclude = re.compile(p['exclude']) if p['exclude'] else None
        except re.error as exc:
            raise CliError(f'regex / exclude: not a regular expression ({exc})') from None
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
                raise CliError(f'config_file {p["config_file"]}: {exc.strerror}') from None
            self.writer.set_custom_data(CUSTOM_CONFIG, text, early=True)
        self.topics: dict[str, _Topic] = {}
        self.skipped: dict[str, str] = {}
        self.closed = False
        self.status_pub = self.create_publisher(String, '~/status', START_QOS)
        self.own = {self.status_pub.topic_name}
        self._last_status = ''
        #: [period, next due (monotonic), what]: run by :meth:`spin` between waits
        now = time.monotonic()
        self.periodic: list[list[Any]] = [
            [float(p['discovery_period']), now, self._discover],
            [float(p['flush_period']), now + float(p['flush_period']), self._flush],
            [0.5, now + 0.5, self._publish_status],
        ]
        self.get_logger().info(
            f'recording into {self.output} ('
            + ('topics ' + ', '.join(self.wanted) if self.wanted else 'all topics')
            + (f', regex {p["regex"]!r}' if self.regex else '')
            + (f', exclude {p["exclude"]!r}' if self.exclude else '')
            + (', zstd' if p['compress'] else '')
            + ')'
        )
        self._discover()

    # --- selection and subscriptions ------------------------------------------------------
    def selected(self, topic: str) -> bool:
        if topic in self.own:
            return False
        if self.wanted and topic not in self.wanted:
            return False
        if self.regex is not None and not self.regex.search(topic):
            return False
        return not (self.exclude is not None and self.exclude.search(topic))

    def _skip(self, topic: str, why: str) -> None:
        if self.skipped.get(topic) != why:
            self.skipped[topic] = why
            self.get_logger().warn(f'not recording {topic}: {why}')

    def _discover(self) -> None:
        if self.closed:
            return
        changed = False
        for topic, types in self.get_topic_names_and_types():
            if topic in self.topics or not self.selected(topic):
                continue
            pubs = [
                i
                for i in self.get_publishers_info_by_topic(topic)
                if not (
                    i.node_name == self.get_name() and i.node_namespace == self.get_namespace()
                )
            ]
            if not pubs:
                continue  # QoS and type come from a publisher: wait for one
            if len(types) != 1:
                self._skip(topic, f'several types {types}')
                continue
            msgtype = types[0]
            cls = _msg_class(msgtype)
            if cls is None:
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
            except CliError as exc:
                self._skip(topic, str(exc))
                continue
            qos = recording_profile(offered, int(self.p['queue_depth']))
            rel = qos.reliability == ReliabilityPolicy.RELIABLE
            tl = qos.durability == DurabilityPolicy.TRANSIENT_LOCAL
            t = _Topic(topic, msgtype, conn)
            t.single_pub = len(pubs) == 1
            # taken by spin(), never by an executor
            t.sub = self.create_subscription(cls, topic, _never_called, qos, raw=True)
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

    def _on_msg(self, t: _Topic, raw: bytes, info: dict[str, Any]) -> None:
        t.received += 1
        seq = info.get('publication_sequence_number')
        if seq:
            if t.single_pub and t.last_seq and seq > t.last_seq + 1:
                t.lost += seq - t.last_seq - 1
            t.last_seq = seq
        ts = info.get('received_timestamp') or time.time_ns()
        if self.closed:
            return
        self.writer.write(t.conn, int(ts), raw)
        t.written += 1

    def _flush(self) -> None:
        if not self.closed:
            self.writer.flush()

    # --- status and counts ----------------------------------------------------------------
    def counts(self) -> dict[str, Any]:
        rec = sum(t.received for t in self.topics.values())
        wr = sum(t.written for t in self.topics.values())
        lost = sum(t.lost for t in self.topics.values())
        return {
            'received': rec,
            'written': wr,
            'lost': lost,
            'dropped': rec - wr + lost,
            'topics': {
                t.name: {'received': t.received, 'written': t.written, 'lost': t.lost}
                for t in self.topics.values()
            },
            'skipped': dict(self.skipped),
        }

    def status(self) -> dict[str, Any]:
        topics = {}
        for t in self.topics.values():
            topics[t.name] = {
                'matched': t.sub.get_publisher_count(),
                'publishers': self.count_publishers(t.name),
            }
        ready = all(v['matched'] >= v['publishers'] for v in topics.values())
        c = self.counts()
        return {
            'bag': str(self.output),
            'ready': ready,
            'topics': topics,
            'received': c['received'],
            'written': c['written'],
            'dropped': c['dropped'],
        }

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


def _str_array_descriptor(name: str, text: str) -> Any:
    from rcl_interfaces.msg import ParameterDescriptor, ParameterType

    return ParameterDescriptor(
        name=name, type=ParameterType.PARAMETER_STRING_ARRAY, description=text, read_only=True
    )


def _never_called(_msg: Any) -> None:  # pragma: no cover -- no executor spins the recorder
    raise AssertionError('the recorder takes its messages in RecorderNode.spin')


def _take_all(node: RecorderNode, t: _Topic) -> int:
    """Take every message queued on ``t`` (with its MessageInfo); returns how many."""
    n = 0
    handle = t.sub.handle
    with handle:
        while True:
            got = handle.take_message(t.sub.msg_type, True)
            if got is None:
                return n
            node._on_msg(t, got[0], got[1])
            n += 1


def spin(node: RecorderNode, stop: list[int], drain: float) -> None:
    """Wait on the subscriptions, take what is ready, run the periodic work; after a signal
    (``stop`` not empty) take what is still queued until 0.2 s pass without a message (at
    most ``drain`` seconds)."""
    from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy

    ws, ws_topics = None, -1
    by_ptr: dict[int, _Topic] = {}
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


def main(args: list[str] | None = None) -> None:
    """Jazzy main: own SIGINT / SIGTERM handling so that the bag is closed after a drain."""
    from apf_swarm_core.errors import ApfSwarmError
    from rclpy.executors import ExternalShutdownException
    from rclpy.signals import SignalHandlerOptions

    stop: list[int] = []
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda signum, _frame: stop.append(signum))
    node: RecorderNode | None = None
    code = 0
    try:
        node = RecorderNode()
        # the start-up heap (rosbags' type store: thousands of classes) out of the collector's
        # reach, so that a full collection does not stall the take loop (the player measured
        # ~0.3 s stalls from it)
        import gc

        gc.collect()
        gc.freeze()
        spin(node, stop, float(node.p['drain_timeout']))
    except (ApfSwarmError, ValueError) as exc:
        print(f'recorder: error: {exc}', file=sys.stderr)
        code = 2
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if node is not None:
            try:
                c = node.close()
                lost = c['lost']
                msg = (
                    f'closed {node.output}: received {c["received"]}, written {c["written"]}, '
                    f'lost in transport {lost}, dropped {c["dropped"]} on '
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
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    sys.exit(code)


if __name__ == '__main__':
    main()
