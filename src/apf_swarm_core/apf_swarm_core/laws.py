"""Control laws: the kinematic law (eq. 7), the sliding manifolds (eq. 22, 25-28, 31), the
low-pass filter (eq. 26) and the switching force (eq. 24), with the traditional sign law of
Yao, Ordonez & Gazi (CDC 2006) as the baseline.

Two selectable additions for sampled (real-time) control, beyond the paper and off by
default (docs/THEORY.md, "Sampled-data control"): the switching force with a continuous
boundary layer of width ``phi`` on the manifold (Slotine & Li, *Applied Nonlinear Control*,
1991, section 7.2), ``u = -u0 sat(s/phi) + f_known``, and a target-velocity feed-forward
``w`` in the manifold, ``s = (v - w v_N) + ...``, which removes the boundary-layer lag of a
moving target. With ``switching='sign'`` and ``w = 0`` the laws are exactly the paper's.

Vectors are the last axis of arrays of shape ``(..., m, 3)`` (m trackers, optional leading
batch dimensions); gains are floats or arrays of shape ``(...)`` (one value per run).

Each equation is written once, as a compiled function of :mod:`apf_swarm_core.kernels`
(``_surface_filtered``, ``_surface_layer``, ``_surface_continuous``, ``_switching``,
``_switching_layer``, ``_known``, ``_filter``); the public functions here broadcast their
arguments and call them elementwise, and :class:`SlidingModeController`, the simulator's loop
and the tracker nodes call them in :func:`~apf_swarm_core.kernels.smc_rows` and
:func:`~apf_swarm_core.kernels.simulate_steps`.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .gains import shaped
from .kernels import (
    elementwise,
    filter_array,
    known_array,
    surface_array,
    switching_array,
)
from .saturation import SATURATIONS, _norm, outside_layer, saturate

__all__ = [
    'LAWS',
    'SWITCHINGS',
    'filter_step',
    'kinematic_velocity',
    'known_force',
    'layer_switching_force',
    'sliding_surface_proposed',
    'sliding_surface_traditional',
    'switching_force',
]

LAWS = ('proposed', 'traditional')

#: switching force of eq. 24: the paper's sign, or a continuous boundary layer on s
SWITCHINGS = ('sign', 'layer')


def _check_saturation(kind: str) -> None:
    if kind not in SATURATIONS:
        raise ValueError(f'saturation must be one of {SATURATIONS}, got {kind!r}')


def _decay(lambda_filter: NDArray[np.float64], dt: float) -> NDArray[np.float64]:
    """Per-step decay ``e^{-dt/lambda}`` of the discretized filter of eq. 26."""
    return np.exp(-dt / lambda_filter)


def kinematic_velocity(
    grad: ArrayLike,
    *,
    alpha: ArrayLike,
    beta: ArrayLike,
    gamma: ArrayLike,
    saturation: str = 'paper',
) -> NDArray[np.float64]:
    """Kinematic (particle) law of paper eq. 7:
    ``xdot_i = -alpha grad_i J - beta sat(grad_i J, gamma)``.

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
    out: NDArray[np.float64] = -shaped(alpha) * grad - shaped(beta) * saturate(
        grad, gamma, saturation
    )
    return out


def filter_step(
    z: ArrayLike, grad: ArrayLike, *, beta: ArrayLike, lambda_filter: ArrayLike, dt: float
) -> NDArray[np.float64]:
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
    decay = _decay(shaped(lambda_filter), dt)
    return elementwise(filter_array, z, grad, decay, (1.0 - decay) * shaped(beta))


def sliding_surface_proposed(
    v: ArrayLike,
    grad: ArrayLike,
    z: ArrayLike,
    *,
    alpha: ArrayLike,
    beta: ArrayLike,
    gamma: ArrayLike,
    saturation: str = 'paper',
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
    grad = np.asarray(grad, dtype=float)
    outside = outside_layer(grad, gamma)
    alpha, beta = shaped(alpha), shaped(beta)
    if saturation == 'paper':
        gain = alpha + beta / shaped(gamma)
        s = elementwise(
            surface_array, v, grad, z, outside[..., None], alpha, gain, 1.0, flags=(0,)
        )
    else:
        _check_saturation(saturation)
        den = np.maximum(_norm(grad)[..., None], shaped(gamma))
        s = elementwise(surface_array, v, grad, 0.0, False, alpha, beta, den, flags=(2,))
    return s, outside


def sliding_surface_traditional(
    v: ArrayLike, grad: ArrayLike, z: ArrayLike, *, alpha: ArrayLike
) -> NDArray[np.float64]:
    """Sliding manifold of the traditional sign law (Yao, Ordonez & Gazi 2006).

    ``s = v + alpha grad + z`` everywhere, with ``lambda zdot + z = beta sign(grad)``.

    Returns
    -------
    s : array, shape (..., m, 3) [m/s]
    """
    return elementwise(surface_array, v, grad, z, False, shaped(alpha), 0.0, 1.0, flags=(1,))


def known_force(v: ArrayLike, drag: ArrayLike) -> NDArray[np.float64]:
    """Known part of the disturbance, ``f_known(x, xdot) = drag * xdot`` (eq. 20) [N].

    A linear drag is the model this project uses for the known term; ``drag = 0`` removes it.
    """
    return elementwise(known_array, v, shaped(drag))


def switching_force(
    s: ArrayLike, v: ArrayLike, *, u0: ArrayLike, drag: ArrayLike = 0.0
) -> NDArray[np.float64]:
    """Control input of paper eq. 24, ``u_i = -u0 sign(s_i) + f_i^known(x_i, xdot_i)`` [N].

    The printed ``J_i^known`` is the known disturbance ``f_i^known`` of eq. 20
    (docs/THEORY.md section 1).
    """
    return elementwise(switching_array, s, v, -shaped(u0), 1.0, shaped(drag), flags=(False,))


def layer_switching_force(
    s: ArrayLike, v: ArrayLike, *, u0: ArrayLike, phi: ArrayLike, drag: ArrayLike = 0.0
) -> NDArray[np.float64]:
    """Switching force with a continuous boundary layer (not in the paper) [N].

    ``u_i = -u0 sat(s_i / phi) + f_i^known``, ``sat`` clipping each component to [-1, 1]:
    eq. 24 outside the layer ``|s| >= phi`` (componentwise), the linear feedback
    ``-(u0/phi) s`` inside it (Slotine & Li 1991, eq. 7.39). Held over a control period T,
    the sign law's velocity ripple is about ``u0 T / M``; inside the layer the loop is linear
    with rate ``u0 / (phi M)``, stable under sampling when that rate times the period and the
    delay is small enough (:mod:`apf_swarm_core.sampled`).

    Parameters
    ----------
    s : array, shape (..., m, 3)
        Sliding surface [m/s].
    v : array, shape (..., m, 3)
        Velocities [m/s].
    u0 : float [N]; phi : float [m/s], > 0; drag : float [N s/m]
    """
    return elementwise(
        switching_array, s, v, -shaped(u0), 1.0 / shaped(phi), shaped(drag), flags=(True,)
    )
