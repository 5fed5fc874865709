"""Vehicle dynamics of paper eq. 19-21 with a seeded, bounded unknown disturbance.

.. math::

    M \\ddot x_i + f_i^{known}(x_i, \\dot x_i) + f_i^{unknown} = u_i,
    \\qquad \\|f_i^{unknown}\\| \\le \\bar f

Integration scheme (documented because a lockstep ROS run must reproduce it bit for bit):
the force ``u_i``, the known term ``f_known(v_k) = drag * v_k`` and the unknown term are all
evaluated at the start of the step and held over it (zero-order hold); with that constant
acceleration ``acc = (u - f_known - f_unknown) / M`` the step is integrated exactly:
``v_{k+1} = v_k + acc dt`` and ``x_{k+1} = x_k + v_k dt + acc dt^2 / 2``.

The unknown disturbance is drawn uniformly in the ball of radius ``f_bar`` from a
:class:`numpy.random.Generator`. Only ``Generator.random`` is used, and it is drawn in blocks
of ``block`` steps: because ``random`` consumes exactly one 64-bit word per double, the
sequence is the same whatever the block size, so a batch of runs, a single run and the ROS
plant node all see identical noise for the same seed.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .laws import known_force

__all__ = ['NOISE_KINDS', 'uniform_ball', 'DisturbanceSource', 'plant_step']

NOISE_KINDS = ('uniform_ball', 'none')


def uniform_ball(u: ArrayLike, radius: ArrayLike) -> NDArray[np.float64]:
    """Map uniform samples ``u`` of shape (..., 3) in [0, 1) to points uniform in a ball.

    ``u[..., 0]`` gives the cosine of the polar angle (Archimedes: uniform on [-1, 1] gives a
    uniform direction), ``u[..., 1]`` the azimuth and ``u[..., 2]`` the radius by the inverse
    CDF ``r = R u^{1/3}``. ``radius`` broadcasts against ``u.shape[:-1]``.
    """
    u = np.asarray(u, dtype=float)
    cos_t = 2.0 * u[..., 0] - 1.0
    sin_t = np.sqrt(np.maximum(0.0, 1.0 - cos_t * cos_t))
    phi = 2.0 * np.pi * u[..., 1]
    r = np.asarray(radius, dtype=float) * np.cbrt(u[..., 2])
    return np.stack([r * sin_t * np.cos(phi), r * sin_t * np.sin(phi), r * cos_t], axis=-1)


@dataclass
class DisturbanceSource:
    """Seeded source of the unknown disturbance for ``n`` trackers, one draw per step.

    Parameters
    ----------
    seed : int, or a sequence of R ints for a batch of runs
        Seed of each run's generator (``numpy.random.default_rng([seed, 2])``; stream 1 is the
        initial positions, see :mod:`apf_swarm_core.simulator`).
    n : int
        Number of trackers.
    f_bar : float, or a sequence of R floats
        Bound of the disturbance [N].
    kind : 'uniform_ball' or 'none'
    block : int
        Steps drawn at once (performance only; does not change the sequence).

    :meth:`next` returns shape (n, 3) for an int seed and (R, n, 3) for a sequence.
    """

    seed: int | Sequence[int]
    n: int
    f_bar: float | Sequence[float]
    kind: str = 'uniform_ball'
    block: int = 1024
    _rngs: list[np.random.Generator] = field(init=False, repr=False)
    _buf: NDArray[np.float64] = field(init=False, repr=False)
    _pos: int = field(init=False, repr=False)

    def __post_init__(self) -> None:
        if self.kind not in NOISE_KINDS:
            raise ValueError(f"noise must be one of {NOISE_KINDS}, got {self.kind!r}")
        self._batched = not np.isscalar(self.seed)
        seeds = list(self.seed) if self._batched else [self.seed]
        self._rngs = [np.random.default_rng([int(s), 2]) for s in seeds]
        self._radius = np.broadcast_to(np.asarray(self.f_bar, dtype=float), (len(seeds),))
        self._silent = self.kind == 'none' or not np.any(self._radius > 0)
        self._zeros = np.zeros((len(seeds), self.n, 3))
        self._buf = np.empty((len(seeds), 0, self.n, 3))
        self._pos = 0

    def next(self) -> NDArray[np.float64]:
        """Disturbance for the next step [N]."""
        if self._silent:
            out = self._zeros
        else:
            if self._pos >= self._buf.shape[1]:
                u = np.stack([rng.random((self.block, self.n, 3)) for rng in self._rngs])
                self._buf = uniform_ball(u, self._radius[:, None, None])
                self._pos = 0
            out = self._buf[:, self._pos]
            self._pos += 1
        return out if self._batched else out[0]


def plant_step(x: ArrayLike, v: ArrayLike, force: ArrayLike, *, mass: ArrayLike, dt: float,
               drag: ArrayLike = 0.0, disturbance: ArrayLike | float = 0.0
               ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Advance eq. 19 by one step of length ``dt`` with the force held constant.

    Parameters
    ----------
    x, v : array, shape (..., n, 3)
        Positions [m] and velocities [m/s] at step k.
    force : array, shape (..., n, 3)
        Control input u_i [N] held over the step.
    mass : float, or array broadcastable to (..., n, 3)
        Mass M (scalar) or the diagonal of M per tracker [kg], within [M_lo, M_hi] (eq. 21).
    dt : float [s]
    drag : float or array (...) [N s/m]
        Coefficient of the known disturbance ``f_known = drag * v``.
    disturbance : array, shape (..., n, 3)
        Unknown disturbance for this step [N].

    Returns
    -------
    x_next, v_next : arrays of shape (..., n, 3)
    """
    x = np.asarray(x, dtype=float)
    v = np.asarray(v, dtype=float)
    acc = (np.asarray(force, dtype=float) - known_force(v, drag)
           - np.asarray(disturbance, dtype=float)) / np.asarray(mass, dtype=float)
    return x + v * dt + (0.5 * dt * dt) * acc, v + acc * dt
