"""Tracker node: one tracking UAV's sliding-mode controller.

Inputs (``inputs`` parameter): ``aggregate`` (default) reads ``/swarm/odom``
(SwarmOdometry), one message per
step with every tracker's odometry and the target's state; ``odom`` subscribes its own
odometry (relative ``odom``), its neighbours' (``/uav_<j>/odom``) and the target's
(``/target/odom``). Publishes ``force_cmd`` (relative) and, as the ``outputs`` parameter
selects, the same command as standard setpoints for a flight-stack bridge: ``accel_cmd``
(geometry_msgs/AccelStamped) and ``velocity_cmd`` (geometry_msgs/TwistStamped), world frame
(:func:`apf_swarm_core.agents.TrackerAgent.setpoints`). Lockstep: answers step k as soon
as every input of step k has arrived. Realtime: with ``trigger:=odom`` (default)
it commands on every new own odometry, with ``trigger:=timer`` at the configuration's
``control_rate`` on the
latest inputs; an input older than ``input_timeout`` is stale and the safe command
(:func:`apf_swarm_core.agents.brake_force`, hover in place) is sent with ``stale = true``
(a watchdog timer at the control rate, at most 20 Hz with ``trigger:=odom``, keeps sending
it). In lockstep only the
target can be stale: the plant holds a silent target's last state and publishes its age in
simulated time, and past ``input_timeout`` the tracker answers each step with the brake.

Neighbours the plant flags inactive (their tracker is silent) leave the formation term of the
potential and stay as obstacles (:mod:`apf_swarm_core.agents`). Refused inputs are logged
with their reason and counted in every ForceCommand (``rejected_inputs``); each command
carries the process's random ``instance`` so that the plant can tell two trackers started
with one ``uav_id`` apart.
"""

from __future__ import annotations

import random
import sys
import time
from functools import partial
from typing import Any

from apf_swarm_core.agents import TrackerAgent
from apf_swarm_core.config import SwarmConfig
from apf_swarm_core.errors import ConfigError
from builtin_interfaces.msg import Time
from geometry_msgs.msg import AccelStamped, TwistStamped
from nav_msgs.msg import Odometry
from rclpy.node import Node

from apf_swarm_msgs.msg import ForceCommand, SwarmOdometry

from .conversions import (
    accel_msg,
    dt_to_ns,
    force_msg,
    odom_arrays,
    stamp_ns,
    step_of,
    swarm_odom_arrays,
    twist_msg,
)
from .node_common import (
    INPUTS,
    REALTIME_RATE,
    MatchGate,
    RejectionLog,
    control_qos,
    run_node,
)
from .params import NodeParam, declare_swarm_node, install_validator
from .topics import ACCEL_CMD, FORCE_CMD, ODOM, SWARM_ODOM, TARGET_ODOM, VELOCITY_CMD, odom_topic

__all__ = ['OUTPUTS', 'TrackerNode', 'main', 'parse_outputs']

NODE_PARAMS = (
    NodeParam(
        'inputs',
        'aggregate',
        'aggregate: one /swarm/odom message per step; odom: '
        'the n odometry topics and /target/odom',
        choices=INPUTS,
    ),
    NodeParam('uav_id', 1, 'id i of this tracker (namespace /uav_<i>)', lo=1, hi=10000),
    NodeParam(
        'trigger',
        'odom',
        'realtime: odom computes on every new own odometry (lowest '
        'latency); timer computes at control_rate on the latest inputs',
        choices=('odom', 'timer'),
    ),
    NodeParam(
        'outputs',
        'force',
        'what the tracker publishes, comma-separated: force (force_cmd, '
        'apf_swarm_msgs/ForceCommand, always: the plant and the bring-up read it), accel '
        '(accel_cmd, geometry_msgs/AccelStamped), velocity (velocity_cmd, '
        'geometry_msgs/TwistStamped): setpoints in the world frame for a flight-stack bridge',
    ),
    NodeParam(
        'input_timeout',
        0.5,
        'an input older than this is stale and the safe brake '
        "is sent [s; lockstep: of simulated time, which only the target's state can "
        'exceed when the target is silent]',
        lo=0.001,
        hi=60.0,
    ),
)


#: what a tracker can publish (the ``outputs`` parameter)
OUTPUTS = ('force', 'accel', 'velocity')

#: realtime with ``trigger:=odom``: the stale-input watchdog's rate [Hz] (at most the control
#: rate): staleness is judged against input_timeout (0.5 s), and the brakes it sends while
#: inputs are stale must come faster than the plant's stale_after (0.1 s)
WATCHDOG_RATE = 20.0


class TrackerNode(Node):
    """The controller of one UAV; no algorithm here, the core's TrackerAgent computes.

    ``swarm_odom``: False leaves the ``/swarm/odom`` subscription to another node of the
    process, which hands each message on (``trackers_node.group_main``, realtime).
    """

    def __init__(self, swarm_odom: bool = True, **kwargs: Any) -> None:
        super().__init__('tracker', **kwargs)
        self.cfg, p = declare_swarm_node(self, NODE_PARAMS, writable=TrackerAgent.RETUNABLE)
        self.mode = p['mode']
        self.uav_id = int(p['uav_id'])
        self.timeout = float(p['input_timeout'])
        self.on_odom = p['trigger'] == 'odom'
        self.inputs = p['inputs']
        # the configuration's control_rate (0: the realtime default) sets the control timer
        # (trigger timer) or the stale-input watchdog (trigger odom)
        self.control_rate = self.cfg.control_rate or REALTIME_RATE
        self._last_command = 0.0
        #: the control period the setpoints hold for [s]
        self.period = self.cfg.dt if self.mode == 'lockstep' else 1.0 / self.control_rate
        self.agent = TrackerAgent(self.cfg, self.uav_id, run=int(p['run']))
        install_validator(self, self._retune)
        self.dt_ns = dt_to_ns(self.cfg.dt)
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
            self.create_subscription(Odometry, ODOM, lambda m: self._on_odom(self.uav_id, m), qos)
            for j in self.agent.ids:
                if j != self.uav_id:
                    self.create_subscription(
                        Odometry, odom_topic(j), partial(self._on_odom, j), qos
                    )
            self.create_subscription(Odometry, TARGET_ODOM, lambda m: self._on_odom(0, m), qos)
        elif swarm_odom:
            self.create_subscription(SwarmOdometry, SWARM_ODOM, self._on_swarm_odom, qos)
        #: the nodes this one hands its /swarm/odom messages to (itself first)
        self.fanout: list[TrackerNode] = [self]
        self._tick = 0
        self._msg = None
        self._stale_reported = False
        self._neighbours = -1
        self._log_rejection = RejectionLog(self)
        self.instance = random.getrandbits(63)  # tells this process apart at the plant
        #: lockstep: a command waits until the plant's reader (and the recorder's) matched
        self.gate = MatchGate(self, self.pub, 1, first=1 + int(p['recorded']))
        if self.mode == 'realtime':
            rate = self.control_rate if not self.on_odom else min(self.control_rate, WATCHDOG_RATE)
            self.create_timer(1.0 / rate, self._on_timer)
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

    def _now_and_age(self, stamp: Time) -> tuple[float, float]:
        """(now, age of a message with this stamp) [s]: lockstep on the simulated clock
        (the stamp is the step's time, age 0), realtime on the monotonic clock (age = ROS
        time now - stamp, never negative)."""
        if self.mode == 'lockstep':
            return stamp_ns(stamp) * 1e-9, 0.0
        age = (self.get_clock().now().nanoseconds - stamp_ns(stamp)) * 1e-9
        return time.monotonic(), max(0.0, age)

    def _warn_rejected(self) -> None:
        self._log_rejection(self.agent.last_rejection, self.agent.rejected)

    def _on_odom(self, source: int, msg: Odometry) -> None:
        x, v = odom_arrays(msg)
        step = step_of(msg.header.stamp, self.dt_ns) if self.mode == 'lockstep' else -1
        now, age = self._now_and_age(msg.header.stamp)
        if not self.agent.offer(
            source, step, x, v, now - age, seq=step if step >= 0 else stamp_ns(msg.header.stamp)
        ):
            self._warn_rejected()
            return
        if self.mode == 'lockstep' and self.agent.ready(step):
            self._publish(step, msg.header.stamp, now)
        elif self.mode == 'realtime' and self.on_odom and source == self.uav_id:
            self._realtime_command(msg.header.stamp)

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
            node._take_swarm_odom(msg, m)

    def _take_swarm_odom(self, msg: SwarmOdometry, m: Any) -> None:
        step = m.step if self.mode == 'lockstep' else -1
        seq = step if step >= 0 else m.stamp_ns
        now, age = self._now_and_age(msg.header.stamp)
        if not self.agent.offer_swarm(
            step,
            m.uav_ids,
            m.x,
            m.v,
            m.active,
            m.target_x,
            m.target_v,
            now - age,
            now - age - m.target_age,
            seq=seq,
            run=m.run,
        ):
            self._warn_rejected()
            return
        if m.command_latency.size:
            self.agent.report_latency(m.command_latency)
        if self.mode == 'lockstep' and self.agent.ready(step):
            self._publish(step, msg.header.stamp, now)
        elif self.mode == 'realtime' and self.on_odom:
            self._realtime_command(msg.header.stamp)

    def _publish(self, step: int, stamp: Time, now: float | None = None) -> None:
        """The command of ``step``; lockstep with a stale input (the target silent for
        longer than input_timeout of simulated time): the safe brake, flagged stale."""
        stale = (
            self.agent.stale_sources(now, self.timeout)
            if self.mode == 'lockstep' and now is not None
            else []
        )
        if stale:
            self._send_brake(step, stamp, stale)
            self.agent.brake(step)
            return
        out = self.agent.command(step)
        self._msg = force_msg(
            out=self._msg,
            uav_id=self.uav_id,
            step=step,
            law=self.cfg.law,
            stamp=stamp,
            force=out.force[0],
            sliding_surface=out.sliding_surface[0],
            gradient=out.gradient[0],
            filter_state=out.filter_state[0],
            saturated=bool(out.saturated[0]),
            rejected_inputs=self.agent.rejected,
            instance=self.instance,
            run=self.agent.run,
        )
        self._send(self._msg, stamp, out.force[0])
        self._stale_reported = False
        if self.agent.active_neighbours != self._neighbours:
            if self._neighbours >= 0:
                self.get_logger().warn(
                    f'potential over {self.agent.active_neighbours} neighbours (was '
                    f'{self._neighbours}): the plant reports '
                    + (
                        'a tracker silent'
                        if self.agent.active_neighbours < self._neighbours
                        else 'a tracker back'
                    )
                )
            self._neighbours = self.agent.active_neighbours

    def _on_timer(self) -> None:
        """trigger timer: command on the latest inputs; trigger odom: watchdog only."""
        if not self.on_odom or self.agent.stale_sources(time.monotonic(), self.timeout):
            self._realtime_command(self.get_clock().now().to_msg())

    def _realtime_command(self, stamp: Time) -> None:
        """Command from the latest inputs, or the safe brake when one is stale.

        The header stamp is the stamp of the odometry that triggered it (trigger odom), so
        ``now - stamp`` at the plant is the control-loop latency.
        """
        self._tick += 1
        now = time.monotonic()
        self.agent.controller.sample_elapsed(
            now - self._last_command if self._last_command else None, 1.0 / self.control_rate
        )
        self._last_command = now
        stale = self.agent.stale_sources(now, self.timeout)
        if not stale:
            self._publish(self._tick, stamp)
            return
        self._send_brake(self._tick, stamp, stale)

    def _send_brake(self, step: int, stamp: Time, stale: list[int]) -> None:
        """Publish the safe brake (:func:`apf_swarm_core.agents.brake_force`), flagged stale."""
        self.agent.stale += 1
        if not self._stale_reported:
            names = ['target' if s == 0 else f'uav_{s}' for s in stale]
            unit = 's of simulated time' if self.mode == 'lockstep' else 's'
            self.get_logger().warn(
                f'stale inputs {names} (older than {self.timeout:g} '
                f'{unit}): commanding the safe brake'
            )
            self._stale_reported = True
        u = self.agent.safe_command()
        zero = u * 0.0
        self._send(
            force_msg(
                uav_id=self.uav_id,
                step=step,
                law=self.cfg.law,
                stamp=stamp,
                force=u,
                sliding_surface=zero,
                gradient=zero,
                filter_state=zero,
                saturated=False,
                stale=True,
                rejected_inputs=self.agent.rejected,
                instance=self.instance,
                run=self.agent.run,
            ),
            stamp,
            u,
        )

    def _send(self, msg: ForceCommand, stamp: Time, force: Any) -> None:
        """Publish a command on every output the ``outputs`` parameter selected. Lockstep:
        the command goes through the :class:`~.node_common.MatchGate` (the plant waits for
        it, and a command published before its reader matched would be lost)."""
        if self.mode == 'lockstep':
            self.gate(partial(self.pub.publish, msg))
        else:
            self.pub.publish(msg)
        if self.accel_pub is None and self.velocity_pub is None:
            return
        a, v = self.agent.setpoints(force, self.period)
        if self.accel_pub is not None:
            self.accel_pub.publish(accel_msg(stamp, a))
        if self.velocity_pub is not None:
            self.velocity_pub.publish(twist_msg(stamp, v))


def parse_outputs(text: str) -> set[str]:
    """The ``outputs`` parameter as a set, ``force`` always in it (ConfigError naming what
    is wrong)."""
    got = {part.strip() for part in str(text).split(',') if part.strip()}
    if got - set(OUTPUTS):
        raise ConfigError(
            f'outputs = {text!r}: expected a comma-separated subset of {", ".join(OUTPUTS)}'
        )
    return got | {'force'}


def main(args: list[str] | None = None) -> None:
    sys.exit(run_node('tracker', TrackerNode, args))


if __name__ == '__main__':
    main()
