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

Each equation is written once, in a private kernel (``_surface_filtered``, ``_surface_layer``,
``_switching``, ``_known``, ``_filter``) that takes its gains already shaped for broadcasting;
the public functions shape their arguments and call the kernel, and
:class:`SlidingModeController` shapes its gains once (``_ControllerGains``) and calls the same
kernels every step. Scalars are kept as 0-d float64 arrays rather than Python floats: on the
arrays of a few elements of a single run, numpy's arithmetic with a 0-d array costs about half
as much as with a Python float.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .gains import shaped
from .saturation import (
    SATURATIONS,
    outside_layer,
    sat_continuous,
    saturate,
)

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


# --- kernels: one per equation, gains already shaped by _g -------------------------------
# (np.sign is saturation.sign, sign(0) = 0, without its conversion of the argument)


def _decay(lambda_filter: NDArray[np.float64], dt: float) -> NDArray[np.float64]:
    """Per-step decay ``e^{-dt/lambda}`` of the discretized filter of eq. 26."""
    return np.exp(-dt / lambda_filter)


def _filter(
    z: NDArray[np.float64],
    grad: NDArray[np.float64],
    decay: NDArray[np.float64],
    gain_in: NDArray[np.float64],
) -> NDArray[np.float64]:
    """Eq. 26 discretized: ``decay z + gain_in sign(grad)``, ``gain_in = (1 - decay) beta``."""
    return decay * z + gain_in * np.sign(grad)


def _surface_filtered(
    v: NDArray[np.float64],
    grad: NDArray[np.float64],
    z: NDArray[np.float64],
    alpha: NDArray[np.float64],
) -> NDArray[np.float64]:
    """``s = v + alpha grad + z``: eq. 28 (outside the layer) and the traditional law."""
    return v + alpha * grad + z


def _surface_layer(
    v: NDArray[np.float64], grad: NDArray[np.float64], gain: NDArray[np.float64]
) -> NDArray[np.float64]:
    """Eq. 31 inside the boundary layer: ``s = v + (alpha + beta/gamma) grad``, ``gain`` the
    bracket."""
    return v + gain * grad


def _surface_proposed(
    v: NDArray[np.float64],
    grad: NDArray[np.float64],
    z: NDArray[np.float64],
    outside: NDArray[np.bool_],
    alpha: NDArray[np.float64],
    gain: NDArray[np.float64],
) -> NDArray[np.float64]:
    """Proposed manifold with the paper's sat: eq. 28 where ``outside``, eq. 31 elsewhere.

    When no tracker is outside the layer (the steady state) the eq. 28 branch is not
    computed at all.
    """
    inner = _surface_layer(v, grad, gain)
    # any True in the (canonical 0/1) bool mask: a byte search, cheaper than count_nonzero
    if b'\x01' not in outside.tobytes():
        return inner
    outer = _surface_filtered(v, grad, z, alpha)
    if inner.size > 96 and inner.shape == outer.shape == (*outside.shape, 3):
        # a contiguous mask: np.where then runs one long loop instead of one per row
        return np.where(np.repeat(outside, 3, axis=-1).reshape(inner.shape), outer, inner)
    return np.where(outside[..., None], outer, inner)


def _surface_continuous(
    v: NDArray[np.float64],
    grad: NDArray[np.float64],
    alpha: NDArray[np.float64],
    beta: NDArray[np.float64],
    gamma: ArrayLike,
) -> NDArray[np.float64]:
    """Eq. 22 with the continuous sat: ``s = v + alpha grad + beta grad / max(|grad|, gamma)``."""
    return v + alpha * grad + beta * sat_continuous(grad, gamma)


def _known(v: NDArray[np.float64], drag: NDArray[np.float64]) -> NDArray[np.float64]:
    """Eq. 20's known term ``f_known = drag * v``."""
    return drag * v


def _switching(
    s: NDArray[np.float64],
    v: NDArray[np.float64],
    neg_u0: NDArray[np.float64],
    drag: NDArray[np.float64],
) -> NDArray[np.float64]:
    """Eq. 24, ``u = -u0 sign(s) + f_known(v)``, with ``neg_u0 = -u0``."""
    return neg_u0 * np.sign(s) + _known(v, drag)


def _switching_layer(
    s: NDArray[np.float64],
    v: NDArray[np.float64],
    neg_u0: NDArray[np.float64],
    inv_phi: NDArray[np.float64],
    drag: NDArray[np.float64],
) -> NDArray[np.float64]:
    """Eq. 24 with a boundary layer, ``u = -u0 clip(s/phi, -1, 1) + f_known(v)``, with
    ``inv_phi = 1/phi``."""
    return neg_u0 * np.clip(s * inv_phi, -1.0, 1.0) + _known(v, drag)


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
    return _filter(
        np.asarray(z, dtype=float),
        np.asarray(grad, dtype=float),
        decay,
        (1.0 - decay) * shaped(beta),
    )


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
    v = np.asarray(v, dtype=float)
    grad = np.asarray(grad, dtype=float)
    outside = outside_layer(grad, gamma)
    if saturation == 'paper':
        s = _surface_proposed(
            v,
            grad,
            np.asarray(z, dtype=float),
            outside,
            shaped(alpha),
            shaped(alpha) + shaped(beta) / shaped(gamma),
        )
    else:
        _check_saturation(saturation)
        s = _surface_continuous(v, grad, shaped(alpha), shaped(beta), gamma)
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
    return _surface_filtered(
        np.asarray(v, dtype=float),
        np.asarray(grad, dtype=float),
        np.asarray(z, dtype=float),
        shaped(alpha),
    )


def known_force(v: ArrayLike, drag: ArrayLike) -> NDArray[np.float64]:
    """Known part of the disturbance, ``f_known(x, xdot) = drag * xdot`` (eq. 20) [N].

    A linear drag is the model this project uses for the known term; ``drag = 0`` removes it.
    """
    return _known(np.asarray(v, dtype=float), shaped(drag))


def switching_force(
    s: ArrayLike, v: ArrayLike, *, u0: ArrayLike, drag: ArrayLike = 0.0
) -> NDArray[np.float64]:
    """Control input of paper eq. 24, ``u_i = -u0 sign(s_i) + f_i^known(x_i, xdot_i)`` [N].

    The printed ``J_i^known`` is the known disturbance ``f_i^known`` of eq. 20
    (docs/THEORY.md section 1).
    """
    return _switching(
        np.asarray(s, dtype=float), np.asarray(v, dtype=float), -shaped(u0), shaped(drag)
    )


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
    return _switching_layer(
        np.asarray(s, dtype=float),
        np.asarray(v, dtype=float),
        -shaped(u0),
        1.0 / shaped(phi),
        shaped(drag),
    )
