"""The plant's lockstep barrier without ROS (:class:`LockstepBarrier`): the protocol that
makes the ROS graph step exactly as the simulator does (docs/ROS.md, "Timing modes"). It takes
the events (start, a target state, a command, a clock tick) and returns the :class:`Action`
list the node carries out in order."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, ClassVar, Literal

import numpy as np
from numpy.typing import NDArray

from .inputs import Sample, input_problem
from .plant_model import Command, PlantModel

__all__ = [
    'LOOKAHEAD',
    'Action',
    'LockstepBarrier',
    'refusal',
    'take_command',
    'target_problem',
    'target_window',
]

#: how many steps ahead the plant asks for the target's states
LOOKAHEAD = 64

Kind = Literal['request', 'swarm_odom', 'step', 'state', 'info', 'warn', 'refuse']


@dataclass(frozen=True)
class Action:
    """What the node does next: ``request`` the target's states up to ``step``; publish
    ``swarm_odom`` of ``step`` (with :attr:`LockstepBarrier.target`), ``step`` (``/clock``
    and the odometry of the model's state) or the ``state`` sample ``data`` of ``step``; log
    ``text`` at ``info`` or ``warn``; ``refuse``: ``text`` says why an input was refused."""

    kind: Kind
    step: int = -1
    data: Any = None
    text: str = ''


def take_command(
    model: PlantModel, running: bool, c: Command, *, latency: float, now: float
) -> tuple[bool, list[Action]]:
    """Offer a tracker's command to ``model`` (both modes): whether it was accepted, and the
    actions: why it was refused, or that its tracker, inactive, commands again."""
    was_active = bool(model.active[c.uav_id - 1])
    if not model.offer_command(
        c.uav_id, c.step, c.force, c.sliding_surface, c.stale,
        now=now, instance=c.instance, latency=latency, run=c.run,
    ):  # fmt: skip
        return False, [Action('refuse', text=model.last_rejection)]
    if was_active or not running:
        return True, []
    text = f'uav_{c.uav_id} commands again: active, back in the neighbour sets'
    return True, [Action('info', text=text)]


def refusal(model: PlantModel, why: str | None) -> list[Action]:
    """An input refused for ``why``, counted in ``model``, as an action ([] for None)."""
    if why is None:
        return []
    model.refuse(why)
    return [Action('refuse', text=why)]


def target_problem(
    model: PlantModel, x: NDArray[np.float64], v: NDArray[np.float64]
) -> list[Action]:
    """A target state the plant cannot use (not finite, out of range): refused and counted
    in ``model``; [] when it is usable."""
    problem = input_problem(x=x, v=v)
    return refusal(model, None if problem is None else f'target state: {problem}')


@dataclass
class LockstepBarrier:
    """The lockstep plant around a :class:`~apf_swarm_core.plant_model.PlantModel`: the
    target's states asked for ahead, step k published once its target state is held, step
    k + 1 once every active tracker's command of step k is in; past ``timeout`` step k again,
    past another a missing tracker inactive or the target's last state held. Times are on
    the caller's monotonic clock [s]."""

    model: PlantModel
    timeout: float
    running: bool = False
    done: bool = False
    target_absent: bool = False  # the target missed a deadline; its last state is held
    requested: int = -1  # the last step whose target state was asked for
    step_started: float = 0.0
    republished: bool = False
    odom_sent: bool = False
    target: Sample = field(init=False)
    targets: dict[int, Sample] = field(default_factory=dict)  # by step, k..requested
    #: step 0 goes out only once every reader of it is matched, or it would be lost
    needs_match: ClassVar[bool] = True
    #: /swarm/odom carries no command latencies (simulated time)
    reports_latency: ClassVar[bool] = False

    def __post_init__(self) -> None:
        self.target = Sample(-1, np.zeros(3), np.zeros(3), 0.0)
        self.steps = self.model.cfg.steps
        self.dt_ns = int(round(self.model.cfg.dt * 1e9))

    # --- events ----------------------------------------------------------------------
    def start(self, now: float) -> list[Action]:
        """Every reader of step 0 is matched: publish step 0."""
        self.running = True
        return self._publish_step(now)

    def on_target(
        self, step: int, x: NDArray[np.float64], v: NDArray[np.float64], now: float
    ) -> list[Action]:
        """The target's state of ``step`` arrived (a step already integrated, or one never
        asked for, is not kept)."""
        k = self.model.k
        if not k <= step <= max(self.requested, k):
            return []
        self.targets[step] = Sample(step, x, v, now)
        out: list[Action] = []
        if self.target.step != k and k in self.targets:
            out += self._take_target()
        out += self._maybe_swarm_odom()
        out += self._maybe_finish(now)
        return out

    def take_command(self, c: Command, age: float, now: float) -> tuple[bool, list[Action]]:
        """A tracker's command (``age`` unused): offered to the model, then the step
        finished if it was the last one missing."""
        ok, out = take_command(self.model, self.running, c, latency=0.0, now=now)
        return ok, (out + self.on_command(now)) if ok else out

    def take_target(
        self, x: NDArray[np.float64], v: NDArray[np.float64], stamp_ns: int, age: float, now: float
    ) -> list[Action]:
        """A target state stamped with its step's time (``age``: unused)."""
        return target_problem(self.model, x, v) or self.on_target(
            stamp_ns // self.dt_ns, x, v, now
        )

    def on_command(self, now: float) -> list[Action]:
        """The model accepted a command (:meth:`PlantModel.offer_command`)."""
        return self._maybe_finish(now)

    def tick(self, now: float) -> list[Action]:
        """A clock tick: past ``timeout`` publish step k once more, past another miss its
        late inputs and go on."""
        if not self.running or self.done or now - self.step_started <= self.timeout:
            return []
        if self.republished:
            return self._maybe_finish(now, force=True)
        self.republished = True
        text = f'step {self.model.k}: inputs {self.late()} late after {self.timeout:g} s; '
        return [
            Action('warn', text=text + 'publishing the step again'),
            *self._publish_step(now, True),
        ]

    # --- what the node reads --------------------------------------------------------------
    def late(self) -> list[str]:
        """The inputs step k waits for: ``uav_<i>`` and ``target``."""
        return [f'uav_{i}' for i in self.model.missing(self.model.k)] + (
            ['target'] if self._target_late() else []
        )

    def target_age(self, now: float | None = None) -> float:
        """Age of the held target state [s of simulated time; ``now``, wall time, unused]."""
        return max(0, self.model.k - self.target.step) * self.model.cfg.dt

    # --- the protocol ----------------------------------------------------------------
    def _publish_step(self, now: float, again: bool = False) -> list[Action]:
        if not again:
            self.republished = False
        self.step_started = now
        self.odom_sent = False
        # what the trackers wait for goes out first
        out = self._maybe_swarm_odom()
        out += self._request(again)
        out.append(Action('step', self.model.k))
        return out

    def _request(self, again: bool) -> list[Action]:
        """Ask for the target's states up to :data:`LOOKAHEAD` - 1 steps ahead once fewer than
        half of that are asked for. ``again`` (step k is late): repeat the last request,
        which the target answers by sending that window once more (step k is in it)."""
        k = self.model.k
        want = min(k + LOOKAHEAD - 1, self.steps)
        if again and self.requested >= k:
            want = self.requested
        elif want <= self.requested or self.requested - k >= LOOKAHEAD // 2:
            return []
        self.requested = want
        return [Action('request', want)]

    def _maybe_swarm_odom(self) -> list[Action]:
        """``/swarm/odom`` of step k once the target state of step k is held."""
        k = self.model.k
        if (
            self.running
            and not self.done
            and not self.odom_sent
            and (self.target.step == k or self.target_absent)
        ):
            self.odom_sent = True
            return [Action('swarm_odom', k)]
        return []

    def _take_target(self) -> list[Action]:
        self.target = self.targets.pop(self.model.k)
        if self.target_absent:
            self.target_absent = False
            return [Action('info', text=f'step {self.model.k}: the target publishes again')]
        return []

    def _target_late(self) -> bool:
        return self.target.step != self.model.k and not self.target_absent

    def _maybe_finish(self, now: float, force: bool = False) -> list[Action]:
        if not self.running or self.done:
            return []
        m, k = self.model, self.model.k
        missing, target_late = m.missing(k), self._target_late()
        if (missing or target_late) and not force:
            return []
        if target_late:
            # /swarm/odom of step k waits for the target, so no tracker has seen step k yet:
            # only the target missed it. Hold its last state and let the trackers answer.
            m.missed += 1
            self.target_absent = True
            self.step_started = now
            self.republished = False
            text = (
                f'step {k}: no target state within 2 x {self.timeout:g} s ({m.missed} missed '
                'so far); holding the last one (its age grows in /swarm/odom) and not waiting '
                'for the target any more'
            )
            return [Action('warn', text=text), *self._maybe_swarm_odom()]
        out: list[Action] = []
        if missing:
            m.missed += len(missing)
            m.deactivate(missing)
            text = (
                f'step {k}: no command from {[f"uav_{i}" for i in missing]} within 2 x '
                f'{self.timeout:g} s ({m.missed} missed so far): zero force, left out of the '
                'neighbour sets, not waited for until they command again'
            )
            out.append(Action('warn', text=text))
        # the state of step k goes out after step k + 1: the trackers, which wait for
        # /swarm/odom of k + 1, start while the node computes the metrics of k
        state = Action('state', k, m.snapshot(k, self.target, self.target_age()))
        m.advance()
        if m.k in self.targets:
            out += self._take_target()
        for old in [j for j in self.targets if j < m.k]:
            del self.targets[old]
        if m.k >= self.steps:
            self.done = True
            # logged before the last state goes out: whoever waits for that state may stop
            # the node right after it
            out += [Action('info', text=f'done: {self.steps} steps, {m.missed} missed'), state]
            return out
        out += self._publish_step(now)
        out.append(state)
        return out


def target_window(last: int, next_step: int, lookahead: int = LOOKAHEAD) -> range:
    """The target's answer to a request for its states up to step ``last``, having published
    every step before ``next_step``: the steps not yet published, at most the last
    ``lookahead`` (``last - lookahead + 1 .. last``); a request for states already published
    (the plant repeating itself because a step is late) gets that window again."""
    first = max(0, last + 1 - lookahead)
    if last >= next_step:
        first = max(first, next_step)
    return range(first, last + 1)
