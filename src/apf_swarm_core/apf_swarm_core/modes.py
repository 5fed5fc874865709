"""The linear model of the formation under sampled, delayed control: near the design and
inside the boundary layer the swarm splits into the Hessian's modes, each a double integrator
under a held, delayed command; :func:`mode_matrix` is one mode's transition over a control
period. Derivation: docs/THEORY.md, "Sampled-data control"; the verdict on a configuration
is :mod:`apf_swarm_core.sampled`'s.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .config import SwarmConfig
from .formation import design_formation
from .metrics import formation_error, pair_distances
from .newton import hessian, hessian_blocks

__all__ = [
    'centroid_curvature',
    'design_block_spectrum',
    'design_hessian_spectrum',
    'effective_spectrum',
    'inner_rate',
    'loop_modes',
    'mode_matrix',
    'mode_radius',
    'start_residual',
]


def _hold(h: float, mass: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Exact double-integrator step over h seconds with a held force: (Phi, Gamma)."""
    return np.array([[1.0, h], [0.0, 1.0]]), np.array([h * h / (2.0 * mass), h / mass])


def mode_matrix(
    lam: float,
    *,
    layer_gain: float,
    inner_rate: float,
    period: float,
    latency: float,
    mass: float = 1.0,
    horizon: float = 0.0,
) -> NDArray[np.float64]:
    """Transition matrix, shape (3 + m, 3 + m), of one formation mode over one control
    period T = ``period`` [s] with ``latency`` tau = m T + r [s].

    State ``(e_k, e'_k, u_{k-1}, ..., u_{k-m-1})``; the command of sample k is
    ``u_k = -g M (e'_k + K lambda e_k)`` with ``lam`` lambda an eigenvalue of the Hessian of
    J, ``layer_gain`` K = alpha + beta/gamma [1/s], ``inner_rate`` g [1/s] (:func:`inner_rate`)
    and ``mass`` M [kg]; with delay compensation (``horizon`` h > 0 [s],
    :mod:`apf_swarm_core.compensation`) the same of the predicted state ``e_k + h e'_k`` and
    ``e'_k + h u_{k-1} / M``.
    """
    T, tau = float(period), float(latency)
    m = int(math.floor(tau / T + 1e-12))
    r = tau - m * T
    size = 3 + m
    A = np.zeros((size, size))
    gain = -inner_rate * mass * np.array([layer_gain * lam, 1.0])  # u_k = gain . (e, e')
    h = float(horizon)
    # the predicted state (e + h e', e' + h u_{k-1} / M): u_k = gain . pred . (e, e') + held
    # u_{k-1} (slot 2)
    held = gain[1] * h / mass
    gain = np.array([gain[0], gain[0] * h + gain[1]])
    phi_T, _ = _hold(T, mass)
    phi_rest, gam_rest = _hold(T - r, mass)
    _, gam_r = _hold(r, mass)
    # the command of sample k - m - 1 for r seconds, then that of k - m for T - r
    early = phi_rest @ gam_r  # effect of u_{k-m-1}
    late = gam_rest  # effect of u_{k-m}
    A[:2, :2] = phi_T
    # index of u_{k-j} in the state: 1 + j (j = 1 .. m + 1); u_k itself is a function of x_k
    if m == 0:
        A[:2, :2] += np.outer(late, gain)  # u_k acts after r
        A[:2, 2] += late * held
    else:
        A[:2, 1 + m] += late  # u_{k-m}
    A[:2, 2 + m] += early  # u_{k-m-1}
    # shift the history: new u_{k} enters slot 2 (u_{(k+1)-1}), u_{k-j} moves to slot 2 + j
    A[2, :2] = gain
    A[2, 2] += held
    for j in range(3, size):
        A[j, j - 1] = 1.0
    return A


def mode_radius(lam: float, **kwargs: Any) -> float:
    """Spectral radius of :func:`mode_matrix`: the mode's decay per period (< 1: stable)."""
    return float(np.max(np.abs(np.linalg.eigvals(mode_matrix(lam, **kwargs)))))


def _design(cfg: SwarmConfig) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The design equilibrium's positions (n, 3) and the Hessian of J there (3n, 3n)."""
    x = design_formation(cfg).relative_positions
    return x, hessian(x, np.zeros(3), **cfg.potential_params())


def design_hessian_spectrum(cfg: SwarmConfig) -> NDArray[np.float64]:
    """Eigenvalues of the Hessian of J at the design equilibrium of ``cfg.n_trackers``
    trackers, ascending (the rotations' zeros included); shape (3n,)."""
    return np.linalg.eigvalsh(_design(cfg)[1]).astype(np.float64, copy=False)


def effective_spectrum(cfg: SwarmConfig, eigs: NDArray[np.float64]) -> NDArray[np.float64]:
    """The curvatures the manifold descends, ascending, for ``cfg.precondition``: the
    Hessian's eigenvalues ``lambda`` (``eigs``) along the gradient, ``lambda / max(|lambda|,
    mu)`` along the Newton direction, :func:`design_block_spectrum` along the block one."""
    eigs = np.asarray(eigs, dtype=float)
    if cfg.precondition == 'block':
        return design_block_spectrum(cfg)
    if cfg.precondition != 'newton':
        return eigs
    return eigs / np.maximum(np.abs(eigs), cfg.newton_mu)


def centroid_curvature(cfg: SwarmConfig) -> float:
    """The curvature the manifold descends along the centroid's mode: k_N along the
    gradient, 1 along the Newton and the block directions (both take it exactly)."""
    return cfg.k_n if cfg.precondition == 'none' else 1.0


def _block_map(cfg: SwarmConfig, x: NDArray[np.float64]) -> NDArray[np.float64]:
    """P of :func:`design_block_spectrum` at positions ``x`` (n, 3) relative to the target:
    each tracker's ``|H_ii|_mu^-1`` on the gradient less its mean, plus the mean over k_N;
    shape (3n, 3n)."""
    params = cfg.potential_params()
    n = x.shape[0]
    w, v = np.linalg.eigh(hessian_blocks(x, **params))
    inv = np.einsum('ikj,ij,ilj->ikl', v, 1.0 / np.maximum(np.abs(w), cfg.newton_mu), v)
    p = np.zeros((3 * n, 3 * n))
    for i in range(n):
        p[3 * i : 3 * i + 3, 3 * i : 3 * i + 3] = inv[i]
    mean = np.kron(np.full((n, n), 1.0 / n), np.eye(3))
    return np.asarray(mean / params['k_n'] + p @ (np.eye(3 * n) - mean))


def design_block_spectrum(cfg: SwarmConfig) -> NDArray[np.float64]:
    """Eigenvalues of ``P H`` at the design equilibrium, ascending (shape (3n,), the
    rotations' zeros included): H the Hessian of J, P the linear map of
    :class:`~apf_swarm_core.control.BlockPreconditioner` there (:func:`_block_map`); each,
    real (P is symmetric positive definite), is a formation mode's decay rate in units of K."""
    x, h = _design(cfg)
    return np.sort(np.linalg.eigvals(_block_map(cfg, x) @ h).real)


def loop_modes(cfg: SwarmConfig) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The modes of the formation's loop ``e' = -K A e`` near the design (with the
    configuration's direction: A = H along the gradient, ``|H|_mu^-1 H`` along the Newton
    direction, ``P H`` along the block direction): their rates in units of K, shape (3n,),
    and their shapes, the columns of a (3n, 3n) array (tracker-major, as ``e.ravel()``)."""
    x, h = _design(cfg)
    if cfg.precondition == 'block':
        rates, shapes = np.linalg.eig(_block_map(cfg, x) @ h)
        return rates.real, shapes.real
    lam, shapes = np.linalg.eigh(h)
    return effective_spectrum(cfg, lam), shapes


def start_residual(
    cfg: SwarmConfig, displacement: NDArray[np.float64], K: float, t: float
) -> tuple[float, float]:
    """What the loop of :func:`loop_modes` leaves at ``t`` [s] of a start displaced by
    ``displacement`` (n, 3) [m] from the design, each mode decaying as ``exp(-K rate t)``:
    the formation error RMS over the design's mean pair distance and the closest pair over
    the design's (docs/THEORY.md, *The start*)."""
    x = design_formation(cfg).relative_positions
    rates, shapes = loop_modes(cfg)
    share = np.linalg.lstsq(shapes, np.asarray(displacement, dtype=float).ravel(), rcond=None)[0]
    moving = rates > 1e-9 * rates.max()
    left = shapes[:, moving] @ (share[moving] * np.exp(-K * rates[moving] * t))
    design = pair_distances(x)
    now = x + left.reshape(x.shape)
    return (
        float(formation_error(now, design)) / float(design.mean()),
        float(pair_distances(now).min()) / float(design.min()),
    )


def inner_rate(cfg: SwarmConfig, period: float, mass: float) -> float:
    """The inner loop's rate g [1/s]: ``u0 / (phi M)`` for the boundary layer,
    ``1 / T`` for the sign law."""
    return cfg.u0 / (cfg.phi * mass) if cfg.switching == 'layer' else 1.0 / period
