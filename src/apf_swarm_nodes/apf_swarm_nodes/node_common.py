"""What every apf_swarm node shares: the QoS profile of each topic (the table and its
reasons: docs/ROS.md, "Topics and QoS"; the names are :mod:`.topics`'), the lockstep match
gate, the executor and the Jazzy ``main()``; for the recorder and player, the message class
of a type name and the start-up heap kept from the collector.
"""

from __future__ import annotations

import faulthandler
import gc
import importlib
import os
import re
import signal
import sys
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any

import rclpy
from apf_swarm_core.errors import ApfSwarmError
from apf_swarm_core.match_gate import MatchGate as CoreMatchGate
from rclpy.exceptions import ParameterException
from rclpy.executors import (
    ExternalShutdownException,
    MultiThreadedExecutor,
    SingleThreadedExecutor,
)
from rclpy.node import Node
from rclpy.qos import QoSProfile
from rclpy.signals import SignalHandlerOptions

from .dds.qos import make_profile
from .dds.secure import complete_environment
from .errors import NodeParameterError
from .stop_watchdog import NODE_STOP_BOUND, StopWatchdog

__all__ = [
    'CLOCK_QOS',
    'DEFAULT_EXECUTOR',
    'EXECUTORS',
    'INPUTS',
    'MATCH_RETRY',
    'REQUEST_QOS',
    'START_QOS',
    'STATE_QOS',
    'MatchGate',
    'RejectionLog',
    'control_qos',
    'environment_refused',
    'freeze_startup_heap',
    'msg_class',
    'run_node',
    'run_nodes',
    'running',
    'spin',
]

INPUTS = ('aggregate', 'odom')

#: deep enough that a reader paused for seconds loses nothing in lockstep
STATE_QOS = make_profile(reliable=True, transient_local=False, depth=5000)
START_QOS = make_profile(reliable=True, transient_local=True, depth=1)
#: only the latest request matters; a (re)started target gets it on joining
REQUEST_QOS = START_QOS
#: lockstep control topics and /clock: a reliable keep-last writer drops what a reader has not
#: acknowledged once ``depth`` newer samples exist; 1000 lets a recorder, or a tracker fed
#: from a bag, fall behind by over a second
LOCKSTEP_DEPTH = 1000


def control_qos(mode: str, depth: int = 1) -> QoSProfile:
    """QoS of odometry and force commands for a timing mode; ``depth``: realtime keep-last
    depth (the nodes' ``qos_depth``; 1, the newest sample, is the default and measured best)."""
    if mode == 'lockstep':
        return make_profile(reliable=True, transient_local=False, depth=LOCKSTEP_DEPTH)
    return make_profile(reliable=False, transient_local=False, depth=int(depth))


#: /clock: the lockstep control topics' profile
CLOCK_QOS = control_qos('lockstep')


#: how often a :class:`MatchGate` holding an action looks at its publisher again [s]
MATCH_RETRY = 0.01


class MatchGate:
    """Lockstep: what a node publishes waits until its publisher has matched its readers;
    the decision is :class:`apf_swarm_core.match_gate.MatchGate`'s (``need``, ``first``),
    this gives it the publisher's matched count and retries every :data:`MATCH_RETRY` s
    while it holds an action."""

    def __init__(self, node: Node, pub: Any, need: int = 1, first: int | None = None) -> None:
        self.pub, self.gate = pub, CoreMatchGate(need, first)
        # runs only while an action is held
        self._timer = node.create_timer(MATCH_RETRY, self._retry)
        self._timer.cancel()

    def __call__(self, action: Callable[[], None]) -> None:
        """Run ``action`` now if the readers are matched, else hold it."""
        self._run(self.gate.offer(action, self.pub.get_subscription_count()))

    def _retry(self) -> None:
        self._run(self.gate.retry(self.pub.get_subscription_count()))

    def _run(self, action: Callable[[], None] | None) -> None:
        if self.gate.holding:
            self._timer.reset()
        else:
            self._timer.cancel()
        if action is not None:
            action()


class RejectionLog:
    """Warn about refused inputs without flooding: each kind of reason (the reason with its
    numbers left out) at most once per ``period`` seconds, with the running total."""

    _NUMBER = re.compile(r'[-+]?\d[\d.e+-]*')

    def __init__(self, node: Node, period: float = 1.0) -> None:
        self.node, self.period = node, float(period)
        self._last: dict[str, float] = {}

    def __call__(self, why: str, total: int) -> None:
        kind = self._NUMBER.sub('#', why)
        now = time.monotonic()
        if now - self._last.get(kind, -1e9) >= self.period:
            self._last[kind] = now
            self.node.get_logger().warn(f'rejected: {why}; {total} rejected so far')


def msg_class(msgtype: str) -> Any:
    """The rclpy message class of ``pkg/msg/Name`` (NodeParameterError when it is not
    installed)."""
    pkg, _, name = msgtype.partition('/msg/')
    try:
        return getattr(importlib.import_module(f'{pkg}.msg'), name)
    except (ImportError, AttributeError, ValueError):
        raise NodeParameterError(
            f'message type {msgtype} is not installed here (no Python module '
            f'{pkg}.msg with {name or "?"}); source the workspace that defines it, '
            'or leave its topic out with --topics'
        ) from None


def freeze_startup_heap() -> None:
    """Move what start-up made (the rosbags type store alone is thousands of classes) out of
    the collector's reach before a timed loop, which a full collection of it would stall."""
    gc.collect()
    gc.freeze()


#: the executors a node can spin with (its ``executor`` parameter), and the default
EXECUTORS = ('events', 'single', 'multi')
DEFAULT_EXECUTOR = 'events'


def spin(node: Node | Sequence[Node], kind: str = DEFAULT_EXECUTOR) -> None:
    """Spin ``node`` (or several nodes on one executor) until shutdown or SIGINT / SIGTERM
    (:func:`run_nodes`), always between callbacks: ``events`` (the default)
    ``rclpy.experimental.EventsExecutor``, ``single`` or ``multi`` (for comparison only,
    docs/PERFORMANCE.md), each driven by ``spin_once`` with a 0.1 s timeout (the
    EventsExecutor's ``spin()`` ignores SIGINT in these wheels, docs/THEORY.md section 5).
    """
    nodes = [node] if isinstance(node, Node) else list(node)
    if kind == 'events':
        from rclpy.experimental import EventsExecutor

        executor = EventsExecutor()
    else:
        executor = MultiThreadedExecutor() if kind == 'multi' else SingleThreadedExecutor()
    for n in nodes:
        executor.add_node(n)
    try:
        while running():
            executor.spin_once(timeout_sec=0.1)
    finally:
        executor.shutdown()


#: set by SIGINT / SIGTERM in a node process (see :func:`run_nodes`)
_STOP = threading.Event()


def running() -> bool:
    """Whether a node process goes on: rclpy is up and no SIGINT / SIGTERM came (the
    spin loop and a ``run`` loop of :func:`run_nodes` check it between their steps)."""
    return rclpy.ok() and not _STOP.is_set()


def _stop_between_callbacks(signum: int, _frame: object) -> None:
    """The first SIGINT / SIGTERM stops the spin loop between callbacks; a second one (a
    callback or the shutdown hangs) terminates the process as usual."""
    _STOP.set()
    signal.signal(signum, signal.SIG_DFL)


def environment_refused(name: str) -> bool:
    """Take what a secure run's profile names into this process's environment before DDS
    starts (:func:`~.dds.secure.complete_environment`: a joining host needs only the
    profile); True, with the reason on stderr, when the environment contradicts it."""
    try:
        complete_environment(os.environ)
    except ApfSwarmError as exc:
        print(f'{name}: error: {exc}', file=sys.stderr)
        return True
    return False


def run_nodes(
    name: str,
    factories: Sequence[Callable[[], Node]],
    args: list[str] | None = None,
    run: Callable[[Any], None] | None = None,
) -> int:
    """The Jazzy ``main()`` for one or several nodes in one process: init, build the nodes,
    spin them together on one executor (the ``executor`` parameter of the first decides),
    and always destroy them and shut down.

    ``run``: what to do with the (single) node instead of spinning it (the player's timed
    loop, which checks :func:`running` between messages). A configuration error (bad
    parameter value or type) stops the process with one line on stderr naming the
    parameter, and exit code 2.
    """
    # SIGINT / SIGTERM end the spin loop (or the run loop) between two steps; rclpy's own
    # handler would shut the context down under a running callback or publish, whose next
    # rcl call then fails and is reported as a FATAL exception (exit 1) on a clean stop
    if environment_refused(name):
        return 2
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    signal.signal(signal.SIGINT, _stop_between_callbacks)
    signal.signal(signal.SIGTERM, _stop_between_callbacks)
    faulthandler.register(signal.SIGUSR1, all_threads=True)  # a hung process says where
    # a stop (signal, or the end) bounded even when the main thread is blocked in DDS
    watchdog = StopWatchdog(NODE_STOP_BOUND, who=name).install()
    nodes: list[Node] = []
    code = 0
    try:
        for factory in factories:
            nodes.append(factory())
        first = nodes[0]
        if run is not None:
            run(first)
        else:
            kind = (
                first.get_parameter('executor').value
                if first.has_parameter('executor')
                else DEFAULT_EXECUTOR
            )
            spin(nodes, kind)
    except (ApfSwarmError, ParameterException, ValueError) as exc:
        print(f'{name}: error: {exc}', file=sys.stderr)
        code = 2
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        watchdog.arm()  # leaving DDS must not hang either
        for n in nodes:
            n.destroy_node()
        rclpy.try_shutdown()
        watchdog.close()
    return code


def run_node(
    name: str,
    factory: Callable[[], Node],
    args: list[str] | None = None,
    run: Callable[[Any], None] | None = None,
) -> int:
    """:func:`run_nodes` for one node (every node's ``main()``)."""
    return run_nodes(name, [factory], args, run)
