"""Vehicle dynamics of paper eq. 19-21 with a seeded, bounded unknown disturbance.

.. math::

    M \\ddot x_i + f_i^{known}(x_i, \\dot x_i) + f_i^{unknown} = u_i,
    \\qquad \\|f_i^{unknown}\\| \\le \\bar f

The force ``u_i``, the known term ``f_known(v_k) = drag * v_k`` and the unknown term are
evaluated at the start of a step and held over it (zero-order hold); with that constant
acceleration the step is integrated exactly (a lockstep ROS run reproduces it bit for bit).

The unknown disturbance is drawn uniformly in the ball of radius ``f_bar`` with
``Generator.random`` only, which consumes one 64-bit word per double, and mapped by a fixed
function of each triple (:func:`uniform_ball`, no rejection): the sequence is the same
whatever the number of steps drawn at once, so a batch of runs, a single run and the ROS plant
node see identical noise for one seed.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .kernels import as_kernel, plant_rows
from .laws import known_force

__all__ = [
    'NOISE_KINDS',
    'DisturbanceSource',
    'acceleration_setpoint',
    'plant_step',
    'uniform_ball',
    'velocity_setpoint',
]

NOISE_KINDS = ('uniform_ball', 'none')


def uniform_ball(u: ArrayLike, radius: ArrayLike) -> NDArray[np.float64]:
    """Map uniform samples ``u`` of shape (..., 3) in [0, 1) to points uniform in a ball.

    ``u[..., 0]`` gives the cosine of the polar angle (uniform on [-1, 1]: a uniform
    direction), ``u[..., 1]`` the azimuth ``phi = 2 pi u`` and ``u[..., 2]`` the radius by the
    inverse CDF ``r = R u^{1/3}``; ``radius`` broadcasts against ``u.shape[:-1]``. ``cos phi``
    and ``sin phi`` come from the half-angle tangent ``t = tan(pi u)`` (one ``tan`` is
    cheaper than ``cos`` and ``sin``): ``2/(1 + t^2) - 1`` and ``2t/(1 + t^2)``; ``t`` stays
    finite in [0, 1). Each point is a fixed function of its own triple.
    """
    u = np.asarray(u, dtype=float)
    cos_t = 2.0 * u[..., 0] - 1.0
    t = np.tan(np.pi * u[..., 1])
    q = 2.0 / (t * t + 1.0)
    r = np.cbrt(u[..., 2]) * np.asarray(radius, dtype=float)
    rs = np.sqrt(1.0 - cos_t * cos_t) * r  # r sin(theta); |cos_t| <= 1
    return np.stack([rs * (q - 1.0), rs * (t * q), r * cos_t], axis=-1)


#: doubles a DisturbanceSource buffer may hold before it draws fewer steps per block
_NOISE_BUFFER = 1 << 21
#: doubles per generator call below which a smaller block is not worth its call overhead
_NOISE_MIN_DRAW = 256
#: doubles mapped by one uniform_ball call (cache-sized pieces)
_NOISE_MAP_CHUNK = 12288


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
        Most steps drawn at once (performance only; does not change the sequence). A batch
        draws fewer so that its buffer stays near ``2**21`` doubles (16 MB), but never fewer
        than about 256 doubles per run and call.

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
            raise ValueError(f'noise must be one of {NOISE_KINDS}, got {self.kind!r}')
        self._batched = not np.isscalar(self.seed)
        seeds = [int(s) for s in np.atleast_1d(np.asarray(self.seed))]
        self._rngs = [np.random.default_rng([int(s), 2]) for s in seeds]
        self._radius = np.broadcast_to(np.asarray(self.f_bar, dtype=float), (len(seeds),))
        self._silent = self.kind == 'none' or not np.any(self._radius > 0)
        zeros = np.zeros((len(seeds), self.n, 3))
        self._zeros = zeros if self._batched else zeros[0]
        per_step = 3 * self.n
        self._steps = max(
            1,
            min(
                int(self.block),
                max(-(-_NOISE_MIN_DRAW // per_step), _NOISE_BUFFER // (len(seeds) * per_step)),
            ),
        )
        self._chunk = max(1, _NOISE_MAP_CHUNK // (self._steps * per_step))
        self._buf = np.empty((0, len(seeds), self.n, 3))
        self._pos = 0

    def _refill(self) -> None:
        """Draw the next ``_steps`` steps of every run into a new buffer (steps, R, n, 3).

        A new buffer each time: arrays returned by :meth:`next` stay valid.
        """
        R, steps = len(self._rngs), self._steps
        buf = np.empty((steps, R, self.n, 3))
        u = np.empty((min(self._chunk, R), steps, self.n, 3))
        for r0 in range(0, R, self._chunk):
            r1 = min(R, r0 + self._chunk)
            for j in range(r1 - r0):
                self._rngs[r0 + j].random(out=u[j])
            radius = self._radius[r0:r1, None, None]
            buf[:, r0:r1] = uniform_ball(u[: r1 - r0], radius).swapaxes(0, 1)
        self._buf = buf if self._batched else buf[:, 0]
        self._pos = 0

    @property
    def silent(self) -> bool:
        """No disturbance: every step's is zero."""
        return self._silent

    def take(self, limit: int) -> NDArray[np.float64]:
        """The disturbances of the next steps, at most ``limit`` (>= 1) and at least one,
        as many as the buffer holds without a refill: shape (steps, R, n, 3) [N], or (1, R,
        n, 3) of zeros for any number of steps when there is no disturbance (a batch)."""
        if self._silent:
            return self._zeros[None] if self._batched else self._zeros[None, None]
        if self._pos >= self._steps or not len(self._buf):
            self._refill()
        count = min(limit, self._steps - self._pos)
        out = self._buf[self._pos : self._pos + count]
        self._pos += count
        return out if self._batched else out[:, None]

    def next(self) -> NDArray[np.float64]:
        """Disturbance for the next step [N]: (n, 3), or (R, n, 3) for a batch."""
        out = self.take(1)[0]
        return out if self._batched else out[0]


def plant_step(
    x: ArrayLike,
    v: ArrayLike,
    force: ArrayLike,
    *,
    mass: ArrayLike,
    dt: float,
    drag: ArrayLike = 0.0,
    disturbance: ArrayLike | float = 0.0,
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
    force = np.asarray(force, dtype=float)
    disturbance = np.asarray(disturbance, dtype=float)
    mass = np.asarray(mass, dtype=float)
    drag = np.asarray(drag, dtype=float)
    shape = x.shape
    if not (v.shape == force.shape == shape and disturbance.shape in (shape, ())):
        shape = np.broadcast_shapes(
            x.shape, v.shape, force.shape, disturbance.shape, mass.shape, (*drag.shape, 1, 1)
        )
    lead, n = shape[:-2], shape[-2] if len(shape) > 1 else 1
    runs = math.prod(lead)

    def rows(arr: NDArray[np.float64]) -> NDArray[np.float64]:
        """(runs, n, 3), or (1, 1, 1) for one value (the kernel broadcasts it)."""
        if not arr.ndim:
            return as_kernel(arr.reshape(1, 1, 1))
        return as_kernel(arr, shape).reshape(runs, n, 3)

    xn, vn = plant_rows(
        rows(x),
        rows(v),
        rows(force),
        rows(disturbance),
        rows(mass),
        as_kernel(drag.reshape(1)) if not drag.ndim else as_kernel(drag, lead).reshape(runs),
        float(dt),
        0.5 * float(dt) * float(dt),
    )
    return xn.reshape(shape), vn.reshape(shape)


def acceleration_setpoint(
    force: ArrayLike, v: ArrayLike, *, mass: ArrayLike, drag: ArrayLike = 0.0
) -> NDArray[np.float64]:
    """Eq. 19 solved for the acceleration, without the unknown term it cannot know:
    ``a = (u - f_known(v)) / M`` -- the acceleration a flight stack that tracks acceleration
    setpoints flies so that the vehicle moves as the model does under the force ``u``.

    Parameters
    ----------
    force, v : array, shape (..., n, 3)
        Control input u_i [N] (eq. 24) and velocity [m/s], world frame.
    mass : float or array broadcastable to (..., n, 3)
        Mass M [kg].
    drag : float or array [N s/m]
        Coefficient of the known disturbance ``f_known = drag * v`` (eq. 20).

    Returns
    -------
    a : array, shape (..., n, 3) [m/s^2]
    """
    return (np.asarray(force, dtype=float) - known_force(v, drag)) / np.asarray(mass, dtype=float)


def velocity_setpoint(v: ArrayLike, acceleration: ArrayLike, period: float) -> NDArray[np.float64]:
    """The velocity at the end of one control period ``period`` [s] flown at the held
    ``acceleration`` (the zero-order hold of eq. 19): ``v + a T`` [m/s], for a flight stack
    that tracks velocity setpoints."""
    return np.asarray(v, dtype=float) + np.asarray(acceleration, dtype=float) * float(period)
