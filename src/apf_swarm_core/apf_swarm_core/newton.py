"""The saddle-free Newton preconditioner of the formation descent: the Hessian of J
(eq. 2 / 44) at a state, its eigen-decomposition shared by a process's trackers, and the
damped (Levenberg-Marquardt) direction with a trust radius."""

from __future__ import annotations

from typing import Unpack

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .gains import shaped
from .kernels import hessian_rows, kernel_args
from .potential import Gains, Rows, gain_values

__all__ = [
    'hessian',
    'hessian_blocks',
    'newton_basis',
    'newton_direction',
]


def hessian(
    x: ArrayLike, x_target: ArrayLike, **gains: Unpack[Gains[ArrayLike]]
) -> NDArray[np.float64]:
    """Hessian of J (eq. 2 / 44) with respect to the tracker positions, shape (..., 3n, 3n).

    Differentiating the gradient once more, with ``d = x_i - x_j``, ``r^2 = |d|^2`` and
    ``e = exp(-r^2/c)``, the pair (i, j) contributes the 3x3 block

    .. math::

        H_{ij} = k_f \\big[(a - b e) I + \\tfrac{2b}{c} e \\, d d^T\\big]

    to the diagonal blocks (i, i) and (j, j) and ``-H_ij`` to the blocks (i, j) and (j, i);
    the tracking term adds ``k_N I`` to every diagonal block. Row-major: entry
    ``(3i + k, 3j + l)`` is ``d^2 J / dx_ik dx_jl``; ``x_target`` does not enter it.

    Parameters
    ----------
    x : array, shape (..., n, 3) [m]
    x_target : array, shape (..., 3) [m]
    k_n, k_f, a, b, c : float or array (...) of per-run values (keywords; default
        :data:`~apf_swarm_core.potential.POTENTIAL_DEFAULTS`)
    """
    k_n, k_f, a, b, c = gain_values(gains)
    x = np.asarray(x, dtype=float)
    lead, n = x.shape[:-2], x.shape[-2]
    kf, ga, gb, gc = (shaped(v, 4) for v in (k_f, a, b, c))
    kn = shaped(k_n, 3)
    d = x[..., :, None, :] - x[..., None, :, :]  # (..., n, n, 3)
    e = np.exp(-np.einsum('...ijk,...ijk->...ij', d, d)[..., None, None] / gc)
    blocks = kf * (
        (ga - gb * e) * np.eye(3)
        + (2.0 * gb / gc) * e * d[..., :, :, :, None] * d[..., :, :, None, :]
    )
    idx = np.arange(n)
    blocks[..., idx, idx, :, :] = 0.0
    h = -blocks
    h[..., idx, idx, :, :] = blocks.sum(axis=-3) + kn * np.eye(3)
    return np.swapaxes(h, -3, -2).reshape((*lead, 3 * n, 3 * n))


def newton_basis(
    x: ArrayLike, x_target: ArrayLike, **gains: Unpack[Gains[ArrayLike]]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The eigendecomposition ``H = V diag(lambda) V^T`` of the :func:`hessian` at x that
    :func:`newton_direction` preconditions with: ``(lambda (..., 3n), V (..., 3n, 3n))``.

    Parameters
    ----------
    x : array (..., n, 3) [m]; x_target : array (..., 3) [m]
    k_n, k_f, a, b, c : gains of eq. 2 / 44 (keywords, as for :func:`hessian`)
    """
    w, v = np.linalg.eigh(hessian(x, x_target, **gains))
    return w, v


def _trust_floor(
    aw: NDArray[np.float64], coef: NDArray[np.float64], n: int, trust: float
) -> NDArray[np.float64]:
    """The floor mu at which the step's RMS per tracker is exactly ``trust``, solved exactly.

    With ``|lambda|`` sorted, between two consecutive ones the squared step is
    ``A_j + B_j / mu^2`` (``A_j``: the modes stiffer than mu, ``c^2 / lambda^2``; ``B_j``:
    the softer ones, ``c^2``), decreasing in mu, so ``n trust^2`` is met in one interval at
    ``mu = sqrt(B_j / (n trust^2 - A_j))``. Shapes: ``aw``, ``coef`` (..., 3n); out (...).
    """
    order = np.argsort(aw, axis=-1)
    lam = np.take_along_axis(aw, order, axis=-1)
    c2 = np.take_along_axis(coef * coef, order, axis=-1)
    lead = lam.shape[:-1]
    zero = np.zeros((*lead, 1))
    soft = np.concatenate([zero, np.cumsum(c2, axis=-1)], axis=-1)  # B_j, j = 0..3n
    with np.errstate(divide='ignore', invalid='ignore'):
        q = np.where(lam > 0.0, c2 / (lam * lam), np.inf)
        stiff = np.concatenate([np.cumsum(q[..., ::-1], axis=-1)[..., ::-1], zero], axis=-1)
        target = n * trust * trust
        mu = np.sqrt(soft / (target - stiff))
    lower = np.concatenate([zero, lam], axis=-1)
    upper = np.concatenate([lam, np.full((*lead, 1), np.inf)], axis=-1)
    ok = (stiff < target) & (mu >= lower * (1.0 - 1e-12)) & (mu <= upper * (1.0 + 1e-12))
    return np.max(np.where(ok, mu, 0.0), axis=-1)


def newton_direction(
    basis: tuple[ArrayLike, ArrayLike],
    grad: ArrayLike,
    *,
    mu: float,
    trust: float = 0.0,
    ceiling: ArrayLike = np.inf,
) -> NDArray[np.float64]:
    r"""The saddle-free Newton direction of J (not in the paper), shape of ``grad``.

    .. math::

        \delta = |H|_{\mu^*}^{-1} \nabla J, \qquad
        |H|_{\mu^*} = V \operatorname{diag}(\max(|\lambda_k|, \mu^*)) V^T

    with ``H = V diag(lambda) V^T`` from :func:`newton_basis` (Dauphin et al., NIPS 2014;
    docs/THEORY.md, Large swarms): every mode with ``lambda >= mu*`` descends at one rate,
    and ``|H|`` is positive definite, so delta vanishes exactly where the gradient does.
    Trust region (``trust`` > 0, Levenberg-Marquardt): ``mu* >= mu`` is the smallest floor
    for which the step's RMS per tracker, ``||delta|| / sqrt(n)``, is at most ``trust``, up
    to ``ceiling`` (:class:`~apf_swarm_core.control.Preconditioner` passes k_N, the
    centroid's curvature); ``trust`` = 0: ``mu* = mu``.

    Parameters
    ----------
    basis : (lambda (..., 3n), V (..., 3n, 3n)) of :func:`newton_basis`
    grad : array (..., n, 3): the gradient of J at the same positions
    mu : float > 0: the smallest curvature used (eigenvalues below it are raised to it)
    trust : float >= 0 [m]: the trust radius
    ceiling : float or array (...): the highest floor the trust region takes (>= mu)
    """
    w, v = (np.asarray(a, dtype=float) for a in basis)
    g = np.asarray(grad, dtype=float)
    n = g.shape[-2]
    coef = np.einsum('...ij,...i->...j', v, g.reshape((*g.shape[:-2], -1)))
    aw = np.abs(w)

    def rms(floor: NDArray[np.float64]) -> NDArray[np.float64]:
        return np.sqrt(np.sum((coef / np.maximum(aw, floor[..., None])) ** 2, axis=-1) / n)

    floor = np.full(coef.shape[:-1], float(mu))
    if trust > 0.0:
        too_long = rms(floor) > trust
        if too_long.any():
            top = np.maximum(np.asarray(ceiling, dtype=float), mu)
            floor = np.where(too_long, np.clip(_trust_floor(aw, coef, n, trust), mu, top), floor)
    step = coef / np.maximum(aw, floor[..., None])
    return np.einsum('...ij,...j->...i', v, step).reshape(g.shape)


def hessian_blocks(
    x: ArrayLike,
    *,
    rows: Rows = None,
    mask: ArrayLike | None = None,
    **gains: Unpack[Gains[ArrayLike]],
) -> NDArray[np.float64]:
    """The diagonal 3x3 blocks ``H_ii`` of the :func:`hessian` of the trackers in ``rows``,
    shape (..., m, 3, 3): each costs what the tracker's own gradient costs, O(n).

    .. math::

        H_{ii} = k_N I + k_f \\sum_{j \\in N_i} \\big[(a - b e_{ij}) I
            + \\tfrac{2b}{c} e_{ij} \\, d_{ij} d_{ij}^T\\big]

    with ``d_ij = x_i - x_j`` and ``e_ij = exp(-|d_ij|^2/c)``; ``N_i`` every other tracker,
    or the row's neighbours in ``mask`` (shape (..., m, n), as for
    :func:`~apf_swarm_core.gradients.gradient`).

    Parameters
    ----------
    x : array (..., n, 3) [m]
    rows : the trackers whose block is wanted (default all)
    mask : bool array (..., m, n), optional
    k_n, k_f, a, b, c : gains of eq. 2 / 44 (floats or arrays (...); default
        :data:`~apf_swarm_core.potential.POTENTIAL_DEFAULTS`)
    """
    args = kernel_args(x, None, gain_values(gains), rows, mask)
    out = hessian_rows(args.x, args.rows, args.mask, args.gains)
    return out.reshape((*args.shape, 3, 3))
