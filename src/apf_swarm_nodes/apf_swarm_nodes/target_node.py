"""Target node: flies the target along its trajectory (eq. 1), publishes ``odom``
(``/target/odom`` in the namespace ``/target``). Lockstep: answers each ``request`` (the last
step the plant wants) with the core's window of states (``target_window``); realtime: publishes
at ``publish_rate`` from the start (``/swarm/start`` with ``wait_for_start``). docs/ROS.md,
"Timing modes"."""

from __future__ import annotations

import sys
import time
from functools import partial
from typing import Any

from apf_swarm_core.lockstep import LOOKAHEAD, target_window
from builtin_interfaces.msg import Time
from nav_msgs.msg import Odometry
from rclpy.node import Node
from std_msgs.msg import Empty, UInt64

from .conversions import dt_to_ns, odom_msg, step_stamp
from .node_common import REQUEST_QOS, START_QOS, MatchGate, control_qos, run_node
from .params import NodeParam, declare_swarm_node
from .topics import ODOM, REQUEST, SWARM_START

__all__ = ['TargetNode', 'main']

NODE_PARAMS = (
    NodeParam('publish_rate', 100.0, 'realtime publish rate [Hz]', lo=1.0, hi=2000.0),
    NodeParam('wait_for_start', False, 'realtime: wait for /swarm/start before t = 0'),
)


class TargetNode(Node):
    """Publishes the trajectory's state; the trajectory itself is the core's."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('target', **kwargs)
        self.cfg, p = declare_swarm_node(self, NODE_PARAMS)
        self.mode = p['mode']
        self.traj = self.cfg.target_trajectory_obj
        self.dt_ns = dt_to_ns(self.cfg.dt)
        self.pub = self.create_publisher(Odometry, ODOM, control_qos(self.mode, p['qos_depth']))
        self.t0: float | None = None
        self.next_step = 0
        self._msg = None
        if self.mode == 'lockstep':
            #: an answer waits until the plant's reader (and the recorder's) matched
            self.gate = MatchGate(self, self.pub, 1, first=1 + int(p['recorded']))
            self.create_subscription(UInt64, REQUEST, self._on_request, REQUEST_QOS)
        else:
            if p['wait_for_start']:
                self.create_subscription(Empty, SWARM_START, self._on_start, START_QOS)
            else:
                self.t0 = time.monotonic()
            self.create_timer(1.0 / float(p['publish_rate']), self._on_timer)
        self.get_logger().info(
            f'target: {self.cfg.target_trajectory} at {self.cfg.target_speed:g} m/s, {self.mode}'
        )

    def _publish(self, t: float, stamp: Time) -> None:
        x, v = self.traj.state(t)
        self._msg = odom_msg(x, v, stamp, 'target', out=self._msg)
        self.pub.publish(self._msg)

    def _on_request(self, msg: UInt64) -> None:
        self.gate(partial(self._answer, int(msg.data)))

    def _answer(self, last: int) -> None:
        """The plant wants the states up to step ``last``: publish the core's window of them
        (:func:`~apf_swarm_core.lockstep.target_window`). The state of step k is exactly
        ``trajectory.state(k dt)`` whenever it is published."""
        for j in target_window(last, self.next_step, LOOKAHEAD):
            self._publish(j * self.cfg.dt, step_stamp(j, self.dt_ns))
        self.next_step = max(self.next_step, last + 1)

    def _on_start(self, _msg: Empty) -> None:
        if self.t0 is None:
            self.t0 = time.monotonic()

    def _on_timer(self) -> None:
        if self.t0 is not None:
            self._publish(time.monotonic() - self.t0, self.get_clock().now().to_msg())


def main(args: list[str] | None = None) -> None:
    sys.exit(run_node('target', TargetNode, args))


if __name__ == '__main__':
    main()
