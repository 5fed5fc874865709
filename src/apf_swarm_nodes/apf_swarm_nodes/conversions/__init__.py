"""The one place where ROS messages meet numpy arrays.

Frames: every pose and twist is in ``world`` (x east, y north, z up), SI units. Times: a
lockstep run stamps step k with the simulated time ``k * dt_ns`` nanoseconds (``dt_ns`` the
step in integer nanoseconds), so the step of a message is ``stamp_ns // dt_ns`` exactly.

By message: :mod:`.stamps` (stamps, steps, ``/clock``), :mod:`.odometry` (Odometry and
SwarmOdometry), :mod:`.commands` (ForceCommand), :mod:`.setpoints` (AccelStamped,
TwistStamped), :mod:`.state` (SwarmState), :mod:`.markers` (MarkerArray); :mod:`.fields`
holds what they share. Import the names from here.
"""

from __future__ import annotations

from .commands import LAW_CODES, force_arrays, force_msg, reply_msg
from .fields import WORLD
from .markers import markers_msg
from .odometry import SwarmOdom, odom_arrays, odom_msg, swarm_odom_arrays, swarm_odom_msg
from .setpoints import accel_msg, twist_msg
from .stamps import clock_msg, dt_to_ns, stamp_ns, step_stamp
from .state import SwarmSample, swarm_state_arrays, swarm_state_msg, swarm_state_step

__all__ = [
    'LAW_CODES',
    'WORLD',
    'SwarmOdom',
    'SwarmSample',
    'accel_msg',
    'clock_msg',
    'dt_to_ns',
    'force_arrays',
    'force_msg',
    'markers_msg',
    'odom_arrays',
    'odom_msg',
    'reply_msg',
    'stamp_ns',
    'step_stamp',
    'swarm_odom_arrays',
    'swarm_odom_msg',
    'swarm_state_arrays',
    'swarm_state_msg',
    'swarm_state_step',
    'twist_msg',
]
