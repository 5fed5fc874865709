"""Neighbour rules beside the paper's all-to-all potential: which trackers enter each
tracker's pair term (the ``k`` nearest, or those within a radius), as the mask
:func:`~apf_swarm_core.gradients.gradient` takes."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .potential import Rows

__all__ = ['NEIGHBOUR_RULES', 'neighbour_mask']


#: how a tracker picks the trackers of its formation term (:func:`neighbour_mask`)
NEIGHBOUR_RULES = ('all', 'nearest', 'radius')


def neighbour_mask(
    x: ArrayLike, *, rule: str, count: int = 2, radius: float = 5.0, rows: Rows = None
) -> NDArray[np.bool_]:
    """Which trackers enter each selected tracker's formation term (not in the paper).

    ``rule = 'nearest'``: the ``count`` nearest other trackers (ties broken by the lower
    index); ``'radius'``: every other tracker closer than ``radius``; ``'all'``: every other
    tracker (the paper's eq. 2). The relation need not be symmetric (i may see j while j does
    not see i): each tracker then descends its own local potential
    ``J_i = k_N/2 |x_i - x_N|^2 + k_f sum_{j in N_i} [a/2 r_ij^2 + b c/2 exp(-r_ij^2/c)]``,
    whose gradient with respect to ``x_i`` is row i of :func:`gradient` with this mask.
    A tracker's own entry is False.

    Parameters
    ----------
    x : array, shape (..., n, 3)
        Positions of every tracker [m].
    rule, count, radius
        See above; ``radius`` in m.
    rows : index array, optional
        The trackers whose neighbour sets are wanted (default all).

    Returns
    -------
    mask : bool array, shape (..., m, n)
        The ``mask`` argument of :func:`gradient` for the same ``rows``.
    """
    if rule not in NEIGHBOUR_RULES:
        raise ValueError(f'neighbours must be one of {NEIGHBOUR_RULES}, got {rule!r}')
    x = np.asarray(x, dtype=float)
    n = x.shape[-2]
    index = np.arange(n) if rows is None else np.arange(n)[rows].reshape(-1)
    xi = x[..., index, :]
    d = xi[..., :, None, :] - x[..., None, :, :]
    r2 = np.einsum('...k,...k->...', d, d)  # (..., m, n)
    own = index[:, None] == np.arange(n)[None, :]
    if rule == 'all':
        return np.broadcast_to(~own, r2.shape).copy()
    if rule == 'radius':
        return (r2 < float(radius) ** 2) & ~own
    k = min(int(count), n - 1)
    r2 = np.where(own, np.inf, r2)
    order = np.argsort(r2, axis=-1, kind='stable')[..., :k]  # stable: lower index on ties
    mask = np.zeros(r2.shape, dtype=bool)
    np.put_along_axis(mask, order, True, axis=-1)
    return mask
