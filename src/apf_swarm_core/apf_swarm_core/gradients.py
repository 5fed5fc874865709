"""The gradients of J (eq. 2 / 44): with respect to the trackers (:func:`gradient`, the hot
path of the simulator and the nodes, a compiled kernel) and to bodies that only repel
(:func:`obstacle_gradient`).

Shapes and gains as in :mod:`apf_swarm_core.potential`: ``x`` of shape ``(..., n, 3)``,
``x_target`` of shape ``(..., 3)``, gains floats or arrays of shape ``(...)`` (one value per
run of a batch).
"""

from __future__ import annotations

from typing import Unpack

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .kernels import gradient_rows, kernel_args
from .potential import POTENTIAL_DEFAULTS, Gains, Rows, gain_values, pair_weight

__all__ = ['gradient', 'obstacle_gradient']


def gradient(
    x: ArrayLike,
    x_target: ArrayLike,
    *,
    rows: Rows = None,
    mask: ArrayLike | None = None,
    **gains: Unpack[Gains[ArrayLike]],
) -> NDArray[np.float64]:
    """Analytic gradient of J with respect to the trackers (from eq. 2 / 44).

    .. math::

        \\nabla_{x_i} J = k_N (x_i - x_N)
            + k_f \\sum_{j \\ne i} (x_i - x_j)\\,(a - b\\,e^{-\\|x_i - x_j\\|^2/c})

    The compiled kernel :func:`~apf_swarm_core.kernels.gradient_rows` computes each row on
    its own, so ``gradient(x, ..., rows=[i])`` (a tracker node) equals row i of
    ``gradient(x, ...)`` (the simulator) bit for bit, and a run in a batch the run alone.

    Parameters
    ----------
    x : array, shape (..., n, 3)
        Tracker positions [m].
    x_target : array, shape (..., 3)
        Target position [m].
    rows : index array, optional
        Trackers whose gradient is wanted (default: all ``n``).
    mask : bool array, shape (..., m, n), optional
        Neighbour mask for the selected rows: ``mask[i, j]`` says whether j is a neighbour of
        row i. ``None`` means all trackers (the paper's potential).
    k_n, k_f, a, b, c : float or array (...)
        Gains and pair parameters of eq. 44 (default
        :data:`~apf_swarm_core.potential.POTENTIAL_DEFAULTS`).

    Returns
    -------
    grad : array, shape (..., m, 3)
        ``m = n`` or ``len(rows)``; units m with unit gains.
    """
    args = kernel_args(x, x_target, gain_values(gains), rows, mask)
    out = gradient_rows(args.x, args.tx, args.rows, args.mask, args.gains)
    return out.reshape((*args.shape, 3))


def obstacle_gradient(
    x: ArrayLike,
    obstacles: ArrayLike,
    *,
    k_f: ArrayLike = POTENTIAL_DEFAULTS['k_f'],
    b: ArrayLike = POTENTIAL_DEFAULTS['b'],
    c: ArrayLike = POTENTIAL_DEFAULTS['c'],
) -> NDArray[np.float64]:
    """Gradient of the repulsive half of the pair term of eq. 44 with respect to ``x``,
    from bodies that repel but do not attract (not in the paper; used for a tracker whose
    controller is silent, see :mod:`apf_swarm_core.agents`).

    .. math::

        \\nabla_{x_i} \\, k_f \\sum_o \\tfrac{bc}{2} e^{-\\|x_i - x_o\\|^2/c}
            = k_f \\sum_o (x_i - x_o)\\,(0 - b\\,e^{-\\|x_i - x_o\\|^2/c})

    i.e. :func:`pair_weight` with ``a = 0``.

    Parameters
    ----------
    x : array, shape (m, 3)
        Positions whose gradient is wanted [m].
    obstacles : array, shape (k, 3)
        Positions of the repelling bodies [m] (k may be 0).
    k_f, b, c : float
        Formation weight and the repulsion parameters of eq. 44.

    Returns
    -------
    array, shape (m, 3) [m with unit gains]
    """
    x = np.asarray(x, dtype=float)
    obstacles = np.asarray(obstacles, dtype=float).reshape(-1, 3)
    d = x[:, None, :] - obstacles[None, :, :]
    w = pair_weight(np.einsum('mok,mok->mo', d, d), 0.0, b, c)
    return float(np.asarray(k_f)) * np.einsum('mok,mo->mk', d, w)
