"""Odometry as arrays and back: one UAV's or the target's ``nav_msgs/Odometry``, and the
whole swarm's ``apf_swarm_msgs/SwarmOdometry`` (what the trackers read)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from apf_swarm_core.tracker_modes import SwarmOdom
from builtin_interfaces.msg import Time
from nav_msgs.msg import Odometry
from numpy.typing import NDArray

from apf_swarm_msgs.msg import SwarmOdometry

from .fields import WORLD, active_flags, set_vec, vec
from .stamps import stamp_ns

__all__ = ['SwarmOdom', 'odom_arrays', 'odom_msg', 'swarm_odom_arrays', 'swarm_odom_msg']


def odom_msg(
    position: NDArray[np.float64],
    velocity: NDArray[np.float64],
    stamp: Time,
    child_frame_id: str,
    out: Odometry | None = None,
) -> Odometry:
    """``nav_msgs/Odometry`` in ``world`` with identity orientation and zero covariance.

    ``out``: a message made by this function before, updated in place (building a new
    Odometry costs about 0.1 ms in Python; publishing serializes, so reuse is safe).
    """
    msg = out
    if msg is None:
        msg = Odometry()
        msg.header.frame_id = WORLD
        msg.child_frame_id = child_frame_id
        msg.pose.pose.orientation.w = 1.0
    msg.header.stamp = stamp
    set_vec(msg.pose.pose.position, position)
    set_vec(msg.twist.twist.linear, velocity)
    return msg


def odom_arrays(msg: Odometry) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Position (3,) [m] and velocity (3,) [m/s] of an odometry message."""
    return vec(msg.pose.pose.position), vec(msg.twist.twist.linear)


def swarm_odom_msg(
    *,
    step: int,
    stamp: Time,
    uav_ids: Sequence[int],
    x: NDArray[np.float64],
    v: NDArray[np.float64],
    target_x: NDArray[np.float64],
    target_v: NDArray[np.float64],
    active: Sequence[bool] | NDArray[np.bool_] | None = None,
    target_age: float = 0.0,
    command_latency: NDArray[np.float64] | None = None,
    run: int = 0,
) -> SwarmOdometry:
    """``apf_swarm_msgs/SwarmOdometry`` from arrays x, v (n, 3) and the target (3,);
    ``active`` defaults to every tracker active, ``command_latency`` (n,) [s] to none."""
    msg = SwarmOdometry()
    msg.header.stamp = stamp
    msg.header.frame_id = WORLD
    msg.step = int(step)
    msg.uav_ids = [int(i) for i in uav_ids]
    msg.positions = np.ascontiguousarray(x, dtype=float).ravel().tolist()
    msg.velocities = np.ascontiguousarray(v, dtype=float).ravel().tolist()
    msg.target_position = np.asarray(target_x, dtype=float)
    msg.target_velocity = np.asarray(target_v, dtype=float)
    msg.active = active_flags(active, len(msg.uav_ids))
    msg.target_age = float(target_age)
    if command_latency is not None:
        msg.command_latency = np.asarray(command_latency, dtype=float).tolist()
    msg.run = int(run)
    return msg


def swarm_odom_arrays(msg: SwarmOdometry) -> SwarmOdom:
    """The arrays of a SwarmOdometry.

    Raises ValueError when the arrays do not have 3 values per id, when ``active`` has
    neither 0 (every tracker active) nor one flag per id, or when an id appears twice.
    """
    ids = [int(i) for i in msg.uav_ids]
    x = np.asarray(msg.positions, dtype=float)
    v = np.asarray(msg.velocities, dtype=float)
    if x.size != 3 * len(ids) or v.size != 3 * len(ids):
        raise ValueError(
            f'SwarmOdometry with {len(ids)} ids has {x.size} position and '
            f'{v.size} velocity values; expected {3 * len(ids)} each'
        )
    if len(set(ids)) != len(ids):
        raise ValueError(f'SwarmOdometry lists a uav_id twice: {ids}')
    active = [bool(a) for a in msg.active] or [True] * len(ids)
    if len(active) != len(ids):
        raise ValueError(f'SwarmOdometry with {len(ids)} ids has {len(active)} active flags')
    latency = np.asarray(getattr(msg, 'command_latency', ()), dtype=float)
    if latency.size not in (0, len(ids)):
        raise ValueError(
            f'SwarmOdometry with {len(ids)} ids has {latency.size} command '
            'latencies; expected none or one per id'
        )
    return SwarmOdom(
        int(msg.step),
        stamp_ns(msg.header.stamp),
        ids,
        x.reshape(-1, 3),
        v.reshape(-1, 3),
        np.asarray(msg.target_position, dtype=float),
        np.asarray(msg.target_velocity, dtype=float),
        active,
        float(msg.target_age),
        latency,
        int(getattr(msg, 'run', 0)),
    )
