"""Sampled-data prediction: whether the formation holds at a control period T and a delay
tau (:func:`predict`), and the gains that make it hold (:func:`propose_gains`,
:func:`schedule_gains`), from the linear modes of :mod:`apf_swarm_core.modes`. The verdict and
how its limits were measured on the emulation: docs/THEORY.md, "Sampled-data control".
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .advice import PLAIN, Advice
from .compensation import compensation_horizon
from .config import SwarmConfig
from .formation import design_formation
from .metrics import FLIGHT_CRITERIA
from .modes import (
    centroid_curvature,
    design_hessian_spectrum,
    effective_spectrum,
    inner_rate,
    mode_radius,
    start_residual,
)
from .simulator import initial_positions

__all__ = [
    'BLOCK_LIMIT',
    'CASCADE',
    'DESIGN_MARGIN',
    'LAG_LIMIT',
    'LAYER_WIDTH',
    'NEWTON_LIMIT',
    'RELAY_LIMIT',
    'RIPPLE_FRACTION',
    'SOFT_SETTLE',
    'SampledPrediction',
    'approach_time',
    'largest_holding',
    'loop_limit',
    'predict',
    'propose_gains',
    'schedule_gains',
    'start_displacement',
]

#: the loop holds while K lambda_max (T + tau) stays below this (the sampled relay)
RELAY_LIMIT = 2.5
#: the same bound along the Newton direction (the curvature 1), measured on the emulation
NEWTON_LIMIT = 0.5
#: the same bound along the block direction (K mu_max, :func:`~.modes.design_block_spectrum`)
BLOCK_LIMIT = 1.5
#: :func:`propose_gains` keeps K lambda_max (T + tau) at this fraction of its limit
DESIGN_MARGIN = 0.8
#: the softest mode's time constant 1 / (K lambda_soft) must fit this many times into the
#: part of the run before the judged window
SOFT_SETTLE = 2.0
#: the boundary layer phi in units of u0 (T + tau) / M that :func:`propose_gains` takes
LAYER_WIDTH = 2.0
#: a boundary layer is linear where its rate u0 / (phi M) is this many times K lambda_max
CASCADE = 2.0
#: a steady lag behind the target above this [m] is warned about
LAG_LIMIT = 0.5
#: the sign law's ripple u0 T / M is large above this fraction of the target speed
RIPPLE_FRACTION = 0.5


def loop_limit(cfg: SwarmConfig) -> float:
    """The bound on ``kappa (T + tau)``: :data:`NEWTON_LIMIT` along the Newton direction,
    :data:`BLOCK_LIMIT` along the block direction, :data:`RELAY_LIMIT` along the
    gradient."""
    return {'newton': NEWTON_LIMIT, 'block': BLOCK_LIMIT}.get(cfg.precondition, RELAY_LIMIT)


@dataclass(frozen=True)
class SampledPrediction:
    """What :func:`predict` found; every rate in 1/s, times in s, speeds in m/s."""

    n_trackers: int
    control_period: float
    latency: float
    switching: str
    layer_gain: float
    inner_rate: float
    hessian_max: float
    hessian_soft: float
    formation_rate: float
    rate_allowed: float
    spectral_radius: float
    linear_radius: float
    ripple: float
    steady_lag: float
    settle_time: float
    settle_allowed: float
    inner_stable: bool
    start_error: float | None = None
    start_closest: float | None = None
    warnings: list[str] = field(default_factory=list)

    @property
    def holds(self) -> bool:
        """The formation is predicted to hold: ``K lambda_max (T + tau)`` below
        :func:`loop_limit` (:attr:`spectral_radius` below 1), a linear boundary layer's own
        loop stable (:attr:`inner_stable`) and the lag within :data:`LAG_LIMIT`. A soft mode
        that settles slowly (:attr:`settle_time` above :attr:`settle_allowed`) is a warning,
        not a verdict: how far the start excites it decides (the emulation does)."""
        return self.spectral_radius < 1.0 and self.steady_lag <= LAG_LIMIT and self.inner_stable

    @property
    def settles(self) -> bool:
        """The start's deformation is predicted to have decayed when the run is judged: for
        a start in the design's shape (:attr:`start_error`) by what its modes leave then,
        judged as flight judges; for any other start by the softest mode's time constant."""
        if self.start_error is not None and self.start_closest is not None:
            return _flown(self.start_error, self.start_closest)
        return self.settle_time <= self.settle_allowed

    def settling(self) -> str:
        """How the formation settles, in words (one clause)."""
        words = f'softest mode settles in {self.settle_time:.3g} s'
        if self.start_error is None or self.start_closest is None:
            return words + f' (of {self.settle_allowed:.3g} allowed)'
        return words + (
            f'; from the formation start its modes leave {100 * self.start_error:.3f} % '
            f'formation error and a closest pair at {100 * self.start_closest:.3g} % of the '
            f"design's when the run is judged"
        )

    def to_dict(self) -> dict[str, Any]:
        """Plain values, for summary.json."""
        return {**asdict(self), 'holds': self.holds}


def predict(
    cfg: SwarmConfig,
    *,
    control_rate: float | None = None,
    latency: float | None = None,
    spectrum: NDArray[np.float64] | None = None,
    advice: Advice = PLAIN,
) -> SampledPrediction:
    """Predict the sampled loop of ``cfg`` at ``control_rate`` [Hz] (default its own, else
    1/dt) with ``latency`` [s] (default its own); ``spectrum``: a precomputed
    :func:`design_hessian_spectrum`; ``advice``: the words of the warnings' remedies."""
    rate = cfg.control_rate if control_rate is None else control_rate
    T = 1.0 / rate if rate and rate > 0 else cfg.dt
    tau = cfg.latency if latency is None else float(latency)
    raw = design_hessian_spectrum(cfg) if spectrum is None else np.asarray(spectrum)
    eigs = effective_spectrum(cfg, raw)
    lam_max = float(eigs.max())
    # the rotations' zeros left out (the block spectrum is sorted apart from raw's)
    soft = float(
        eigs[3:].min() if cfg.precondition == 'block' else eigs[raw > 1e-6 * raw.max()].min()
    )
    mass = float(np.min(cfg.mass_matrix_diag()))
    K = cfg.alpha + cfg.beta / cfg.gamma
    g = inner_rate(cfg, T, mass)
    limit = loop_limit(cfg)
    allowed = limit / (T + tau)
    # compensation = predict: the commands act on the state predicted by tau
    h = compensation_horizon(tau) if cfg.compensation == 'predict' else 0.0
    linear = mode_radius(
        lam_max, layer_gain=K, inner_rate=g, period=T, latency=tau, mass=mass, horizon=h
    )
    ripple = cfg.u0 * T / mass
    vn = cfg.target_speed_bound
    lag = (1.0 - cfg.feedforward) * vn / (cfg.k_n * K)
    settle = 1.0 / (K * soft)
    judged = (1.0 - FLIGHT_CRITERIA['window']) * cfg.duration
    settle_allowed = judged / SOFT_SETTLE
    displacement = start_displacement(cfg)
    start_error = start_closest = None
    if displacement is not None:
        start_error, start_closest = start_residual(
            cfg, displacement, K, max(0.0, judged - approach_time(cfg))
        )
    warnings = []
    if start_error is not None and start_closest is not None:
        if not _flown(start_error, start_closest):
            warnings.append(
                f"slow formation: {cfg.n_trackers} trackers started in the formation's shape "
                f'are predicted to keep {100 * start_error:.3f} % formation error and a closest '
                f"pair at {100 * start_closest:.3g} % of the design's at {judged:.3g} s, when "
                f'the {cfg.duration:g} s run is judged (the softest mode, lambda = {soft:.3g}, '
                f'has the time constant 1 / (K lambda) = {settle:.3g} s): fly longer, or '
                f'raise K with a higher control rate'
            )
    elif settle > settle_allowed:
        warnings.append(
            f'slow formation: the softest deformation mode of {cfg.n_trackers} trackers '
            f'(lambda = {soft:.3g}) settles with the time constant 1 / (K lambda) = '
            f'{settle:.3g} s, more than {settle_allowed:.3g} s ({1 / SOFT_SETTLE:g} of the '
            f'first {1 - FLIGHT_CRITERIA["window"]:g} of the {cfg.duration:g} s run): the '
            f'pair distances may not reach the design in time; fly longer, or raise K with '
            f'a higher control rate'
        )
    if K * lam_max > allowed:
        Kmax = DESIGN_MARGIN * allowed / lam_max
        fix = (
            f'raise gamma to >= {cfg.beta / (Kmax - cfg.alpha):.3g} m (K = {Kmax:.3g} '
            f'1/s, with feedforward = 1 against the lag)'
            if Kmax > cfg.alpha
            else 'lower the latency'
        )
        warnings.append(
            f'formation predicted to fail at {1.0 / T:g} Hz with {tau * 1e3:g} ms latency: '
            f'the stiffest mode of {cfg.n_trackers} trackers has the rate K lambda_max = '
            f'{K:.3g} x {lam_max:.3g} = {K * lam_max:.3g} 1/s, and a control period of '
            f'{T * 1e3:g} ms with that delay allows {limit:g} / (T + tau) = '
            f'{allowed:.3g} 1/s: {fix}, raise the control rate, or '
            f'{advice.redesign(1.0 / T, tau, cfg.n_trackers)}'
        )
    inner_stable = True
    if cfg.switching == 'layer' and g >= CASCADE * K * lam_max:
        # the linear regime: the layer's own loop must be stable at the latency, and should
        # be with it doubled plus half a period (the jitter of a real delay)
        centroid = centroid_curvature(cfg)
        jitter = 2.0 * tau + 0.5 * T
        kw = {'layer_gain': K, 'inner_rate': g, 'period': T, 'mass': mass, 'horizon': h}
        if mode_radius(centroid, latency=tau, **kw) >= 1.0:
            inner_stable = False
            warnings.append(
                f'formation predicted to fail: the boundary layer phi = {cfg.phi:g} m/s is '
                f'too narrow for a period of {T * 1e3:g} ms with {tau * 1e3:g} ms latency: '
                f'its linear loop (rate u0 / (phi M) = {g:.3g} 1/s) is unstable; use phi >= '
                f'{LAYER_WIDTH * cfg.u0 * (T + tau) / mass:.3g} m/s and K <= '
                f'{cfg.u0 / (LAYER_WIDTH * cfg.u0 * (T + tau)) / (CASCADE * lam_max):.3g} '
                f'1/s, or {advice.redesign(1.0 / T, tau)}'
            )
        elif mode_radius(centroid, latency=jitter, **kw) >= 1.0:
            warnings.append(
                f'the boundary layer phi = {cfg.phi:g} m/s is too narrow for a period of '
                f'{T * 1e3:g} ms with a latency jittering up to 2 tau + T/2 = '
                f'{jitter * 1e3:g} ms: the inner loop (rate u0 / (phi M) = {g:.3g} 1/s) '
                f'goes unstable and the switching chatters; use phi >= '
                f'{LAYER_WIDTH * cfg.u0 * (T + tau) / mass:.3g} m/s'
            )
    if cfg.switching == 'sign' and ripple > RIPPLE_FRACTION * vn:
        warnings.append(
            f'large chattering: u0 = {cfg.u0:g} N held for the control period T = '
            f'{T * 1e3:g} ms gives a velocity ripple u0 T / M = {ripple:.3g} m/s, more than '
            f'{RIPPLE_FRACTION:g} x the target speed {vn:g} m/s: lower u0 to <= '
            f'{RIPPLE_FRACTION * vn * mass / T:.3g} N, raise the control rate, or use '
            f'switching = layer (phi about {ripple:.2g} m/s)'
        )
    if lag > LAG_LIMIT:
        warnings.append(
            f'steady lag (1 - w) v_N / (k_N K) = {lag:.3g} m behind a target at {vn:g} m/s '
            f'(K = {K:.3g} 1/s, w = {cfg.feedforward:g}): set feedforward = 1 or a smaller '
            f'gamma'
        )
    return SampledPrediction(
        n_trackers=cfg.n_trackers,
        control_period=T,
        latency=tau,
        switching=cfg.switching,
        layer_gain=K,
        inner_rate=g,
        hessian_max=lam_max,
        hessian_soft=soft,
        formation_rate=K * lam_max,
        rate_allowed=allowed,
        spectral_radius=K * lam_max / allowed,
        linear_radius=linear,
        ripple=ripple,
        steady_lag=lag,
        settle_time=settle,
        settle_allowed=settle_allowed,
        inner_stable=inner_stable,
        start_error=start_error,
        start_closest=start_closest,
        warnings=warnings,
    )


def _flown(error: float, closest: float) -> bool:
    """Formation error and closest pair (fractions) within flight's criteria."""
    return error <= FLIGHT_CRITERIA['formation_rms'] and closest >= FLIGHT_CRITERIA['closest']


def approach_time(cfg: SwarmConfig) -> float:
    """The time [s] the swarm takes to reach the target from its start: the distance from
    the start's centroid to the target's start over the closing speed the saturation of
    eq. 8 allows, ``beta - (1 - w) v_N`` (w the feed-forward); inf if it cannot close. While
    the swarm closes, its trackers move at that bound and the linear model of
    :func:`~apf_swarm_core.modes.start_residual` does not hold; it starts then."""
    gap = float(np.linalg.norm(initial_positions(cfg).mean(axis=0) - np.asarray(cfg.target_start)))
    closing = cfg.beta - (1.0 - cfg.feedforward) * cfg.target_speed_bound
    return gap / closing if closing > 0 else math.inf


def start_displacement(cfg: SwarmConfig) -> NDArray[np.float64] | None:
    """How far ``cfg``'s start lies from the design formation (n, 3) [m], both about their
    centroids and the start turned onto the design (Kabsch), when it starts in the design's
    shape (``init_layout = formation``, more than 3 trackers); None for a random start,
    which no linear model follows (which minimum of J it reaches is the emulation's to say)."""
    if cfg.init_layout != 'formation' or cfg.n_trackers <= 3:
        return None
    start = initial_positions(cfg)
    start = start - start.mean(axis=0)
    design = design_formation(cfg).relative_positions
    design = design - design.mean(axis=0)
    u, _, vt = np.linalg.svd(start.T @ design)
    if np.linalg.det(u @ vt) < 0:  # a rotation, not a reflection
        u[:, -1] = -u[:, -1]
    return np.asarray(start @ (u @ vt) - design)


def _schedule(
    cfg: SwarmConfig, eigs: NDArray[np.float64], T: float, latency: float
) -> dict[str, float | str] | None:
    """The gains of :func:`propose_gains` for the direction ``cfg.precondition``, or None."""
    lam_max = float(effective_spectrum(cfg, eigs).max())
    mass = float(np.min(cfg.mass_matrix_diag()))
    K = min(
        cfg.alpha + cfg.beta / cfg.gamma,
        DESIGN_MARGIN * loop_limit(cfg) / (lam_max * (T + latency)),
    )
    if cfg.alpha >= K:
        return None
    wide = LAYER_WIDTH * cfg.u0 * (T + latency) / mass
    # a wide, linear layer whose inner loop is CASCADE times faster than the formation's
    # stiffest mode, if that costs at most half of K; otherwise the narrow layer of the
    # relay regime with the whole K
    K_cascade = cfg.u0 / (wide * mass) / (CASCADE * lam_max)
    if K_cascade >= 0.5 * K:
        K, phi = min(K, K_cascade), wide
    else:
        phi = cfg.u0 * T / mass
    return {
        'switching': 'layer',
        'phi': phi,
        'gamma': cfg.beta / (K - cfg.alpha),
        'feedforward': 1.0,
        'precondition': cfg.precondition,
    }


def propose_gains(
    cfg: SwarmConfig,
    *,
    control_rate: float,
    latency: float,
    spectrum: NDArray[np.float64] | None = None,
) -> dict[str, float | str]:
    """Gains that :func:`predict` passes at this rate and delay, for ``cfg.n_trackers``: for
    the configuration's direction (the gradient, then the Newton direction if that fails or
    settles too slowly), ``K = DESIGN_MARGIN loop_limit / (lambda_max (T + tau))`` at most the
    configuration's (``gamma = beta / (K - alpha)``), ``feedforward = 1`` against the lag, and
    the layer ``phi = LAYER_WIDTH u0 (T + tau) / M`` where that inner loop is :data:`CASCADE`
    times faster than ``K lambda_max``, else ``phi = u0 T / M`` (docs/THEORY.md, *Design*).
    ValueError when no direction has a K above alpha (the delay alone is too long).
    """
    T = 1.0 / control_rate
    eigs = design_hessian_spectrum(cfg) if spectrum is None else np.asarray(spectrum)
    tried = []
    # the gradient may give way to the Newton direction; the block direction never does
    # (the Newton direction costs O(n^3) per command, the block direction O(n))
    directions = (
        (cfg.precondition, 'newton') if cfg.precondition == 'none' else (cfg.precondition,)
    )
    for direction in directions:
        base = cfg.replace(precondition=direction)
        gains = _schedule(base, eigs, T, latency)
        if gains is None:
            continue
        tried.append(gains)
        tuned = base.replace(**gains, control_rate=control_rate, latency=latency)
        pred = predict(tuned, spectrum=eigs)
        if pred.holds and pred.settles:
            return gains
    if not tried:
        raise ValueError(
            f'no layer gain holds {cfg.n_trackers} trackers at '
            f'{control_rate:g} Hz with {latency * 1e3:g} ms latency: even '
            f'K = alpha = {cfg.alpha:g} is too fast; lower the latency'
        )
    return tried[-1]


def schedule_gains(
    cfg: SwarmConfig, *, latency: float, advice: Advice = PLAIN
) -> tuple[SwarmConfig, SampledPrediction, dict[str, Any] | None, list[str]]:
    """The configuration a realtime run flies at ``cfg.control_rate`` (> 0) with ``latency``:
    the prediction of ``cfg``; when it does not hold, :func:`propose_gains` replaces gamma,
    phi (and what they need) if the proposal predicts a smaller spectral radius or a smaller
    steady lag. Returns ``(cfg, prediction, gains or None, warnings)``; the warnings are the
    kept prediction's plus a failed proposal's reason (``advice``: their remedies' words)."""
    pred = predict(cfg, latency=latency, advice=advice)
    if pred.holds:
        return cfg, pred, None, list(pred.warnings)
    try:
        gains = propose_gains(cfg, control_rate=cfg.control_rate, latency=latency)
    except ValueError as exc:
        return cfg, pred, None, [*pred.warnings, str(exc)]
    tuned = cfg.replace(**gains)
    tuned_pred = predict(tuned, latency=latency, advice=advice)
    if (
        tuned_pred.spectral_radius < pred.spectral_radius
        or tuned_pred.steady_lag < pred.steady_lag
    ):
        return tuned, tuned_pred, dict(gains), list(tuned_pred.warnings)
    return cfg, pred, None, list(pred.warnings)


#: the sizes :func:`largest_holding` tries, as fractions of the size that fails
SMALLER_SIZES = (0.875, 0.75, 0.625, 0.5, 0.375, 0.25, 0.125)


def largest_holding(
    cfg: SwarmConfig, latency_of: Callable[[int], float]
) -> tuple[int, SampledPrediction, dict[str, Any]] | None:
    """The largest swarm, of :data:`SMALLER_SIZES` of ``cfg.n_trackers`` (at least 2, none
    the configuration refuses), whose :func:`schedule_gains` hold at ``cfg.control_rate`` with
    ``latency_of(n)`` [s] for n trackers: ``(n, prediction, gains or {})``, or None."""
    n = cfg.n_trackers
    for m in sorted({int(n * f) for f in SMALLER_SIZES if 2 <= int(n * f) < n}, reverse=True):
        try:
            smaller = cfg.replace(n_trackers=m)
        except ValueError:  # the configuration names a tracker beyond m (a per-UAV section)
            continue
        _, pred, gains, _ = schedule_gains(smaller, latency=latency_of(m))
        if pred.holds:
            return m, pred, dict(gains or {})
    return None
