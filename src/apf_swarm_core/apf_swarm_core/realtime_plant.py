"""The realtime plant without ROS (:class:`RealtimePlant`): its physics clock, the target state
it holds, and the inputs it refuses for their age or order (docs/ROS.md, "Timing modes").
Times are the node's monotonic clock [s]; what to log comes back as lockstep's
:class:`~apf_swarm_core.lockstep.Action` (``info``, ``warn``, ``refuse``)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from .inputs import Sample
from .lockstep import Action, refusal, take_command, target_problem
from .plant_model import Command, PlantModel

__all__ = ['RealtimePlant']


@dataclass
class RealtimePlant:
    """The realtime clock and target of a :class:`~apf_swarm_core.plant_model.PlantModel`;
    ``timeout`` is the node's ``command_timeout`` [s]."""

    model: PlantModel
    timeout: float
    stale_after: float
    arm_timeout: float
    target: Sample | None = None  # the latest target state
    target_seq: int = -1  # its stamp [ns]
    clock_started: bool = False
    wall0: float = 0.0  # when the clock started
    arm_deadline: float = 0.0
    done: bool = False
    final_published: bool = False  # the state at the end of the run went out
    running: bool = False  # started (the clock may still wait: :meth:`arm`)
    #: the run starts at once; :meth:`arm` waits for the trackers
    needs_match: ClassVar[bool] = False
    #: /swarm/odom carries the latencies of the trackers' latest commands
    reports_latency: ClassVar[bool] = True

    def start(self, now: float) -> list[Action]:
        """The run starts at ``now``: the clock waits at most ``arm_timeout`` from here."""
        self.running = True
        self.arm_deadline = now + self.arm_timeout
        return self.arm(now)

    def arm(self, now: float) -> list[Action]:
        """Start the clock at ``now`` once every tracker has commanded from its inputs (both
        directions of its loop work), or at the deadline (:attr:`clock_started`). Until then
        no tracker is judged late for the time its first messages take to match."""
        if self.clock_started:
            return []
        waiting = self.model.clock_start(now, self.arm_deadline)
        if waiting is None:
            return []
        self.clock_started, self.wall0 = True, now
        if waiting:
            text = f'clock started after arm_timeout = {self.arm_timeout:g} s without a command '
            return [Action('warn', text=text + f'from {[f"uav_{i}" for i in waiting]}')]
        return [Action('info', text='clock started: every tracker commands')]

    def stale_command(self, uav_id: int, age: float) -> str | None:
        """Why a command of ``uav_id`` stamped ``age`` seconds ago is refused, or None."""
        if age > self.timeout:
            return (
                f'command of uav_{uav_id} is stale: stamped {age:.3f} s ago '
                f'(command_timeout {self.timeout:g} s)'
            )
        return None

    def command_arrives(self, now: float) -> bool:
        """A command arrives at ``now``: the held commands act up to this instant, the new
        one from here on (the physics integrated to ``now``); True when the clock runs, so
        that the command's latency counts."""
        if not self.clock_started or self.done:
            return False
        self.model.advance_to(now - self.wall0)
        return True

    def take_command(self, c: Command, age: float, now: float) -> tuple[bool, list[Action]]:
        """A tracker's command stamped ``age`` seconds ago arrived at ``now``: refused if
        stale, else offered to the model with its latency (once the clock runs)."""
        refused = refusal(self.model, self.stale_command(c.uav_id, age))
        if refused:
            return False, refused
        latency = age if self.command_arrives(now) else 0.0
        return take_command(self.model, self.running, c, latency=latency, now=now)

    def take_target(
        self, x: NDArray[np.float64], v: NDArray[np.float64], stamp_ns: int, age: float, now: float
    ) -> list[Action]:
        """A target state stamped ``stamp_ns``, ``age`` seconds ago: held, or refused."""
        return target_problem(self.model, x, v) or refusal(
            self.model, self.offer_target(x, v, stamp_ns, age, now)
        )

    def offer_target(
        self, x: NDArray[np.float64], v: NDArray[np.float64], seq: int, age: float, now: float
    ) -> str | None:
        """Hold the target state (x, v) stamped ``seq`` [ns], ``age`` seconds ago; why it is
        refused (stale, out of order), or None."""
        if age > self.timeout:
            return f'target state is stale: stamped {age:.3f} s ago'
        if seq < self.target_seq:
            return f'target state out of order (stamp {seq} ns after {self.target_seq})'
        self.target_seq = seq
        self.target = Sample(-1, x, v, now)
        return None

    def target_age(self, now: float) -> float:
        """Age of the held target state at ``now`` [s of wall time]."""
        assert self.target is not None
        return max(0.0, now - self.target.received)

    def physics(self, now: float) -> list[Action]:
        """The physics step at ``now`` (clock started): zero or deactivate the late trackers,
        integrate to ``now``, and be :attr:`done` after the configuration's steps."""
        out = []
        newly = self.model.expire(now, self.stale_after, self.timeout)
        if newly:
            self.model.missed += len(newly)
            text = (
                f'no command from {[f"uav_{i}" for i in newly]} for {self.timeout:g} s: '
                f'inactive, left out of the neighbour sets (zero force since '
                f'{self.stale_after:g} s; {self.model.missed} missed so far)'
            )
            out.append(Action('warn', text=text))
        self.model.advance_to(now - self.wall0)
        cfg = self.model.cfg
        if self.model.k >= cfg.steps:
            self.done = True
            text = (
                f'done: {cfg.steps} steps of {cfg.dt:g} s; {self.model.zeroed} held commands '
                f'zeroed (tracker later than stale_after = {self.stale_after:g} s)'
            )
            out.append(Action('info', text=text))
        return out

    def state_sample(self, now: float) -> dict[str, Any]:
        """The ``/swarm/state`` sample of the current step, going out at ``now`` (the
        trackers answer it: :meth:`PlantModel.published`); once :attr:`done`, the last."""
        assert self.target is not None
        self.final_published = self.done
        self.model.published(now)
        return self.model.snapshot(self.model.k, self.target, self.target_age(now))
