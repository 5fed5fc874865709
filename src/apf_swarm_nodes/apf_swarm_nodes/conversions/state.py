"""The swarm's state as arrays and back: ``apf_swarm_msgs/SwarmState`` (``/swarm/state``,
what is recorded and summed) from the plant's sample, its arrays (:class:`SwarmSample`), and
its step read from the serialized bytes."""

from __future__ import annotations

import struct
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from builtin_interfaces.msg import Time
from geometry_msgs.msg import Point, Vector3
from numpy.typing import NDArray

from apf_swarm_msgs.msg import SwarmState

from .fields import WORLD, active_flags, rows, set_vec, vec

__all__ = ['SwarmSample', 'swarm_state_arrays', 'swarm_state_msg', 'swarm_state_step']


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
    set_vec(msg.target_position, target_x)
    set_vec(msg.target_velocity, target_v)
    msg.potential = float(potential)
    msg.centroid_error = float(centroid_error)
    msg.formation_error = float(formation_error)
    msg.missed_deadlines = int(missed_deadlines)
    msg.stale_inputs = int(stale_inputs)
    msg.rejected_inputs = int(rejected_inputs)
    msg.active = active_flags(active, len(x))
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
        rows(msg.positions),
        rows(msg.velocities),
        rows(msg.forces),
        rows(msg.sliding_surfaces),
        vec(msg.target_position),
        vec(msg.target_velocity),
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
