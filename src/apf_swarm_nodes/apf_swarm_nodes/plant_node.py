"""Plant node: integrates every tracker's dynamics (eq. 19-21) with bounded noise.

Publishes the odometry, ``/swarm/odom``, ``/swarm/state``, ``/swarm/markers`` and (lockstep)
``/clock`` (:mod:`.plant_outputs`); subscribes ``/uav_<i>/force_cmd``, (realtime)
``/swarm/force_cmds`` and ``/target/odom``. The core decides: a ``LockstepBarrier`` or a
``RealtimePlant`` returns the actions the node carries out (docs/ROS.md)."""

from __future__ import annotations

import sys
import time
from functools import partial
from typing import Any

from apf_swarm_core.config import REALTIME_RATE
from apf_swarm_core.lockstep import Action, LockstepBarrier
from apf_swarm_core.plant_model import PlantModel
from apf_swarm_core.realtime_plant import RealtimePlant
from builtin_interfaces.msg import Time
from nav_msgs.msg import Odometry
from rclpy.node import Node
from std_msgs.msg import Empty

from apf_swarm_msgs.msg import ForceCommand, ForceCommands

from .conversions import dt_to_ns, force_arrays, odom_arrays, stamp_ns, step_stamp
from .node_common import START_QOS, RejectionLog, control_qos, run_node
from .params import PLANT_PARAMS, declare_swarm_node
from .plant_outputs import PlantOutputs
from .topics import SWARM_FORCE_CMDS, SWARM_START, TARGET_ODOM, force_topic

__all__ = ['PlantNode', 'main']


class PlantNode(Node):
    """Owns the swarm's state: the core's PlantModel integrates, its mode's object decides."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('plant', **kwargs)
        self.cfg, p = declare_swarm_node(self, PLANT_PARAMS)
        mode = p['mode']
        self.inputs = p['inputs']
        self.recorded = bool(p['recorded'])
        self.model = PlantModel(self.cfg, run=int(p['run']))
        self.dt_ns = dt_to_ns(self.cfg.dt)
        qos = control_qos(mode, p['qos_depth'])
        publish_rate = float(p['publish_rate']) or self.cfg.control_rate or REALTIME_RATE
        period = self.cfg.dt if mode == 'lockstep' else 1.0 / publish_rate
        self.out = PlantOutputs(self, self.model, mode, qos, p['markers_rate'], period)
        self.force_subs = [
            self.create_subscription(ForceCommand, force_topic(i), partial(self._on_force, i), qos)
            for i in self.model.ids
        ]
        if mode == 'realtime':  # batch_commands: a writer per process, each batch kept
            qos_n = control_qos(mode, max(p['qos_depth'], len(self.model.ids)))
            self.create_subscription(ForceCommands, SWARM_FORCE_CMDS, self._on_forces, qos_n)
        self.tracker_rejected: dict[int, int] = {}
        self._log_rejection = RejectionLog(self)
        self.create_timer(1.0, self._check_duplicates)
        self.target_sub = self.create_subscription(Odometry, TARGET_ODOM, self._on_target, qos)
        timeout = float(p['command_timeout'])
        self.core: LockstepBarrier | RealtimePlant
        if mode == 'lockstep':
            self.core = barrier = LockstepBarrier(self.model, timeout)
            self.create_timer(0.01, partial(self._check_deadline, barrier))
        else:
            self.core = rt = RealtimePlant(
                self.model, timeout, float(p['stale_after']), float(p['arm_timeout'])
            )
            self.create_timer(1.0 / float(p['physics_rate']), partial(self._on_physics, rt))
            self.create_timer(1.0 / publish_rate, partial(self._on_publish, rt))
        self.running = self.starting = False
        if p['wait_for_start']:
            self.create_subscription(Empty, SWARM_START, self._on_start, START_QOS)
            self.get_logger().info('waiting for /swarm/start')
        else:
            self._start_timer = self.create_timer(0.5, self._autostart)
        self.get_logger().info(
            f'plant: {self.cfg.n_trackers} trackers, {mode}, '
            f'dt {self.cfg.dt:g} s, {self.cfg.steps} steps'
        )

    def _autostart(self) -> None:
        """Without a start signal: start once every force_cmd topic has its publisher."""
        topics = [TARGET_ODOM, *(force_topic(i) for i in self.model.ids)]
        if all(self.count_publishers(t) > 0 for t in topics):
            self._start_timer.cancel()
            self._start()

    def _on_start(self, _msg: Empty) -> None:
        if not self.running and not self.core.done:
            self._start()

    def _start(self) -> None:
        self.running = self.starting = True
        self.get_logger().info('started')
        self._start_when_matched()

    def _matched(self) -> bool:
        """Every command publisher matched to this plant's readers, every reader of step k
        to its writers (the recorder's too when ``recorded``): else a first message is lost."""
        subs = [self.target_sub, *self.force_subs]
        if any(sub.get_publisher_count() < 1 for sub in subs):
            return False
        return self.out.readers_matched(self.inputs, int(self.recorded))

    def _start_when_matched(self) -> None:
        if self.starting and (not self.core.needs_match or self._matched()):
            self.starting = False
            self._carry_out(self.core.start(time.monotonic()))

    # --- the core decides, the node publishes ---------------------------------------------
    def _carry_out(self, actions: list[Action]) -> None:
        for a in actions:
            if a.kind == 'request':
                self.out.request(a.step)
            elif a.kind == 'swarm_odom':
                self._publish_swarm_odom(a.step, step_stamp(a.step, self.dt_ns))
            elif a.kind == 'step':
                self.out.step(step_stamp(a.step, self.dt_ns))
            elif a.kind == 'state':
                self._publish_state(a.data, step_stamp(a.step, self.dt_ns))
            elif a.kind == 'refuse':
                self._log_rejection(a.text, self.model.rejected)
            elif a.kind == 'warn':
                self.get_logger().warn(a.text)
            else:
                self.get_logger().info(a.text)

    def _publish_swarm_odom(self, k: int, stamp: Time) -> None:
        target, age = self.core.target, self.core.target_age(time.monotonic())
        assert target is not None  # a realtime plant publishes once it holds one
        self.out.swarm_odom(k, stamp, target, age, latency=self.core.reports_latency)

    def _publish_state(self, state: dict[str, Any], stamp: Time) -> None:
        self.out.state(state, stamp, sum(self.tracker_rejected.values()))

    def _age(self, stamp: Time) -> float:
        """How long ago ``stamp`` was, on the ROS clock [s]."""
        return (self.get_clock().now().nanoseconds - stamp_ns(stamp)) * 1e-9

    def _on_force(self, topic_id: int, msg: ForceCommand) -> None:
        c = force_arrays(msg)
        if c.uav_id != topic_id:
            self.model.refuse(f'a command on {force_topic(topic_id)} claims uav_id {c.uav_id}')
            self._carry_out([Action('refuse', text=self.model.last_rejection)])
            return
        ok, actions = self.core.take_command(c, self._age(msg.header.stamp), time.monotonic())
        if ok:
            self.tracker_rejected[c.uav_id] = c.rejected_inputs
        self._carry_out(actions)

    def _on_forces(self, msg: ForceCommands) -> None:
        for c in msg.commands:
            self._on_force(c.uav_id, c)

    def _on_target(self, msg: Odometry) -> None:
        x, v = odom_arrays(msg)
        t = msg.header.stamp
        self._carry_out(self.core.take_target(x, v, stamp_ns(t), self._age(t), time.monotonic()))

    def _check_duplicates(self) -> None:
        """1 Hz: a force topic with more than one publisher means two trackers share an id."""
        for i in self.model.ids:
            if (count := self.count_publishers(force_topic(i))) > 1:
                self.get_logger().error(
                    f'duplicate uav_id {i}: {count} publishers on {force_topic(i)}; '
                    'following the first tracker process that commanded, refusing the others'
                )

    def _check_deadline(self, barrier: LockstepBarrier) -> None:
        """Lockstep, 10 ms: start when matched; past the deadline re-send step k, then miss."""
        if self.starting:
            self._start_when_matched()
        elif self.running:
            self._carry_out(barrier.tick(time.monotonic()))

    def _on_physics(self, rt: RealtimePlant) -> None:
        if self.running and not rt.done:
            self._carry_out(rt.arm(time.monotonic()))
            if rt.clock_started:
                self._carry_out(rt.physics(time.monotonic()))

    def _on_publish(self, rt: RealtimePlant) -> None:
        if not self.running or rt.final_published or rt.target is None:
            return  # not started, finished, or no target state yet
        stamp = self.get_clock().now().to_msg()
        self._carry_out(rt.arm(time.monotonic()))  # the UAVs held still until the clock runs
        self.out.odoms(stamp)
        self._publish_swarm_odom(self.model.k, stamp)
        if rt.clock_started:  # else the trackers' first inputs went out; no state before
            self._publish_state(rt.state_sample(time.monotonic()), stamp)


def main(args: list[str] | None = None) -> None:
    sys.exit(run_node('plant', PlantNode, args))


if __name__ == '__main__':
    main()
