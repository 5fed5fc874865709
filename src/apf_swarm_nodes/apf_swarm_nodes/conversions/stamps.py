"""Times: a lockstep run stamps step k with the simulated time ``k * dt_ns`` nanoseconds
(``dt_ns`` the step in integer nanoseconds), so the step of a message is ``stamp_ns // dt_ns``
exactly; and ``/clock``."""

from __future__ import annotations

from builtin_interfaces.msg import Time
from rosgraph_msgs.msg import Clock

__all__ = ['clock_msg', 'dt_to_ns', 'stamp_ns', 'step_stamp']


def dt_to_ns(dt: float) -> int:
    """The step length in integer nanoseconds."""
    return int(round(dt * 1e9))


def step_stamp(step: int, dt_ns: int) -> Time:
    """Simulated time of step k as a ``builtin_interfaces/Time``."""
    ns = int(step) * int(dt_ns)
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def stamp_ns(stamp: Time) -> int:
    """A ``builtin_interfaces/Time`` in integer nanoseconds."""
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def clock_msg(stamp: Time) -> Clock:
    """``rosgraph_msgs/Clock`` for a stamp."""
    return Clock(clock=stamp)
