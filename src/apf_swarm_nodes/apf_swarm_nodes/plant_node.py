"""Plant node: integrates every tracker's dynamics (eq. 19-21) with bounded noise.

Publishes ``/uav_<i>/odom`` for every tracker, ``/swarm/odom`` (all of them and the target
state, one message), ``/swarm/state``, ``/swarm/markers`` (RViz / Foxglove) and, in
lockstep, ``/clock``;
subscribes ``/uav_<i>/force_cmd`` and ``/target/odom``.

Lockstep barrier, step k: wait for the target's state of step k (the target's states are
asked for ahead on ``/target/request``, see :mod:`.node_common`), then publish ``/swarm/odom``
of step k, ``/clock`` (k dt) and the per-UAV odometry; wait until the command of step k of
every active tracker has arrived; integrate to k + 1, publish step k + 1 and only
then the ``/swarm/state`` sample of step k (its metrics are computed while the trackers
work). Past ``command_timeout``
seconds of wall time the step is published once more; still missing after another
``command_timeout``, the input is counted in ``missed_deadlines`` and logged, and its
source is no longer waited for: a silent tracker becomes inactive (zero force, left out of
the other trackers' potential, see :mod:`apf_swarm_core.agents`), a silent target's last
state is held and its age grows in ``/swarm/odom`` (trackers brake once it exceeds their
``input_timeout``). A command or target state that arrives again ends that.

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

import numpy as np
from apf_swarm_core.agents import PlantModel, input_problem
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
    TARGET_LOOKAHEAD,
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

    def __init__(self, **kwargs) -> None:
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
        self.republished = False
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
        self.odom_sent = False
        for i in self.model.ids:
            self.create_subscription(
                ForceCommand, force_topic(i), lambda m, i=i: self._on_force(i, m), qos
            )
        self.tracker_rejected: dict[int, int] = {}
        self._log_rejection = RejectionLog(self)
        self.target_absent = False  # lockstep: the target missed a deadline
        self.create_timer(1.0, self._check_duplicates)
        self.create_subscription(Odometry, TARGET_ODOM, self._on_target, qos)
        self.target = (-1, np.zeros(3), np.zeros(3), 0.0)  # step, x, v, received
        self.targets: dict[int, tuple] = {}  # lockstep: target states by step, k..requested
        self.running = False
        self.clock_started = False  # realtime: the physics clock runs (see _arm)
        self.arm_deadline = 0.0
        self.done = False
        self.published_final = False
        self.step_started = 0.0
        if self.mode == 'lockstep':
            self.clock_pub = self.create_publisher(Clock, CLOCK, CLOCK_QOS)
            self.request_pub = self.create_publisher(UInt64, TARGET_REQUEST, REQUEST_QOS)
            self._request = UInt64()
            self.requested = -1  # the last step whose target state was asked for
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
            self._publish_step()

    # --- lockstep ------------------------------------------------------------------------
    def _publish_step(self, again: bool = False) -> None:
        if not again:
            self.republished = False
        k = self.model.k
        stamp = step_stamp(k, self.dt_ns)
        self.step_started = time.monotonic()
        # what the trackers wait for goes out first
        self.odom_sent = False
        self._maybe_publish_swarm_odom()
        self._request_target(again)
        self.clock_pub.publish(clock_msg(stamp))
        self._publish_odoms(stamp)

    def _request_target(self, again: bool = False) -> None:
        """Lockstep: ask the target for its states up to ``TARGET_LOOKAHEAD - 1`` steps
        ahead once fewer than half of that are asked for. ``again`` (step k is late): repeat
        the last request, which the target answers by sending that window once more (step k
        is in it), e.g. when its states went out before a reader had matched."""
        k = self.model.k
        want = min(k + TARGET_LOOKAHEAD - 1, self.steps)
        if again and self.requested >= k:
            want = self.requested
        elif want <= self.requested or self.requested - k >= TARGET_LOOKAHEAD // 2:
            return
        self.requested = want
        self._request.data = want
        self.request_pub.publish(self._request)

    def _maybe_publish_swarm_odom(self) -> None:
        """Lockstep: ``/swarm/odom`` of step k once the target state of step k is held."""
        k = self.model.k
        if (
            self.running
            and not self.done
            and not self.odom_sent
            and (self.target[0] == k or self.target_absent)
        ):
            self._publish_swarm_odom(k, step_stamp(k, self.dt_ns))
            self.odom_sent = True

    def _target_age(self) -> float:
        """Age of the held target state [s]: simulated (lockstep) or wall time (realtime)."""
        if self.mode == 'lockstep':
            return max(0, self.model.k - self.target[0]) * self.cfg.dt
        return max(0.0, time.monotonic() - self.target[3])

    def _publish_swarm_odom(self, k: int, stamp) -> None:
        self.swarm_odom_pub.publish(
            swarm_odom_msg(
                step=k,
                stamp=stamp,
                uav_ids=self.model.ids,
                x=self.model.x,
                v=self.model.v,
                target_x=self.target[1],
                target_v=self.target[2],
                active=self.model.active,
                target_age=self._target_age(),
                command_latency=self.model.latency if self.mode == 'realtime' else None,
            )
        )

    def _refuse(self, why: str) -> None:
        self.model.refuse(why)
        self._log_rejection(why, self.model.rejected)

    def _stale_stamp(self, stamp) -> float | None:
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
            self._maybe_finish()

    def _on_target(self, msg: Odometry) -> None:
        x, v = odom_arrays(msg)
        problem = input_problem(x=x, v=v)
        if problem is not None:
            self._refuse(f'target state: {problem}')
            return
        if self.mode == 'lockstep':
            step = step_of(msg.header.stamp, self.dt_ns)
            if not self.model.k <= step <= max(self.requested, self.model.k):
                return  # a step already integrated, or one never asked for: not kept
            self.targets[step] = (step, x, v, time.monotonic())
            if self.target[0] != self.model.k and self.model.k in self.targets:
                self.target = self.targets.pop(self.model.k)
                if self.target_absent:
                    self.target_absent = False
                    self.get_logger().info(f'step {self.model.k}: the target publishes again')
            self._maybe_publish_swarm_odom()
            self._maybe_finish()
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
                self.target = (-1, x, v, time.monotonic())

    def _check_duplicates(self) -> None:
        """1 Hz: a force topic with more than one publisher means two trackers share an id."""
        for i in self.model.ids:
            count = self.count_publishers(force_topic(i))
            if count > 1:
                self.get_logger().error(
                    f'duplicate uav_id {i}: {count} publishers on {force_topic(i)}; '
                    'following the first tracker process that commanded, refusing the others'
                )

    def _maybe_finish(self, force: bool = False) -> None:
        if not self.running or self.done:
            return
        k = self.model.k
        missing = self.model.missing(k)
        target_late = self._target_late()
        if (missing or target_late) and not force:
            return
        if target_late:
            # /swarm/odom of step k waits for the target, so no tracker has seen step k yet:
            # only the target missed it. Hold its last state and let the trackers answer.
            self.model.missed += 1
            self.target_absent = True
            self.get_logger().warn(
                f'step {k}: no target state within 2 x {self.timeout:g} s ({self.model.missed} '
                f'missed so far); holding the last one (its age grows in /swarm/odom) and '
                f'not waiting for the target any more'
            )
            self.step_started = time.monotonic()
            self.republished = False
            self._maybe_publish_swarm_odom()
            return
        if missing:
            self.model.missed += len(missing)
            self.model.deactivate(missing)
            self.get_logger().warn(
                f'step {k}: no command from {[f"uav_{i}" for i in missing]} within 2 x '
                f'{self.timeout:g} s ({self.model.missed} missed so far): zero force, left '
                f'out of the neighbour sets, not waited for until they command again'
            )
        # the state of step k goes out after step k + 1 (below): the trackers, which wait
        # for /swarm/odom of k + 1, start while this process computes the metrics of k
        state = self._state_of(k)
        self.model.advance()
        if self.model.k in self.targets:
            self.target = self.targets.pop(self.model.k)
            if self.target_absent:
                self.target_absent = False
                self.get_logger().info(f'step {self.model.k}: the target publishes again')
        for old in [j for j in self.targets if j < self.model.k]:
            del self.targets[old]
        if self.model.k >= self.steps:
            self.done = True
            # logged before the last state goes out: whoever waits for that state may stop
            # this process right after it (a log call in a shut-down context raises)
            self.get_logger().info(f'done: {self.steps} steps, {self.model.missed} missed')
            self._publish_state(state, step_stamp(k, self.dt_ns))
            return
        self._publish_step()
        self._publish_state(state, step_stamp(k, self.dt_ns))

    def _check_deadline(self) -> None:
        """10 ms timer: start when matched; past the deadline re-send step k once, then miss."""
        if self.waiting_for_match:
            self._start_when_matched()
            return
        if self.running and not self.done and time.monotonic() - self.step_started > self.timeout:
            if not self.republished:
                self.republished = True
                self.get_logger().warn(
                    f'step {self.model.k}: inputs {self._late()} late after '
                    f'{self.timeout:g} s; publishing the step again'
                )
                self._publish_step(again=True)
            else:
                self._maybe_finish(force=True)

    def _target_late(self) -> bool:
        """Lockstep: the target state of step k is awaited and has not arrived."""
        return self.target[0] != self.model.k and not self.target_absent

    def _late(self) -> list[str]:
        return [f'uav_{i}' for i in self.model.missing(self.model.k)] + (
            ['target'] if self._target_late() else []
        )

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
        if not self.running or self.published_final or self.target[3] == 0.0:
            return  # not started, finished, or no target state yet
        stamp = self.get_clock().now().to_msg()
        armed = self._arm()
        self._publish_odoms(stamp)
        self._publish_swarm_odom(self.model.k, stamp)
        if not armed:
            return  # the trackers' first inputs went out; no state before the clock runs
        self.published_final = self.done  # the state at the end of the run goes out once
        self.model.published(time.monotonic())
        self._publish_state(self._state_of(self.model.k), stamp)

    # --- shared ------------------------------------------------------------------------------
    def _publish_odoms(self, stamp) -> None:
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

    def _state_of(self, k: int) -> dict:
        """The fields of the ``/swarm/state`` sample of step k, taken now (the model's arrays
        are replaced by :meth:`PlantModel.advance`, the commands are copied)."""
        m = self.model
        return {
            'step': k,
            'sim_time': k * self.cfg.dt,
            'x': m.x,
            'v': m.v,
            'u': m.u.copy(),
            's': m.s.copy(),
            'target_x': self.target[1],
            'target_v': self.target[2],
            'missed_deadlines': m.missed,
            'stale_inputs': m.stale,
            'rejected_inputs': m.rejected + sum(self.tracker_rejected.values()),
            'active': m.active.copy(),
            'target_age': self._target_age(),
            'command_latency': m.latency.copy(),
        }

    def _publish_state(self, state: dict, stamp) -> None:
        """``/swarm/state`` (and every ``markers_every``-th time the markers) of a state
        taken by :meth:`_state_of`, with its metrics."""
        x, tx = state['x'], state['target_x']
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
