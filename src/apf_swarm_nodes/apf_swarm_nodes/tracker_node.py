"""Tracker node: one tracking UAV's sliding-mode controller.

Inputs (``inputs`` parameter): ``aggregate`` (default) reads ``/swarm/odom`` (SwarmOdometry), one message per
step with every tracker's odometry and the target's state; ``odom`` subscribes its own
odometry (relative ``odom``), its neighbours' (``/uav_<j>/odom``) and the target's
(``/target/odom``). Publishes ``force_cmd`` (relative). Lockstep: answers step k as soon
as every input of step k has arrived. Realtime: with ``trigger:=odom`` (default)
it commands on every new own odometry, with ``trigger:=timer`` at ``control_rate`` on the
latest inputs; an input older than ``input_timeout`` is stale and the safe command
(:func:`apf_swarm_core.agents.brake_force`, hover in place) is sent with ``stale = true``
(the ``control_rate`` timer is then the watchdog that keeps sending it).
"""

from __future__ import annotations

import sys
import time

from nav_msgs.msg import Odometry
from rclpy.node import Node

from apf_swarm_core.agents import TrackerAgent
from apf_swarm_msgs.msg import ForceCommand, SwarmOdometry

from .conversions import dt_to_ns, force_msg, odom_arrays, step_of, swarm_odom_arrays
from .node_common import INPUTS, SWARM_ODOM, TARGET_ODOM, control_qos, odom_topic, run_node
from .params import EXECUTOR_PARAM, MODES, NodeParam, declare_config, declare_node_params, install_validator, \
    read_config

__all__ = ['TrackerNode', 'main']

NODE_PARAMS = (
    EXECUTOR_PARAM,
    NodeParam('inputs', 'aggregate', 'aggregate: one /swarm/odom message per step; odom: '
              'the n odometry topics and /target/odom', choices=INPUTS),
    NodeParam('uav_id', 1, 'id i of this tracker (namespace /uav_<i>)', lo=1, hi=10000),
    NodeParam('mode', 'lockstep', 'timing mode', choices=MODES),
    NodeParam('control_rate', 100.0, 'realtime: rate of the control timer (trigger timer) or '
              'of the stale-input watchdog (trigger odom) [Hz]', lo=1.0, hi=2000.0),
    NodeParam('trigger', 'odom', 'realtime: odom computes on every new own odometry (lowest '
              'latency); timer computes at control_rate on the latest inputs',
              choices=('odom', 'timer')),
    NodeParam('input_timeout', 0.5, 'realtime: an input older than this is stale [s]',
              lo=0.001, hi=60.0),
)


class TrackerNode(Node):
    """The controller of one UAV; no algorithm here, the core's TrackerAgent computes."""

    def __init__(self, **kwargs) -> None:
        super().__init__('tracker', **kwargs)
        declare_config(self, writable=TrackerAgent.RETUNABLE)
        p = declare_node_params(self, NODE_PARAMS)
        self.cfg = read_config(self)
        self.mode = p['mode']
        self.uav_id = int(p['uav_id'])
        self.timeout = float(p['input_timeout'])
        self.on_odom = p['trigger'] == 'odom'
        self.control_rate = float(p['control_rate'])
        self._last_command = 0.0
        self.agent = TrackerAgent(self.cfg, self.uav_id)
        install_validator(self, self._retune)
        self.dt_ns = dt_to_ns(self.cfg.dt)
        qos = control_qos(self.mode)
        self.pub = self.create_publisher(ForceCommand, 'force_cmd', qos)
        if p['inputs'] == 'odom':
            self.create_subscription(Odometry, 'odom', lambda m: self._on_odom(self.uav_id, m),
                                     qos)
            for j in self.agent.ids:
                if j != self.uav_id:
                    self.create_subscription(Odometry, odom_topic(j),
                                             lambda m, j=j: self._on_odom(j, m), qos)
            self.create_subscription(Odometry, TARGET_ODOM, lambda m: self._on_odom(0, m), qos)
        else:
            self.create_subscription(SwarmOdometry, SWARM_ODOM, self._on_swarm_odom, qos)
        self._tick = 0
        self._msg = None
        self._stale_reported = False
        if self.mode == 'realtime':
            self.create_timer(1.0 / float(p['control_rate']), self._on_timer)
        self.get_logger().info(
            f'uav_{self.uav_id}: {self.cfg.law} law, {self.mode}, neighbours '
            f'{[j for j in self.agent.ids if j != self.uav_id]}, dt {self.cfg.dt:g} s')

    def _retune(self, cfg) -> None:
        """An accepted parameter change: the controller and potential use it from now on."""
        changed = self.agent.retune(cfg)
        self.cfg = cfg
        if changed:
            self.get_logger().info('retuned: ' + ', '.join(
                f'{k} = {getattr(cfg, k)!r}' for k in changed))

    def _on_odom(self, source: int, msg: Odometry) -> None:
        x, v = odom_arrays(msg)
        step = step_of(msg.header.stamp, self.dt_ns) if self.mode == 'lockstep' else -1
        if not self.agent.offer(source, step, x, v, time.monotonic()):
            name = 'target' if source == 0 else f'uav_{source}'
            self.get_logger().warn(f'rejected odometry from {name} (non-finite, unknown or out '
                                   f'of order); {self.agent.rejected} rejected so far',
                                   throttle_duration_sec=1.0)
            return
        if self.mode == 'lockstep' and self.agent.ready(step):
            self._publish(step, msg.header.stamp)
        elif self.mode == 'realtime' and self.on_odom and source == self.uav_id:
            self._realtime_command(msg.header.stamp)

    def _on_swarm_odom(self, msg: SwarmOdometry) -> None:
        try:
            k, ids, xs, vs, tx, tv = swarm_odom_arrays(msg)
        except ValueError as exc:
            self.agent.rejected += 1
            self.get_logger().warn(f'rejected /swarm/odom: {exc}', throttle_duration_sec=1.0)
            return
        step = k if self.mode == 'lockstep' else -1
        now = time.monotonic()
        ok = self.agent.offer(0, step, tx, tv, now)
        for j, x, v in zip(ids, xs, vs):
            if j in self.agent.ids:
                ok = self.agent.offer(j, step, x, v, now) and ok
        if not ok:
            self.get_logger().warn(f'rejected part of /swarm/odom (non-finite or out of order); '
                                   f'{self.agent.rejected} rejected so far',
                                   throttle_duration_sec=1.0)
            return
        if self.mode == 'lockstep' and self.agent.ready(step):
            self._publish(step, msg.header.stamp)
        elif self.mode == 'realtime' and self.on_odom:
            self._realtime_command(msg.header.stamp)

    def _publish(self, step: int, stamp) -> None:
        out = self.agent.command(step)
        self._msg = force_msg(
            out=self._msg, uav_id=self.uav_id, step=step, law=self.cfg.law, stamp=stamp,
            force=out.force[0], sliding_surface=out.sliding_surface[0],
            gradient=out.gradient[0], filter_state=out.filter_state[0],
            saturated=bool(out.saturated[0]))
        self.pub.publish(self._msg)

    def _on_timer(self) -> None:
        """trigger timer: command on the latest inputs; trigger odom: watchdog only."""
        if not self.on_odom:
            self._realtime_command(self.get_clock().now().to_msg())
        elif self.agent.stale_sources(time.monotonic(), self.timeout):
            self._realtime_command(self.get_clock().now().to_msg())

    def _realtime_command(self, stamp) -> None:
        """Command from the latest inputs, or the safe brake when one is stale.

        The header stamp is the stamp of the odometry that triggered it (trigger odom), so
        ``now - stamp`` at the plant is the control-loop latency.
        """
        self._tick += 1
        now = time.monotonic()
        # the filter of eq. 26 advances by the time actually elapsed between commands
        self.agent.controller.dt = min(0.1, max(1e-4, now - self._last_command)) if \
            self._last_command else 1.0 / self.control_rate
        self._last_command = now
        stale = self.agent.stale_sources(now, self.timeout)
        if not stale:
            self._stale_reported = False
            self._publish(self._tick, stamp)
            return
        self.agent.stale += 1
        if not self._stale_reported:
            names = ['target' if s == 0 else f'uav_{s}' for s in stale]
            self.get_logger().warn(f'stale inputs {names} (older than {self.timeout:g} s): '
                                   'commanding the safe brake')
            self._stale_reported = True
        u = self.agent.safe_command()
        zero = u * 0.0
        self.pub.publish(force_msg(uav_id=self.uav_id, step=self._tick, law=self.cfg.law,
                                   stamp=stamp, force=u, sliding_surface=zero, gradient=zero,
                                   filter_state=zero, saturated=False, stale=True))


def main(args: list[str] | None = None) -> None:
    sys.exit(run_node('tracker', TrackerNode, args))


if __name__ == '__main__':
    main()
