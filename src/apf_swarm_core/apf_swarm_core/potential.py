"""The artificial potential of the paper (eq. 2 with the choice of eq. 44) and its gradients.

.. math::

    J = k_N \\sum_i \\tfrac12\\|x_i - x_N\\|^2
        + k_f \\sum_{i<j} \\Big[\\tfrac a2 \\|x_i - x_j\\|^2
        + \\tfrac{bc}{2} e^{-\\|x_i - x_j\\|^2 / c}\\Big]

The extracted text of eq. 44 lost the ``exp``; the form above is the Gazi--Passino
attraction/repulsion function the paper cites. Positions are in metres; with unit gains
``J`` is in m^2 and its gradient in m.

All functions accept optional leading batch dimensions: ``x`` of shape ``(..., n, 3)`` and
``x_target`` of shape ``(..., 3)``. Gains may be Python floats or arrays of shape ``(...)``
broadcastable against the batch shape (one value per run of a batch).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ['pair_weight', 'potential', 'gradient', 'target_gradient']


def _gain(value: ArrayLike, extra_dims: int) -> NDArray[np.float64] | float:
    """Reshape a scalar or per-run gain of shape ``(...)`` to broadcast over ``extra_dims``."""
    if type(value) is float:
        return value
    arr = np.asarray(value, dtype=float)
    if arr.ndim == 0:
        return float(arr)
    return arr.reshape(arr.shape + (1,) * extra_dims)


def pair_weight(r2: ArrayLike, a: ArrayLike, b: ArrayLike, c: ArrayLike) -> NDArray[np.float64]:
    """Attraction/repulsion weight of a pair, ``a - b exp(-r^2/c)`` (derivative of eq. 44).

    The pair force on agent i from agent j is ``-(x_i - x_j) * pair_weight``: positive values
    attract, negative values repel. With ``b <= a`` the weight is positive for every ``r``,
    i.e. the pair term never repels (SPEC section 2, fact 1).

    Parameters
    ----------
    r2 : array, shape (..., n, n)
        Squared pair distances [m^2].
    a, b, c : float or array of shape (...)
        Potential parameters (a, b dimensionless, c in m^2).
    """
    r2 = np.asarray(r2, dtype=float)
    return _gain(a, 2) - _gain(b, 2) * np.exp(-r2 / _gain(c, 2))


def _pair_geometry(x: NDArray[np.float64], rows: ArrayLike | None):
    """Differences ``x_i - x_j`` (..., m, n, 3) and squared distances (..., m, n)."""
    xi = x if rows is None else x[..., rows, :]
    diff = xi[..., :, None, :] - x[..., None, :, :]
    r2 = np.einsum('...k,...k->...', diff, diff)
    return diff, r2


def potential(x: ArrayLike, x_target: ArrayLike, *, k_n: ArrayLike = 1.0,
              k_f: ArrayLike = 1.0, a: ArrayLike = 1.0, b: ArrayLike = 6.0,
              c: ArrayLike = 1.7, mask: ArrayLike | None = None) -> NDArray[np.float64]:
    """Potential J of the whole swarm, paper eq. 2 with eq. 44.

    Parameters
    ----------
    x : array, shape (..., n, 3)
        Tracker positions x_i [m].
    x_target : array, shape (..., 3)
        Target position x_N [m].
    k_n, k_f : float or array (...)
        Weights of the tracking term and of the formation term.
    a, b, c : float or array (...)
        Pair-potential parameters of eq. 44.
    mask : bool array, shape (..., n, n), optional
        Symmetric neighbour mask: pair (i, j) contributes only where ``mask[i, j]``.
        ``None`` means every pair (the paper's all-to-all potential).

    Returns
    -------
    J : array, shape (...)
        The potential [m^2 with unit gains].
    """
    x = np.asarray(x, dtype=float)
    x_target = np.asarray(x_target, dtype=float)
    rel = x - x_target[..., None, :]
    track = 0.5 * np.einsum('...ik,...ik->...', rel, rel)
    _, r2 = _pair_geometry(x, None)
    pair = 0.5 * _gain(a, 2) * r2 + 0.5 * _gain(b, 2) * _gain(c, 2) * np.exp(-r2 / _gain(c, 2))
    n = x.shape[-2]
    offdiag = ~np.eye(n, dtype=bool)
    if mask is not None:
        offdiag = offdiag & np.asarray(mask, dtype=bool)
    # each unordered pair appears twice in the full (n, n) matrix
    form = 0.5 * np.sum(np.where(offdiag, pair, 0.0), axis=(-2, -1))
    return _gain(k_n, 0) * track + _gain(k_f, 0) * form


def gradient(x: ArrayLike, x_target: ArrayLike, *, k_n: ArrayLike = 1.0, k_f: ArrayLike = 1.0,
             a: ArrayLike = 1.0, b: ArrayLike = 6.0, c: ArrayLike = 1.7,
             rows: ArrayLike | None = None, mask: ArrayLike | None = None) -> NDArray[np.float64]:
    """Analytic gradient of J with respect to the trackers (from eq. 2 / 44).

    .. math::

        \\nabla_{x_i} J = k_N (x_i - x_N)
            + k_f \\sum_{j \\ne i} (x_i - x_j)\\,(a - b\\,e^{-\\|x_i - x_j\\|^2/c})

    Vectorized over pairs; no Python loop over agents. A tracker node that knows its own
    position and its neighbours' evaluates its own row with ``rows=[i]``: the same function,
    the same arithmetic, as the simulator that evaluates all rows.

    Parameters
    ----------
    x : array, shape (..., n, 3)
        Tracker positions [m].
    x_target : array, shape (..., 3)
        Target position [m].
    k_n, k_f, a, b, c : float or array (...)
        Gains and pair parameters of eq. 44.
    rows : index array, optional
        Trackers whose gradient is wanted (default: all ``n``).
    mask : bool array, shape (..., m, n), optional
        Neighbour mask for the selected rows: ``mask[i, j]`` says whether j is a neighbour of
        row i. ``None`` means all trackers (the paper's potential).

    Returns
    -------
    grad : array, shape (..., m, 3)
        ``m = n`` or ``len(rows)``; units m with unit gains.
    """
    x = np.asarray(x, dtype=float)
    x_target = np.asarray(x_target, dtype=float)
    diff, r2 = _pair_geometry(x, rows)
    w = pair_weight(r2, a, b, c)
    if mask is not None:
        w = np.where(mask, w, 0.0)
    # the self pair has diff == 0, so it contributes nothing whatever its weight
    pair = np.einsum('...ij,...ijk->...ik', w, diff)
    xi = x if rows is None else x[..., rows, :]
    return _gain(k_n, 2) * (xi - x_target[..., None, :]) + _gain(k_f, 2) * pair


def target_gradient(x: ArrayLike, x_target: ArrayLike, *,
                    k_n: ArrayLike = 1.0) -> NDArray[np.float64]:
    """Gradient of J with respect to the target, ``-k_N sum_i (x_i - x_N)`` (eq. 6, 17).

    Parameters
    ----------
    x : array, shape (..., n, 3)
    x_target : array, shape (..., 3)

    Returns
    -------
    grad_N : array, shape (..., 3)
    """
    x = np.asarray(x, dtype=float)
    x_target = np.asarray(x_target, dtype=float)
    return -_gain(k_n, 1) * np.sum(x - x_target[..., None, :], axis=-2)
