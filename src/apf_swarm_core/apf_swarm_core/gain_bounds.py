"""The lower bounds on the switching gain u0 (Theorem 1 / eq. 29, eq. 37, eq. 43), as printed
(``-f_bar``) and corrected (``+f_bar/M_lo``; docs/THEORY.md, "Gain conditions"), a priori
(:func:`gain_bounds`) or from run data (:func:`gain_bounds_from_run`)."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from .config import SwarmConfig
from .gradients import gradient

__all__ = ['GainBound', 'gain_bounds', 'gain_bounds_from_run', 'pair_hessian_bound']


@dataclass(frozen=True)
class GainBound:
    """A lower bound on u0: the printed form and the corrected form, and whether u0 clears them."""

    name: str  # 'theorem1_eq29', 'eq37', 'eq43'
    regime: str  # which part of the law it covers
    printed: float  # bound as printed in the paper [N]
    corrected: float  # bound with +f_bar/M_lo [N]
    u0: float

    @property
    def holds_printed(self) -> bool:
        return self.u0 > self.printed

    @property
    def holds_corrected(self) -> bool:
        return self.u0 > self.corrected

    def as_dict(self) -> dict[str, Any]:
        return {
            **asdict(self),
            'holds_printed': self.holds_printed,
            'holds_corrected': self.holds_corrected,
        }


def pair_hessian_bound(a: float, b: float) -> float:
    """Bound on the spectral norm of the Hessian of one pair term of eq. 44: its
    eigenvalues ``a - b e^{-u}`` and ``a - b e^{-u}(1 - 2u)``, ``u = r^2/c``, lie in
    ``[a - b, a + 2b e^{-3/2}]``."""
    return max(abs(a - b), a + 2.0 * b * math.exp(-1.5))


def gain_bounds(
    cfg: SwarmConfig, *, j_bar: float | None = None, j_bar_s: float | None = None
) -> tuple[list[GainBound], dict[str, float]]:
    """The u0 bounds of eq. 29, 37 and 43 for ``cfg``, printed and corrected, and the
    estimates they use. Without ``j_bar`` / ``j_bar_s``, a priori: ``||d/dt grad_i J|| <= L V
    + k_N v_N`` with L = k_N + 2 (n-1) k_f :func:`pair_hessian_bound` and a speed bound V,
    ``alpha g0 + sqrt(3) beta`` outside the layer (g0 the largest initial gradient),
    ``alpha gamma + beta`` inside, times alpha for ``J_bar`` and alpha + beta/gamma for
    ``J_bar_s``; ``J_bar_sign = 2 beta / lambda`` (eq. 35)."""
    from .simulator import initial_positions

    n, vn = cfg.n_trackers, cfg.target_speed_bound
    lip = cfg.k_n + 2.0 * max(0, n - 1) * cfg.k_f * pair_hessian_bound(cfg.a, cfg.swarm_b())
    grad0 = gradient(
        initial_positions(cfg), np.asarray(cfg.target_start), **cfg.potential_params()
    )
    g0 = float(np.linalg.norm(grad0, axis=-1).max())
    if j_bar is None:
        j_bar = cfg.alpha * (lip * (cfg.alpha * g0 + math.sqrt(3.0) * cfg.beta) + cfg.k_n * vn)
    if j_bar_s is None:
        j_bar_s = (cfg.alpha + cfg.beta / cfg.gamma) * (
            lip * (cfg.alpha * cfg.gamma + cfg.beta) + cfg.k_n * vn
        )
    j_sign = 2.0 * cfg.beta / cfg.lambda_filter
    m_lo, m_hi, f = cfg.mass_lo, cfg.mass_hi, cfg.f_bar

    def bound(name: str, regime: str, m_printed: float, *terms: float) -> GainBound:
        """``M_hi (-f_bar/m_printed + terms)`` as printed, ``M_hi (f_bar/M_lo + terms)``
        corrected (the terms summed in the order given, as the equation writes them)."""
        printed, corrected = -f / m_printed, f / m_lo
        for term in terms:
            printed, corrected = printed + term, corrected + term
        return GainBound(name, regime, m_hi * printed, m_hi * corrected, cfg.u0)

    bounds = [
        bound(
            'theorem1_eq29',
            'outside the layer (and the traditional law)',
            m_lo,
            j_bar,
            j_sign,
            cfg.epsilon,
        ),
        bound('eq37', 'outside the layer, proof of Theorem 1', m_hi, j_sign, j_bar, cfg.epsilon),
        bound('eq43', 'inside the layer (proposed law only)', m_hi, j_bar_s, cfg.mu),
    ]
    return bounds, {
        'J_bar': j_bar,
        'J_bar_sign': j_sign,
        'J_bar_s': j_bar_s,
        'lipschitz_grad': lip,
        'initial_gradient_max': g0,
    }


def gain_bounds_from_run(
    cfg: SwarmConfig,
    t: ArrayLike,
    x: ArrayLike,
    target_x: ArrayLike,
    steady_fraction: float | None = None,
) -> tuple[list[GainBound], dict[str, float]]:
    """The u0 bounds with ``J_bar`` and ``J_bar_s`` measured along a run (``t`` (T,) [s],
    ``x`` (T, n, 3), ``target_x`` (T, 3) [m]) over its last ``steady_fraction`` (default
    ``cfg.steady_fraction``): with the rate ``||d/dt grad_i J||`` by first differences,
    ``J_bar = alpha max rate`` outside the boundary layer (eq. 29 / 37), ``J_bar_s = (alpha +
    beta/gamma) max rate`` inside it (eq. 43); 0 for a regime never visited."""
    frac = cfg.steady_fraction if steady_fraction is None else steady_fraction
    t = np.asarray(t, dtype=float)
    g = gradient(
        np.asarray(x, dtype=float), np.asarray(target_x, dtype=float), **cfg.potential_params()
    )
    start = min(len(t) - 2, int(len(t) * (1.0 - frac))) if len(t) > 1 else 0
    t, g = t[max(0, start) :], g[max(0, start) :]
    if len(t) < 2:
        return gain_bounds(cfg, j_bar=0.0, j_bar_s=0.0)
    rate = np.linalg.norm(np.diff(g, axis=0), axis=-1) / np.diff(t)[:, None]  # (T-1, n)
    outside = np.linalg.norm(g[:-1], axis=-1) >= cfg.gamma
    r_out = float(rate[outside].max()) if outside.any() else 0.0
    r_in = float(rate[~outside].max()) if (~outside).any() else 0.0
    bounds, est = gain_bounds(
        cfg, j_bar=cfg.alpha * r_out, j_bar_s=(cfg.alpha + cfg.beta / cfg.gamma) * r_in
    )
    est['fraction_inside_layer'] = float(np.mean(~outside))
    return bounds, est
