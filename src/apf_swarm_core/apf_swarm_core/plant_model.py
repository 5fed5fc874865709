"""The plant node's model without ROS (:class:`PlantModel`): every tracker's dynamics
(eq. 19-21) as the simulator integrates them, the commands it holds and refuses, who is
active, and the ``/swarm/state`` sample of a step."""

from __future__ import annotations

import bisect
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .agents import PLANT_FORMATION_METRIC_MAX, Sample
from .config import SwarmConfig
from .formation import expected_pairs
from .inputs import input_problem
from .kernels import warm
from .metrics import centroid_error, formation_error
from .plant import DisturbanceSource, plant_step
from .potential import potential
from .simulator import initial_positions

__all__ = ['Command', 'PlantModel']


@dataclass(frozen=True)
class Command:
    """One tracker's command as the plant receives it: its ``uav_id`` and ``step``, force and
    sliding surface (3,), whether it is the safe brake (``stale``), the tracker's count of
    refused inputs, its stamp [ns], its process (``instance``) and run identity."""

    uav_id: int
    step: int
    force: NDArray[np.float64]
    sliding_surface: NDArray[np.float64]
    stale: bool
    rejected_inputs: int = 0
    stamp_ns: int = 0
    instance: int = 0
    run: int = 0


@dataclass
class PlantModel:
    """Dynamics of all trackers (eq. 19-21), as the simulator integrates them.

    Holds x, v (n, 3), the disturbance source and the latest commands. Lockstep: collect the
    commands of step k from the active trackers (:meth:`missing`), then :meth:`advance`; a
    tracker still silent after the deadline is deactivated (:meth:`deactivate`). Realtime:
    :meth:`expire` deactivates the trackers whose latest command is older than the timeout.
    An inactive tracker's UAV gets zero force until its next command, which reactivates it.
    """

    cfg: SwarmConfig
    k: int = 0
    missed: int = 0
    stale: int = 0
    rejected: int = 0
    zeroed: int = 0  # realtime: held commands zeroed because their tracker was late
    last_rejection: str = ''
    run: int = 0  # the run's identity: commands of another run are refused (0: any)

    def __post_init__(self) -> None:
        n = self.cfg.n_trackers
        self.ids = list(range(1, n + 1))
        self.x = initial_positions(self.cfg)
        self.v = np.zeros((n, 3))
        self.mass = np.asarray(self.cfg.mass_matrix_diag(), dtype=float)
        self.noise = DisturbanceSource(self.cfg.seed, n, self.cfg.f_bar, self.cfg.noise)
        self.u = np.zeros((n, 3))
        self.s = np.zeros((n, 3))
        self.got: dict[int, int] = {}  # uav_id -> step of the latest command
        self.instances: dict[int, int] = {}  # uav_id -> the tracker process it follows
        # uav_ids whose process has sent a command from its inputs: only their stale brakes
        # count (before its first inputs a tracker brakes while the graph still matches)
        self.commanded: set[int] = set()
        self.active = np.ones(n, dtype=bool)
        self.command_time = np.zeros(n)  # realtime: when each latest command arrived
        self.latency = np.zeros(n)  # realtime: its arrival minus its state's stamp [s]
        self._asked: list[float] = []  # realtime: when the state went out, ascending
        # the formation error published every step needs the design shape; for more than
        # 12 trackers it is a numerical minimization of seconds, which would delay the
        # plant's start: /swarm/state then carries NaN (summary.json still has the metric)
        pairs = expected_pairs(self.cfg) if n <= PLANT_FORMATION_METRIC_MAX else None
        self.expected_pairs = None if pairs is None else np.asarray(pairs)
        warm()  # the compiled plant loaded now, not in the first step's deadline

    def refuse(self, why: str) -> bool:
        """Count a refused input and keep its reason in ``last_rejection``; returns False."""
        self.rejected += 1
        self.last_rejection = why
        return False

    def _foreign(self, uav_id: int, run: int) -> str | None:
        """Why a command is not this swarm's, or None: another run, or an unknown id."""
        if self.run and run != self.run:
            return f'command of uav_{uav_id} from another run ({run:x}; this run: {self.run:x})'
        if uav_id not in self.ids:
            return f'uav_id {uav_id} is not in this swarm (ids 1..{len(self.ids)})'
        return None

    def offer_command(
        self,
        uav_id: int,
        step: int,
        force: NDArray[np.float64],
        s: NDArray[np.float64],
        stale: bool = False,
        now: float = 0.0,
        instance: int = 0,
        latency: float = 0.0,
        run: int = 0,
    ) -> bool:
        """Store the command of one tracker; False (counted, ``last_rejection`` says why) if
        the id is unknown, a value is not finite or out of range, the command comes from
        another tracker process (``instance``) than the one this ``uav_id`` follows (a
        duplicate ``uav_id``), the step is older than the one held, or (lockstep) this step
        was answered already. An accepted command makes its tracker active; an inactive
        tracker follows the next instance that commands (a respawned tracker). A ``stale``
        command (the tracker's safe brake) counts in ``stale`` only once its process has
        commanded from its inputs: the brakes before its first inputs are its start-up. A
        command of another ``run`` than the plant's (:attr:`run`, when not 0) is refused."""
        foreign = self._foreign(uav_id, run)
        if foreign is not None:
            return self.refuse(foreign)
        problem = input_problem(force=force, s=s)
        if problem is not None:
            return self.refuse(f'command of uav_{uav_id}: {problem}')
        j = uav_id - 1
        followed = self.instances.get(uav_id)
        if followed is not None and instance != followed:
            if self.active[j]:
                return self.refuse(
                    f'duplicate uav_id {uav_id}: a command from a second '
                    f'tracker process (instance {instance:x}; following '
                    f'{followed:x})'
                )
            self.got.pop(uav_id, None)  # a new process starts its own sequence
        if self.instances.get(uav_id) != instance:
            self.commanded.discard(uav_id)  # a new process starts without inputs
        self.instances[uav_id] = instance
        held = self.got.get(uav_id, -1)
        if step >= 0 and step < held:
            return self.refuse(
                f'command of uav_{uav_id} for step {step} is out of order (step {held} held)'
            )
        if step >= 0 and step == held:
            return self.refuse(
                f'second command of uav_{uav_id} for step {step}: another '
                f'tracker with the same uav_id? (the first one is used)'
            )
        self.u[j], self.s[j] = force, s
        self.got[uav_id] = step
        self.active[j] = True
        self.command_time[j] = now
        self.latency[j] = latency
        if not stale:
            self.commanded.add(uav_id)
        elif uav_id in self.commanded:
            self.stale += 1
        return True

    def uncommanded(self) -> list[int]:
        """Active trackers whose process has not yet commanded from its inputs."""
        return [i for i in self.ids if self.active[i - 1] and i not in self.commanded]

    def clock_start(self, now: float, deadline: float) -> list[int] | None:
        """Realtime: whether the physics clock may start at ``now``: None while an active
        tracker has not yet commanded from its inputs and ``deadline`` has not passed (its
        first messages may still be matching; the UAVs hold still); else the trackers it
        starts without (empty when every one commands)."""
        waiting = self.uncommanded()
        return None if waiting and now < deadline else waiting

    def missing(self, step: int) -> list[int]:
        """Active trackers whose command for ``step`` has not arrived (inactive ones are not
        waited for)."""
        return [i for i in self.ids if self.active[i - 1] and self.got.get(i, -1) != step]

    def deactivate(self, ids: Sequence[int]) -> None:
        """Trackers silent past the deadline: zero force from now on, left out of the
        neighbour sets, not waited for, until their next command."""
        for i in ids:
            self.active[i - 1] = False
            self.u[i - 1] = 0.0

    def published(self, now: float) -> None:
        """Realtime: the state went out to the trackers at ``now`` (they answer it)."""
        self._asked.append(now)

    def _asked_before(self, t: float) -> float | None:
        """The latest time the state went out no later than ``t`` (None: never)."""
        k = bisect.bisect_right(self._asked, t)
        return self._asked[k - 1] if k else None

    def expire(self, now: float, zero_after: float, inactive_after: float) -> list[int]:
        """Realtime: a tracker that has not answered a state published ``zero_after`` seconds
        ago or earlier gets zero force (a held bang-bang command would fling the UAV); one
        that has not answered a state published ``inactive_after`` ago is deactivated (left
        out of the others' formation: a short hiccup does not reshape it). Measured from the
        publications (:meth:`published`), not from the clock alone, so a plant that was
        itself late in publishing does not blame the trackers. Returns the ids just
        deactivated."""
        zero_ref = self._asked_before(now - zero_after)
        if zero_ref is None:
            return []
        late = self.command_time < zero_ref
        self.zeroed += int(np.count_nonzero(late & np.any(self.u != 0.0, axis=1)))
        self.u[late] = 0.0
        ref = self._asked_before(now - inactive_after)
        # forget publications no longer needed
        keep = bisect.bisect_right(self._asked, now - inactive_after) - 1
        if keep > 0:
            del self._asked[:keep]
        if ref is None:
            return []
        old = self.command_time < ref
        newly = [i for i in self.ids if old[i - 1] and self.active[i - 1]]
        self.deactivate([i for i in self.ids if old[i - 1]])
        return newly

    def advance_to(self, elapsed: float, most: int = 1000) -> None:
        """Realtime: integrate the steps of dt that ``elapsed`` seconds of wall time since
        the start contain and that are not integrated yet (at most ``most``), with the held
        commands. Called before a new command is stored too, so that each command acts
        from its arrival on (a zero-order hold with the loop's true delay), as the
        emulation's :class:`~apf_swarm_core.command_hold.CommandHold` assumes."""
        due = int(elapsed / self.cfg.dt) - self.k
        if due > 0:
            self.advance(min(due, most))

    def advance(self, steps: int = 1) -> None:
        """Integrate ``steps`` steps with the held commands (lockstep: one)."""
        for _ in range(steps):
            self.x, self.v = plant_step(
                self.x,
                self.v,
                self.u,
                mass=self.mass,
                dt=self.cfg.dt,
                drag=self.cfg.drag,
                disturbance=self.noise.next(),
            )
            self.k += 1

    def snapshot(self, k: int, target: Sample, target_age: float) -> dict[str, Any]:
        """The fields of the ``/swarm/state`` sample of step ``k`` with the target state
        ``target`` of age ``target_age`` [s], taken now (:meth:`advance` replaces the state
        arrays, the commands are copied); ``rejected_inputs`` counts the plant's refusals
        only (the node adds what the trackers report)."""
        return {
            'step': k,
            'sim_time': k * self.cfg.dt,
            'x': self.x,
            'v': self.v,
            'u': self.u.copy(),
            's': self.s.copy(),
            'target_x': target.x,
            'target_v': target.v,
            'missed_deadlines': self.missed,
            'stale_inputs': self.stale,
            'rejected_inputs': self.rejected,
            'active': self.active.copy(),
            'target_age': target_age,
            'command_latency': self.latency.copy(),
        }

    def metrics(
        self, target_x: NDArray[np.float64], x: NDArray[np.float64] | None = None
    ) -> tuple[float, float, float]:
        """J, centroid error and formation error (NaN without a design) of positions ``x``
        (n, 3) [m] (default: the current state) around the target at ``target_x``."""
        x = self.x if x is None else x
        j = float(potential(x, target_x, **self.cfg.potential_params()))
        ce = float(centroid_error(x, target_x))
        fe = (
            float(formation_error(x, self.expected_pairs))
            if (self.expected_pairs is not None)
            else float('nan')
        )
        return j, ce, fe
