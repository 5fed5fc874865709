"""The control laws in plain numpy: the tests' oracle for the compiled kernels
(``apf_swarm_core.kernels``), which are the implementation. Equation numbers are the paper's
(docs/THEORY.md); vectors are the last axis of arrays ``(..., m, 3)``, gains floats or arrays
of per-run values ``(...)``."""

from __future__ import annotations

import numpy as np
from apf_swarm_core.gains import shaped
from apf_swarm_core.laws import SATURATIONS
from numpy.typing import ArrayLike, NDArray

Array = NDArray[np.float64]


def sign(g: ArrayLike) -> Array:
    """Componentwise sign, ``sign(0) = 0`` (eq. 8, 24, 26)."""
    return np.sign(np.asarray(g, dtype=float))


def outside_layer(g: ArrayLike, gamma: ArrayLike) -> NDArray[np.bool_]:
    """``||g|| >= gamma`` over the last axis: outside the boundary layer of eq. 8, (..., m)."""
    return np.linalg.norm(np.asarray(g, dtype=float), axis=-1) >= shaped(gamma, 1)


def sat(g: ArrayLike, gamma: ArrayLike) -> Array:
    """Eq. 8 as printed: ``sign(g)`` where ``||g|| >= gamma``, ``g / gamma`` inside."""
    g = np.asarray(g, dtype=float)
    return np.where(outside_layer(g, gamma)[..., None], np.sign(g), g / shaped(gamma))


def sat_continuous(g: ArrayLike, gamma: ArrayLike) -> Array:
    """The continuous saturation ``g / max(||g||, gamma)`` (not in the paper)."""
    g = np.asarray(g, dtype=float)
    return g / np.maximum(np.linalg.norm(g, axis=-1)[..., None], shaped(gamma))


def saturate(g: ArrayLike, gamma: ArrayLike, kind: str = 'paper') -> Array:
    """:func:`sat` (``'paper'``) or :func:`sat_continuous` (``'continuous'``)."""
    if kind == 'paper':
        return sat(g, gamma)
    if kind == 'continuous':
        return sat_continuous(g, gamma)
    raise ValueError(f'saturation must be one of {SATURATIONS}, got {kind!r}')


def kinematic_velocity(
    grad: ArrayLike,
    *,
    alpha: ArrayLike,
    beta: ArrayLike,
    gamma: ArrayLike,
    saturation: str = 'paper',
) -> Array:
    """Eq. 7: ``xdot_i = -alpha grad_i J - beta sat(grad_i J, gamma)`` [m/s]."""
    grad = np.asarray(grad, dtype=float)
    return -shaped(alpha) * grad - shaped(beta) * saturate(grad, gamma, saturation)


def filter_step(
    z: ArrayLike, grad: ArrayLike, *, beta: ArrayLike, lambda_filter: ArrayLike, dt: float
) -> Array:
    """Eq. 26 over one step with the input held (exact):
    ``z_{k+1} = e^{-dt/lambda} z_k + (1 - e^{-dt/lambda}) beta sign(grad_k)``."""
    decay = np.exp(-dt / shaped(lambda_filter))
    return decay * np.asarray(z, dtype=float) + ((1.0 - decay) * shaped(beta)) * sign(grad)


def sliding_surface_proposed(
    v: ArrayLike,
    grad: ArrayLike,
    z: ArrayLike,
    *,
    alpha: ArrayLike,
    beta: ArrayLike,
    gamma: ArrayLike,
    saturation: str = 'paper',
) -> tuple[Array, NDArray[np.bool_]]:
    """The proposed manifold and whether each row is outside the layer: eq. 28
    (``v + alpha g + z``) outside, eq. 31 (``v + (alpha + beta/gamma) g``) inside; with
    ``saturation='continuous'`` eq. 22 with the continuous sat, without the filter."""
    v, g, z = (np.asarray(a, dtype=float) for a in (v, grad, z))
    alpha, beta = shaped(alpha), shaped(beta)
    outside = outside_layer(g, gamma)
    if saturation == 'paper':
        inside = v + (alpha + beta / shaped(gamma)) * g
        return np.where(outside[..., None], (v + alpha * g) + z, inside), outside
    if saturation != 'continuous':
        raise ValueError(f'saturation must be one of {SATURATIONS}, got {saturation!r}')
    return (v + alpha * g) + beta * sat_continuous(g, gamma), outside


def sliding_surface_traditional(
    v: ArrayLike, grad: ArrayLike, z: ArrayLike, *, alpha: ArrayLike
) -> Array:
    """The traditional manifold (Yao, Ordonez & Gazi 2006): ``s = v + alpha grad + z``."""
    v, g, z = (np.asarray(a, dtype=float) for a in (v, grad, z))
    return (v + shaped(alpha) * g) + z


def layer_switching_force(
    s: ArrayLike, v: ArrayLike, *, u0: ArrayLike, phi: ArrayLike, drag: ArrayLike = 0.0
) -> Array:
    """Eq. 24 with a boundary layer (not in the paper): ``-u0 clip(s / phi, -1, 1) + drag v``."""
    s, v = np.asarray(s, dtype=float), np.asarray(v, dtype=float)
    clipped = np.clip(s * (1.0 / shaped(phi)), -1.0, 1.0)
    return -shaped(u0) * clipped + shaped(drag) * v


def block_direction(
    blocks: ArrayLike,
    grad: ArrayLike,
    centroid_grad: ArrayLike,
    *,
    k_n: ArrayLike,
    mu: float,
    trust: float = 0.0,
) -> Array:
    """The direction of ``precondition = block`` (docs/THEORY.md, Large swarms):
    ``g_bar / k_N + |H_ii|_mu_i^-1 (g_i - g_bar)``, ``|H|_mu = V diag(max(|lambda|, mu_i))
    V^T``, ``mu_i = max(mu, |g_i - g_bar| / trust)`` with a trust radius. blocks (..., m, 3,
    3), grad (..., m, 3), centroid_grad (..., 3)."""
    g = np.asarray(grad, dtype=float)
    gbar = np.asarray(centroid_grad, dtype=float)[..., None, :]
    rel = g - gbar
    w, vecs = np.linalg.eigh(np.asarray(blocks, dtype=float))
    floor = np.full(rel.shape[:-1], float(mu))
    if trust > 0.0:
        floor = np.maximum(floor, np.linalg.norm(rel, axis=-1) / trust)
    coef = np.einsum('...qp,...q->...p', vecs, rel) / np.maximum(np.abs(w), floor[..., None])
    return gbar / shaped(k_n) + np.einsum('...qp,...p->...q', vecs, coef)
