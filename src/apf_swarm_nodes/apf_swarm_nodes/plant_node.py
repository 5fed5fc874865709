"""Plant node: integrates every tracker's dynamics (eq. 19-21) with bounded noise.

Publishes ``/uav_<i>/odom`` for every tracker, ``/swarm/odom`` (all of them and the target
state, one message), ``/swarm/state``, ``/swarm/markers`` (RViz / Foxglove) and, in
lockstep, ``/clock``;
subscribes ``/uav_<i>/force_cmd`` and ``/target/odom``.

Lockstep: the core's :class:`~apf_swarm_core.lockstep.LockstepBarrier` runs the barrier
(the target's states asked for ahead on ``/target/request``, step k published once its
target state is held, integrated once every active tracker's command of step k arrived,
re-sent past ``command_timeout``, then its late inputs missed: a silent tracker inactive, a
silent target's last state held, its age growing in ``/swarm/odom``); this node carries out
the actions it returns.

Realtime: a physics timer integrates the steps of dt that wall time has advanced (held
commands; a tracker whose latest command is older than ``stale_after`` gets zero force, older
than ``command_timeout`` it becomes inactive, counted in ``missed_deadlines``); a publish
timer publishes odometry and
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

from apf_swarm_core.agents import Sample, input_problem
from apf_swarm_core.lockstep import Action, LockstepBarrier
from apf_swarm_core.plant_model import PlantModel
from builtin_interfaces.msg import Time
from nav_msgs.msg import Odometry
from rclpy.node import Node
from rosgraph_msgs.msg import Clock
from std_msgs.msg import Empty, UInt64
from visualization_msgs.msg import MarkerArray

from apf_swarm_msgs.msg import ForceCommand, SwarmOdometry, SwarmState

from .conversions import (
    clock_msg,
    dt_to_ns,
    force_arrays,
    markers_msg,
    odom_arrays,
    odom_msg,
    stamp_ns,
    step_of,
    step_stamp,
    swarm_odom_msg,
    swarm_state_msg,
)
from .node_common import (
    CLOCK,
    CLOCK_QOS,
    INPUTS,
    REALTIME_RATE,
    REQUEST_QOS,
    START_QOS,
    STATE_QOS,
    SWARM_MARKERS,
    SWARM_ODOM,
    SWARM_START,
    SWARM_STATE,
    TARGET_ODOM,
    TARGET_REQUEST,
    RejectionLog,
    control_qos,
    force_topic,
    odom_topic,
    run_node,
)
from .params import (
    EXECUTOR_PARAM,
    MODES,
    QOS_DEPTH_PARAM,
    NodeParam,
    declare_config,
    declare_node_params,
    read_config,
)

__all__ = ['PlantNode', 'main']

NODE_PARAMS = (
    EXECUTOR_PARAM,
    QOS_DEPTH_PARAM,
    NodeParam('mode', 'lockstep', 'timing mode', choices=MODES),
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
        0.1,
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
        declare_config(self)
        p = declare_node_params(self, NODE_PARAMS)
        self.cfg = read_config(self)
        self.mode = p['mode']
        self.timeout = float(p['command_timeout'])
        self.stale_after = float(p['stale_after'])
        self.arm_timeout = float(p['arm_timeout'])
        self.inputs = p['inputs']
        self.waiting_for_match = False
        self.model = PlantModel(self.cfg)
        self.steps = self.cfg.steps
        self.dt_ns = dt_to_ns(self.cfg.dt)
        qos = control_qos(self.mode, p['qos_depth'])
        self.odom_pubs = [
            self.create_publisher(Odometry, odom_topic(i), qos) for i in self.model.ids
        ]
        self.state_pub = self.create_publisher(SwarmState, SWARM_STATE, STATE_QOS)
        self.swarm_odom_pub = self.create_publisher(SwarmOdometry, SWARM_ODOM, qos)
        rate = float(p['markers_rate'])
        self.publish_rate = float(p['publish_rate']) or self.cfg.control_rate or REALTIME_RATE
        period = self.cfg.dt if self.mode == 'lockstep' else 1.0 / self.publish_rate
        self.markers_every = max(1, round(1.0 / (rate * period))) if rate > 0 else 0
        self.state_count = 0
        self._state_msg = None
        self._odom_msgs: dict[int, Odometry] = {}
        self.markers_pub = (
            self.create_publisher(MarkerArray, SWARM_MARKERS, 1) if self.markers_every else None
        )
        for i in self.model.ids:
            self.create_subscription(ForceCommand, force_topic(i), partial(self._on_force, i), qos)
        self.tracker_rejected: dict[int, int] = {}
        self._log_rejection = RejectionLog(self)
        self.create_timer(1.0, self._check_duplicates)
        self.create_subscription(Odometry, TARGET_ODOM, self._on_target, qos)
        # realtime: the latest target state (lockstep: the barrier holds it)
        self.rt_target: Sample | None = None
        self.barrier = LockstepBarrier(self.model, self.timeout)
        self.running = False
        self.clock_started = False  # realtime: the physics clock runs (see _arm)
        self.arm_deadline = 0.0
        self.done = False
        self.published_final = False
        if self.mode == 'lockstep':
            self.clock_pub = self.create_publisher(Clock, CLOCK, CLOCK_QOS)
            self.request_pub = self.create_publisher(UInt64, TARGET_REQUEST, REQUEST_QOS)
            self._request = UInt64()
            self.create_timer(0.01, self._check_deadline)
        else:
            self.create_timer(1.0 / float(p['physics_rate']), self._on_physics)
            self.create_timer(1.0 / self.publish_rate, self._on_publish)
            self._target_seq = -1
        if p['wait_for_start']:
            self.create_subscription(Empty, SWARM_START, self._on_start, START_QOS)
            self.get_logger().info('waiting for /swarm/start')
        else:
            self._start_timer = self.create_timer(0.5, self._autostart)
        self.get_logger().info(
            f'plant: {self.cfg.n_trackers} trackers, {self.mode}, '
            f'dt {self.cfg.dt:g} s, {self.steps} steps'
        )

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
            self.arm_deadline = time.monotonic() + self.arm_timeout
            self._arm()

    def _arm(self) -> bool:
        """Realtime: start the physics clock once every tracker has commanded from its
        inputs (both directions of its loop work), or at ``arm_timeout``; True once it runs.
        Until then odometry goes out with the UAVs held still, so no tracker is judged late
        for the time its first messages take to match."""
        if self.clock_started:
            return True
        now = time.monotonic()
        waiting = self.model.clock_start(now, self.arm_deadline)
        if waiting is None:
            return False
        self.clock_started, self.wall0 = True, now
        if waiting:
            self.get_logger().warn(
                f'clock started after arm_timeout = {self.arm_timeout:g} s without a command '
                f'from {[f"uav_{i}" for i in waiting]}'
            )
        else:
            self.get_logger().info('clock started: every tracker commands')
        return True

    def _matched(self) -> bool:
        """Lockstep: every tracker's command has a publisher and every step-k reader a match."""
        n = self.cfg.n_trackers
        if self.request_pub.get_subscription_count() < 1 or self.count_publishers(TARGET_ODOM) < 1:
            return False
        if any(self.count_publishers(force_topic(i)) < 1 for i in self.model.ids):
            return False
        if self.inputs == 'aggregate':
            return self.swarm_odom_pub.get_subscription_count() >= n
        return all(p.get_subscription_count() >= 1 for p in self.odom_pubs)

    def _start_when_matched(self) -> None:
        if self.waiting_for_match and self._matched():
            self.waiting_for_match = False
            self._carry_out(self.barrier.start(time.monotonic()))

    # --- lockstep: the core's barrier decides, the node publishes -------------------------
    def _carry_out(self, actions: list[Action]) -> None:
        for a in actions:
            if a.kind == 'request':
                self._request.data = a.step
                self.request_pub.publish(self._request)
            elif a.kind == 'swarm_odom':
                self._publish_swarm_odom(a.step, step_stamp(a.step, self.dt_ns))
            elif a.kind == 'step':
                stamp = step_stamp(a.step, self.dt_ns)
                self.clock_pub.publish(clock_msg(stamp))
                self._publish_odoms(stamp)
            elif a.kind == 'state':
                self._publish_state(a.data, step_stamp(a.step, self.dt_ns))
            elif a.kind == 'warn':
                self.get_logger().warn(a.text)
            else:
                self.get_logger().info(a.text)
        self.done = self.barrier.done

    def _target(self) -> Sample:
        if self.mode == 'lockstep':
            return self.barrier.target
        assert self.rt_target is not None
        return self.rt_target

    def _target_age(self) -> float:
        """Age of the held target state [s]: simulated (lockstep) or wall time (realtime)."""
        if self.mode == 'lockstep':
            return self.barrier.target_age()
        assert self.rt_target is not None
        return max(0.0, time.monotonic() - self.rt_target.received)

    def _publish_swarm_odom(self, k: int, stamp: Time) -> None:
        self.swarm_odom_pub.publish(
            swarm_odom_msg(
                step=k,
                stamp=stamp,
                uav_ids=self.model.ids,
                x=self.model.x,
                v=self.model.v,
                target_x=self._target().x,
                target_v=self._target().v,
                active=self.model.active,
                target_age=self._target_age(),
                command_latency=self.model.latency if self.mode == 'realtime' else None,
            )
        )

    def _refuse(self, why: str) -> None:
        self.model.refuse(why)
        self._log_rejection(why, self.model.rejected)

    def _stale_stamp(self, stamp: Time) -> float | None:
        """Realtime: the age [s] of a stamp older than command_timeout, else None."""
        if self.mode == 'lockstep':
            return None
        age = (self.get_clock().now().nanoseconds - stamp_ns(stamp)) * 1e-9
        return age if age > self.timeout else None

    def _on_force(self, topic_id: int, msg: ForceCommand) -> None:
        f = force_arrays(msg)
        if f.uav_id != topic_id:
            self._refuse(f'a command on {force_topic(topic_id)} claims uav_id {f.uav_id}')
            return
        age = self._stale_stamp(msg.header.stamp)
        if age is not None:
            self._refuse(
                f'command of uav_{f.uav_id} is stale: stamped {age:.3f} s ago '
                f'(command_timeout {self.timeout:g} s)'
            )
            return
        was_active = bool(self.model.active[f.uav_id - 1])
        now = time.monotonic()
        latency = 0.0
        if self.mode == 'realtime' and self.clock_started and not self.done:
            # the held commands act up to this instant, the new one from here on
            self.model.advance_to(now - self.wall0)
            latency = (self.get_clock().now().nanoseconds - stamp_ns(msg.header.stamp)) * 1e-9
        if not self.model.offer_command(
            f.uav_id,
            f.step,
            f.force,
            f.sliding_surface,
            f.stale,
            now=now,
            instance=f.instance,
            latency=latency,
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
        if self.mode == 'lockstep':
            step = step_of(msg.header.stamp, self.dt_ns)
            self._carry_out(self.barrier.on_target(step, x, v, time.monotonic()))
        else:
            age = self._stale_stamp(msg.header.stamp)
            seq = stamp_ns(msg.header.stamp)
            if age is not None:
                self._refuse(f'target state is stale: stamped {age:.3f} s ago')
            elif seq < self._target_seq:
                self._refuse(
                    f'target state out of order (stamp {seq} ns after {self._target_seq})'
                )
            else:
                self._target_seq = seq
                self.rt_target = Sample(-1, x, v, time.monotonic())

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
        if not self.running or self.done or not self._arm():
            return
        now = time.monotonic()
        newly = self.model.expire(now, self.stale_after, self.timeout)
        if newly:
            self.model.missed += len(newly)
            self.get_logger().warn(
                f'no command from {[f"uav_{i}" for i in newly]} for {self.timeout:g} s: '
                f'inactive, left out of the neighbour sets (zero force since '
                f'{self.stale_after:g} s; {self.model.missed} missed so far)'
            )
        self.model.advance_to(now - self.wall0)
        if self.model.k >= self.steps:
            self.done = True
            self.get_logger().info(
                f'done: {self.steps} steps of {self.cfg.dt:g} s; '
                f'{self.model.zeroed} held commands zeroed (tracker later '
                f'than stale_after = {self.stale_after:g} s)'
            )

    def _on_publish(self) -> None:
        if not self.running or self.published_final or self.rt_target is None:
            return  # not started, finished, or no target state yet
        stamp = self.get_clock().now().to_msg()
        armed = self._arm()
        self._publish_odoms(stamp)
        self._publish_swarm_odom(self.model.k, stamp)
        if not armed:
            return  # the trackers' first inputs went out; no state before the clock runs
        self.published_final = self.done  # the state at the end of the run goes out once
        self.model.published(time.monotonic())
        self._publish_state(
            self.model.snapshot(self.model.k, self._target(), self._target_age()), stamp
        )

    # --- shared ------------------------------------------------------------------------------
    def _publish_odoms(self, stamp: Time) -> None:
        """``/uav_<i>/odom`` of every tracker that has a reader (building an Odometry costs
        about 0.1 ms in Python, a third of a lockstep step when nobody listens)."""
        for i, pub in zip(self.model.ids, self.odom_pubs, strict=False):
            if pub.get_subscription_count():
                self._odom_msgs[i] = odom_msg(
                    self.model.x[i - 1],
                    self.model.v[i - 1],
                    stamp,
                    f'uav_{i}',
                    out=self._odom_msgs.get(i),
                )
                pub.publish(self._odom_msgs[i])

    def _publish_state(self, state: dict[str, Any], stamp: Time) -> None:
        """``/swarm/state`` (and every ``markers_every``-th time the markers) of a state
        taken by :meth:`PlantModel.snapshot`, with its metrics and the trackers' own refusal
        counts."""
        x, tx = state['x'], state['target_x']
        state['rejected_inputs'] += sum(self.tracker_rejected.values())
        if self.markers_pub is not None and self.state_count % self.markers_every == 0:
            self.markers_pub.publish(markers_msg(x, tx, stamp, self.model.ids))
        self.state_count += 1
        j, ce, fe = self.model.metrics(tx, x)
        self._state_msg = swarm_state_msg(
            out=self._state_msg,
            stamp=stamp,
            uav_ids=self.model.ids,
            potential=j,
            centroid_error=ce,
            formation_error=fe,
            **state,
        )
        self.state_pub.publish(self._state_msg)


def main(args: list[str] | None = None) -> None:
    sys.exit(run_node('plant', PlantNode, args))


if __name__ == '__main__':
    main()
