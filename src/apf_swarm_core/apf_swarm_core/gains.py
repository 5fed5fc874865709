"""Gains as the vectorized functions take them: one value for every run, or one per run of
a batch (scalars become 0-d float64 arrays). The one place that shapes a gain.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ['per_run', 'shaped']


def shaped(value: ArrayLike, extra: int = 2) -> NDArray[np.float64]:
    """A gain broadcastable against arrays with ``extra`` trailing axes beyond the runs':
    0-d for one value; per-run values of shape ``(...)`` become ``(..., 1, ..., 1)`` with
    ``extra`` ones (2 for ``(..., m, 3)``, 1 for ``(..., m)``, 0 for ``(...)``)."""
    arr = np.asarray(value, dtype=float)
    return arr if arr.ndim == 0 else arr.reshape(arr.shape + (1,) * extra)


def per_run(values: Iterable[float]) -> NDArray[np.float64]:
    """One gain of every run of a batch: a 0-d array when all runs share it, else shape
    ``(R,)``. Raises ValueError for no runs."""
    vals = np.array(list(values), dtype=float)
    if vals.size == 0:
        raise ValueError('per_run needs the gain of at least one run')
    return np.array(vals[0]) if np.all(vals == vals[0]) else vals
