"""Tracker node: one tracking UAV's sliding-mode controller. Reads ``/swarm/odom`` (or, with
``inputs:=odom``, every ``odom`` and ``/target/odom``); publishes ``force_cmd`` and, as
``outputs`` selects, ``accel_cmd`` / ``velocity_cmd`` setpoints. What to send and when (a
command, the safe brake, a refusal) is decided by :mod:`apf_swarm_core.tracker_modes`; each
command carries the process's random ``instance`` (docs/ROS.md)."""

from __future__ import annotations

import random
import sys
import time
from functools import partial
from typing import Any

from apf_swarm_core.agents import TrackerAgent
from apf_swarm_core.config import REALTIME_RATE, SwarmConfig
from apf_swarm_core.tracker_modes import Reply, SwarmOdom, tracker_mode
from builtin_interfaces.msg import Time
from geometry_msgs.msg import AccelStamped, TwistStamped
from nav_msgs.msg import Odometry
from rclpy.node import Node

from apf_swarm_msgs.msg import ForceCommand, SwarmOdometry

from .conversions import (
    accel_msg,
    dt_to_ns,
    odom_arrays,
    reply_msg,
    stamp_ns,
    swarm_odom_arrays,
    twist_msg,
)
from .node_common import MatchGate, RejectionLog, control_qos, run_node
from .params import (
    TRACKER_PARAMS,
    WATCHDOG_RATE,
    declare_swarm_node,
    install_validator,
    parse_outputs,
)
from .topics import ACCEL_CMD, FORCE_CMD, ODOM, SWARM_ODOM, TARGET_ODOM, VELOCITY_CMD, odom_topic

__all__ = ['TrackerNode', 'main']


class TrackerNode(Node):
    """The controller of one UAV: converts each input, hands it to the core's tracker of its
    timing mode (:mod:`apf_swarm_core.tracker_modes`), publishes what that decides.

    ``swarm_odom``: False leaves the ``/swarm/odom`` subscription to another node of the
    process, which hands each message on (``trackers_node.group_main``, realtime).
    """

    def __init__(self, swarm_odom: bool = True, **kwargs: Any) -> None:
        super().__init__('tracker', **kwargs)
        self.cfg, p = declare_swarm_node(self, TRACKER_PARAMS, writable=TrackerAgent.RETUNABLE)
        self.mode = p['mode']
        self.uav_id = int(p['uav_id'])
        self.inputs = p['inputs']
        on_odom = p['trigger'] == 'odom'
        # the configuration's control_rate (0: the realtime default) sets the control timer
        # (trigger timer) or the stale-input watchdog (trigger odom)
        rate = self.cfg.control_rate or REALTIME_RATE
        self.period = self.cfg.dt if self.mode == 'lockstep' else 1.0 / rate  # setpoints' [s]
        self.agent = TrackerAgent(self.cfg, self.uav_id, run=int(p['run']))
        self.core = tracker_mode(
            self.mode,
            self.agent,
            float(p['input_timeout']),
            dt_ns=dt_to_ns(self.cfg.dt),
            control_rate=rate,
            on_odom=on_odom,
        )
        install_validator(self, self._retune)
        qos = control_qos(self.mode, p['qos_depth'])
        outputs = parse_outputs(p['outputs'])
        self.pub = self.create_publisher(ForceCommand, FORCE_CMD, qos)
        self.accel_pub = (
            self.create_publisher(AccelStamped, ACCEL_CMD, qos) if 'accel' in outputs else None
        )
        self.velocity_pub = (
            self.create_publisher(TwistStamped, VELOCITY_CMD, qos)
            if 'velocity' in outputs
            else None
        )
        if p['inputs'] == 'odom':
            for j in (self.uav_id, *(j for j in self.agent.ids if j != self.uav_id)):
                topic = ODOM if j == self.uav_id else odom_topic(j)
                self.create_subscription(Odometry, topic, partial(self._on_odom, j), qos)
            self.create_subscription(Odometry, TARGET_ODOM, partial(self._on_odom, 0), qos)
        elif swarm_odom:
            self.create_subscription(SwarmOdometry, SWARM_ODOM, self._on_swarm_odom, qos)
        #: the nodes this one hands its /swarm/odom messages to (itself first)
        self.fanout: list[TrackerNode] = [self]
        self._msg: ForceCommand | None = None
        self._log_rejection = RejectionLog(self)
        self.instance = random.getrandbits(63)  # tells this process apart at the plant
        # lockstep: a command waits until the plant's reader (and the recorder's) matched
        gate = MatchGate(self, self.pub, 1, first=1 + int(p['recorded']))
        self._publish = (
            (lambda msg: gate(partial(self.pub.publish, msg)))
            if self.mode == 'lockstep'
            else self.pub.publish
        )
        if self.mode == 'realtime':
            self.create_timer(
                1.0 / (min(rate, WATCHDOG_RATE) if on_odom else rate), self._on_timer
            )
        self.get_logger().info(
            f'uav_{self.uav_id}: {self.cfg.law} law, {self.mode}, neighbours '
            f'{[j for j in self.agent.ids if j != self.uav_id]}, dt {self.cfg.dt:g} s'
        )

    def _retune(self, cfg: SwarmConfig) -> None:
        """An accepted parameter change: the controller and potential use it from now on."""
        changed = self.agent.retune(cfg)
        self.cfg = cfg
        if changed:
            self.get_logger().info(
                'retuned: ' + ', '.join(f'{k} = {getattr(cfg, k)!r}' for k in changed)
            )

    def _on_odom(self, source: int, msg: Odometry) -> None:
        x, v = odom_arrays(msg)
        now = self.get_clock().now().nanoseconds
        stamp = msg.header.stamp
        self._answer(
            self.core.on_odom(source, stamp_ns(stamp), x, v, now, time.monotonic()), stamp
        )

    def _on_swarm_odom(self, msg: SwarmOdometry) -> None:
        """One /swarm/odom, converted once, for this node and those it hands it on to."""
        try:
            m = swarm_odom_arrays(msg)
        except ValueError as exc:
            for node in self.fanout:
                node.agent.rejected += 1
                node._log_rejection(f'/swarm/odom: {exc}', node.agent.rejected)
            return
        for node in self.fanout:
            node._take_swarm_odom(msg.header.stamp, m)

    def _take_swarm_odom(self, stamp: Time, m: SwarmOdom) -> None:
        now = self.get_clock().now().nanoseconds
        self._answer(self.core.on_swarm(m, now, time.monotonic()), stamp)

    def _on_timer(self) -> None:
        now = self.get_clock().now()
        self._answer(self.core.on_timer(now.nanoseconds, time.monotonic()), now.to_msg())

    def _answer(self, r: Reply | None, stamp: Time) -> None:
        """Publish the core's reply (a command or the safe brake) with ``stamp``, the
        triggering input's (so that ``now - stamp`` at the plant is the loop's latency)."""
        if r is None:
            if self.core.refused:
                self._log_rejection(self.core.refused, self.agent.rejected)
            return
        log = self.get_logger()
        if r.report_stale:
            names = ['target' if s == 0 else f'uav_{s}' for s in r.stale]
            log.warn(
                f'stale inputs {names} (older than {self.core.timeout:g} '
                f'{self.core.TIME_UNIT}): '
                'commanding the safe brake'
            )
        if r.neighbours is not None:
            before, now = r.neighbours
            log.warn(
                f'potential over {now} neighbours (was {before}): the plant reports a '
                + ('tracker silent' if now < before else 'tracker back')
            )
        msg = reply_msg(
            r,
            stamp=stamp,
            uav_id=self.uav_id,
            law=self.cfg.law,
            rejected_inputs=self.agent.rejected,
            instance=self.instance,
            run=self.agent.run,
            out=self._msg if r.output is not None else None,
        )
        if r.output is not None:
            self._msg = msg
        self._publish(msg)
        if self.accel_pub is None and self.velocity_pub is None:
            return
        a, v = self.agent.setpoints(r.force, self.period)
        if self.accel_pub is not None:
            self.accel_pub.publish(accel_msg(stamp, a))
        if self.velocity_pub is not None:
            self.velocity_pub.publish(twist_msg(stamp, v))


def main(args: list[str] | None = None) -> None:
    sys.exit(run_node('tracker', TrackerNode, args))


if __name__ == '__main__':
    main()
