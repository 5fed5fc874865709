"""The per-process logic of the ROS nodes, free of ROS: a tracker and the plant.

The nodes only convert messages to arrays, call these classes and publish. Both classes use the
simulator's own functions (:func:`~apf_swarm_core.simulator.control_step`,
:func:`~apf_swarm_core.simulator.integrate`, :class:`~apf_swarm_core.plant.DisturbanceSource`,
:func:`~apf_swarm_core.simulator.initial_positions`), so a lockstep ROS run reproduces the
headless simulator.

Safe command: when an input a tracker needs is stale (older than its timeout) the tracker
commands :func:`brake_force`, the switching law on the manifold ``s = v``: it drives the
UAV's velocity to zero (hover in place) with the same bounded force ``u0``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping, Sequence

import numpy as np
from numpy.typing import NDArray

from .config import SwarmConfig
from .laws import ControlOutput, switching_force
from .metrics import centroid_error, formation_error
from .plant import DisturbanceSource
from .potential import potential
from .simulator import control_step, expected_pairs, initial_positions, integrate, make_controller

__all__ = ['brake_force', 'Sample', 'TrackerAgent', 'PlantModel']


def brake_force(v: NDArray[np.float64], *, u0: float, drag: float) -> NDArray[np.float64]:
    """Safe command: eq. 24 on the manifold ``s = v``, ``u = -u0 sign(v) + drag v`` [N]."""
    return switching_force(v, v, u0=u0, drag=drag)


@dataclass
class Sample:
    """The latest value of one input: step (lockstep) or -1, arrays, and arrival time [s]."""

    step: int
    x: NDArray[np.float64]
    v: NDArray[np.float64]
    received: float


@dataclass
class TrackerAgent:
    """Inputs and controller of one tracking UAV.

    Parameters
    ----------
    cfg : SwarmConfig
    uav_id : int
        1-based id of this tracker.
    neighbour_ids : sequence of int
        Ids of the other trackers whose odometry enters the potential (default: all others).
    """

    cfg: SwarmConfig
    uav_id: int
    neighbour_ids: Sequence[int] | None = None
    rejected: int = 0
    stale: int = 0
    inputs: dict[int, Sample] = field(default_factory=dict)   # latest per source, 0 = target
    pending: dict[int, dict[int, Sample]] = field(default_factory=dict)  # lockstep: by step
    _last_step: int = -1

    def __post_init__(self) -> None:
        if not 1 <= self.uav_id <= self.cfg.n_trackers:
            raise ValueError(f'uav_id = {self.uav_id}: must be within 1..{self.cfg.n_trackers} '
                             f'(n_trackers = {self.cfg.n_trackers})')
        if self.neighbour_ids is None:
            self.neighbour_ids = [j for j in range(1, self.cfg.n_trackers + 1) if j != self.uav_id]
        self.ids = sorted({self.uav_id, *self.neighbour_ids})
        self.row = self.ids.index(self.uav_id)
        self.controller = make_controller(self.cfg, (1, 3))
        self.params = self.cfg.potential_params()

    #: configuration keys a running tracker takes over at once (:meth:`retune`): the
    #: controller's gains (eq. 22-28, 31, 24, 26) and the potential (eq. 2 / 44)
    RETUNABLE = ('alpha', 'beta', 'gamma', 'lambda_filter', 'u0', 'drag', 'k_n', 'k_f', 'a',
                 'b', 'c')

    def retune(self, cfg: SwarmConfig) -> list[str]:
        """Take over the gains and potential of ``cfg``; returns the keys that changed.

        The filter state and the held inputs are kept, so the controller continues from
        where it is. Only :data:`RETUNABLE` keys may differ from the current configuration.
        """
        changed = [k for k in self.RETUNABLE if getattr(cfg, k) != getattr(self.cfg, k)]
        others = [f for f in ('n_trackers', 'law', 'saturation', 'dt', 'seed')
                  if getattr(cfg, f) != getattr(self.cfg, f)]
        if others:
            raise ValueError(f'{", ".join(others)} cannot change while the tracker runs')
        for key in ('alpha', 'beta', 'gamma', 'lambda_filter', 'u0', 'drag'):
            setattr(self.controller, key, getattr(cfg, key))
        self.cfg = cfg
        self.params = cfg.potential_params()
        return changed

    def reset(self) -> None:
        """Forget every input and zero the filter state (after a restart)."""
        self.inputs.clear()
        self.controller.reset()
        self._last_step = -1

    def offer(self, source: int, step: int, x: NDArray[np.float64], v: NDArray[np.float64],
              now: float) -> bool:
        """Store an input (``source`` = tracker id, 0 = target); False if rejected.

        Non-finite values and unknown sources are rejected and counted; an older step than
        the one held is ignored (out of order). Lockstep inputs (``step >= 0``) are also kept
        by step, a few steps deep, because the target publishes one step ahead.
        """
        if source != 0 and source not in self.ids:
            self.rejected += 1
            return False
        if not (np.all(np.isfinite(x)) and np.all(np.isfinite(v))):
            self.rejected += 1
            return False
        held = self.inputs.get(source)
        if held is not None and step >= 0 and step < held.step:
            self.rejected += 1
            return False
        sample = Sample(step, np.asarray(x, float), np.asarray(v, float), now)
        self.inputs[source] = sample
        if step >= 0:
            by_step = self.pending.setdefault(step, {})
            by_step[source] = sample
            for old in [k for k in self.pending if k < self._last_step - 1]:
                del self.pending[old]
        return True

    def ready(self, step: int) -> bool:
        """Lockstep: every input of ``step`` has arrived and no command was sent for it yet."""
        if step <= self._last_step:
            return False
        got = self.pending.get(step, {})
        return all(src in got for src in (0, *self.ids))

    def command(self, step: int) -> ControlOutput:
        """The controller's command from the held inputs (one row, shape (1, 3) arrays)."""
        held = self.pending.pop(step, None) if step >= 0 else None
        src = held if held is not None else self.inputs
        x = np.stack([src[j].x for j in self.ids])
        out = control_step(self.controller, x, src[self.uav_id].v[None, :], src[0].x,
                           self.params, rows=[self.row])
        self._last_step = step
        return out

    def stale_sources(self, now: float, timeout: float) -> list[int]:
        """Inputs missing or older than ``timeout`` seconds (0 = the target)."""
        return [src for src in (0, *self.ids)
                if src not in self.inputs or now - self.inputs[src].received > timeout]

    def safe_command(self) -> NDArray[np.float64]:
        """:func:`brake_force` from the last own velocity (zero force if none is known)."""
        own = self.inputs.get(self.uav_id)
        if own is None:
            return np.zeros(3)
        return brake_force(own.v, u0=self.cfg.u0, drag=self.cfg.drag)


@dataclass
class PlantModel:
    """Dynamics of all trackers (eq. 19-21), as the simulator integrates them.

    Holds x, v (n, 3), the disturbance source and the latest commands. Lockstep: collect the
    commands of step k, then :meth:`advance`. A command that never arrives is held from the
    previous step (zero-order hold) and counted in ``missed``.
    """

    cfg: SwarmConfig
    k: int = 0
    missed: int = 0
    stale: int = 0
    rejected: int = 0

    def __post_init__(self) -> None:
        n = self.cfg.n_trackers
        self.ids = list(range(1, n + 1))
        self.x = initial_positions(self.cfg)
        self.v = np.zeros((n, 3))
        self.mass = np.asarray(self.cfg.mass_matrix_diag(), dtype=float)
        self.noise = DisturbanceSource(self.cfg.seed, n, self.cfg.f_bar, self.cfg.noise)
        self.u = np.zeros((n, 3))
        self.s = np.zeros((n, 3))
        self.got: dict[int, int] = {}       # uav_id -> step of the latest command
        self.stale_flags = np.zeros(n, dtype=bool)
        pairs = expected_pairs(self.cfg)
        self.expected_pairs = None if pairs is None else np.asarray(pairs)

    def offer_command(self, uav_id: int, step: int, force: NDArray[np.float64],
                      s: NDArray[np.float64], stale: bool = False) -> bool:
        """Store the command of one tracker; False (and counted) if invalid."""
        if uav_id not in self.ids or not (np.all(np.isfinite(force)) and np.all(np.isfinite(s))):
            self.rejected += 1
            return False
        j = uav_id - 1
        if step >= 0 and step < self.got.get(uav_id, -1):
            self.rejected += 1
            return False
        self.u[j], self.s[j] = force, s
        self.got[uav_id] = step
        if stale:
            self.stale += 1
        return True

    def missing(self, step: int) -> list[int]:
        """Trackers whose command for ``step`` has not arrived."""
        return [i for i in self.ids if self.got.get(i, -1) != step]

    def advance(self, steps: int = 1) -> None:
        """Integrate ``steps`` steps with the held commands (lockstep: one)."""
        for _ in range(steps):
            self.x, self.v = integrate(self.x, self.v, self.u, mass=self.mass, dt=self.cfg.dt,
                                       drag=self.cfg.drag, disturbance=self.noise.next())
            self.k += 1

    def metrics(self, target_x: NDArray[np.float64]) -> tuple[float, float, float]:
        """J, centroid error and formation error (NaN without a design) of the current state."""
        j = float(potential(self.x, target_x, **self.cfg.potential_params()))
        ce = float(centroid_error(self.x, target_x))
        fe = float(formation_error(self.x, self.expected_pairs)) if (
            self.expected_pairs is not None) else float('nan')
        return j, ce, fe
