"""Plant node: integrates every tracker's dynamics (eq. 19-21) with bounded noise.

Publishes ``/uav_<i>/odom`` for every tracker, ``/swarm/odom`` (all of them and the target
state, one message), ``/swarm/state``, ``/swarm/markers`` (RViz / Foxglove) and, in
lockstep, ``/clock`` (:mod:`.plant_outputs`);
subscribes ``/uav_<i>/force_cmd`` and ``/target/odom``.

Lockstep: the core's :class:`~apf_swarm_core.lockstep.LockstepBarrier` runs the barrier
(the target's states asked for ahead on ``/target/request``, step k published once its
target state is held, integrated once every active tracker's command of step k arrived,
re-sent past ``command_timeout``, then its late inputs missed: a silent tracker inactive, a
silent target's last state held, its age growing in ``/swarm/odom``); this node carries out
the actions it returns.

Realtime (:class:`~apf_swarm_core.realtime_plant.RealtimePlant`): a physics timer
integrates the steps of dt that wall time has advanced (held commands; a tracker whose
latest command is older than ``stale_after`` gets zero force, older than
``command_timeout`` it becomes inactive, counted in ``missed_deadlines``); a publish timer
publishes odometry and
``/swarm/state`` at ``publish_rate``; commands and target states whose stamp is older than
``command_timeout``, or older than the one held, are refused.

Every refused input (non-finite, out of range, unknown or mismatched ``uav_id``, a second
command for a lockstep step, out of order, stale) is logged with its reason and counted; the
``rejected_inputs`` of ``/swarm/state`` is the plant's count plus the latest count each
tracker reports in its commands. Each command names the tracker process that sent it
(``instance``): the plant follows one process per ``uav_id`` and refuses the commands of any
other (two trackers started with one ``uav_id``) until the followed one falls silent. A force
topic with more than one publisher is also logged as an error once a second while it lasts.
"""

from __future__ import annotations

import sys
import time
from functools import partial
from typing import Any

from apf_swarm_core.agents import Sample
from apf_swarm_core.inputs import input_problem
from apf_swarm_core.lockstep import Action, LockstepBarrier
from apf_swarm_core.plant_model import PlantModel
from apf_swarm_core.realtime_plant import STALE_AFTER, RealtimePlant
from builtin_interfaces.msg import Time
from nav_msgs.msg import Odometry
from rclpy.node import Node
from std_msgs.msg import Empty

from apf_swarm_msgs.msg import ForceCommand

from .conversions import dt_to_ns, force_arrays, odom_arrays, stamp_ns, step_of, step_stamp
from .node_common import (
    INPUTS,
    REALTIME_RATE,
    START_QOS,
    RejectionLog,
    control_qos,
    run_node,
)
from .params import NodeParam, declare_swarm_node
from .plant_outputs import PlantOutputs
from .topics import SWARM_START, TARGET_ODOM, force_topic

__all__ = ['PlantNode', 'main']

NODE_PARAMS = (
    NodeParam('wait_for_start', False, 'wait for /swarm/start before step 0'),
    NodeParam(
        'inputs',
        'aggregate',
        'what the trackers read (as their inputs parameter): '
        'lockstep step 0 waits until those subscriptions are matched',
        choices=INPUTS,
    ),
    NodeParam(
        'command_timeout',
        1.0,
        'lockstep: a command later than this is sent for '
        'again, then missed; realtime: a tracker silent for this long is inactive, and '
        'a command or target state stamped longer ago is refused [s of wall time]',
        lo=0.001,
        hi=600.0,
    ),
    NodeParam(
        'stale_after',
        STALE_AFTER,
        'realtime: a tracker whose latest command arrived longer '
        'ago than this gets zero force instead of its held bang-bang command (25 N held '
        'for 1 s would fling a 1 kg UAV 12 m) [s of wall time]',
        lo=0.001,
        hi=60.0,
    ),
    NodeParam('physics_rate', 200.0, 'realtime: physics timer rate [Hz]', lo=1.0, hi=5000.0),
    NodeParam(
        'arm_timeout',
        10.0,
        'realtime: after the start the clock waits until every '
        'tracker has commanded from its inputs (odometry goes out, the UAVs hold '
        'still), at most this long; then it starts without the silent ones (warned) '
        '[s of wall time]',
        lo=0.0,
        hi=600.0,
    ),
    NodeParam(
        'markers_rate',
        10.0,
        '/swarm/markers (visualization_msgs/MarkerArray) per second '
        'of simulated (lockstep) or wall (realtime) time; 0 turns them off',
        lo=0.0,
        hi=1000.0,
    ),
    NodeParam(
        'publish_rate',
        0.0,
        'realtime: odometry and state rate [Hz]; 0: the '
        "configuration's control_rate, or 100 Hz when that is 0",
        lo=0.0,
        hi=2000.0,
    ),
)


class PlantNode(Node):
    """Owns the swarm's physical state; the core's PlantModel integrates it."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('plant', **kwargs)
        self.cfg, p = declare_swarm_node(self, NODE_PARAMS)
        self.mode = p['mode']
        self.timeout = float(p['command_timeout'])
        self.inputs = p['inputs']
        self.recorded = bool(p['recorded'])
        self.waiting_for_match = False
        self.model = PlantModel(self.cfg, run=int(p['run']))
        self.dt_ns = dt_to_ns(self.cfg.dt)
        qos = control_qos(self.mode, p['qos_depth'])
        publish_rate = float(p['publish_rate']) or self.cfg.control_rate or REALTIME_RATE
        period = self.cfg.dt if self.mode == 'lockstep' else 1.0 / publish_rate
        self.out = PlantOutputs(self, self.model, self.mode, qos, p['markers_rate'], period)
        self.force_subs = [
            self.create_subscription(ForceCommand, force_topic(i), partial(self._on_force, i), qos)
            for i in self.model.ids
        ]
        self.tracker_rejected: dict[int, int] = {}
        self._log_rejection = RejectionLog(self)
        self.create_timer(1.0, self._check_duplicates)
        self.target_sub = self.create_subscription(Odometry, TARGET_ODOM, self._on_target, qos)
        self.barrier = LockstepBarrier(self.model, self.timeout)
        self.rt = RealtimePlant(
            self.model, self.timeout, float(p['stale_after']), float(p['arm_timeout'])
        )
        self.running = False
        if self.mode == 'lockstep':
            self.create_timer(0.01, self._check_deadline)
        else:
            self.create_timer(1.0 / float(p['physics_rate']), self._on_physics)
            self.create_timer(1.0 / publish_rate, self._on_publish)
        if p['wait_for_start']:
            self.create_subscription(Empty, SWARM_START, self._on_start, START_QOS)
            self.get_logger().info('waiting for /swarm/start')
        else:
            self._start_timer = self.create_timer(0.5, self._autostart)
        self.get_logger().info(
            f'plant: {self.cfg.n_trackers} trackers, {self.mode}, '
            f'dt {self.cfg.dt:g} s, {self.cfg.steps} steps'
        )

    @property
    def done(self) -> bool:
        """The run's last step is integrated."""
        return self.barrier.done if self.mode == 'lockstep' else self.rt.done

    # --- start -------------------------------------------------------------------------
    def _autostart(self) -> None:
        """Without a start signal: start once every force_cmd topic has its publisher."""
        if (
            all(self.count_publishers(force_topic(i)) > 0 for i in self.model.ids)
            and self.count_publishers(TARGET_ODOM) > 0
        ):
            self._start_timer.cancel()
            self._start()

    def _on_start(self, _msg: Empty) -> None:
        if not self.running and not self.done:
            self._start()

    def _start(self) -> None:
        self.running = True
        self.get_logger().info('started')
        if self.mode == 'lockstep':
            # step 0 goes out only when every reader of it is matched, or it would be lost
            self.waiting_for_match = True
            self._start_when_matched()
        else:
            self._carry_out(self.rt.start(time.monotonic()))

    def _arm(self) -> bool:
        """Realtime: start the physics clock when :meth:`RealtimePlant.arm` says so; True once
        it runs. Until then odometry goes out with the UAVs held still."""
        if not self.rt.clock_started:
            self._carry_out(self.rt.arm(time.monotonic()))
        return self.rt.clock_started

    def _matched(self) -> bool:
        """Lockstep: every tracker's command publisher matched to this plant's subscription
        (the graph showing it is not enough: the plant's own reader may not have matched it
        yet, and a command sent before that is lost) and every step-k reader a match."""
        if self.target_sub.get_publisher_count() < 1:
            return False
        if any(sub.get_publisher_count() < 1 for sub in self.force_subs):
            return False
        return self.out.readers_matched(self.inputs, int(self.recorded))

    def _start_when_matched(self) -> None:
        if self.waiting_for_match and self._matched():
            self.waiting_for_match = False
            self._carry_out(self.barrier.start(time.monotonic()))

    # --- the core decides (lockstep barrier, realtime clock), the node publishes -----------
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
            elif a.kind == 'warn':
                self.get_logger().warn(a.text)
            else:
                self.get_logger().info(a.text)

    def _target(self) -> Sample:
        if self.mode == 'lockstep':
            return self.barrier.target
        assert self.rt.target is not None
        return self.rt.target

    def _target_age(self) -> float:
        """Age of the held target state [s]: simulated (lockstep) or wall time (realtime)."""
        if self.mode == 'lockstep':
            return self.barrier.target_age()
        return self.rt.target_age(time.monotonic())

    def _publish_swarm_odom(self, k: int, stamp: Time) -> None:
        self.out.swarm_odom(
            k, stamp, self._target(), self._target_age(), latency=self.mode == 'realtime'
        )

    def _publish_state(self, state: dict[str, Any], stamp: Time) -> None:
        self.out.state(state, stamp, sum(self.tracker_rejected.values()))

    def _refuse(self, why: str) -> None:
        self.model.refuse(why)
        self._log_rejection(why, self.model.rejected)

    def _age(self, stamp: Time) -> float:
        """How long ago ``stamp`` was, on the ROS clock [s]."""
        return (self.get_clock().now().nanoseconds - stamp_ns(stamp)) * 1e-9

    def _on_force(self, topic_id: int, msg: ForceCommand) -> None:
        f = force_arrays(msg)
        if f.uav_id != topic_id:
            self._refuse(f'a command on {force_topic(topic_id)} claims uav_id {f.uav_id}')
            return
        if self.mode == 'realtime':
            why = self.rt.stale_command(f.uav_id, self._age(msg.header.stamp))
            if why is not None:
                self._refuse(why)
                return
        was_active = bool(self.model.active[f.uav_id - 1])
        now = time.monotonic()
        latency = 0.0
        if self.mode == 'realtime' and self.rt.command_arrives(now):
            latency = self._age(msg.header.stamp)
        if not self.model.offer_command(
            f.uav_id,
            f.step,
            f.force,
            f.sliding_surface,
            f.stale,
            now=now,
            instance=f.instance,
            latency=latency,
            run=f.run,
        ):
            self._log_rejection(self.model.last_rejection, self.model.rejected)
            return
        self.tracker_rejected[f.uav_id] = f.rejected_inputs
        if not was_active and self.running:
            self.get_logger().info(
                f'uav_{f.uav_id} commands again: active, back in the neighbour sets'
            )
        if self.mode == 'lockstep':
            self._carry_out(self.barrier.on_command(now))

    def _on_target(self, msg: Odometry) -> None:
        x, v = odom_arrays(msg)
        problem = input_problem(x=x, v=v)
        if problem is not None:
            self._refuse(f'target state: {problem}')
            return
        stamp = msg.header.stamp
        if self.mode == 'lockstep':
            now = time.monotonic()
            self._carry_out(self.barrier.on_target(step_of(stamp, self.dt_ns), x, v, now))
            return
        why = self.rt.offer_target(x, v, stamp_ns(stamp), self._age(stamp), time.monotonic())
        if why is not None:
            self._refuse(why)

    def _check_duplicates(self) -> None:
        """1 Hz: a force topic with more than one publisher means two trackers share an id."""
        for i in self.model.ids:
            count = self.count_publishers(force_topic(i))
            if count > 1:
                self.get_logger().error(
                    f'duplicate uav_id {i}: {count} publishers on {force_topic(i)}; '
                    'following the first tracker process that commanded, refusing the others'
                )

    def _check_deadline(self) -> None:
        """10 ms timer: start when matched; past the deadline re-send step k once, then miss."""
        if self.waiting_for_match:
            self._start_when_matched()
        elif self.running:
            self._carry_out(self.barrier.tick(time.monotonic()))

    # --- realtime ------------------------------------------------------------------------
    def _on_physics(self) -> None:
        if self.running and not self.done and self._arm():
            self._carry_out(self.rt.physics(time.monotonic()))

    def _on_publish(self) -> None:
        if not self.running or self.rt.final_published or self.rt.target is None:
            return  # not started, finished, or no target state yet
        stamp = self.get_clock().now().to_msg()
        armed = self._arm()
        self.out.odoms(stamp)
        self._publish_swarm_odom(self.model.k, stamp)
        if armed:  # else the trackers' first inputs went out; no state before the clock runs
            self._publish_state(self.rt.state_sample(time.monotonic()), stamp)


def main(args: list[str] | None = None) -> None:
    sys.exit(run_node('plant', PlantNode, args))


if __name__ == '__main__':
    main()
