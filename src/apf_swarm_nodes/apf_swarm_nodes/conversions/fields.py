"""The pieces every conversion shares: the ``world`` frame, a vector field as an array and
back, a sequence of vector fields as rows, per-tracker flags."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = ['WORLD', 'active_flags', 'rows', 'set_vec', 'vec']

WORLD = 'world'


def vec(msg: Any) -> NDArray[np.float64]:
    """A Point or Vector3 (any object with x, y, z) as an array (3,)."""
    return np.array((msg.x, msg.y, msg.z), dtype=float)


def set_vec(msg: Any, v: NDArray[np.float64]) -> Any:
    """Set a Point or Vector3 from an array (3,); returns ``msg``."""
    msg.x, msg.y, msg.z = float(v[0]), float(v[1]), float(v[2])
    return msg


def rows(seq: Sequence[Any]) -> NDArray[np.float64]:
    """A sequence of Points or Vector3s as an array (n, 3)."""
    return np.array([(m.x, m.y, m.z) for m in seq], dtype=float).reshape(-1, 3)


def active_flags(active: Sequence[bool] | NDArray[np.bool_] | None, n: int) -> list[bool]:
    """The ``active`` field of n trackers: ``active`` as bools, every one active when None."""
    return [True] * n if active is None else [bool(a) for a in active]
