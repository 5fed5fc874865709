"""Control laws: the kinematic law (eq. 7), the sliding manifolds (eq. 22, 25-28, 31), the
low-pass filter (eq. 26) and the switching force (eq. 24), with the traditional sign law of
Yao, Ordonez & Gazi (CDC 2006) as the baseline.

Vectors are the last axis of arrays of shape ``(..., m, 3)`` (m trackers, optional leading
batch dimensions); gains are floats or arrays of shape ``(...)`` (one value per run).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .saturation import outside_layer, saturate, sign

__all__ = [
    'LAWS', 'kinematic_velocity', 'filter_step', 'sliding_surface_proposed',
    'sliding_surface_traditional', 'switching_force', 'known_force', 'ControlOutput',
    'SlidingModeController',
]

LAWS = ('proposed', 'traditional')


def _g(value: ArrayLike, extra: int = 2) -> NDArray[np.float64] | float:
    if type(value) is float:
        return value
    arr = np.asarray(value, dtype=float)
    return float(arr) if arr.ndim == 0 else arr.reshape(arr.shape + (1,) * extra)


def kinematic_velocity(grad: ArrayLike, *, alpha: ArrayLike, beta: ArrayLike,
                       gamma: ArrayLike, saturation: str = 'paper') -> NDArray[np.float64]:
    """Kinematic (particle) law of paper eq. 7: ``xdot_i = -alpha grad_i J - beta sat(grad_i J, gamma)``.

    Parameters
    ----------
    grad : array, shape (..., m, 3)
        Gradients grad_i J [m].
    alpha : float [1/s]; beta : float [m/s]; gamma : float [m]
    saturation : 'paper' (eq. 8) or 'continuous'

    Returns
    -------
    velocity : array, shape (..., m, 3) [m/s]
    """
    grad = np.asarray(grad, dtype=float)
    return -_g(alpha) * grad - _g(beta) * saturate(grad, gamma, saturation)


def filter_step(z: ArrayLike, grad: ArrayLike, *, beta: ArrayLike, lambda_filter: ArrayLike,
                dt: float) -> NDArray[np.float64]:
    """One step of the low-pass filter of paper eq. 26, ``lambda zdot + z = beta sign(grad_i J)``.

    Discretized exactly for an input held constant over the step (zero-order hold):
    ``z_{k+1} = e^{-dt/lambda} z_k + (1 - e^{-dt/lambda}) beta sign(grad_k)``. The scheme is
    stable for every ``dt > 0`` and keeps ``|z| <= beta`` componentwise.

    Parameters
    ----------
    z : array, shape (..., m, 3)
        Filter state [m/s].
    grad : array, shape (..., m, 3)
        Gradient at step k.
    beta : float [m/s]; lambda_filter : float [s]; dt : float [s]

    Returns
    -------
    z_next : array, shape (..., m, 3)
    """
    decay = np.exp(-dt / _g(lambda_filter))
    return decay * np.asarray(z, dtype=float) + (1.0 - decay) * _g(beta) * sign(grad)


def sliding_surface_proposed(v: ArrayLike, grad: ArrayLike, z: ArrayLike, *, alpha: ArrayLike,
                             beta: ArrayLike, gamma: ArrayLike, saturation: str = 'paper'
                             ) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Sliding manifold of the proposed (saturated) law, paper eq. 22, 28 and 31.

    * Outside the boundary layer (``||grad|| >= gamma``), eq. 28: ``s = v + alpha grad + z``,
      the discontinuous ``beta sign(grad)`` of eq. 25 replaced by the filter output z (eq. 26).
      With ``saturation='continuous'`` the term ``beta grad/||grad||`` is already continuous
      and is used directly (eq. 22 with the continuous sat), without the filter.
    * Inside (``||grad|| < gamma``), eq. 31: ``s = v + (alpha + beta/gamma) grad``.

    Parameters
    ----------
    v : array, shape (..., m, 3)
        Velocities [m/s].
    grad : array, shape (..., m, 3)
        Gradients [m].
    z : array, shape (..., m, 3)
        Filter state [m/s].

    Returns
    -------
    s : array, shape (..., m, 3) [m/s]
    outside : bool array, shape (..., m): True outside the boundary layer.
    """
    v = np.asarray(v, dtype=float)
    grad = np.asarray(grad, dtype=float)
    outside = outside_layer(grad, gamma)
    if saturation == 'paper':
        outer = v + _g(alpha) * grad + np.asarray(z, dtype=float)
        inner = v + (_g(alpha) + _g(beta) / _g(gamma)) * grad
        s = np.where(outside[..., None], outer, inner)
    else:
        s = v + _g(alpha) * grad + _g(beta) * saturate(grad, gamma, saturation)
    return s, outside


def sliding_surface_traditional(v: ArrayLike, grad: ArrayLike, z: ArrayLike, *,
                                alpha: ArrayLike) -> NDArray[np.float64]:
    """Sliding manifold of the traditional sign law (Yao, Ordonez & Gazi 2006).

    ``s = v + alpha grad + z`` everywhere, with ``lambda zdot + z = beta sign(grad)``.

    Returns
    -------
    s : array, shape (..., m, 3) [m/s]
    """
    return (np.asarray(v, dtype=float) + _g(alpha) * np.asarray(grad, dtype=float)
            + np.asarray(z, dtype=float))


def known_force(v: ArrayLike, drag: ArrayLike) -> NDArray[np.float64]:
    """Known part of the disturbance, ``f_known(x, xdot) = drag * xdot`` (eq. 20) [N].

    A linear drag is the model this project uses for the known term; ``drag = 0`` removes it.
    """
    return _g(drag) * np.asarray(v, dtype=float)


def switching_force(s: ArrayLike, v: ArrayLike, *, u0: ArrayLike,
                    drag: ArrayLike = 0.0) -> NDArray[np.float64]:
    """Control input of paper eq. 24, ``u_i = -u0 sign(s_i) + f_i^known(x_i, xdot_i)`` [N].

    The printed ``J_i^known`` is the known disturbance ``f_i^known`` of eq. 20 (SPEC section 1).
    """
    return -_g(u0) * sign(s) + known_force(v, drag)


@dataclass(frozen=True)
class ControlOutput:
    """What one controller step produced for m trackers (arrays of shape (..., m, 3))."""

    force: NDArray[np.float64]
    sliding_surface: NDArray[np.float64]
    gradient: NDArray[np.float64]
    filter_state: NDArray[np.float64]
    saturated: NDArray[np.bool_]


@dataclass
class SlidingModeController:
    """Stateful sliding-mode controller for m trackers (m = 1 in a tracker node).

    Holds the filter state z of eq. 26 explicitly; :meth:`reset` zeroes it. One call of
    :meth:`step` computes the manifold with the current z, the force of eq. 24, and advances z
    by one sample of length ``dt``.

    Parameters
    ----------
    law : 'proposed' or 'traditional'
    alpha [1/s], beta [m/s], gamma [m], lambda_filter [s], u0 [N], drag [N s/m] : gains, floats
        or arrays of shape (...) for a batch of runs.
    dt : float
        Control period [s].
    shape : tuple
        Shape of the state, ``(..., m, 3)``.
    saturation : 'paper' or 'continuous'
    """

    law: Literal['proposed', 'traditional']
    alpha: ArrayLike
    beta: ArrayLike
    gamma: ArrayLike
    lambda_filter: ArrayLike
    u0: ArrayLike
    dt: float
    shape: tuple[int, ...] = (1, 3)
    drag: ArrayLike = 0.0
    saturation: str = 'paper'
    z: NDArray[np.float64] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        if self.law not in LAWS:
            raise ValueError(f"law must be one of {LAWS}, got {self.law!r}")
        self.reset()

    def reset(self, z: ArrayLike | None = None) -> None:
        """Set the filter state to ``z`` (default zeros), e.g. after a respawn."""
        self.z = np.zeros(self.shape) if z is None else np.array(z, dtype=float).reshape(self.shape)

    def step(self, v: ArrayLike, grad: ArrayLike) -> ControlOutput:
        """Compute the command for velocities ``v`` and gradients ``grad`` (shape ``(..., m, 3)``)."""
        z = self.z
        if self.law == 'proposed':
            s, outside = sliding_surface_proposed(
                v, grad, z, alpha=self.alpha, beta=self.beta, gamma=self.gamma,
                saturation=self.saturation)
        else:
            s = sliding_surface_traditional(v, grad, z, alpha=self.alpha)
            outside = outside_layer(grad, self.gamma)
        force = switching_force(s, v, u0=self.u0, drag=self.drag)
        self.z = filter_step(z, grad, beta=self.beta, lambda_filter=self.lambda_filter, dt=self.dt)
        return ControlOutput(force=force, sliding_surface=s, gradient=np.asarray(grad, dtype=float),
                             filter_state=z, saturated=outside)
