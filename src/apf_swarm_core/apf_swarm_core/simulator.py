"""Headless fixed-step simulator of the closed loop: R runs (seeds, parameter values) as one
array program with a leading run axis; a single run is the batch R = 1.

A step k -> k+1 follows a lockstep ROS run: the target at ``t_k = k dt`` (eq. 1), then
:func:`~apf_swarm_core.control.control_step` for every tracker (as the tracker node), then the
plant (eq. 19-21, as the plant node) with the command held over the step. With
``control_rate`` > 0 or a latency it emulates the realtime loop: a command every
``hold_steps`` steps, acting after its delay (:class:`~apf_swarm_core.command_hold.CommandHold`).
Random streams: ``[seed, 1]`` the start, ``[seed, 2]`` the disturbance, ``[seed, 3]`` the
delays drawn from ``latency_samples``.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, cast

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .command_hold import STALE_AFTER, CommandHold
from .config import KEYS, SwarmConfig
from .control import (
    BlockPreconditioner,
    control_step,
    make_controller,
    make_preconditioner,
    make_predictor,
)
from .controller import CONTROLLER_GAINS, ControlOutput
from .errors import ConfigError
from .formation import design_formations, design_pair_sets
from .gains import per_run
from .kernels import as_kernel, simulate_steps
from .metrics import summarize
from .neighbours import neighbour_mask
from .plant import DisturbanceSource, plant_step, uniform_ball
from .potential import POTENTIAL_KEYS, PotentialParams
from .target import BatchTarget

__all__ = [
    'BATCHABLE',
    'TRAJECTORY_KEYS',
    'BatchSimulator',
    'SimResult',
    'formation_start',
    'initial_positions',
    'simulate',
    'simulate_batch',
    'start_radius',
    'summarize_run',
]

#: arrays of trajectory.npz
TRAJECTORY_KEYS = ('t', 'x', 'v', 'u', 's', 'target_x', 'target_v')

#: configuration keys that may differ between the runs of one batch; every other key of
#: :data:`~apf_swarm_core.config.KEYS` must be the same in every run
BATCHABLE = (
    *POTENTIAL_KEYS,
    'b_growth',
    *CONTROLLER_GAINS,
    'f_bar',
    'mass',
    'seed',
    'init_spread',
    'init_separation',
    'init_layout',
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
    'uav_overrides',
    'latency',
    'steady_fraction',
)


#: the size of the formation start against the design's: room to expand into it
START_SCALE = 0.7
#: draws of one tracker's start before :func:`initial_positions` gives up
MAX_DRAWS = 10_000
#: the fraction of the start ball that the trackers' separation spheres fill
START_PACKING = 0.2


def initial_positions(cfg: SwarmConfig) -> NDArray[np.float64]:
    """Initial tracker positions, shape (n, 3) [m]: uniform in a ball of radius
    ``init_spread`` around ``init_center`` (stream ``[seed, 1]``), then per-UAV overrides;
    ``init_layout: formation`` (more than 3 trackers): :func:`formation_start` around
    ``init_center`` instead.

    With ``init_separation`` d > 0 a tracker drawn closer than d to one drawn before it is
    drawn again (random sequential addition, the same stream), in a ball of radius at least
    ``start_radius(n, d)``, which holds them with room to spare: no two start closer than d.
    """
    rng = np.random.default_rng([cfg.seed, 1])
    n, sep = cfg.n_trackers, cfg.init_separation
    if cfg.init_layout == 'formation' and n > 3:
        return _overridden(cfg, formation_start(cfg, rng) + np.asarray(cfg.init_center))
    radius = max(cfg.init_spread, start_radius(n, sep))
    x = uniform_ball(rng.random((n, 3)), radius)
    for i in range(1, n) if sep > 0 else ():
        for _ in range(MAX_DRAWS):
            if np.min(np.linalg.norm(x[:i] - x[i], axis=1)) >= sep:
                break
            x[i] = uniform_ball(rng.random((1, 3)), radius)[0]
        else:  # not reached at the packing of start_radius: a guard, not a limit
            raise ConfigError(
                f'init_separation = {sep:g} m: no room for tracker {i + 1} of {n} in a '
                f'ball of {radius:g} m after {MAX_DRAWS} draws; lower init_separation'
            )
    return _overridden(cfg, x + np.asarray(cfg.init_center))


def _overridden(cfg: SwarmConfig, x: NDArray[np.float64]) -> NDArray[np.float64]:
    """``x`` with the per-UAV ``initial_position`` overrides."""
    for i, over in cfg.uav_overrides.items():
        if 'initial_position' in over:
            x[int(i) - 1] = np.asarray(over['initial_position'], dtype=float)
    return x


def formation_start(cfg: SwarmConfig, rng: np.random.Generator) -> NDArray[np.float64]:
    """``init_layout: formation``: the design formation (the lowest minimum of J,
    :func:`~apf_swarm_core.formation.design_formations`) about its centroid, at
    :data:`START_SCALE` of its size, turned by a uniform random rotation drawn from ``rng``;
    shape (n, 3) [m]. A swarm started so settles in the design, not in a higher minimum of
    J that a random ball may lead it to (docs/THEORY.md, *The start*)."""
    designs = [f for f in design_formations(cfg) if f.spacing > 1e-6]
    if not designs:
        raise ConfigError(
            f'init_layout = formation: J of {cfg.n_trackers} trackers has no formation '
            '(it collapses); raise b, or start from init_layout = ball'
        )
    rel = designs[0].relative_positions - designs[0].relative_positions.mean(axis=0)
    q, r = np.linalg.qr(rng.standard_normal((3, 3)))
    q = q * np.sign(np.diag(r))  # uniform over the orthogonal group
    q[:, 0] *= np.linalg.det(q)  # and a rotation, not a reflection
    return np.asarray(START_SCALE * rel @ q.T, dtype=float)


def start_radius(n: int, separation: float) -> float:
    """The radius [m] of a ball in which ``n`` spheres of diameter ``separation`` fill
    :data:`START_PACKING` of the volume: ``n (d/2)^3 = 0.2 R^3``, well below the 0.38 at which
    random sequential addition jams (0 for d = 0)."""
    return 0.5 * separation * (n / START_PACKING) ** (1 / 3)


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
        return summarize_run(traj, cfg, warnings=warnings)


def summarize_run(
    traj: Mapping[str, NDArray[Any]], cfg: SwarmConfig, *, warnings: list[str] | None = None
) -> dict[str, Any]:
    """summary.json of one run's trajectory (the arrays of :data:`TRAJECTORY_KEYS`) flown
    with ``cfg``: :func:`~apf_swarm_core.metrics.summarize` judged against every design
    minimum of ``cfg`` (:func:`~apf_swarm_core.formation.design_pair_sets`). The one summary
    of a headless run and of a ROS run."""
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


#: tracker-steps a step (runs x trackers) up to which :meth:`BatchSimulator.run` takes the
#: compiled loop (docs/PERFORMANCE.md, "Headless simulator")
COMPILED_LOOP_MAX = 1024
#: steps between two calls of :meth:`BatchSimulator.run`'s ``progress``
PROGRESS_EVERY = 1000


class BatchSimulator:
    """R runs with the same n, law, saturation, dt and duration, stepped together.

    Parameters
    ----------
    cfgs : sequence of SwarmConfig
        One configuration per run; only keys in :data:`BATCHABLE` may differ.
    latency_samples : array (k,) [s], optional
        Measured control-loop latencies: each tracker's command at each sample takes effect
        after one of them, drawn with stream ``[seed, 3]`` of the first run (instead of the
        fixed ``latency``); needs ``control_rate`` > 0. Shape (m, n): a run's own delays
        replayed in their order (:class:`~apf_swarm_core.command_hold.CommandHold`).
    stale_after : float [s] or None
        A delayed command that answers a state older than this gets zero force, as the
        realtime plant does (None: held however late).
    """

    def __init__(
        self,
        cfgs: Sequence[SwarmConfig],
        latency_samples: ArrayLike | None = None,
        stale_after: float | None = STALE_AFTER,
    ) -> None:
        if not cfgs:
            raise ValueError('a batch needs at least one configuration')
        self.cfgs = list(cfgs)
        first = self.cfgs[0]
        for c in self.cfgs[1:]:
            for key in KEYS:
                if key not in BATCHABLE and getattr(c, key) != getattr(first, key):
                    raise ValueError(
                        f'every run of a batch must share {key}; got '
                        f'{getattr(first, key)!r} and {getattr(c, key)!r}'
                    )
        self.R, self.n, self.dt = len(self.cfgs), first.n_trackers, first.dt
        # per-run arrays where one run has floats: gradient() broadcasts either
        per: list[dict[str, Any]] = [dict(c.potential_params()) for c in self.cfgs]
        self.params = cast(
            PotentialParams, {k: per_run(p[k] for p in per) for k in POTENTIAL_KEYS}
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
            stale_after,
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
        self.noise = DisturbanceSource(
            [c.seed for c in self.cfgs], self.n, [c.f_bar for c in self.cfgs], first.noise
        )
        self.x = np.array([initial_positions(c) for c in self.cfgs])
        self.v = np.zeros_like(self.x)
        #: the target of every run at each step (runs that share a trajectory share its
        #: evaluation)
        self.target = BatchTarget([c.target_trajectory_obj for c in self.cfgs], self.dt)
        self.k = 0

    def step(self) -> tuple[ControlOutput, NDArray[np.float64], NDArray[np.float64]]:
        """Advance every run by one step; returns the command and the target state used (the
        force applied over the step, which an actuator delay may make an older command's, is
        :attr:`force`). :meth:`run` is this step in a loop."""
        tx, tv = self.target.state(self.k)
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
        self.x, self.v = plant_step(
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
        k0 = self.k
        # step-major views: sample j of every run is view[j] (no samples without a record)
        views = [
            rec[key].swapaxes(0, 1)
            for key in ('x', 'v', 'u', 's', 'saturated', 'target_x', 'target_v')
        ]
        if self._compiled():
            self._run_compiled(steps, record, views, progress)
        else:
            rec_x, rec_v, rec_u, rec_s, rec_sat, rec_tx, rec_tv = views
            for i in range(steps):
                x, v, k = self.x, self.v, self.k
                out, tx, tv = self.step()
                if record and k % every == 0:
                    j = i // every
                    rec_x[j] = x
                    rec_v[j] = v
                    rec_u[j] = self.force
                    rec_s[j] = out.sliding_surface
                    rec_sat[j] = out.saturated
                    rec_tx[j] = tx
                    rec_tv[j] = tv
                if progress is not None and (i + 1) % PROGRESS_EVERY == 0:
                    progress(i + 1, steps)
        if record:
            first = (-k0) % every  # the first recorded step is k0 + first
            m = len(range(first, steps, every))
            rec['t'][:m] = (k0 + first + every * np.arange(m)) * dt  # k dt, as k * dt
        if progress is not None:
            progress(steps, steps)
        return rec

    def _compiled(self) -> bool:
        """Whether :meth:`run` takes the compiled loop
        (:func:`~apf_swarm_core.kernels.simulate_steps`): for at most
        :data:`COMPILED_LOOP_MAX` tracker-steps a step (beyond, the step-by-step kernels'
        own loops are faster and Python's overhead per step is small); every command acts
        at its own sample, no prediction, every tracker a neighbour, the gradient or the block
        direction (the realtime emulation's delays, a limited neighbour set and the Newton
        direction step in Python, with the same kernels)."""
        return (
            self.R * self.n <= COMPILED_LOOP_MAX
            and self.actuator is None
            and self.predictor is None
            and not self.neighbour_rule
            and (self.precondition is None or isinstance(self.precondition, BlockPreconditioner))
            and self.controller.shape == (self.R, self.n, 3)
        )

    def _run_compiled(
        self,
        steps: int,
        record: bool,
        views: list[NDArray[Any]],
        progress: Callable[[int, int], None] | None,
    ) -> None:
        """:meth:`run`'s steps in the compiled loop, in pieces bounded by the disturbance's
        buffer, the target's block and the progress reports; the same bits as
        :meth:`step` in a loop."""
        R, n = self.R, self.n
        ctl = self.controller
        gains = np.empty((R, 5))
        for q, value in enumerate(self.params[key] for key in ('k_n', 'k_f', 'a', 'b', 'c')):
            gains[:, q] = np.broadcast_to(np.asarray(value, dtype=np.float64), (R,))
        pre = self.precondition
        mu, trust = (pre.mu, pre.trust) if isinstance(pre, BlockPreconditioner) else (0.0, 0.0)
        mass = as_kernel(self.mass, (R, n, 3))
        drag = as_kernel(self.drag, (R,))
        target = self.target
        tindex = target.index.astype(np.int64)  # the trajectory of each run
        x = np.array(self.x, dtype=float)
        v = np.array(self.v, dtype=float)
        z = np.array(self.controller.z, dtype=float).reshape(R, n, 3)
        held = np.zeros((4, R, n, 3))
        outside = np.zeros((R, n), dtype=np.bool_)
        out = self.out
        if out is not None:
            for q, arr in enumerate(
                (out.force, out.sliding_surface, out.gradient, out.filter_state)
            ):
                held[q] = arr
            outside[:] = out.saturated
        dt = float(self.dt)
        have = out is not None
        i = 0
        while i < steps:
            k = self.k
            target.state(k)  # the block holding step k
            base, pos, vel = target.block
            limit = min(steps - i, base + target.BLOCK - k)
            if progress is not None:
                limit = min(limit, PROGRESS_EVERY - i % PROGRESS_EVERY)
            dist = self.noise.take(limit)
            count = limit if self.noise.silent else dist.shape[0]
            have = simulate_steps(
                x,
                v,
                z,
                held,
                outside,
                have,
                k,
                i,
                count,
                self.hold,
                dist,
                as_kernel(pos[k - base : k - base + count]),
                as_kernel(vel[k - base : k - base + count]),
                tindex,
                gains,
                pre is not None,
                mu,
                trust,
                ctl.table,
                ctl.manifold,
                ctl.switching == 'layer',
                ctl.uses_feedforward,
                mass,
                drag,
                dt,
                0.5 * dt * dt,
                self.cfgs[0].record_every,
                record,
                *views,
            )
            i += count
            self.k += count
            if progress is not None and i % PROGRESS_EVERY == 0:
                progress(i, steps)
        self.x, self.v = x, v
        self.controller.z = z.reshape(self.controller.shape)
        self.out = ControlOutput(held[0], held[1], held[2], held[3], outside)
        self.force = held[0]


def simulate_batch(
    cfgs: Sequence[SwarmConfig],
    *,
    record: bool = True,
    progress: Callable[[int, int], None] | None = None,
    latency_samples: ArrayLike | None = None,
    stale_after: float | None = STALE_AFTER,
) -> SimResult:
    """Run a batch; trajectory arrays carry a leading run axis (except ``t``)."""
    sim = BatchSimulator(cfgs, latency_samples, stale_after)
    traj = sim.run(record=record, progress=progress)
    return SimResult(traj, list(cfgs), {'x': sim.x, 'v': sim.v, 'z': sim.controller.z})


def simulate(
    cfg: SwarmConfig,
    *,
    record: bool = True,
    progress: Callable[[int, int], None] | None = None,
    latency_samples: ArrayLike | None = None,
    stale_after: float | None = STALE_AFTER,
) -> SimResult:
    """Run one configuration: the batch of one, with the run axis removed."""
    res = simulate_batch(
        [cfg],
        record=record,
        progress=progress,
        latency_samples=latency_samples,
        stale_after=stale_after,
    )
    traj = {k: (v if k == 't' else v[0]) for k, v in res.trajectory.items()}
    return SimResult(traj, cfg, {k: v[0] for k, v in res.final.items()})
