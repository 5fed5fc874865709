"""Force commands as arrays and back: ``apf_swarm_msgs/ForceCommand`` from one tracker's
controller output or reply, and its numbers (:class:`ForceArrays`) at the plant."""

from __future__ import annotations

from typing import Any

import numpy as np
from apf_swarm_core.plant_model import Command
from apf_swarm_core.tracker_modes import Reply
from builtin_interfaces.msg import Time
from numpy.typing import NDArray

from apf_swarm_msgs.msg import ForceCommand

from .fields import WORLD, set_vec, vec
from .stamps import stamp_ns

__all__ = ['LAW_CODES', 'force_arrays', 'force_msg', 'reply_msg']

LAW_CODES = {'proposed': ForceCommand.LAW_PROPOSED, 'traditional': ForceCommand.LAW_TRADITIONAL}


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
    set_vec(msg.force, force)
    set_vec(msg.sliding_surface, sliding_surface)
    set_vec(msg.gradient, gradient)
    set_vec(msg.filter_state, filter_state)
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
    common: dict[str, Any] = {
        'uav_id': uav_id,
        'step': r.step,
        'law': law,
        'stamp': stamp,
        'rejected_inputs': rejected_inputs,
        'instance': instance,
        'run': run,
    }
    if r.output is None:
        zero = r.force * 0.0
        return force_msg(
            force=r.force,
            sliding_surface=zero,
            gradient=zero,
            filter_state=zero,
            saturated=False,
            stale=True,
            **common,
        )
    o = r.output
    return force_msg(
        out=out,
        force=o.force[0],
        sliding_surface=o.sliding_surface[0],
        gradient=o.gradient[0],
        filter_state=o.filter_state[0],
        saturated=bool(o.saturated[0]),
        **common,
    )


def force_arrays(msg: ForceCommand) -> Command:
    """Numbers of a ``ForceCommand`` (the core's :class:`~apf_swarm_core.plant_model.Command`)."""
    return Command(
        int(msg.uav_id),
        int(msg.step),
        vec(msg.force),
        vec(msg.sliding_surface),
        bool(msg.stale),
        int(msg.rejected_inputs),
        stamp_ns(msg.header.stamp),
        int(msg.instance),
        int(msg.run),
    )
