"""What the plant node publishes (:class:`PlantOutputs`), built from its model's arrays:
``/uav_<i>/odom`` (to the readers it has), ``/swarm/odom``, ``/swarm/state`` with its metrics,
``/swarm/markers`` and, in lockstep, ``/clock`` and the target requests."""

from __future__ import annotations

from typing import Any

from apf_swarm_core.inputs import Sample
from apf_swarm_core.plant_model import PlantModel
from builtin_interfaces.msg import Time
from nav_msgs.msg import Odometry
from rclpy.node import Node
from rclpy.qos import QoSProfile
from rosgraph_msgs.msg import Clock
from std_msgs.msg import UInt64
from visualization_msgs.msg import MarkerArray

from apf_swarm_msgs.msg import SwarmOdometry, SwarmState

from .conversions import markers_msg, odom_msg, swarm_odom_msg, swarm_state_msg
from .node_common import CLOCK_QOS, REQUEST_QOS, STATE_QOS
from .topics import CLOCK, SWARM_MARKERS, SWARM_ODOM, SWARM_STATE, TARGET_REQUEST, odom_topic

__all__ = ['PlantOutputs']


class PlantOutputs:
    """The plant's publishers on ``node``, the messages it reuses, and how often markers go
    out: ``markers_rate`` per second of the period of ``/swarm/state`` (``period`` [s]; 0:
    no markers)."""

    def __init__(
        self,
        node: Node,
        model: PlantModel,
        mode: str,
        qos: QoSProfile,
        markers_rate: float,
        period: float,
    ) -> None:
        self.model = model
        self.odom_pubs = [node.create_publisher(Odometry, odom_topic(i), qos) for i in model.ids]
        self.state_pub = node.create_publisher(SwarmState, SWARM_STATE, STATE_QOS)
        self.swarm_odom_pub = node.create_publisher(SwarmOdometry, SWARM_ODOM, qos)
        rate = float(markers_rate)
        self.markers_every = max(1, round(1.0 / (rate * period))) if rate > 0 else 0
        self.markers_pub = (
            node.create_publisher(MarkerArray, SWARM_MARKERS, 1) if self.markers_every else None
        )
        self.state_count = 0
        self._state_msg = None
        self._odom_msgs: dict[int, Odometry] = {}
        if mode == 'lockstep':
            self.clock_pub = node.create_publisher(Clock, CLOCK, CLOCK_QOS)
            self.request_pub = node.create_publisher(UInt64, TARGET_REQUEST, REQUEST_QOS)
            self._request = UInt64()

    def readers_matched(self, inputs: str, recorder: int = 0) -> bool:
        """Lockstep: the target reads the requests and every reader of step k is matched
        (``inputs``: what the trackers read, ``aggregate`` or ``odom``), on the writers' own
        counts; ``recorder``: 1 if a recorder reads every topic too, and each writer must
        have matched it before step 0 (see :class:`~.node_common.MatchGate`)."""
        trackers = len(self.model.ids) if inputs == 'aggregate' else 0
        per_uav = 1 if inputs == 'odom' else 0
        need = [
            (self.request_pub, 1),
            (self.swarm_odom_pub, trackers),
            (self.state_pub, 0),
            (self.clock_pub, 0),
            *((pub, per_uav) for pub in self.odom_pubs),
        ]
        return all(pub.get_subscription_count() >= n + recorder for pub, n in need)

    def request(self, step: int) -> None:
        """Lockstep: ask the target for its states up to ``step``."""
        self._request.data = step
        self.request_pub.publish(self._request)

    def step(self, stamp: Time) -> None:
        """Lockstep: ``/clock`` and every UAV's odometry of the model's current state."""
        self.clock_pub.publish(Clock(clock=stamp))
        self.odoms(stamp)

    def odoms(self, stamp: Time) -> None:
        """``/uav_<i>/odom`` of every tracker that has a reader (building an Odometry costs
        about 0.1 ms in Python, a third of a lockstep step when nobody listens)."""
        m = self.model
        for i, pub in zip(m.ids, self.odom_pubs, strict=False):
            if pub.get_subscription_count():
                self._odom_msgs[i] = odom_msg(
                    m.x[i - 1], m.v[i - 1], stamp, f'uav_{i}', out=self._odom_msgs.get(i)
                )
                pub.publish(self._odom_msgs[i])

    def swarm_odom(
        self, k: int, stamp: Time, target: Sample, target_age: float, latency: bool
    ) -> None:
        """``/swarm/odom`` of step ``k``: every UAV, the held ``target`` of age
        ``target_age`` [s] and, with ``latency`` (realtime), each tracker's command latency."""
        m = self.model
        self.swarm_odom_pub.publish(
            swarm_odom_msg(
                step=k,
                stamp=stamp,
                uav_ids=m.ids,
                x=m.x,
                v=m.v,
                target_x=target.x,
                target_v=target.v,
                active=m.active,
                target_age=target_age,
                command_latency=m.latency if latency else None,
                run=m.run,
            )
        )

    def state(self, state: dict[str, Any], stamp: Time, tracker_rejected: int) -> None:
        """``/swarm/state`` (and every ``markers_every``-th time the markers) of a state
        taken by :meth:`PlantModel.snapshot`, with its metrics and the trackers' own refusal
        counts (``tracker_rejected``)."""
        x, tx = state['x'], state['target_x']
        state['rejected_inputs'] += tracker_rejected
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
