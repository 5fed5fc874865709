"""A node's inputs: the latest value of one (:class:`Sample`), and what one is refused for
before it reaches the mathematics: values that are not finite or not physical
(:func:`input_problem`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

__all__ = ['MAX_FORCE', 'MAX_POSITION', 'MAX_SPEED', 'Sample', 'input_problem']

#: inputs beyond these magnitudes are refused as not physical (componentwise) [m, m/s, N]
MAX_POSITION = 1.0e6
MAX_SPEED = 1.0e4
MAX_FORCE = 1.0e6


@dataclass
class Sample:
    """The latest value of one input: step (lockstep) or -1, arrays, the time it was produced
    [s] (on the clock the caller uses for ``now``), its order key, and whether its tracker is
    active (commanding; always True for the target)."""

    step: int
    x: NDArray[np.float64]
    v: NDArray[np.float64]
    received: float
    seq: int = -1
    active: bool = True


_LIMITS = {
    'x': MAX_POSITION,
    'target_x': MAX_POSITION,
    'v': MAX_SPEED,
    'force': MAX_FORCE,
    's': MAX_SPEED,
}


def input_problem(**arrays: NDArray[np.float64]) -> str | None:
    """Why an input is refused, or ``None``: ``x``/``target_x`` positions, ``v`` speeds,
    ``force`` and ``s`` forces and surfaces, each checked for finite values and magnitude."""
    for name, arr in arrays.items():
        a = np.asarray(arr, dtype=float)
        lim = _LIMITS[name]
        # one reduction for the common case: the largest magnitude is NaN when any value is
        # NaN, so a finite, in-range input is exactly one whose maximum is <= the limit
        if a.size and np.abs(a).max() <= lim:
            continue
        if not np.all(np.isfinite(a)):
            return f'{name} is not finite ({a.tolist()})'
        if np.any(np.abs(a) > lim):
            return f'{name} = {a.tolist()} exceeds {lim:g} in magnitude'
    return None
