"""One control step of the trackers, shared by the simulator and the tracker nodes: the
controller of a configuration (or a batch), the Newton preconditioner, the latency
predictor, and :func:`control_step` (gradient, sliding surface, command)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .compensation import Predictor, compensation_horizon
from .config import SwarmConfig
from .controller import CONTROLLER_GAINS, ControlOutput, SlidingModeController
from .gains import per_run
from .gradients import gradient, obstacle_gradient
from .kernels import block_rows, kernel_args
from .newton import newton_basis, newton_direction
from .potential import PotentialParams, Rows

__all__ = [
    'BlockPreconditioner',
    'Preconditioner',
    'control_step',
    'make_controller',
    'make_preconditioner',
    'make_predictor',
]


def make_controller(
    cfg: SwarmConfig | Sequence[SwarmConfig], shape: tuple[int, ...]
) -> SlidingModeController:
    """A controller with the gains of one configuration, or per-run gains of a batch."""
    cfgs = [cfg] if isinstance(cfg, SwarmConfig) else list(cfg)
    gains: dict[str, Any] = {
        key: per_run(getattr(c, key) for c in cfgs) for key in CONTROLLER_GAINS
    }
    return SlidingModeController(
        law=cfgs[0].law,
        dt=cfgs[0].control_period,
        shape=shape,
        saturation=cfgs[0].saturation,
        switching=cfgs[0].switching,
        **gains,
    )


class Preconditioner:
    """The Newton direction of ``precondition = newton`` along a run
    (:func:`~apf_swarm_core.newton.newton_direction` with floor ``mu`` and trust radius
    ``trust``), from the :func:`~apf_swarm_core.newton.newton_basis` of the positions
    every ``every``-th call and the held one in between.

    Trackers hosted in one process receive the same states: the last basis and the last
    direction computed in the process are reused for identical positions, target and gains
    (the eigendecomposition, then the gradient of every tracker, are the dearest parts of a
    command).
    """

    _last_basis: tuple[Any, Any] | None = None  # shared by the process
    _last_direction: tuple[Any, NDArray[np.float64], Any] | None = None

    def __init__(self, mu: float, every: int = 1, trust: float = 0.0) -> None:
        self.mu, self.every, self.trust, self.calls = float(mu), int(every), float(trust), 0
        self.basis: tuple[NDArray[np.float64], NDArray[np.float64]] | None = None

    def direction(
        self, x: ArrayLike, target_x: ArrayLike, params: PotentialParams
    ) -> NDArray[np.float64]:
        """The Newton direction of every tracker, shape of ``x`` (..., n, 3)."""
        x = np.asarray(x, dtype=float)
        tx = np.asarray(target_x, dtype=float)
        gains = tuple(np.asarray(v, dtype=float).tobytes() for v in params.values())
        key = (x.tobytes(), x.shape, gains)
        if (
            self.basis is None
            or self.basis[0].shape[-1] != x.shape[-2] * 3
            or self.calls % self.every == 0
        ):
            last = Preconditioner._last_basis
            if last is not None and last[0] == key:
                self.basis = last[1]
            else:
                self.basis = newton_basis(x, tx, **params)
                Preconditioner._last_basis = (key, self.basis)
        self.calls += 1
        dkey = (key, tx.tobytes(), self.mu, self.trust)
        last = Preconditioner._last_direction
        if last is not None and last[2] is self.basis and last[0] == dkey:
            return last[1]
        out = newton_direction(
            self.basis,
            gradient(x, tx, **params),
            mu=self.mu,
            trust=self.trust,
            ceiling=params['k_n'],
        )
        Preconditioner._last_direction = (dkey, out, self.basis)
        return out


class BlockPreconditioner:
    """The direction of ``precondition = block`` (not in the paper; docs/THEORY.md, Large
    swarms): ``g_bar / k_N + |H_ii|_mu_i^-1 (g_i - g_bar)``, each tracker's gradient row
    scaled by its own Hessian block with the centroid's mode ``g_bar = k_N (mean x - x_N)``
    apart, floor ``mu`` and trust radius ``trust`` (``mu_i = max(mu, |g_i - g_bar| /
    trust)``). O(n) per tracker (O(k) with k sensed neighbours); no state."""

    def __init__(self, mu: float, trust: float = 0.0) -> None:
        self.mu, self.trust = float(mu), float(trust)

    def direction(
        self,
        x: ArrayLike,
        target_x: ArrayLike,
        params: PotentialParams,
        rows: Rows = None,
        mask: ArrayLike | None = None,
    ) -> NDArray[np.float64]:
        """The direction of the trackers in ``rows`` (default all), shape (..., m, 3);
        ``x`` (..., n, 3): every tracker the potential sees. One pass of the compiled
        kernel :func:`~apf_swarm_core.kernels.block_rows` over each row's pairs gives its
        gradient row, its Hessian block and the step."""
        gains = (params['k_n'], params['k_f'], params['a'], params['b'], params['c'])
        args = kernel_args(x, target_x, gains, rows, mask)
        out = block_rows(args.x, args.tx, args.rows, args.mask, args.gains, self.mu, self.trust)
        return out.reshape((*args.shape, 3))


def make_preconditioner(cfg: SwarmConfig) -> Preconditioner | BlockPreconditioner | None:
    """The preconditioner of a configuration (:class:`Preconditioner` for ``newton``,
    :class:`BlockPreconditioner` for ``block``), or None for the gradient (the paper)."""
    if cfg.precondition == 'newton':
        return Preconditioner(cfg.newton_mu, cfg.newton_every, cfg.newton_trust)
    if cfg.precondition == 'block':
        return BlockPreconditioner(cfg.newton_mu, cfg.newton_trust)
    return None


def control_step(
    controller: SlidingModeController,
    x: ArrayLike,
    v: ArrayLike,
    target_x: ArrayLike,
    potential_params: PotentialParams,
    *,
    rows: Rows = None,
    mask: ArrayLike | None = None,
    obstacles: ArrayLike | None = None,
    target_v: ArrayLike | None = None,
    precondition: Preconditioner | BlockPreconditioner | None = None,
    predictor: Predictor | None = None,
    velocities: ArrayLike | None = None,
) -> ControlOutput:
    """Commands of the trackers in ``rows`` (default all) at one step.

    Parameters
    ----------
    controller : SlidingModeController
        Holds the filter state of the selected rows, shape ``(..., m, 3)``.
    x : array (..., n, 3)
        Positions of every tracker the potential sees [m].
    v : array (..., m, 3)
        Velocities of the selected trackers [m/s].
    target_x : array (..., 3)
    potential_params : keyword arguments of :func:`apf_swarm_core.gradients.gradient`
    rows, mask : see :func:`apf_swarm_core.gradients.gradient`
    obstacles : array (k, 3), optional
        Bodies that only repel (silent trackers, see :mod:`apf_swarm_core.agents`): their
        :func:`~apf_swarm_core.gradients.obstacle_gradient` is added to the gradient of the
        selected rows (a single run).
    target_v : array (..., 3), optional
        Target velocity, for a controller with ``feedforward`` (ignored without) and for a
        ``predictor``.
    precondition : Preconditioner or BlockPreconditioner, optional
        The manifold descends the Newton direction (``precondition = newton``: computed for
        every tracker the potential sees, then the rows selected) or the block-preconditioned
        one (``block``: the selected rows only, each from its own gradient row and Hessian
        block) instead of the gradient.
    predictor : Predictor, optional
        ``compensation = predict``: the command is computed from the state predicted by the
        predictor's horizon (:mod:`apf_swarm_core.compensation`), which then holds it.
    velocities : array (..., n, 3), optional
        Velocities of every tracker in ``x``, for a ``predictor`` (default ``v``, which
        then has to hold every row).
    """
    if predictor is not None:
        if target_v is None:
            raise ValueError('a predictor needs the target velocity (target_v)')
        x, v, target_x = predictor.state(
            x, v if velocities is None else velocities, v, target_x, target_v
        )
    if precondition is None:
        grad = gradient(x, target_x, **potential_params, rows=rows, mask=mask)
    elif isinstance(precondition, BlockPreconditioner):
        grad = precondition.direction(x, target_x, potential_params, rows, mask)
    else:
        grad = precondition.direction(x, target_x, potential_params)
        grad = grad if rows is None else grad[..., rows, :]
    if obstacles is not None and np.size(obstacles):
        xi = np.asarray(x, dtype=float)
        xi = xi if rows is None else xi[..., rows, :]
        grad = grad + obstacle_gradient(
            xi,
            obstacles,
            k_f=potential_params['k_f'],
            b=potential_params['b'],
            c=potential_params['c'],
        )
    out = controller.step(v, grad, target_v)
    if predictor is not None:
        predictor.hold(out.force)
    return out


def make_predictor(cfg: SwarmConfig, latency: float | None = None) -> Predictor | None:
    """The :class:`~apf_swarm_core.compensation.Predictor` of a configuration with sampled
    control (``compensation = predict`` and ``control_rate`` > 0), or None. ``latency``:
    the loop's [s] (default ``cfg.latency``)."""
    if cfg.compensation != 'predict' or cfg.control_rate <= 0:
        return None
    tau = cfg.latency if latency is None else latency
    return Predictor(compensation_horizon(tau), 0.5 * (cfg.mass_lo + cfg.mass_hi))
