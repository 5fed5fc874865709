"""The control laws' options, and the two terms of eq. 24 used outside the controller.

The laws (eq. 20, 22-28, 31, 24, 26, and the boundary layer and target-velocity feed-forward
beyond the paper, docs/THEORY.md) are written once, in the compiled kernel
:func:`~apf_swarm_core.kernels.smc_rows` that the controller, the simulator's loop and the
tracker nodes call; test/core/reference.py holds the numpy forms the tests check it against.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .gains import shaped

__all__ = ['LAWS', 'SATURATIONS', 'SWITCHINGS', 'known_force', 'switching_force']

LAWS = ('proposed', 'traditional')

#: switching force of eq. 24: the paper's sign, or a continuous boundary layer on s
SWITCHINGS = ('sign', 'layer')

#: the saturation of eq. 8 as printed, or the continuous ``g / max(||g||, gamma)``
SATURATIONS = ('paper', 'continuous')


def known_force(v: ArrayLike, drag: ArrayLike) -> NDArray[np.float64]:
    """Known part of the disturbance, ``f_known(x, xdot) = drag * xdot`` (eq. 20) [N]."""
    return shaped(drag) * np.asarray(v, dtype=float)


def switching_force(
    s: ArrayLike, v: ArrayLike, *, u0: ArrayLike, drag: ArrayLike = 0.0
) -> NDArray[np.float64]:
    """Eq. 24, ``u_i = -u0 sign(s_i) + f_i^known(x_i, xdot_i)`` [N] (the printed
    ``J_i^known`` is the ``f_i^known`` of eq. 20); s, v (..., m, 3)."""
    return -shaped(u0) * np.sign(np.asarray(s, dtype=float)) + known_force(v, drag)
