"""A tracker's command as the standard messages a flight-stack bridge consumes:
``geometry_msgs/AccelStamped`` (an acceleration setpoint) and ``geometry_msgs/TwistStamped``
(a velocity setpoint), both in the ``world`` frame (x east, y north, z up; a bridge to a
north-east-down stack such as PX4 swaps x and y and negates z), angular parts zero."""

from __future__ import annotations

import numpy as np
from builtin_interfaces.msg import Time
from geometry_msgs.msg import AccelStamped, TwistStamped
from numpy.typing import NDArray

from .fields import WORLD, set_vec

__all__ = ['accel_msg', 'twist_msg']


def accel_msg(stamp: Time, a: NDArray[np.float64]) -> AccelStamped:
    """``AccelStamped`` of the acceleration setpoint ``a`` (3,) [m/s^2]."""
    m = AccelStamped()
    m.header.stamp = stamp
    m.header.frame_id = WORLD
    set_vec(m.accel.linear, a)
    return m


def twist_msg(stamp: Time, v: NDArray[np.float64]) -> TwistStamped:
    """``TwistStamped`` of the velocity setpoint ``v`` (3,) [m/s]."""
    m = TwistStamped()
    m.header.stamp = stamp
    m.header.frame_id = WORLD
    set_vec(m.twist.linear, v)
    return m
