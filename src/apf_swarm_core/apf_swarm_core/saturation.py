"""Switching functions: ``sign`` and the saturation of eq. 8 with its continuous variant.

Vectors are the last axis (length 3) of arrays of shape ``(..., 3)``.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ['SATURATIONS', 'sign', 'sat', 'sat_continuous', 'saturate', 'outside_layer']

SATURATIONS = ('paper', 'continuous')


def _gamma(gamma: ArrayLike) -> NDArray[np.float64] | float:
    if type(gamma) is float:
        return gamma
    g = np.asarray(gamma, dtype=float)
    return float(g) if g.ndim == 0 else g[..., None, None]


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
    g = np.asarray(g, dtype=float)
    gam = _gamma(gamma)
    gam = gam[..., 0] if isinstance(gam, np.ndarray) else gam
    return np.linalg.norm(g, axis=-1) >= gam


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
    return np.where(out, np.sign(g), g / _gamma(gamma))


def sat_continuous(g: ArrayLike, gamma: ArrayLike) -> NDArray[np.float64]:
    """Continuous saturation ``g / max(||g||, gamma)`` (not in the paper; SPEC section 1).

    Equal to eq. 8 inside the layer; outside it is the unit vector ``g/||g||`` instead of the
    componentwise sign, so the function is continuous everywhere.
    """
    g = np.asarray(g, dtype=float)
    norm = np.linalg.norm(g, axis=-1, keepdims=True)
    return g / np.maximum(norm, _gamma(gamma))


def saturate(g: ArrayLike, gamma: ArrayLike,
             kind: Literal['paper', 'continuous'] = 'paper') -> NDArray[np.float64]:
    """Dispatch to :func:`sat` (``'paper'``) or :func:`sat_continuous` (``'continuous'``)."""
    if kind == 'paper':
        return sat(g, gamma)
    if kind == 'continuous':
        return sat_continuous(g, gamma)
    raise ValueError(f"saturation must be one of {SATURATIONS}, got {kind!r}")
