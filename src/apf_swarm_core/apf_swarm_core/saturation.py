"""Switching functions: ``sign`` and the saturation of eq. 8 with its continuous variant.

Vectors are the last axis (length 3) of arrays of shape ``(..., 3)``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .gains import shaped

__all__ = ['SATURATIONS', 'outside_layer', 'sat', 'sat_continuous', 'saturate', 'sign']

SATURATIONS = ('paper', 'continuous')


def _sq_norm(g: NDArray[np.float64]) -> NDArray[np.float64]:
    """Squared Euclidean norm over the last axis, the very arithmetic of
    ``np.linalg.norm(g, axis=-1)`` before its square root (``add.reduce(g * g)``).

    numpy reduces fewer than 8 elements left to right, so for 3-vectors of many rows the sum
    is written out as ``(g0^2 + g1^2) + g2^2``: the same value, with long inner loops instead
    of one reduction of length 3 per row (a few rows: the one reduction, fewer numpy calls).
    """
    sq = g * g
    if sq.size <= 96 or g.shape[-1] != 3:
        return np.add.reduce(sq, axis=-1)
    n2 = sq[..., 0] + sq[..., 1]
    n2 += sq[..., 2]
    return n2


def _norm(g: NDArray[np.float64]) -> NDArray[np.float64]:
    """Euclidean norm over the last axis, as ``np.linalg.norm(g, axis=-1)`` computes it
    (``sqrt(add.reduce(g * g))``) without its overhead."""
    n2 = _sq_norm(g)
    return np.sqrt(n2, n2) if type(n2) is np.ndarray else np.sqrt(n2)


def _layer_bound(gamma: ArrayLike) -> NDArray[np.float64]:
    """The smallest double ``q`` with ``sqrt(q) >= gamma``, elementwise (``-inf`` for
    ``gamma < 0``, NaN for NaN): ``||g|| >= gamma`` holds exactly when
    ``||g||^2 >= q``, so the layer test needs no square root per step.

    Exact, not approximate: float64 ``sqrt`` is correctly rounded, hence non-decreasing, so
    the ``q`` with ``sqrt(q) >= gamma`` form the interval ``[bound, inf)``; ``gamma^2``
    rounded is within an ulp or two of its lower end, which the loops below step to with
    ``nextafter``, testing with ``np.sqrt`` itself.
    """
    g = np.asarray(gamma, dtype=float)
    with np.errstate(invalid='ignore', over='ignore'):  # sqrt of a negative is NaN: fails
        q = np.where(g < 0, -np.inf, g * g)
        while True:  # up while sqrt(q) < gamma
            low = np.sqrt(q) < g
            if not np.any(low):
                break
            q = np.where(low, np.nextafter(q, np.inf), q)
        while True:  # down while the double below still passes
            below = np.nextafter(q, -np.inf)
            ok = (np.sqrt(below) >= g) & (g >= 0)
            if not np.any(ok):
                break
            q = np.where(ok, below, q)
    return q


def _outside(g: NDArray[np.float64], bound: NDArray[np.float64]) -> NDArray[np.bool_]:
    """Boundary-layer test of eq. 8, ``||g|| >= gamma``, with ``bound`` =
    ``_layer_bound(shaped(gamma, 1))``: the same answer for every g as comparing the norm."""
    return _sq_norm(g) >= bound


def sign(g: ArrayLike) -> NDArray[np.float64]:
    """Componentwise sign, with ``sign(0) = 0`` (the convention of eq. 8, 24 and 26)."""
    return np.sign(np.asarray(g, dtype=float))


def outside_layer(g: ArrayLike, gamma: ArrayLike) -> NDArray[np.bool_]:
    """``True`` where ``||g|| >= gamma``: outside the boundary layer of eq. 8.

    Parameters
    ----------
    g : array, shape (..., m, 3)
    gamma : float or array (...) of per-run layer thicknesses (same units as g)

    Returns
    -------
    array of bool, shape (..., m)
    """
    return _outside(np.asarray(g, dtype=float), _layer_bound(shaped(gamma, 1)))


def sat(g: ArrayLike, gamma: ArrayLike) -> NDArray[np.float64]:
    """Saturation of paper eq. 8, exactly as printed.

    .. math::

        \\mathrm{sat}(g, \\gamma) = \\begin{cases}
            \\mathrm{sign}(g) & \\|g\\| \\ge \\gamma \\\\
            g / \\gamma & \\|g\\| < \\gamma \\end{cases}

    ``sign`` is componentwise, so the function jumps at ``||g|| = gamma`` (from ``g/gamma``, of
    norm just under 1, to a vector of +-1 entries of norm up to sqrt(3)).

    Parameters
    ----------
    g : array, shape (..., m, 3)
        Gradients, one row per tracker.
    gamma : float or array (...)
        Boundary-layer thickness, > 0.

    Returns
    -------
    array, shape (..., m, 3)
    """
    g = np.asarray(g, dtype=float)
    out = outside_layer(g, gamma)[..., None]
    return np.where(out, np.sign(g), g / shaped(gamma))


def sat_continuous(g: ArrayLike, gamma: ArrayLike) -> NDArray[np.float64]:
    """Continuous saturation ``g / max(||g||, gamma)`` (not in the paper;
    docs/THEORY.md section 1).

    Equal to eq. 8 inside the layer; outside it is the unit vector ``g/||g||`` instead of the
    componentwise sign, so the function is continuous everywhere.
    """
    g = np.asarray(g, dtype=float)
    return g / np.maximum(_norm(g)[..., None], shaped(gamma))


def saturate(g: ArrayLike, gamma: ArrayLike, kind: str = 'paper') -> NDArray[np.float64]:
    """Dispatch to :func:`sat` (``'paper'``) or :func:`sat_continuous` (``'continuous'``);
    any other ``kind`` is a ValueError."""
    if kind == 'paper':
        return sat(g, gamma)
    if kind == 'continuous':
        return sat_continuous(g, gamma)
    raise ValueError(f'saturation must be one of {SATURATIONS}, got {kind!r}')
