"""Formation design: the equilibria of the potential J (eq. 44) for n trackers, their
spacings and the gains that give a spacing; closed forms for 3 trackers (the triangle) and
for a pair, a numerical minimization of J otherwise (docs/THEORY.md, section 2).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from typing import Unpack

import numpy as np
from numpy.typing import NDArray

from .errors import ConfigError
from .gradients import gradient
from .newton import hessian
from .potential import Gains, PotentialParams, gain_values, potential

__all__ = [
    'MULTISTART_MAX',
    'Formation',
    'b_for_spacing',
    'design_formations',
    'design_pairs',
    'equilibrium_formation',
    'equilibrium_formations',
    'expected_spacing',
    'pair_equilibrium_distance',
    'polish_minimum',
    'triangle_b_for_spacing',
    'triangle_c_for_spacing',
    'triangle_spacing',
]


def _triangle_threshold(a: float, k_n: float, k_f: float) -> float:
    return a + k_n / (3.0 * k_f)


def triangle_spacing(
    a: float, b: float, c: float, k_n: float = 1.0, k_f: float = 1.0
) -> float | None:
    """Side ``d = sqrt(c ln(b / (a + k_N/(3 k_f))))`` [m] of the equilateral equilibrium of 3
    trackers centred on the target (docs/THEORY.md section 2); ``None`` when b is not above
    ``a + k_N/(3 k_f)`` (the trackers collapse)."""
    thr = _triangle_threshold(a, k_n, k_f)
    if b <= thr:
        return None
    return math.sqrt(c * math.log(b / thr))


def triangle_b_for_spacing(
    d: float, a: float, c: float, k_n: float = 1.0, k_f: float = 1.0
) -> float:
    """The b that makes the 3-tracker triangle side equal to ``d`` (inverse of the formula)."""
    return _triangle_threshold(a, k_n, k_f) * math.exp(d * d / c)


def triangle_c_for_spacing(
    d: float, a: float, b: float, k_n: float = 1.0, k_f: float = 1.0
) -> float:
    """The c that makes the 3-tracker triangle side equal to ``d``; needs
    ``b > a + k_N/(3k_f)``."""
    thr = _triangle_threshold(a, k_n, k_f)
    if b <= thr:
        raise ConfigError(
            f'b = {b:g} <= a + k_n/(3 k_f) = {thr:g}: no c gives a triangle; '
            'raise b or solve for b instead'
        )
    return d * d / math.log(b / thr)


def pair_equilibrium_distance(a: float, b: float, c: float) -> float | None:
    """Gazi--Passino equilibrium distance of two agents, ``delta = sqrt(c ln(b/a))`` (b > a)."""
    return math.sqrt(c * math.log(b / a)) if b > a else None


@dataclass(frozen=True)
class Formation:
    """An equilibrium of J: positions relative to the target and the pair distances."""

    relative_positions: NDArray[np.float64]  # (n, 3) [m]
    pair_distances: NDArray[np.float64]  # (n(n-1)/2,) sorted [m]
    potential: float
    gradient_norm: float  # max_i ||grad_i J|| at the solution

    @property
    def spacing(self) -> float:
        """Smallest pair distance (the nearest-neighbour spacing) [m]."""
        return float(self.pair_distances.min()) if self.pair_distances.size else 0.0


def equilibrium_formation(
    n: int, *, starts: int = 8, seed: int = 0, **gains: Unpack[Gains[float]]
) -> Formation:
    """The lowest of :func:`equilibrium_formations`: the equilibrium of n trackers around a
    target at the origin (its rotations are equilibria too). Gains ``k_n, k_f, a, b, c`` as
    keywords (default :data:`~apf_swarm_core.potential.POTENTIAL_DEFAULTS`)."""
    return equilibrium_formations(n, starts=starts, seed=seed, **gains)[0]


def equilibrium_formations(
    n: int,
    *,
    starts: int = 8,
    seed: int = 0,
    tolerance: float = 1e-6,
    **gains: Unpack[Gains[float]],
) -> list[Formation]:
    """The distinct minima of J (L-BFGS with the gradient of eq. 44 from ``starts`` random
    shapes, each :func:`polish_minimum`-ed) within ``tolerance`` (relative) of the lowest,
    lowest first (docs/THEORY.md, section 4). Gains as for :func:`equilibrium_formation`."""
    from scipy.optimize import minimize

    k_n, k_f, a, b, c = gain_values(gains)
    params: PotentialParams = {'k_n': k_n, 'k_f': k_f, 'a': a, 'b': b, 'c': c}
    origin = np.zeros(3)
    rng = np.random.default_rng(seed)
    scale = pair_equilibrium_distance(a, b, c) or 1.0

    def fun(flat: NDArray[np.float64]) -> tuple[float, NDArray[np.float64]]:
        x = flat.reshape(n, 3)
        return float(potential(x, origin, **params)), gradient(x, origin, **params).ravel()

    found: list[Formation] = []
    iu = np.triu_indices(n, 1)
    options = {'gtol': 1e-12, 'ftol': 1e-15, 'maxiter': 20000}
    for _ in range(max(1, starts)):
        x0 = rng.normal(scale=scale, size=(n, 3))
        res = minimize(fun, x0.ravel(), jac=True, method='L-BFGS-B', options=options)
        x = polish_minimum(res.x.reshape(n, 3), params)
        d = np.sort(np.linalg.norm(x[:, None, :] - x[None, :, :], axis=-1)[iu])
        g = np.linalg.norm(gradient(x, origin, **params), axis=-1).max()
        found.append(Formation(x, d, float(potential(x, origin, **params)), float(g)))
    best = found[0]
    for f in found[1:]:  # the lowest; of equal ones (1e-12), the first
        if f.potential < best.potential - 1e-12:
            best = f
    out = [best]
    for f in sorted(found, key=lambda f: f.potential):
        if f.potential - best.potential > tolerance * max(abs(best.potential), 1.0):
            break
        # the same minimum found twice (rotated): the same sorted pair distances
        if not any(np.allclose(f.pair_distances, o.pair_distances, atol=1e-3) for o in out):
            out.append(f)
    return out


def _rotation_basis(x: NDArray[np.float64]) -> NDArray[np.float64]:
    """Orthonormal columns (3n, r) spanning the rotations of ``x`` (n, 3) about the
    origin, ``omega x x_i``: the directions along which J is flat at every state."""
    gen = np.stack([np.cross(np.eye(3)[k], x).ravel() for k in range(3)], axis=1)
    q, r = np.linalg.qr(gen)
    return q[:, np.abs(np.diag(r)) > 1e-9 * max(1.0, float(np.abs(r).max()))]


def polish_minimum(
    x: NDArray[np.float64], params: PotentialParams, *, iterations: int = 200
) -> NDArray[np.float64]:
    """A true minimum of J (target at the origin) from ``x`` (n, 3), where L-BFGS stopped:
    saddle-free Newton steps ``-|H|^{-1} grad J`` and steps along negative curvature, each
    with a line search on J's slope (docs/THEORY.md, section 4); O(n^3) per iteration."""
    origin = np.zeros(3)

    def slope(t: float, step: NDArray[np.float64]) -> float:
        # J along the step is compared through its derivative: on a J of 2e4 that is flat
        # to 1e-8, differences of J itself are lost to rounding, its gradient's are not
        y = x + t * step.reshape(x.shape)
        return float(gradient(y, origin, **params).ravel() @ step)

    x = np.array(x, dtype=float)
    for _ in range(iterations):
        g = gradient(x, origin, **params).ravel()
        rot = _rotation_basis(x)
        h = hessian(x, origin, **params)
        scale = max(1.0, float(np.abs(np.diag(h)).max()))
        w, v = np.linalg.eigh(h + scale * (rot @ rot.T))  # rotations moved out of the way
        if w[0] < -1e-9 * scale:
            step = v[:, 0] * (0.1 if g @ v[:, 0] <= 0 else -0.1)
        elif float(np.abs(g).max()) < 1e-11 * scale:
            break
        else:
            step = -(v @ ((v.T @ g) / np.maximum(np.abs(w), 1e-9 * scale)))
        # the line minimum along the step: where the slope changes sign (bisection)
        lo, hi = 0.0, 1.0
        while slope(hi, step) < 0.0 and hi < 64.0:
            lo, hi = hi, 2.0 * hi
        for _ in range(40):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if slope(mid, step) < 0.0 else (lo, mid)
        if hi <= 1e-12:
            break
        x = x + hi * step.reshape(x.shape)
    return x


#: the design search's random starts: 4 up to this many trackers (one start may land in a
#: higher minimum that a flown swarm does not keep), one above (each start of a
#: 3n-dimensional minimization grows with n^2)
MULTISTART_MAX = 40


@lru_cache(maxsize=32)
def _designs(
    n: int, k_n: float, k_f: float, a: float, b: float, c: float
) -> tuple[Formation, ...]:
    found = equilibrium_formations(
        n, k_n=k_n, k_f=k_f, a=a, b=b, c=c, starts=4 if n <= MULTISTART_MAX else 1
    )
    for f in found:
        f.pair_distances.flags.writeable = False
        f.relative_positions.flags.writeable = False
    return tuple(found)


def design_formations(
    n: int, *, k_n: float, k_f: float, a: float, b: float, c: float
) -> list[Formation]:
    """The minima of J that a swarm of ``n`` settles in (:func:`equilibrium_formations` from
    4 random shapes up to :data:`MULTISTART_MAX` trackers, one above), lowest first;
    computed once per size and potential, its arrays read-only."""
    return list(_designs(n, k_n, k_f, a, b, c))


def design_pairs(
    n: int, *, k_n: float, k_f: float, a: float, b: float, c: float
) -> NDArray[np.float64] | None:
    """The design pair distances the formation metrics compare against: n = 2,
    ``sqrt(c ln(b/(a + k_N/(2 k_f))))`` (opposite sides of the target); n = 3, three times
    :func:`triangle_spacing`; more, those of the lowest of :func:`design_formations`.
    ``None`` without a formation (n < 2, or it collapses below 1e-6 m)."""
    if n < 2:
        return None
    if n == 2:
        thr = a + k_n / (2.0 * k_f)
        return np.array([math.sqrt(c * math.log(b / thr))]) if b > thr else None
    if n == 3:
        d = triangle_spacing(a, b, c, k_n, k_f)
        return None if d is None else np.full(3, d)
    f = _designs(n, k_n, k_f, a, b, c)[0]
    return f.pair_distances if f.spacing > 1e-6 else None


def expected_spacing(
    n: int, *, k_n: float, k_f: float, a: float, b: float, c: float
) -> float | None:
    """The design's nearest-neighbour spacing: the smallest of :func:`design_pairs`, or
    ``None`` without a formation."""
    pairs = design_pairs(n, k_n=k_n, k_f=k_f, a=a, b=b, c=c)
    return None if pairs is None else float(pairs.min())


def b_for_spacing(
    d: float, n: int, *, k_n: float = 1.0, k_f: float = 1.0, a: float = 1.0, c: float = 1.7
) -> float:
    """The b whose equilibrium nearest-neighbour spacing is ``d`` for n trackers: closed
    form for n = 3, else a root search (``brentq``) on :func:`expected_spacing`."""
    if n == 3:
        return triangle_b_for_spacing(d, a, c, k_n, k_f)
    from scipy.optimize import brentq

    def spacing_error(b: float) -> float:
        s = expected_spacing(n, k_n=k_n, k_f=k_f, a=a, b=b, c=c)
        return (s or 0.0) - d

    lo, hi = a * 1.0001, a * 2.0
    while spacing_error(hi) < 0:
        hi *= 2.0
        if hi > 1e9:
            raise ConfigError(f'no b below 1e9 gives spacing {d:g} m for n = {n}')
    return float(brentq(spacing_error, lo, hi, xtol=1e-10))
