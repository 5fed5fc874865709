"""One tracker's logic without ROS (:class:`TrackerAgent`): its inputs, checked
(:func:`~apf_swarm_core.inputs.input_problem`) and held, and its command from the simulator's
own :func:`~apf_swarm_core.control.control_step`, so that a lockstep run reproduces the
headless simulator. A stale input gets :func:`brake_force` (hover in place); inactive
neighbours leave the formation term and stay as obstacles (docs/RELIABILITY.md)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .compensation import LatencyEstimate, compensation_horizon
from .config import DEFAULT_LATENCY, KEYS, SwarmConfig
from .control import (
    control_step,
    make_controller,
    make_preconditioner,
    make_predictor,
)
from .controller import CONTROLLER_GAINS, ControlOutput
from .inputs import Sample, input_problem
from .kernels import warm
from .laws import switching_force
from .neighbours import neighbour_mask
from .plant import acceleration_setpoint, velocity_setpoint
from .potential import POTENTIAL_KEYS

__all__ = ['TrackerAgent', 'brake_force']


def brake_force(v: NDArray[np.float64], *, u0: float, drag: float) -> NDArray[np.float64]:
    """Safe command: eq. 24 on the manifold ``s = v``, ``u = -u0 sign(v) + drag v`` [N]."""
    return switching_force(v, v, u0=u0, drag=drag)


@dataclass
class TrackerAgent:
    """Inputs and controller of one tracking UAV: ``uav_id`` (1-based) of ``cfg``, with the
    ``neighbour_ids`` whose odometry enters the potential (default: all others)."""

    cfg: SwarmConfig
    uav_id: int
    neighbour_ids: Sequence[int] | None = None
    rejected: int = 0
    stale: int = 0
    run: int = 0  # the run's identity: /swarm/odom of another run is refused (0: any)
    inputs: dict[int, Sample] = field(default_factory=dict)  # latest per source, 0 = target
    pending: dict[int, dict[int, Sample]] = field(default_factory=dict)  # lockstep: by step
    last_rejection: str = ''
    neighbours_used: int = -1  # neighbours in the formation term of the last command
    active_neighbours: int = -1  # neighbours the plant reported active then
    _last_step: int = -1
    #: the own velocity the last command was computed from [m/s] (zero before any)
    own_velocity: NDArray[np.float64] = field(default_factory=lambda: np.zeros(3))

    def __post_init__(self) -> None:
        if not 1 <= self.uav_id <= self.cfg.n_trackers:
            raise ValueError(
                f'uav_id = {self.uav_id}: must be within 1..{self.cfg.n_trackers} '
                f'(n_trackers = {self.cfg.n_trackers})'
            )
        if self.neighbour_ids is None:
            self.neighbour_ids = [j for j in range(1, self.cfg.n_trackers + 1) if j != self.uav_id]
        self.ids = sorted({self.uav_id, *self.neighbour_ids})
        self._id_set = frozenset(self.ids)
        self._own_row = self.ids.index(self.uav_id)
        #: the latest /swarm/odom as arrays (x, v, active) in the order of :attr:`ids`, while no
        #: single odometry has replaced a row: :meth:`command` reads it, not one Sample per row
        self._swarm: tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]] | None
        self._swarm = None
        #: realtime: (step, produced, seq) of :attr:`_swarm` while its rows are not in
        #: :attr:`inputs` yet; :meth:`_held` makes their Samples when a reader needs them
        self._lazy: tuple[int, float, int] | None = None
        self._seq_max = -1  # the largest order key held of any tracker
        #: the last /swarm/odom's ids and the rows of :attr:`ids` in it (:meth:`_rows_of`)
        self._order: tuple[NDArray[Any], NDArray[np.intp]] | None = None
        self.controller = make_controller(self.cfg, (1, 3))
        warm()  # the compiled kernels loaded now, not at the first command
        self.precondition = make_preconditioner(self.cfg)
        #: compensation = predict with control_rate > 0: the state a command acts on, and the
        #: loop latency the plant reports (:meth:`report_latency`)
        self.predictor = make_predictor(self.cfg)
        self.latency = LatencyEstimate(self.cfg.latency or DEFAULT_LATENCY)
        self.params = self.cfg.potential_params()

    #: configuration keys a running tracker takes over at once (:meth:`retune`): the
    #: controller's gains (eq. 22-28, 31, 24, 26) and the potential (eq. 2 / 44)
    RETUNABLE = (*CONTROLLER_GAINS, *POTENTIAL_KEYS, 'b_growth')

    def retune(self, cfg: SwarmConfig) -> list[str]:
        """Take over the gains and potential of ``cfg`` (only :data:`RETUNABLE` keys may
        differ), keeping the filter state and the held inputs; returns the keys changed."""
        differ = [k for k in KEYS if getattr(cfg, k) != getattr(self.cfg, k)]
        changed = [k for k in self.RETUNABLE if k in differ]
        others = [k for k in differ if k not in self.RETUNABLE]
        if others:
            raise ValueError(f'{", ".join(others)} cannot change while the tracker runs')
        self.controller.retune(**{key: getattr(cfg, key) for key in CONTROLLER_GAINS})
        self.cfg = cfg
        self.params = cfg.potential_params()
        return changed

    def offer(
        self,
        source: int,
        step: int,
        x: NDArray[np.float64],
        v: NDArray[np.float64],
        now: float,
        *,
        seq: int | None = None,
        active: bool = True,
    ) -> bool:
        """Store an input (``source`` = tracker id, 0 = target) produced at ``now`` (caller's
        clock); False if rejected (non-finite or out of range, unknown source, ``seq`` below
        the one held; counted, ``last_rejection`` says why). ``seq``: order key (default
        ``step``; realtime: the stamp [ns]); ``active``: False when the plant reports this
        tracker silent. Lockstep inputs are also kept by step; a target state of a step
        answered or held already (a repeated window) is ignored, not refused."""
        seq = step if seq is None else int(seq)
        if (
            source == 0
            and step >= 0
            and (step <= self._last_step or 0 in self.pending.get(step, {}))
        ):
            return True
        if not self._acceptable(source, x, v, seq):
            return False
        self._store(source, step, x, v, now, seq, active)
        return True

    def _store(
        self,
        source: int,
        step: int,
        x: NDArray[np.float64],
        v: NDArray[np.float64],
        now: float,
        seq: int,
        active: bool,
    ) -> None:
        """Keep an input already checked by :meth:`_acceptable`."""
        if source != 0:
            self._held()  # the swarm's rows, before this one replaces one of them
        active = bool(active) or source in (0, self.uav_id)
        sample = Sample(step, np.asarray(x, float), np.asarray(v, float), now, seq, active)
        self.inputs[source] = sample
        if source != 0:
            self._swarm = None
            self._seq_max = max(self._seq_max, seq)
        if step >= 0:
            self.pending.setdefault(step, {})[source] = sample
            for old in [k for k in self.pending if k < self._last_step - 1]:
                del self.pending[old]

    def offer_swarm(
        self,
        step: int,
        ids: Sequence[int],
        x: NDArray[np.float64],
        v: NDArray[np.float64],
        active: Sequence[bool],
        target_x: NDArray[np.float64],
        target_v: NDArray[np.float64],
        now: float,
        target_time: float,
        *,
        seq: int | None = None,
        run: int = 0,
    ) -> bool:
        """Store one aggregated message (every tracker's state and the target's) as a whole:
        if any part would be refused, nothing is stored and it counts as one rejection; so is
        a message of another ``run`` than this tracker's (:attr:`run`, when not 0).
        ``now`` / ``target_time``: when the trackers' and the target's states were produced;
        rows of trackers that are not neighbours of this one are ignored."""
        if self.run and run != self.run:
            return self._reject(f'/swarm/odom of another run ({run:x}; this run: {self.run:x})')
        seq = step if seq is None else int(seq)
        x, v = np.asarray(x, dtype=float), np.asarray(v, dtype=float)
        order = self._rows_of(ids)
        if order is None:
            return self._reject(
                f'the message has no state of {[f"uav_{j}" for j in self.ids if j not in ids]}'
            )
        # the values of every row at once (two reductions); only a message that fails this is
        # checked row by row, for the reason and for rows that are not this tracker's inputs
        clean = input_problem(x=x, v=v) is None and input_problem(x=target_x, v=target_v) is None
        if not self._acceptable(0, target_x, target_v, seq, checked=clean):
            return False
        # a tracker's row is out of order only if some row held is newer than this message
        if not clean or seq < self._seq_max:
            for j, r in zip(self.ids, order, strict=True):
                if not self._acceptable(j, x[r], v[r], seq, checked=clean):
                    return False
        self._store(0, step, target_x, target_v, target_time, seq, True)
        xs, vs = x[order], v[order]
        act = np.asarray(active, dtype=bool)[order]
        act[self._own_row] = True
        self._seq_max = max(self._seq_max, seq)
        self._swarm = (xs, vs, act)
        self._lazy = (step, now, seq)
        if step >= 0:  # lockstep: by step too; realtime: arrays until a reader needs rows
            self.pending.setdefault(step, {}).update(self._rows())
        return True

    def _rows_of(self, ids: Sequence[int]) -> NDArray[np.intp] | None:
        """The rows of :attr:`ids` in a message listing ``ids`` (None if one is missing);
        the last message's answer again while the list is the same (the plant's order)."""
        key = np.asarray(ids)
        if self._order is not None and np.array_equal(key, self._order[0]):
            return self._order[1]
        where = {int(j): r for r, j in enumerate(key.tolist()) if j in self._id_set}
        if len(where) < len(self.ids):
            return None
        order = np.fromiter((where[j] for j in self.ids), dtype=np.intp, count=len(self.ids))
        self._order = (key.copy(), order)
        return order

    def _rows(self) -> dict[int, Sample]:
        """The rows of the latest ``/swarm/odom`` held as arrays, one Sample each, now in
        :attr:`inputs` (none when they are there already)."""
        if self._lazy is None or self._swarm is None:
            return {}
        (step, now, seq), (xs, vs, act) = self._lazy, self._swarm
        self._lazy = None
        rows = {
            j: Sample(step, xs[k], vs[k], now, seq, a)
            for k, (j, a) in enumerate(zip(self.ids, act.tolist(), strict=True))
        }
        self.inputs.update(rows)
        return rows

    def _held(self) -> dict[int, Sample]:
        """:attr:`inputs`, with the rows of the latest ``/swarm/odom`` in it."""
        self._rows()
        return self.inputs

    def _acceptable(
        self,
        source: int,
        x: NDArray[np.float64],
        v: NDArray[np.float64],
        seq: int,
        checked: bool = False,
    ) -> bool:
        """The checks of :meth:`offer` without storing (counts and records a rejection);
        ``checked``: the values are known to pass :func:`input_problem`."""
        name = 'target' if source == 0 else f'uav_{source}'
        if source != 0 and source not in self._id_set:
            return self._reject(f'{name} is not in this swarm (ids {self.ids})')
        problem = None if checked else input_problem(x=x, v=v)
        if problem is not None:
            return self._reject(f'{name}: {problem}')
        held = (self.inputs if source == 0 else self._held()).get(source)
        if held is not None and seq >= 0 and seq < held.seq:
            return self._reject(f'{name}: out of order ({seq} after {held.seq})')
        return True

    def _reject(self, why: str) -> bool:
        self.rejected += 1
        self.last_rejection = why
        return False

    def report_latency(self, latencies: ArrayLike) -> None:
        """The latencies the plant measured for the swarm's latest commands [s] (realtime,
        :class:`~apf_swarm_core.compensation.LatencyEstimate`)."""
        self.latency.add(latencies)

    def ready(self, step: int) -> bool:
        """Lockstep: every input of ``step`` has arrived and no command was sent for it yet."""
        if step <= self._last_step:
            return False
        got = self.pending.get(step, {})
        return all(src in got for src in (0, *self.ids))

    def command(self, step: int) -> ControlOutput:
        """The controller's command from the held inputs (one row, shape (1, 3) arrays)."""
        held = self.pending.pop(step, None) if step >= 0 else None
        if held is None and self._swarm is not None:
            # the latest /swarm/odom whole: its arrays, without one Sample per tracker
            src, (xs, vs, act) = self.inputs, self._swarm
        else:
            src = held if held is not None else self._held()
            rows = [src[j] for j in self.ids]
            xs, vs = np.stack([r.x for r in rows]), np.stack([r.v for r in rows])
            act = np.array([r.active for r in rows])
        n_active = int(np.count_nonzero(act))
        row = int(np.count_nonzero(act[: self._own_row]))
        x, all_v = (xs, vs) if n_active == act.size else (xs[act], vs[act])
        silent_x, own_v = xs[~act], vs[self._own_row]
        rule = self.cfg.neighbour_rule()
        # a limited neighbour set (cfg.neighbours): this row of the simulator's mask
        mask = neighbour_mask(x, **rule, rows=[row]) if rule else None
        if self.predictor is not None:
            self.predictor.horizon = compensation_horizon(self.latency.value)
        # inactive neighbours leave the formation term and stay as obstacles
        out = control_step(
            self.controller,
            x,
            own_v[None, :],
            src[0].x,
            self.params,
            rows=[row],
            mask=mask,
            obstacles=silent_x if silent_x.size else None,
            target_v=src[0].v,
            precondition=self.precondition,
            predictor=self.predictor,
            velocities=None if self.predictor is None else all_v,
        )
        self.neighbours_used = n_active - 1 if mask is None else int(np.count_nonzero(mask))
        self.active_neighbours = n_active - 1
        self.own_velocity = own_v
        self._last_step = step
        return out

    def brake(self, step: int) -> NDArray[np.float64]:
        """Answer ``step`` with :meth:`safe_command` (lockstep: an input is stale, but the
        barrier must still get a command for this step)."""
        self.pending.pop(step, None)
        self._last_step = step
        return self.safe_command()

    def stale_sources(self, now: float, timeout: float) -> list[int]:
        """Inputs missing or older than ``timeout`` seconds (0 = the target)."""
        held = self.inputs
        late = [0] if 0 not in held or now - held[0].received > timeout else []
        if self._lazy is not None:  # every tracker's row from one message
            return late + (list(self.ids) if now - self._lazy[1] > timeout else [])
        return late + [s for s in self.ids if s not in held or now - held[s].received > timeout]

    def setpoints(
        self, force: ArrayLike, period: float
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """The acceleration and velocity setpoints of ``force`` for a flight stack
        (:func:`~apf_swarm_core.plant.acceleration_setpoint`, and
        :func:`~apf_swarm_core.plant.velocity_setpoint` over the coming control ``period``
        [s]), from the own velocity the last input gave (the measured one)."""
        mass = self.cfg.mass_matrix_diag()[self.uav_id - 1]
        a = acceleration_setpoint(force, self.own_velocity, mass=mass, drag=self.cfg.drag)
        return a, velocity_setpoint(self.own_velocity, a, period)

    def safe_command(self) -> NDArray[np.float64]:
        """:func:`brake_force` from the last own velocity (zero force if none is known)."""
        own, force = self._held().get(self.uav_id), np.zeros(3)
        if own is not None:
            self.own_velocity = own.v
            force = brake_force(own.v, u0=self.cfg.u0, drag=self.cfg.drag)
        if self.predictor is not None:
            self.predictor.hold(force[None, :])
        return force
