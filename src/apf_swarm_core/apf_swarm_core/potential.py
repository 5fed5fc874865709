"""The artificial potential of the paper (eq. 2 with the choice of eq. 44): J, its gains, and
the pair weight every gradient of J is made of.

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

The gradients of J, the simulator's hot path among them, are in :mod:`apf_swarm_core.gradients`.
"""

from __future__ import annotations

from typing import Any, Generic, TypeAlias, TypedDict, TypeVar, Unpack

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .gains import shaped

__all__ = [
    'POTENTIAL_DEFAULTS',
    'POTENTIAL_KEYS',
    'Gains',
    'PotentialParams',
    'Rows',
    'gain_values',
    'pair_weight',
    'potential',
]


class PotentialParams(TypedDict):
    """The gains and shape of J (eq. 2 / 44), all five: the :class:`Gains` keywords of
    :func:`potential` and :func:`~apf_swarm_core.gradients.gradient` (a batch passes arrays
    of per-run values in their place, see :class:`~apf_swarm_core.simulator.BatchSimulator`)."""

    k_n: float
    k_f: float
    a: float
    b: float
    c: float


#: the configuration keys of J's gains and shape, in the order of :class:`PotentialParams`
POTENTIAL_KEYS: tuple[str, ...] = tuple(PotentialParams.__annotations__)

#: the gains and shape of J where a caller gives none (the paper's simulation, eq. 44)
POTENTIAL_DEFAULTS: PotentialParams = {'k_n': 1.0, 'k_f': 1.0, 'a': 1.0, 'b': 6.0, 'c': 1.7}

_V = TypeVar('_V')


class Gains(TypedDict, Generic[_V], total=False):
    """The keyword arguments ``k_n, k_f, a, b, c`` of the functions of J (:func:`potential`,
    :func:`~apf_swarm_core.gradients.gradient`, :mod:`~apf_swarm_core.newton`,
    :mod:`~apf_swarm_core.design`), each of type ``_V`` (floats, or arrays of per-run values
    of shape ``(...)``) and :data:`POTENTIAL_DEFAULTS` where absent: read them with
    :func:`gain_values`."""

    k_n: _V
    k_f: _V
    a: _V
    b: _V
    c: _V


def gain_values(gains: Gains[_V]) -> tuple[_V | float, ...]:
    """``(k_n, k_f, a, b, c)`` of the keywords ``gains``, :data:`POTENTIAL_DEFAULTS` for each
    one absent; TypeError for a keyword that is none of them (a misspelt gain)."""
    g: Gains[_V | float] = {**POTENTIAL_DEFAULTS, **gains}
    if len(g) != len(POTENTIAL_DEFAULTS):
        raise TypeError(f'unexpected gain(s) {sorted(g.keys() - POTENTIAL_DEFAULTS.keys())}')
    return g['k_n'], g['k_f'], g['a'], g['b'], g['c']


#: which trackers' rows a function computes: all (None), an index array, a list or a slice
Rows: TypeAlias = 'NDArray[np.integer[Any]] | list[int] | slice | int | None'


def pair_weight(r2: ArrayLike, a: ArrayLike, b: ArrayLike, c: ArrayLike) -> NDArray[np.float64]:
    """Attraction/repulsion weight of a pair, ``a - b exp(-r^2/c)`` (derivative of eq. 44).

    The pair force on agent i from agent j is ``-(x_i - x_j) * pair_weight``: positive values
    attract, negative values repel. With ``b <= a`` the weight is positive for every ``r``,
    i.e. the pair term never repels (docs/THEORY.md section 2).

    Parameters
    ----------
    r2 : array, shape (..., n, n)
        Squared pair distances [m^2].
    a, b, c : float or array of shape (...)
        Potential parameters (a, b dimensionless, c in m^2).
    """
    r2 = np.asarray(r2, dtype=float)
    return shaped(a, 2) - shaped(b, 2) * np.exp(r2 / -shaped(c, 2))


def potential(
    x: ArrayLike,
    x_target: ArrayLike,
    *,
    mask: ArrayLike | None = None,
    **gains: Unpack[Gains[ArrayLike]],
) -> NDArray[np.float64]:
    """Potential J of the whole swarm, paper eq. 2 with eq. 44.

    Parameters
    ----------
    x : array, shape (..., n, 3)
        Tracker positions x_i [m].
    x_target : array, shape (..., 3)
        Target position x_N [m].
    mask : bool array, shape (..., n, n), optional
        Symmetric neighbour mask: pair (i, j) contributes only where ``mask[i, j]``.
        ``None`` means every pair (the paper's all-to-all potential).
    k_n, k_f : float or array (...)
        Weights of the tracking term and of the formation term (:class:`Gains`; default
        :data:`POTENTIAL_DEFAULTS`).
    a, b, c : float or array (...)
        Pair-potential parameters of eq. 44.

    Returns
    -------
    J : array, shape (...)
        The potential [m^2 with unit gains].
    """
    k_n, k_f, a, b, c = gain_values(gains)
    x = np.asarray(x, dtype=float)
    x_target = np.asarray(x_target, dtype=float)
    rel = x - x_target[..., None, :]
    track = 0.5 * np.einsum('...ik,...ik->...', rel, rel)
    d = x[..., :, None, :] - x[..., None, :, :]
    r2 = np.einsum('...k,...k->...', d, d)
    pair = 0.5 * shaped(a, 2) * r2 + 0.5 * shaped(b, 2) * shaped(c, 2) * np.exp(-r2 / shaped(c, 2))
    offdiag = ~np.eye(x.shape[-2], dtype=bool)
    if mask is not None:
        offdiag = offdiag & np.asarray(mask, dtype=bool)
    # each unordered pair appears twice in the full (n, n) matrix
    form = 0.5 * np.sum(np.where(offdiag, pair, 0.0), axis=(-2, -1))
    return shaped(k_n, 0) * track + shaped(k_f, 0) * form
