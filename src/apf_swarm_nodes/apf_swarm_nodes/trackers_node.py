"""The ``trackers`` executable: several tracker nodes in one process
(:func:`group_main`), with the ids it hosts (:func:`parse_uav_ids`)."""

from __future__ import annotations

import sys
from typing import Any

from apf_swarm_msgs.msg import ForceCommand, ForceCommands

from .node_common import control_qos, run_nodes
from .topics import SWARM_FORCE_CMDS, uav_namespace
from .tracker_node import TrackerNode

__all__ = ['LeadTrackerNode', 'group_main', 'parse_uav_ids']


class LeadTrackerNode(TrackerNode):
    """The tracker node that reads ``/swarm/odom`` for its process and hands each state to
    the others (:attr:`fanout`); with ``batch_commands``, the commands they answer it with
    go out together as one ``/swarm/force_cmds`` message."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.batch: list[ForceCommand] | None = None
        self.batch_pub = None
        #: whether this node reads /swarm/odom for its process (realtime, aggregate inputs)
        self.leads = self.mode == 'realtime' and self.inputs == 'aggregate'
        if self.leads and self.get_parameter('batch_commands').value:
            qos = control_qos(self.mode, self.get_parameter('qos_depth').value)
            self.batch_pub = self.create_publisher(ForceCommands, SWARM_FORCE_CMDS, qos)
            self.join(self)
            self.get_logger().info(
                f'the process sends its commands together on {SWARM_FORCE_CMDS}'
            )

    def join(self, node: TrackerNode) -> None:
        """``node`` answers the states this one hands it; with ``batch_commands`` its commands
        on a state go into the batch (its others, brakes on the watchdog's timer, on its own
        topic as before)."""
        if node is not self:
            self.fanout.append(node)
        if self.batch_pub is None:
            return
        alone = node._publish
        node._publish = lambda msg: alone(msg) if self.batch is None else self.batch.append(msg)

    def _on_swarm_odom(self, msg: Any) -> None:
        self.batch = None if self.batch_pub is None else []
        try:
            super()._on_swarm_odom(msg)
        finally:
            batch, self.batch = self.batch, None
        if batch and self.batch_pub is not None:
            self.batch_pub.publish(ForceCommands(commands=batch))


def parse_uav_ids(text: str) -> list[int]:
    """``1,2,3`` or ``4-6`` or a mix: the ids a ``trackers`` process hosts (ValueError if bad)."""
    ids: list[int] = []
    for part in text.split(','):
        lo, _, hi = part.strip().partition('-')
        try:
            a, b = int(lo), int(hi or lo)
        except ValueError:
            raise ValueError(f'--uav-ids {text!r}: expected ids like 1,2,3 or 1-3') from None
        if a < 1 or b < a:
            raise ValueError(f'--uav-ids {text!r}: ids are 1-based, ranges ascending')
        ids.extend(range(a, b + 1))
    if len(set(ids)) != len(ids):
        raise ValueError(f'--uav-ids {text!r}: an id appears twice')
    return ids


def group_main(args: list[str] | None = None) -> None:
    """``trackers --uav-ids 1,2,3 --ros-args ...``: several tracker nodes in one process.

    Each is its own node ``/uav_<i>/tracker`` with its own parameters (the params file's
    ``/**`` and ``/uav_<i>/tracker`` sections, ``uav_id`` = i), spun on one executor. Do not
    remap ``__ns`` or ``__node`` here: that would rename every node of the process.
    """
    from rclpy.parameter import Parameter
    from rclpy.utilities import remove_ros_args

    argv = sys.argv if args is None else args
    own = remove_ros_args(argv)[1:]
    usage = 'usage: trackers --uav-ids IDS [--ros-args ...]'
    if len(own) != 2 or own[0] != '--uav-ids':
        print(f'trackers: error: {usage}', file=sys.stderr)
        sys.exit(2)
    try:
        ids = parse_uav_ids(own[1])
    except ValueError as exc:
        print(f'trackers: error: {exc}', file=sys.stderr)
        sys.exit(2)
    # realtime with the aggregated inputs: one /swarm/odom subscription for the process, whose
    # node hands each message to the others (one delivery and one conversion per state
    # instead of one per tracker); lockstep keeps one per node, the readers the plant counts
    lead: list[LeadTrackerNode] = []  # the node that subscribes for the process, if any

    def make(i: int) -> TrackerNode:
        ns, uav_id = uav_namespace(i), [Parameter('uav_id', value=i)]
        if lead:
            node = TrackerNode(namespace=ns, parameter_overrides=uav_id, swarm_odom=False)
            lead[0].join(node)
            return node
        first = LeadTrackerNode(namespace=ns, parameter_overrides=uav_id)
        if first.leads:
            lead.append(first)
        return first

    factories = [lambda i=i: make(i) for i in ids]
    sys.exit(run_nodes('trackers', factories, argv))


if __name__ == '__main__':
    group_main()
