"""Headless fixed-step simulator of the closed loop, single or batched.

One step ``k -> k+1`` (``t_k = k dt``), the order a lockstep ROS run follows too:

1. the target state ``x_N(t_k), xdot_N(t_k)`` from its trajectory (eq. 1);
2. :func:`control_step`: gradients (eq. 2 / 44) and the sliding-mode command of every tracker
   from the state at step k (eq. 22-28, 31, 24) -- the tracker node calls the same function for
   its own row;
3. :func:`integrate`: the plant (eq. 19-21) advances with the command held over the step and a
   seeded bounded disturbance -- the plant node calls the same function.

Real time emulated (``control_rate`` > 0, ``latency``): step 2 runs only every
``hold_steps`` steps (sample and hold, the controller's filter advancing by the period), and
each tracker's command takes effect ``latency`` seconds after its sample, rounded to steps,
or after a delay drawn per tracker and sample from measured latencies (``latency_samples``,
stream ``[seed, 3]``); until then the plant keeps the command it holds, and a command
overtaken by a newer one is dropped, as the realtime plant refuses an out-of-order command
(:class:`CommandHold`). With ``control_rate = 0`` and no latency the loop is the lockstep
one, unchanged.

The batched form runs R independent runs (different seeds and/or parameter values, the same
number of trackers) as one array program with a leading run axis; a single run is the batch
R = 1, so there is one code path. Random streams: ``default_rng([seed, 1])`` draws the initial
positions, ``default_rng([seed, 2])`` the disturbance (see :mod:`apf_swarm_core.plant`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, cast

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .config import SwarmConfig
from .control import (
    Preconditioner,
    control_step,
    make_controller,
    make_preconditioner,
    make_predictor,
)
from .controller import ControlOutput
from .design import Formation, design_pairs
from .design import design_formations as _design_formations
from .gains import per_run
from .metrics import summarize
from .neighbours import neighbour_mask
from .plant import DisturbanceSource, plant_step, uniform_ball
from .potential import (
    PotentialParams,
)

__all__ = [
    'TRAJECTORY_KEYS',
    'BatchSimulator',
    'CommandHold',
    'Preconditioner',
    'SimResult',
    'control_step',
    'design_formation',
    'design_formations',
    'design_pair_sets',
    'expected_pairs',
    'initial_positions',
    'integrate',
    'make_controller',
    'make_preconditioner',
    'make_predictor',
    'simulate',
    'simulate_batch',
]

#: arrays of trajectory.npz
TRAJECTORY_KEYS = ('t', 'x', 'v', 'u', 's', 'target_x', 'target_v')

#: configuration keys that may differ between the runs of one batch
BATCHABLE = (
    'k_n',
    'k_f',
    'a',
    'b',
    'c',
    'alpha',
    'beta',
    'gamma',
    'lambda_filter',
    'u0',
    'drag',
    'f_bar',
    'mass',
    'seed',
    'init_spread',
    'target_speed',
    'target_radius',
    'target_yaw_deg',
    'target_pitch_deg',
    'target_trajectory',
    'target_start',
    'target_waypoints',
    'init_center',
    'v_n',
    'epsilon',
    'mu',
    'mass_lo',
    'mass_hi',
    'noise',
    'uav_overrides',
    'phi',
    'feedforward',
    'latency',
)


def initial_positions(cfg: SwarmConfig) -> NDArray[np.float64]:
    """Initial tracker positions, shape (n, 3) [m]: uniform in a ball of radius
    ``init_spread`` around ``init_center`` (stream ``[seed, 1]``), then per-UAV overrides."""
    rng = np.random.default_rng([cfg.seed, 1])
    x = np.asarray(cfg.init_center) + uniform_ball(
        rng.random((cfg.n_trackers, 3)), cfg.init_spread
    )
    for i, over in cfg.uav_overrides.items():
        if 'initial_position' in over:
            x[int(i) - 1] = np.asarray(over['initial_position'], dtype=float)
    return x


def expected_pairs(cfg: SwarmConfig) -> NDArray[np.float64] | None:
    """Design pair distances of ``cfg``'s size and potential for the formation metrics
    (:func:`~apf_swarm_core.design.design_pairs`), or ``None`` when J has no formation."""
    return design_pairs(cfg.n_trackers, **cfg.potential_params())


def design_formation(cfg: SwarmConfig) -> Formation:
    """The lowest equilibrium formation of ``cfg``'s size and potential
    (:func:`~apf_swarm_core.design.design_formations`): a run's summary, its flight
    judgement, its emulation and the sampled-data prediction all ask for it."""
    return design_formations(cfg)[0]


def design_formations(cfg: SwarmConfig) -> list[Formation]:
    """Every minimum of J of ``cfg``'s size and potential that a swarm settles in, lowest
    first (:func:`~apf_swarm_core.design.design_formations`)."""
    return _design_formations(cfg.n_trackers, **cfg.potential_params())


def design_pair_sets(cfg: SwarmConfig) -> list[NDArray[np.float64]]:
    """The pair distances of every design minimum (:func:`design_formations`); for 3 and
    fewer trackers the one of :func:`expected_pairs`. Empty without a formation."""
    pairs = expected_pairs(cfg)
    if pairs is None:
        return []
    if cfg.n_trackers <= 3:
        return [pairs]
    return [f.pair_distances for f in design_formations(cfg) if f.spacing > 1e-6]


def integrate(
    x: ArrayLike,
    v: ArrayLike,
    force: ArrayLike,
    *,
    mass: ArrayLike,
    dt: float,
    drag: ArrayLike,
    disturbance: ArrayLike,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Advance the plant one step (eq. 19-21); see :func:`apf_swarm_core.plant.plant_step`."""
    return plant_step(x, v, force, mass=mass, dt=dt, drag=drag, disturbance=disturbance)


class CommandHold:
    """The plant's side of a sampled, delayed control loop: which command each UAV holds.

    :meth:`submit` hands over the commands computed at step k; each tracker's takes effect at
    step ``k + d``, d its delay in steps (a fixed ``latency`` or one drawn from
    ``latency_samples`` per tracker and sample, both rounded to steps of dt). Until then the
    UAV keeps the command it holds (zero force before the first). A command that arrives
    after a newer one of the same tracker is dropped (out of order).

    Parameters
    ----------
    shape : (R, n): runs and trackers.
    latency : float or array (R,) [s]; dt : float [s]
    latency_samples : array (k,) [s], optional; rng : numpy Generator for them
    """

    def __init__(
        self,
        shape: tuple[int, int],
        latency: ArrayLike,
        dt: float,
        latency_samples: ArrayLike | None = None,
        rng: np.random.Generator | None = None,
    ) -> None:
        self.shape = shape
        self.fixed = np.broadcast_to(
            np.rint(np.asarray(latency, dtype=float) / dt).astype(np.int64).reshape(-1, 1), shape
        )
        self.samples = (
            None
            if latency_samples is None
            else np.rint(np.asarray(latency_samples, dtype=float) / dt).astype(np.int64)
        )
        if self.samples is not None and (self.samples.size == 0 or np.any(self.samples < 0)):
            raise ValueError('latency_samples must be a non-empty array of delays >= 0 s')
        self.rng = rng if rng is not None else np.random.default_rng()
        self.force = np.zeros((*shape, 3))
        self.seq = np.full(shape, -1, dtype=np.int64)
        self.pending: list[tuple[int, NDArray[np.int64], NDArray[np.float64]]] = []
        self.count = 0

    @property
    def delayed(self) -> bool:
        """Whether any command waits at all (False: a command acts at its own step)."""
        return self.samples is not None or bool(np.any(self.fixed > 0))

    def submit(self, k: int, force: NDArray[np.float64]) -> None:
        """The commands computed from the state of step k, shape (R, n, 3)."""
        delay = (
            self.fixed if self.samples is None else self.rng.choice(self.samples, size=self.shape)
        )
        self.pending.append((self.count, k + delay, np.array(force, dtype=float)))
        self.count += 1

    def applied(self, k: int) -> NDArray[np.float64]:
        """The force every UAV holds over step k, shape (R, n, 3)."""
        keep = []
        for seq, at, force in self.pending:
            arrived = at <= k
            newer = arrived & (seq > self.seq)
            if newer.any():
                self.force[newer] = force[newer]
                self.seq[newer] = seq
            if not arrived.all():
                keep.append((seq, at, force))
        self.pending = keep
        return self.force


@dataclass
class SimResult:
    """Trajectory arrays (R leading axis removed for a single run) and the configuration(s)."""

    trajectory: dict[str, NDArray[Any]]
    config: SwarmConfig | list[SwarmConfig]
    final: dict[str, NDArray[np.float64]] = field(default_factory=dict)

    def summary(
        self, *, warnings: list[str] | None = None, run: int | None = None
    ) -> dict[str, Any]:
        """summary.json of the (single) run, or of run ``run`` of a batch."""
        cfg = self.config if isinstance(self.config, SwarmConfig) else self.config[run or 0]
        traj = (
            self.trajectory
            if run is None
            else {k: (v if k == 't' else v[run]) for k, v in self.trajectory.items()}
        )
        return summarize(
            traj,
            law=cfg.law,
            dt=cfg.dt,
            seed=cfg.seed,
            potential_params=cfg.potential_params(),
            expected_pairs=design_pair_sets(cfg),
            steady_fraction=cfg.steady_fraction,
            warnings=warnings,
        )


class BatchSimulator:
    """R runs with the same n, law, saturation, dt and duration, stepped together.

    Parameters
    ----------
    cfgs : sequence of SwarmConfig
        One configuration per run; only keys in :data:`BATCHABLE` may differ.
    latency_samples : array (k,) [s], optional
        Measured control-loop latencies: each tracker's command at each sample takes effect
        after one of them, drawn with stream ``[seed, 3]`` of the first run (instead of the
        fixed ``latency``); needs ``control_rate`` > 0.
    """

    def __init__(
        self, cfgs: Sequence[SwarmConfig], latency_samples: ArrayLike | None = None
    ) -> None:
        if not cfgs:
            raise ValueError('a batch needs at least one configuration')
        self.cfgs = list(cfgs)
        first = self.cfgs[0]
        for c in self.cfgs[1:]:
            for key in (
                'n_trackers',
                'law',
                'saturation',
                'dt',
                'duration',
                'record_every',
                'neighbours',
                'neighbour_count',
                'sensing_radius',
                'control_rate',
                'switching',
                'precondition',
                'newton_mu',
                'newton_every',
                'newton_trust',
                'compensation',
            ):
                if getattr(c, key) != getattr(first, key):
                    raise ValueError(
                        f'every run of a batch must share {key}; got '
                        f'{getattr(first, key)!r} and {getattr(c, key)!r}'
                    )
        self.R, self.n, self.dt = len(self.cfgs), first.n_trackers, first.dt
        # per-run arrays where one run has floats: gradient() broadcasts either
        self.params = cast(
            PotentialParams,
            {k: per_run(getattr(c, k) for c in self.cfgs) for k in ('k_n', 'k_f', 'a', 'b', 'c')},
        )
        self.neighbour_rule = first.neighbour_rule()  # {} = all-to-all (eq. 2)
        self.drag = per_run(c.drag for c in self.cfgs)
        mass = np.array([c.mass_matrix_diag() for c in self.cfgs])  # (R, n, 3)
        # one mass for every axis, tracker and run: a 0-d array (plant_step skips a unit one)
        self.mass = np.array(mass.flat[0]) if mass.size and np.all(mass == mass.flat[0]) else mass
        self.controller = make_controller(self.cfgs, (self.R, self.n, 3))
        self.hold = first.hold_steps
        if latency_samples is not None and first.control_rate <= 0:
            raise ValueError('latency_samples emulate a realtime loop: set control_rate > 0')
        act = CommandHold(
            (self.R, self.n),
            [c.latency for c in self.cfgs],
            self.dt,
            latency_samples,
            np.random.default_rng([first.seed, 3]),
        )
        #: the delayed commands in flight, or None when each acts at its own sample
        self.actuator = act if act.delayed else None
        self.out: ControlOutput | None = None
        #: the force applied over the latest step, (R, n, 3) [N]
        self.force: NDArray[np.float64] = np.zeros((self.R, self.n, 3))
        self.precondition = make_preconditioner(first)
        if first.compensation == 'predict' and len({c.latency for c in self.cfgs}) > 1:
            raise ValueError(
                'compensation = predict: every run of a batch must share the '
                'latency (the prediction horizon)'
            )
        self.predictor = make_predictor(
            first,
            None
            if latency_samples is None
            else float(np.median(np.asarray(latency_samples, dtype=float))),
        )
        if len({c.noise for c in self.cfgs}) > 1:
            raise ValueError('every run of a batch must share the noise kind')
        self.noise = DisturbanceSource(
            [c.seed for c in self.cfgs], self.n, [c.f_bar for c in self.cfgs], first.noise
        )
        self.x = np.array([initial_positions(c) for c in self.cfgs])
        self.v = np.zeros_like(self.x)
        # runs that share a trajectory share its evaluation
        trajs = [c.target_trajectory_obj for c in self.cfgs]
        self._trajs: list[Any] = []
        self._traj_index = np.empty(self.R, dtype=int)
        for r, tr in enumerate(trajs):
            if tr not in self._trajs:
                self._trajs.append(tr)
            self._traj_index[r] = self._trajs.index(tr)
        # every run its own trajectory, in order: index the block directly (no gather)
        self._traj_identity = len(self._trajs) == self.R
        self.k = 0
        self._tblock = (-1, np.empty((0, 0, 3)), np.empty((0, 0, 3)))

    def target_state(self, k: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Target position and velocity of every run at step k, shapes (R, 3).

        Evaluated for blocks of 1024 steps at once (``t = k dt``, vectorized over k), once per
        distinct trajectory; runs that share a trajectory gather its row at each step.
        """
        base, pos, vel = self._tblock
        if base < 0 or not base <= k < base + 1024:
            base = k
            t = np.arange(k, k + 1024) * self.dt
            states = [tr.state(t) for tr in self._trajs]
            pos = np.stack([s[0] for s in states], axis=1)  # (1024, trajectories, 3)
            vel = np.stack([s[1] for s in states], axis=1)
            self._tblock = (base, pos, vel)
        if self._traj_identity:
            return pos[k - base], vel[k - base]
        if len(self._trajs) == 1:  # one trajectory for every run: a read-only view
            shape = (self.R, 3)
            return np.broadcast_to(pos[k - base, 0], shape), np.broadcast_to(
                vel[k - base, 0], shape
            )
        return pos[k - base][self._traj_index], vel[k - base][self._traj_index]

    def _gather(self, rows: NDArray[np.float64]) -> NDArray[np.float64]:
        """Rows of a target block, shape (m, trajectories, 3), for every run: (m, R, 3) or
        (m, 1, 3) when one trajectory serves every run (broadcast on assignment)."""
        if self._traj_identity or len(self._trajs) == 1:
            return rows
        return rows[:, self._traj_index]

    def step(self) -> tuple[ControlOutput, NDArray[np.float64], NDArray[np.float64]]:
        """Advance every run by one step; returns the command and the target state used (the
        force applied over the step, which an actuator delay may make an older command's, is
        :attr:`force`). :meth:`run` is this step in a loop."""
        tx, tv = self.target_state(self.k)
        out = self.out
        if out is None or self.k % self.hold == 0:
            mask = neighbour_mask(self.x, **self.neighbour_rule) if self.neighbour_rule else None
            out = self.out = control_step(
                self.controller,
                self.x,
                self.v,
                tx,
                self.params,
                mask=mask,
                target_v=tv,
                precondition=self.precondition,
                predictor=self.predictor,
            )
            if self.actuator is not None:
                self.actuator.submit(self.k, out.force)
        force = self.force = out.force if self.actuator is None else self.actuator.applied(self.k)
        dist = self.noise.next()
        self.x, self.v = integrate(
            self.x, self.v, force, mass=self.mass, dt=self.dt, drag=self.drag, disturbance=dist
        )
        self.k += 1
        return out, tx, tv

    def run(
        self,
        steps: int | None = None,
        *,
        record: bool = True,
        progress: Callable[[int, int], None] | None = None,
        progress_every: int = 1000,
    ) -> dict[str, NDArray[Any]]:
        """Run ``steps`` steps (default: the configured duration) and return the trajectory.

        Sample k holds the state at ``t_k`` and the command computed from it (applied over
        ``[t_k, t_{k+1})``); every ``record_every``-th step is kept.
        """
        steps = self.cfgs[0].steps if steps is None else steps
        every = self.cfgs[0].record_every
        T = (steps + every - 1) // every if record else 0
        R, n, dt = self.R, self.n, self.dt
        shape = (R, T, n, 3)
        rec = {
            't': np.empty(T),
            'x': np.empty(shape),
            'v': np.empty(shape),
            'u': np.empty(shape),
            's': np.empty(shape),
            'target_x': np.empty((R, T, 3)),
            'target_v': np.empty((R, T, 3)),
            'saturated': np.empty((R, T, n), dtype=bool),
        }
        # step-major views: sample j of every run is rec_*[j]. Per step, one copy each of
        # the state, the command and the mask; the times and the target's samples are
        # copied in slices: t_k = k dt afterwards, the target rows from each block of the
        # target's path when the block is replaced (and at the end)
        rec_x, rec_v, rec_u, rec_s, rec_sat = (
            rec[key].swapaxes(0, 1) for key in ('x', 'v', 'u', 's', 'saturated')
        )
        rec_tx, rec_tv = (rec[key].swapaxes(0, 1) for key in ('target_x', 'target_v'))
        k0 = self.k
        first = (-k0) % every  # the first recorded step is k0 + first
        held = [0, 0]  # samples from the current block: j, count

        def target_samples(block: tuple[int, Any, Any]) -> None:
            j, m = held
            if m:
                base, pos, vel = block
                k = k0 + first + j * every - base  # row of sample j in the block
                rows = slice(k, k + (m - 1) * every + 1, every)
                rec_tx[j : j + m] = self._gather(pos[rows])
                rec_tv[j : j + m] = self._gather(vel[rows])
                held[:] = [j + m, 0]

        for i in range(steps):
            block = self._tblock
            x, v, k = self.x, self.v, self.k
            out, _, _ = self.step()
            if record:
                if self._tblock is not block:  # a new block: the old one's samples
                    target_samples(block)
                if k % every == 0:
                    j = i // every
                    rec_x[j] = x
                    rec_v[j] = v
                    rec_u[j] = self.force
                    rec_s[j] = out.sliding_surface
                    rec_sat[j] = out.saturated
                    held[1] += 1
            if progress is not None and (i + 1) % progress_every == 0:
                progress(i + 1, steps)
        if record:
            target_samples(self._tblock)
            m = held[0]
            rec['t'][:m] = (k0 + first + every * np.arange(m)) * dt  # k dt, as k * dt
        if progress is not None:
            progress(steps, steps)
        return rec


def simulate_batch(
    cfgs: Sequence[SwarmConfig],
    *,
    record: bool = True,
    progress: Callable[[int, int], None] | None = None,
    latency_samples: ArrayLike | None = None,
) -> SimResult:
    """Run a batch; trajectory arrays carry a leading run axis (except ``t``)."""
    sim = BatchSimulator(cfgs, latency_samples)
    traj = sim.run(record=record, progress=progress)
    return SimResult(traj, list(cfgs), {'x': sim.x, 'v': sim.v, 'z': sim.controller.z})


def simulate(
    cfg: SwarmConfig,
    *,
    record: bool = True,
    progress: Callable[[int, int], None] | None = None,
    latency_samples: ArrayLike | None = None,
) -> SimResult:
    """Run one configuration: the batch of one, with the run axis removed."""
    res = simulate_batch([cfg], record=record, progress=progress, latency_samples=latency_samples)
    traj = {k: (v if k == 't' else v[0]) for k, v in res.trajectory.items()}
    return SimResult(traj, cfg, {k: v[0] for k, v in res.final.items()})
