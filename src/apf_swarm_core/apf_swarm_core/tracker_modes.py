"""How a tracker answers its inputs in each timing mode, without ROS: one call per input
decides everything (accept or refuse, stale or not, brake or command) and returns a
:class:`Reply` the node only converts and publishes. :class:`LockstepTracker` (simulated
time) and :class:`RealtimeTracker` (wall-clock time) share one
:class:`~apf_swarm_core.agents.TrackerAgent`; :func:`tracker_mode` picks one for a mode.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from .agents import TrackerAgent
from .controller import ControlOutput

__all__ = ['LockstepTracker', 'RealtimeTracker', 'Reply', 'SwarmOdom', 'tracker_mode']


@dataclass(frozen=True)
class SwarmOdom:
    """One ``/swarm/odom`` message as arrays: its step (lockstep) and stamp [ns], every
    tracker's id, x and v (n, 3) and whether it is active, the target's x and v (3,) and its
    age at the plant [s], the command latencies the plant measured [s] (none or one per id)
    and the run's identity."""

    step: int
    stamp_ns: int
    uav_ids: list[int]
    x: NDArray[np.float64]
    v: NDArray[np.float64]
    target_x: NDArray[np.float64]
    target_v: NDArray[np.float64]
    active: list[bool]
    target_age: float
    command_latency: NDArray[np.float64]
    run: int = 0


@dataclass
class Reply:
    """What the tracker sends for an input: a command (``output``) or the safe brake
    (``brake``, with the ``stale`` inputs), for ``step``; ``report_stale`` on the first brake
    after commands, ``neighbours`` ``(before, now)`` when the active neighbours changed."""

    step: int
    output: ControlOutput | None = None
    brake: NDArray[np.float64] | None = None
    stale: list[int] = field(default_factory=list)
    report_stale: bool = False
    neighbours: tuple[int, int] | None = None

    @property
    def force(self) -> NDArray[np.float64]:
        """The force sent [N], shape (3,)."""
        if self.output is not None:
            return self.output.force[0]
        assert self.brake is not None
        return self.brake


class _TrackerMode:
    """What both modes share: the agent, the input timeout [s], the stale report."""

    #: the unit of the input timeout, as a warning says it
    TIME_UNIT = 's'

    def __init__(self, agent: TrackerAgent, timeout: float) -> None:
        self.agent, self.timeout = agent, float(timeout)
        self._stale_reported = False
        self._neighbours = -1
        #: why the last input was refused (None: accepted)
        self.refused: str | None = None

    def _took(self, ok: bool) -> bool:
        """Whether the agent took an input; else why not in :attr:`refused`."""
        self.refused = None if ok else self.agent.last_rejection
        return ok

    def _offer_swarm(self, m: SwarmOdom, step: int, now: float, seq: int) -> bool:
        """Offer ``m``, produced at ``now``, to the agent with its command latencies."""
        ok = self.agent.offer_swarm(
            step, m.uav_ids, m.x, m.v, m.active, m.target_x, m.target_v, now,
            now - m.target_age, seq=seq, run=m.run,
        )  # fmt: skip
        if self._took(ok) and m.command_latency.size:
            self.agent.report_latency(m.command_latency)
        return ok

    def _brake(self, step: int, stale: list[int], force: NDArray[np.float64]) -> Reply:
        self.agent.stale += 1
        first, self._stale_reported = not self._stale_reported, True
        return Reply(step, brake=force, stale=stale, report_stale=first)

    def _command(self, step: int) -> Reply:
        out = self.agent.command(step)
        self._stale_reported = False
        now, before = self.agent.active_neighbours, self._neighbours
        self._neighbours = now
        changed = (before, now) if before >= 0 and now != before else None
        return Reply(step, output=out, neighbours=changed)


class LockstepTracker(_TrackerMode):
    """Simulated time: an input's stamp is its step's time (``dt_ns``: the step [ns]); step
    k is answered once all its inputs are in, with the brake when one is older than the
    timeout in simulated time."""

    TIME_UNIT = 's of simulated time'

    def __init__(self, agent: TrackerAgent, timeout: float, dt_ns: int) -> None:
        super().__init__(agent, timeout)
        self.dt_ns = int(dt_ns)

    def on_swarm(self, m: SwarmOdom, ros_now_ns: int = 0, mono: float = 0.0) -> Reply | None:
        """A ``/swarm/odom`` of step ``m.step``: its command, its brake, or None (refused, see
        :attr:`refused`, or not complete yet)."""
        now = m.stamp_ns * 1e-9
        return self._answer(m.step, now) if self._offer_swarm(m, m.step, now, m.step) else None

    def on_odom(
        self, source: int, stamp_ns: int, x: NDArray[np.float64], v: NDArray[np.float64],
        ros_now_ns: int = 0, mono: float = 0.0,
    ) -> Reply | None:  # fmt: skip
        """One odometry (``source`` 0: the target): as :meth:`on_swarm`."""
        step, now = stamp_ns // self.dt_ns, stamp_ns * 1e-9
        ok = self._took(self.agent.offer(source, step, x, v, now, seq=step))
        return self._answer(step, now) if ok else None

    def on_timer(self, ros_now_ns: int, mono: float) -> Reply | None:
        """Lockstep runs no timer: nothing."""
        return None

    def _answer(self, step: int, now: float) -> Reply | None:
        if not self.agent.ready(step):
            return None
        stale = self.agent.stale_sources(now, self.timeout)
        if stale:  # the barrier still needs a command for this step
            return self._brake(step, stale, self.agent.brake(step))
        return self._command(step)


class RealtimeTracker(_TrackerMode):
    """Wall-clock time: an input's age is the ROS clock's now minus its stamp; command on
    each own state (``on_odom``, trigger odom) or at the control rate (trigger timer); a
    stale input gets the brake."""

    def __init__(
        self, agent: TrackerAgent, timeout: float, control_rate: float, on_odom: bool
    ) -> None:
        super().__init__(agent, timeout)
        self.period = 1.0 / float(control_rate)
        self.on_own_odom = bool(on_odom)
        self._tick = 0
        self._last_command = 0.0

    def _arrival(self, stamp_ns: int, ros_now_ns: int, mono: float) -> float:
        """When an input was produced, on the monotonic clock ``mono`` [s]."""
        return mono - max(0.0, (ros_now_ns - stamp_ns) * 1e-9)

    def on_swarm(self, m: SwarmOdom, ros_now_ns: int, mono: float) -> Reply | None:
        """A ``/swarm/odom``: held; with the odom trigger, answered at once."""
        t = self._arrival(m.stamp_ns, ros_now_ns, mono)
        if self._offer_swarm(m, -1, t, m.stamp_ns) and self.on_own_odom:
            return self.command_now(mono)
        return None

    def on_odom(
        self, source: int, stamp_ns: int, x: NDArray[np.float64], v: NDArray[np.float64],
        ros_now_ns: int, mono: float,
    ) -> Reply | None:  # fmt: skip
        """One odometry: held; the own one answered at once with the odom trigger."""
        t = self._arrival(stamp_ns, ros_now_ns, mono)
        ok = self._took(self.agent.offer(source, -1, x, v, t, seq=stamp_ns))
        if ok and self.on_own_odom and source == self.agent.uav_id:
            return self.command_now(mono)
        return None

    def on_timer(self, ros_now_ns: int, mono: float) -> Reply | None:
        """The node's timer: the command (trigger timer), or the watchdog's brake while an
        input is stale (trigger odom)."""
        if not self.on_own_odom or self.agent.stale_sources(mono, self.timeout):
            return self.command_now(mono)
        return None

    def command_now(self, mono: float) -> Reply:
        """The command on the latest inputs, or the brake when one is stale."""
        self._tick += 1
        self.agent.controller.sample_elapsed(
            mono - self._last_command if self._last_command else None, self.period
        )
        self._last_command = mono
        stale = self.agent.stale_sources(mono, self.timeout)
        if stale:
            return self._brake(self._tick, stale, self.agent.safe_command())
        return self._command(self._tick)


def tracker_mode(
    mode: str,
    agent: TrackerAgent,
    timeout: float,
    *,
    dt_ns: int,
    control_rate: float,
    on_odom: bool,
) -> LockstepTracker | RealtimeTracker:
    """The tracker of a timing mode (``lockstep`` or ``realtime``)."""
    if mode == 'lockstep':
        return LockstepTracker(agent, timeout, dt_ns)
    return RealtimeTracker(agent, timeout, control_rate, on_odom)
