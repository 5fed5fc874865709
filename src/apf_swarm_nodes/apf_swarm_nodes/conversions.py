"""The one place where ROS messages meet numpy arrays, by message: stamps,
Odometry and SwarmOdometry, ForceCommand, the setpoints (AccelStamped, TwistStamped),
SwarmState, MarkerArray.

Frames: every pose and twist is in ``world`` (x east, y north, z up), SI units. Times: a
lockstep run stamps step k with the simulated time ``k * dt_ns`` nanoseconds (``dt_ns`` the
step in integer nanoseconds), so the step of a message is ``stamp_ns // dt_ns`` exactly.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from apf_swarm_core.plant_model import Command
from apf_swarm_core.tracker_modes import Reply, SwarmOdom
from builtin_interfaces.msg import Time
from geometry_msgs.msg import AccelStamped, Point, TwistStamped, Vector3
from nav_msgs.msg import Odometry
from numpy.typing import NDArray

from apf_swarm_msgs.msg import ForceCommand, SwarmOdometry, SwarmState

if TYPE_CHECKING:
    from visualization_msgs.msg import MarkerArray

__all__ = [
    'LAW_CODES',
    'WORLD',
    'SwarmSample',
    'accel_msg',
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

WORLD = 'world'
LAW_CODES = {'proposed': ForceCommand.LAW_PROPOSED, 'traditional': ForceCommand.LAW_TRADITIONAL}


# --- what every conversion shares -------------------------------------------------------------
def _vec(msg: Any) -> NDArray[np.float64]:
    """A Point or Vector3 (any object with x, y, z) as an array (3,)."""
    return np.array((msg.x, msg.y, msg.z), dtype=float)


def _set_vec(msg: Any, v: NDArray[np.float64]) -> Any:
    """Set a Point or Vector3 from an array (3,); returns ``msg``."""
    msg.x, msg.y, msg.z = float(v[0]), float(v[1]), float(v[2])
    return msg


def _rows(seq: Sequence[Any]) -> NDArray[np.float64]:
    """A sequence of Points or Vector3s as an array (n, 3)."""
    return np.array([(m.x, m.y, m.z) for m in seq], dtype=float).reshape(-1, 3)


def _active_flags(active: Sequence[bool] | NDArray[np.bool_] | None, n: int) -> list[bool]:
    """The ``active`` field of n trackers: ``active`` as bools, every one active when None."""
    return [True] * n if active is None else [bool(a) for a in active]


# --- stamps -----------------------------------------------------------------------------------
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


# --- odometry ---------------------------------------------------------------------------------
def odom_msg(
    position: NDArray[np.float64],
    velocity: NDArray[np.float64],
    stamp: Time,
    child_frame_id: str,
    out: Odometry | None = None,
) -> Odometry:
    """``nav_msgs/Odometry`` in ``world`` with identity orientation and zero covariance.

    ``out``: a message made by this function before, updated in place (publishing
    serializes, so reuse is safe).
    """
    msg = out
    if msg is None:
        msg = Odometry()
        msg.header.frame_id = WORLD
        msg.child_frame_id = child_frame_id
        msg.pose.pose.orientation.w = 1.0
    msg.header.stamp = stamp
    _set_vec(msg.pose.pose.position, position)
    _set_vec(msg.twist.twist.linear, velocity)
    return msg


def odom_arrays(msg: Odometry) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Position (3,) [m] and velocity (3,) [m/s] of an odometry message."""
    return _vec(msg.pose.pose.position), _vec(msg.twist.twist.linear)


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
    msg.active = _active_flags(active, len(msg.uav_ids))
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


# --- force commands ---------------------------------------------------------------------------
def force_msg(
    *,
    uav_id: int,
    step: int,
    law: str,
    stamp: Time,
    force: NDArray[np.float64],
    sliding_surface: NDArray[np.float64],
    gradient: NDArray[np.float64],
    filter_state: NDArray[np.float64],
    saturated: bool,
    stale: bool = False,
    rejected_inputs: int = 0,
    instance: int = 0,
    run: int = 0,
    out: ForceCommand | None = None,
) -> ForceCommand:
    """``apf_swarm_msgs/ForceCommand`` from one tracker's controller output (vectors (3,));
    ``out``: a previous message to update in place."""
    msg = out if out is not None else ForceCommand()
    msg.header.stamp = stamp
    msg.header.frame_id = WORLD
    msg.uav_id = int(uav_id)
    msg.step = int(step)
    msg.law = LAW_CODES[law]
    _set_vec(msg.force, force)
    _set_vec(msg.sliding_surface, sliding_surface)
    _set_vec(msg.gradient, gradient)
    _set_vec(msg.filter_state, filter_state)
    msg.saturated = bool(saturated)
    msg.stale = bool(stale)
    msg.rejected_inputs = int(rejected_inputs)
    msg.instance = int(instance)
    msg.run = int(run)
    return msg


def reply_msg(
    r: Reply,
    *,
    stamp: Time,
    uav_id: int,
    law: str,
    rejected_inputs: int,
    instance: int,
    run: int,
    out: ForceCommand | None = None,
) -> ForceCommand:
    """The ForceCommand of a tracker's :class:`~apf_swarm_core.tracker_modes.Reply`: its
    command's row, or the safe brake flagged ``stale`` with zero surface, gradient and
    filter; ``out`` (commands only) a previous message to update in place."""
    o = r.output
    surface, gradient, filter_state = (
        (r.force * 0.0,) * 3
        if o is None
        else (o.sliding_surface[0], o.gradient[0], o.filter_state[0])
    )
    return force_msg(
        out=out if o is not None else None,
        uav_id=uav_id,
        step=r.step,
        law=law,
        stamp=stamp,
        force=r.force,
        sliding_surface=surface,
        gradient=gradient,
        filter_state=filter_state,
        saturated=o is not None and bool(o.saturated[0]),
        stale=o is None,
        rejected_inputs=rejected_inputs,
        instance=instance,
        run=run,
    )


def force_arrays(msg: ForceCommand) -> Command:
    """Numbers of a ``ForceCommand`` (the core's :class:`~apf_swarm_core.plant_model.Command`)."""
    return Command(
        int(msg.uav_id),
        int(msg.step),
        _vec(msg.force),
        _vec(msg.sliding_surface),
        bool(msg.stale),
        int(msg.rejected_inputs),
        stamp_ns(msg.header.stamp),
        int(msg.instance),
        int(msg.run),
    )


# --- setpoints for a flight-stack bridge (angular parts zero; docs/ROS.md, "Real vehicles") ----
def accel_msg(stamp: Time, a: NDArray[np.float64]) -> AccelStamped:
    """``AccelStamped`` of the acceleration setpoint ``a`` (3,) [m/s^2]."""
    m = AccelStamped()
    m.header.stamp = stamp
    m.header.frame_id = WORLD
    _set_vec(m.accel.linear, a)
    return m


def twist_msg(stamp: Time, v: NDArray[np.float64]) -> TwistStamped:
    """``TwistStamped`` of the velocity setpoint ``v`` (3,) [m/s]."""
    m = TwistStamped()
    m.header.stamp = stamp
    m.header.frame_id = WORLD
    _set_vec(m.twist.linear, v)
    return m


# --- the swarm's state ------------------------------------------------------------------------
def swarm_state_msg(
    *,
    step: int,
    sim_time: float,
    stamp: Time,
    uav_ids: Sequence[int],
    x: NDArray[np.float64],
    v: NDArray[np.float64],
    u: NDArray[np.float64],
    s: NDArray[np.float64],
    target_x: NDArray[np.float64],
    target_v: NDArray[np.float64],
    potential: float,
    centroid_error: float,
    formation_error: float,
    missed_deadlines: int,
    stale_inputs: int,
    rejected_inputs: int,
    active: Sequence[bool] | NDArray[np.bool_] | None = None,
    target_age: float = 0.0,
    command_latency: Sequence[float] | None = None,
    out: SwarmState | None = None,
) -> SwarmState:
    """``apf_swarm_msgs/SwarmState`` from arrays of shape (n, 3) and (3,).

    ``out``: a message made by this function before for the same trackers, updated in place
    (its Point / Vector3 objects are reused).
    """
    msg = out
    if msg is None or len(msg.positions) != len(x) or len(msg.forces) != len(u):
        msg = SwarmState()
        msg.header.frame_id = WORLD
        msg.uav_ids = [int(i) for i in uav_ids]
        msg.positions = [Point() for _ in x]
        msg.velocities = [Vector3() for _ in v]
        msg.forces = [Vector3() for _ in u]
        msg.sliding_surfaces = [Vector3() for _ in s]
    msg.header.stamp = stamp
    msg.step = int(step)
    msg.sim_time = float(sim_time)
    for objs, arr in (
        (msg.positions, x),
        (msg.velocities, v),
        (msg.forces, u),
        (msg.sliding_surfaces, s),
    ):
        for o, row in zip(objs, np.asarray(arr, dtype=float).tolist(), strict=False):
            o.x, o.y, o.z = row
    _set_vec(msg.target_position, target_x)
    _set_vec(msg.target_velocity, target_v)
    msg.potential = float(potential)
    msg.centroid_error = float(centroid_error)
    msg.formation_error = float(formation_error)
    msg.missed_deadlines = int(missed_deadlines)
    msg.stale_inputs = int(stale_inputs)
    msg.rejected_inputs = int(rejected_inputs)
    msg.active = _active_flags(active, len(x))
    msg.target_age = float(target_age)
    msg.command_latency = (
        [0.0] * len(x) if command_latency is None else [float(a) for a in command_latency]
    )
    return msg


@dataclass(frozen=True)
class SwarmSample:
    """One SwarmState as arrays: x, v, u, s of shape (n, 3); target_x, target_v of shape (3,)."""

    step: int
    t: float
    uav_ids: tuple[int, ...]
    x: NDArray[np.float64]
    v: NDArray[np.float64]
    u: NDArray[np.float64]
    s: NDArray[np.float64]
    target_x: NDArray[np.float64]
    target_v: NDArray[np.float64]
    potential: float
    centroid_error: float
    formation_error: float
    missed_deadlines: int
    stale_inputs: int
    rejected_inputs: int
    active: tuple[bool, ...] = ()
    target_age: float = 0.0
    command_latency: tuple[float, ...] = ()


def swarm_state_arrays(msg: SwarmState) -> SwarmSample:
    """Arrays of a ``SwarmState`` message (works for rclpy and rosbags-deserialized objects)."""
    return SwarmSample(
        int(msg.step),
        float(msg.sim_time),
        tuple(int(i) for i in msg.uav_ids),
        _rows(msg.positions),
        _rows(msg.velocities),
        _rows(msg.forces),
        _rows(msg.sliding_surfaces),
        _vec(msg.target_position),
        _vec(msg.target_velocity),
        float(msg.potential),
        float(msg.centroid_error),
        float(msg.formation_error),
        int(msg.missed_deadlines),
        int(msg.stale_inputs),
        int(msg.rejected_inputs),
        tuple(bool(a) for a in getattr(msg, 'active', ())),  # absent in older bags
        float(getattr(msg, 'target_age', 0.0)),
        tuple(float(a) for a in getattr(msg, 'command_latency', ())),
    )


def swarm_state_step(raw: bytes) -> int:
    """The ``step`` field of a serialized ``SwarmState`` without deserializing it.

    CDR (XCDR1): a 4-byte encapsulation header (byte 1: 1 little endian, 0 big endian), then
    ``header.stamp`` (int32, uint32), ``header.frame_id`` (uint32 length with the NUL, then
    the bytes), then ``step`` (uint64) aligned to 8 relative to the end of the encapsulation.
    Raises ValueError for bytes that are too short to hold it.
    """
    if len(raw) < 16:
        raise ValueError(f'{len(raw)} bytes cannot hold a SwarmState')
    order = '<' if raw[1] & 1 else '>'
    (length,) = struct.unpack_from(order + 'I', raw, 4 + 8)
    off = (12 + length + 7) & ~7
    if 4 + off + 8 > len(raw):
        raise ValueError(f'{len(raw)} bytes end before the step field of a SwarmState')
    return struct.unpack_from(order + 'Q', raw, 4 + off)[0]


# --- markers (visualization_msgs is imported on the first call: most processes build none) ----
def markers_msg(
    x: NDArray[np.float64], target_x: NDArray[np.float64], stamp: Time, uav_ids: Sequence[int]
) -> MarkerArray:
    """``visualization_msgs/MarkerArray`` for RViz / Foxglove: a sphere per tracker (blue),
    the target (red) and the formation outline (a closed line through the trackers)."""
    from visualization_msgs.msg import Marker, MarkerArray

    def marker(mid: int, kind: int, rgb: tuple[float, float, float], scale: float) -> Marker:
        m = Marker()
        m.header.stamp = stamp
        m.header.frame_id = WORLD
        m.ns = 'apf_swarm'
        m.id = mid
        m.type = kind
        m.action = Marker.ADD
        m.pose.orientation.w = 1.0
        m.scale.x = m.scale.y = m.scale.z = scale
        m.color.r, m.color.g, m.color.b = rgb
        m.color.a = 1.0
        return m

    out = MarkerArray()
    for uid, p in zip(uav_ids, x, strict=False):
        m = marker(int(uid), Marker.SPHERE, (0.2, 0.4, 1.0), 0.3)
        _set_vec(m.pose.position, p)
        out.markers.append(m)
    t = marker(0, Marker.SPHERE, (1.0, 0.2, 0.2), 0.4)
    _set_vec(t.pose.position, target_x)
    out.markers.append(t)
    if len(x) > 1:
        line = marker(10_000, Marker.LINE_STRIP, (0.6, 0.6, 0.6), 0.05)
        line.points = [_set_vec(Point(), p) for p in [*list(x), x[0]]]
        out.markers.append(line)
    return out
