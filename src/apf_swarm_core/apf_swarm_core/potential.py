"""The artificial potential of the paper (eq. 2 with the choice of eq. 44) and its gradients.

.. math::

    J = k_N \\sum_i \\tfrac12\\|x_i - x_N\\|^2
        + k_f \\sum_{i<j} \\Big[\\tfrac a2 \\|x_i - x_j\\|^2
        + \\tfrac{bc}{2} e^{-\\|x_i - x_j\\|^2 / c}\\Big]

The extracted text of eq. 44 lost the ``exp``; the form above is the Gazi--Passino
attraction/repulsion function the paper cites. Positions are in metres; with unit gains
``J`` is in m^2 and its gradient in m.

All functions accept optional leading batch dimensions: ``x`` of shape ``(..., n, 3)`` and
``x_target`` of shape ``(..., 3)``. Gains may be Python floats or arrays of shape ``(...)``
broadcastable against the batch shape (one value per run of a batch).

:func:`gradient` is the simulator's hot path; how it is organized (and why row ``i`` of the
full gradient equals ``gradient(..., rows=[i])`` bit for bit) is described in its docstring.
"""

from __future__ import annotations

from functools import lru_cache
from typing import Any, TypeAlias, TypedDict

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .gains import shaped

__all__ = [
    'PotentialParams',
    'Rows',
    'gradient',
    'obstacle_gradient',
    'pair_weight',
    'potential',
    'target_gradient',
]


class PotentialParams(TypedDict):
    """The gains and shape of J (eq. 2 / 44): the keyword arguments of :func:`gradient`
    (a batch passes arrays of per-run values in their place, see
    :class:`~apf_swarm_core.simulator.BatchSimulator`)."""

    k_n: float
    k_f: float
    a: float
    b: float
    c: float


#: which trackers' rows a function computes: all (None), an index array, a list or a slice
Rows: TypeAlias = 'NDArray[np.integer[Any]] | list[int] | slice | int | None'


#: elements of the pair arrays (3, rows, n, runs) of one block of rows in :func:`gradient`
_PAIR_BLOCK = 1 << 16
#: below this many trackers :func:`gradient` sums over j left to right whatever the layout
#: (numpy reduces fewer than 8 elements sequentially), and uses the pair arrays in the
#: arrays' own layout for fewer than ``_LOOP_MIN_RUNS`` runs, a loop over the pairs
#: vectorized over the runs otherwise
_SMALL_N = 8
_LOOP_MIN_RUNS = 64
_F64 = np.dtype(np.float64)
#: three trackers, all rows (the paper's swarm): pairs (i, i+1 mod 3) along the tracker axis
_NEXT3 = np.array([1, 2, 0])
_PREV3 = np.array([2, 0, 1])
_ZERO3 = np.zeros(3, dtype=np.intp)


def pair_weight(r2: ArrayLike, a: ArrayLike, b: ArrayLike, c: ArrayLike) -> NDArray[np.float64]:
    """Attraction/repulsion weight of a pair, ``a - b exp(-r^2/c)`` (derivative of eq. 44).

    The pair force on agent i from agent j is ``-(x_i - x_j) * pair_weight``: positive values
    attract, negative values repel. With ``b <= a`` the weight is positive for every ``r``,
    i.e. the pair term never repels (docs/THEORY.md section 2).

    Parameters
    ----------
    r2 : array, shape (..., n, n)
        Squared pair distances [m^2].
    a, b, c : float or array of shape (...)
        Potential parameters (a, b dimensionless, c in m^2).
    """
    return _pair_weight_neg(np.negative(np.asarray(r2, dtype=float)), a, b, c)


def _pair_weight_neg(
    neg_r2: NDArray[np.float64], a: ArrayLike, b: ArrayLike, c: ArrayLike
) -> NDArray[np.float64]:
    """:func:`pair_weight` from ``-r^2`` (the form in which :func:`gradient`'s strategy for
    three trackers obtains it from its reduction, a negation fewer): ``a - b exp(-r^2 / c)``.

    ``(-r^2)/c`` equals ``-(r^2/c)`` and ``r^2/(-c)`` exactly (rounding is symmetric), so
    the weight has the same bits whichever way the sign enters. Works in place on one
    temporary when the shapes allow (``out`` given positionally: cheaper on small arrays).
    """
    a = a if type(a) is np.ndarray and a.dtype is _F64 and not a.ndim else shaped(a, 2)
    b = b if type(b) is np.ndarray and b.dtype is _F64 and not b.ndim else shaped(b, 2)
    c = c if type(c) is np.ndarray and c.dtype is _F64 and not c.ndim else shaped(c, 2)
    w = np.divide(neg_r2, c)
    if type(w) is not np.ndarray or (
        a.ndim | b.ndim and w.shape != np.broadcast_shapes(w.shape, a.shape, b.shape)
    ):
        return a - b * np.exp(w)
    np.exp(w, w)
    np.multiply(b, w, w)
    return np.subtract(a, w, w)


def _pair_geometry(
    x: NDArray[np.float64], rows: Rows
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Differences ``x_i - x_j`` (..., m, n, 3) and squared distances (..., m, n)."""
    xi = x if rows is None else x[..., rows, :]
    diff = xi[..., :, None, :] - x[..., None, :, :]
    r2 = np.einsum('...k,...k->...', diff, diff)
    return diff, r2


@lru_cache(maxsize=64)
def _off_diagonal(n: int) -> NDArray[np.bool_]:
    """``~np.eye(n, dtype=bool)``, computed once per n (read-only: shared between calls)."""
    out = ~np.eye(n, dtype=bool)
    out.flags.writeable = False
    return out


def potential(
    x: ArrayLike,
    x_target: ArrayLike,
    *,
    k_n: ArrayLike = 1.0,
    k_f: ArrayLike = 1.0,
    a: ArrayLike = 1.0,
    b: ArrayLike = 6.0,
    c: ArrayLike = 1.7,
    mask: ArrayLike | None = None,
) -> NDArray[np.float64]:
    """Potential J of the whole swarm, paper eq. 2 with eq. 44.

    Parameters
    ----------
    x : array, shape (..., n, 3)
        Tracker positions x_i [m].
    x_target : array, shape (..., 3)
        Target position x_N [m].
    k_n, k_f : float or array (...)
        Weights of the tracking term and of the formation term.
    a, b, c : float or array (...)
        Pair-potential parameters of eq. 44.
    mask : bool array, shape (..., n, n), optional
        Symmetric neighbour mask: pair (i, j) contributes only where ``mask[i, j]``.
        ``None`` means every pair (the paper's all-to-all potential).

    Returns
    -------
    J : array, shape (...)
        The potential [m^2 with unit gains].
    """
    x = np.asarray(x, dtype=float)
    x_target = np.asarray(x_target, dtype=float)
    rel = x - x_target[..., None, :]
    track = 0.5 * np.einsum('...ik,...ik->...', rel, rel)
    _, r2 = _pair_geometry(x, None)
    pair = 0.5 * shaped(a, 2) * r2 + 0.5 * shaped(b, 2) * shaped(c, 2) * np.exp(-r2 / shaped(c, 2))
    offdiag = _off_diagonal(x.shape[-2])
    if mask is not None:
        offdiag = offdiag & np.asarray(mask, dtype=bool)
    # each unordered pair appears twice in the full (n, n) matrix
    form = 0.5 * np.sum(np.where(offdiag, pair, 0.0), axis=(-2, -1))
    return shaped(k_n, 0) * track + shaped(k_f, 0) * form


def gradient(
    x: ArrayLike,
    x_target: ArrayLike,
    *,
    k_n: ArrayLike = 1.0,
    k_f: ArrayLike = 1.0,
    a: ArrayLike = 1.0,
    b: ArrayLike = 6.0,
    c: ArrayLike = 1.7,
    rows: Rows = None,
    mask: ArrayLike | None = None,
) -> NDArray[np.float64]:
    """Analytic gradient of J with respect to the trackers (from eq. 2 / 44).

    .. math::

        \\nabla_{x_i} J = k_N (x_i - x_N)
            + k_f \\sum_{j \\ne i} (x_i - x_j)\\,(a - b\\,e^{-\\|x_i - x_j\\|^2/c})

    Vectorized over pairs; no Python loop over agents. A tracker node that knows its own
    position and its neighbours' evaluates its own row with ``rows=[i]``: the same function,
    the same arithmetic, as the simulator that evaluates all rows.

    Evaluation strategy (performance only; the same terms, ``d_ij = x_i - x_j``,
    ``r_ij^2 = (d_x^2 + d_y^2) + d_z^2``, ``d_ij * pair_weight_ij`` summed over j):

    * exactly 3 trackers, every row, fewer than 64 runs (a single run of the paper's
      swarm): the three pairs (i, i+1 mod 3) once each, every array of the run's own shape
      (..., 3, 3) so that numpy takes its fast path for operands of equal shapes;
    * otherwise fewer than 8 trackers and fewer than 64 runs: whole pair arrays of shape
      (..., m, n, 3) in the arrays' own layout;
    * fewer than 8 trackers and at least 64 runs: a loop over the pairs, each evaluated once
      and vectorized over the runs (``_pair_sums_by_pair``);
    * 8 trackers or more: a component-major copy of the positions and whole pair arrays for
      blocks of rows of about ``2**16`` elements (``_pair_sums_by_rows``), runs innermost if
      there are at least n runs, outermost otherwise, so that large swarms work in
      cache-sized pieces with long inner loops.

    Every term is computed independently of the others and each row's sum over j depends
    only on that row, so the result of a row does not depend on which or how many other rows
    are evaluated: ``gradient(x, ..., rows=[i])`` equals row i of ``gradient(x, ...)``
    exactly, and the blocking changes no value. Below 8 trackers numpy sums over j left to
    right in every strategy, so a run inside a batch also equals the same run alone bit for
    bit; from 8 trackers on, a batch with runs innermost sums in another order than a single
    run and the two may differ by rounding.

    Parameters
    ----------
    x : array, shape (..., n, 3)
        Tracker positions [m].
    x_target : array, shape (..., 3)
        Target position [m].
    k_n, k_f, a, b, c : float or array (...)
        Gains and pair parameters of eq. 44.
    rows : index array, optional
        Trackers whose gradient is wanted (default: all ``n``).
    mask : bool array, shape (..., m, n), optional
        Neighbour mask for the selected rows: ``mask[i, j]`` says whether j is a neighbour of
        row i. ``None`` means all trackers (the paper's potential).

    Returns
    -------
    grad : array, shape (..., m, 3)
        ``m = n`` or ``len(rows)``; units m with unit gains.
    """
    x = np.asarray(x, dtype=float)
    x_target = np.asarray(x_target, dtype=float)
    lead, n = x.shape[:-2], x.shape[-2]
    # (0-d float64 arrays, the simulator's prepared gains, pass through unchanged)
    kn = k_n if type(k_n) is np.ndarray and k_n.dtype is _F64 and not k_n.ndim else shaped(k_n, 0)
    kf = k_f if type(k_f) is np.ndarray and k_f.dtype is _F64 and not k_f.ndim else shaped(k_f, 0)
    if mask is not None:
        mask = np.asarray(mask, dtype=bool)
    if (
        x_target.shape[:-1] != lead
        or kn.ndim
        or kf.ndim
        or (mask is not None and mask.ndim > 2)
        or not (
            (type(a) is type(b) is type(c) is np.ndarray and not (a.ndim | b.ndim | c.ndim))
            or (_is_scalar(a) and _is_scalar(b) and _is_scalar(c))
        )
    ):
        full = np.broadcast_shapes(
            lead,
            x_target.shape[:-1],
            kn.shape,
            kf.shape,
            np.shape(a),
            np.shape(b),
            np.shape(c),
            () if mask is None else mask.shape[:-2],
        )
        if full != lead:  # more runs in the target, gains or mask than in x
            return gradient(
                np.broadcast_to(x, (*full, n, 3)),
                x_target,
                k_n=k_n,
                k_f=k_f,
                a=a,
                b=b,
                c=c,
                rows=rows,
                mask=mask,
            )
        x_target = np.broadcast_to(x_target, (*lead, 3))
    B = x.size // (3 * n) if n else 1  # runs in the batch
    if n == 3 and rows is None and mask is None and B < _LOOP_MIN_RUNS:
        # the paper's swarm: the three pairs (i, i+1 mod 3) once each, every array of the
        # shape (..., 3, 3), so that each numpy call takes its fast path for equal shapes
        # (no broadcasting and one reduction). t_i = (x_i - x_{i+1}) w_{i,i+1} is row i's
        # term for j = i+1 and -t_{i-1} its term for j = i-1 (x_i - x_{i-1} and its squared
        # norm are exact under negation), so row i's pair sum is t_i - t_{i-1}: the two terms
        # the whole-array form adds (its self term is a signed zero, which adds nothing), and
        # with two terms the order of the sum is immaterial (addition commutes exactly). Same
        # bits as every other strategy, and as rows=[i].
        d = x - x.take(_NEXT3, axis=-2)  # x_i - x_{i+1}
        # -r^2 = ((0 - d_x^2) - d_y^2) - d_z^2, exactly the negated sum of the other forms;
        # a unit last axis so that per-run gains (..., 1, 1) broadcast as in the others
        w = _pair_weight_neg(np.subtract.reduce(d * d, -1, keepdims=True, initial=0.0), a, b, c)
        np.multiply(d, w.take(_ZERO3, axis=-1), d)  # t_i
        pair = d.take(_PREV3, axis=-2)
        np.subtract(d, pair, pair)  # t_i - t_{i-1}
        rel = x - x_target[..., None, :].take(_ZERO3, axis=-2)  # x_i - x_N
        if kn.ndim or float(kn) != 1.0:  # (a product by 1.0 changes nothing)
            rel *= kn[..., None, None]
        if kf.ndim or float(kf) != 1.0:
            pair *= kf[..., None, None]
        return np.add(rel, pair, rel)
    if n < _SMALL_N and (B < _LOOP_MIN_RUNS or mask is not None):
        # few trackers, few runs: arrays in their own layout, pair arrays (..., m, n, 3)
        xi = x if rows is None else x[..., rows, :]
        d = xi[..., :, None, :] - x[..., None, :, :]
        w = pair_weight(np.add.reduce(d * d, axis=-1), a, b, c)
        if mask is not None:
            w = np.where(mask, w, 0.0)
        # the self pair has d == 0, so it contributes nothing whatever its weight
        d *= w[..., None]
        pair = np.add.reduce(d, axis=-2)
        rel = xi - x_target[..., None, :]
        if kn.ndim or float(kn) != 1.0:  # (a product by 1.0 changes nothing)
            rel *= kn[..., None, None]
        if kf.ndim or float(kf) != 1.0:
            pair *= kf[..., None, None]
        rel += pair
        return rel
    # component-major copy, logical shape (3, n, B): physically (3, n, B) when the runs go
    # innermost, (B, 3, n) otherwise; numpy keeps that memory order in every temporary
    xb = x.reshape((B, n, 3))
    runs_inner = B > 1 and n <= B
    if runs_inner:
        X = xb.transpose(2, 1, 0).copy()
    else:
        X = xb.transpose(0, 2, 1).copy().transpose(1, 2, 0)
    Xi = X if rows is None else X[:, rows]  # (3, m, B)
    if n < _SMALL_N:
        pair = _pair_sums_by_pair(X, rows, lead, a, b, c)
    else:
        pair = _pair_sums_by_rows(X, Xi, lead, a, b, c, mask)
    rel = Xi - x_target.reshape((B, 3)).T[:, None, :]  # x_i - x_N, (3, m, B)
    if kn.ndim or float(kn) != 1.0:
        rel *= kn.reshape(B) if kn.ndim else kn
    if kf.ndim or float(kf) != 1.0:
        pair *= kf.reshape(B) if kf.ndim else kf
    out = np.empty((*lead, Xi.shape[1], 3))
    np.add(rel, pair, out=out.reshape((B, -1, 3)).transpose(2, 1, 0))
    return out


def _is_scalar(value: ArrayLike) -> bool:
    if type(value) is np.ndarray:
        return not value.ndim
    return type(value) is float or np.ndim(value) == 0


def _pair_sums_by_rows(
    X: NDArray[np.float64],
    Xi: NDArray[np.float64],
    lead: tuple[int, ...],
    a: ArrayLike,
    b: ArrayLike,
    c: ArrayLike,
    mask: NDArray[np.bool_] | None,
) -> NDArray[np.float64]:
    """``sum_j (x_i - x_j) pair_weight_ij`` for the rows ``Xi`` (3, m, B) against ``X``
    (3, n, B), in blocks of rows, as whole (3, rows, n, B) arrays; returns (3, m, B)."""
    _, n, B = X.shape
    m = Xi.shape[1]
    step = max(1, _PAIR_BLOCK // (3 * n * B))
    parts = []
    for r0 in range(0, m, step):
        d = (Xi if step >= m else Xi[:, r0 : r0 + step])[:, :, None, :] - X[:, None, :, :]
        sq = d * d
        r2 = sq[0] + sq[1]
        r2 += sq[2]  # (mb, n, B), same sum as a reduce
        mb = r2.shape[0]
        # pair_weight sees the usual (..., mb, n) axes, for per-run gains of shape (...)
        w = pair_weight(r2.transpose(2, 0, 1).reshape((*lead, mb, n)), a, b, c)
        if mask is not None:
            w = np.where(mask[..., r0 : r0 + mb, :], w, 0.0)
        # the self pair has d == 0, so it contributes nothing whatever its weight
        d *= w.reshape((B, mb, n)).transpose(1, 2, 0)
        parts.append(np.add.reduce(d, axis=2))  # (3, mb, B)
    return parts[0] if len(parts) == 1 else np.concatenate(parts, axis=1)


def _pair_sums_by_pair(
    X: NDArray[np.float64],
    rows: Rows,
    lead: tuple[int, ...],
    a: ArrayLike,
    b: ArrayLike,
    c: ArrayLike,
) -> NDArray[np.float64]:
    """The same sums as :func:`_pair_sums_by_rows`, one pair at a time, vectorized over the
    runs of a batch (X of shape (3, n, B), runs innermost): for few trackers and many runs.

    Without ``rows`` each unordered pair is evaluated once and its term added to row i and
    subtracted from row j (``x_j - x_i = -(x_i - x_j)`` and ``r^2`` are exact under
    negation). Each row still receives its terms in the order j = 0, 1, ..., n-1, the
    left-to-right order in which numpy reduces fewer than 8 terms, so for n < 8 this gives
    the same bits as the whole-array forms.
    """
    _, n, B = X.shape
    wshape = (*lead, 1, 1)

    def term(i: int, j: int) -> NDArray[np.float64]:
        """(x_i - x_j) pair_weight_ij of every run, shape (3, B)."""
        d = X[:, i] - X[:, j]
        sq = d * d
        r2 = sq[0] + sq[1]
        r2 += sq[2]
        d *= pair_weight(r2.reshape(wshape), a, b, c).reshape(B)
        return d

    if rows is None:
        acc = np.zeros((3, n, B))
        for i in range(n):
            for j in range(i + 1, n):
                t = term(i, j)
                acc[:, i] += t
                acc[:, j] -= t
        return acc
    index = np.arange(n)[rows].reshape(-1)  # any index form -> tracker numbers
    acc = np.zeros((3, len(index), B))
    for p, i in enumerate(index.tolist()):
        for j in range(n):
            if j != i:
                acc[:, p] += term(i, j)
    return acc


def target_gradient(
    x: ArrayLike, x_target: ArrayLike, *, k_n: ArrayLike = 1.0
) -> NDArray[np.float64]:
    """Gradient of J with respect to the target, ``-k_N sum_i (x_i - x_N)`` (eq. 6, 17).

    Parameters
    ----------
    x : array, shape (..., n, 3)
    x_target : array, shape (..., 3)

    Returns
    -------
    grad_N : array, shape (..., 3)
    """
    x = np.asarray(x, dtype=float)
    x_target = np.asarray(x_target, dtype=float)
    return -shaped(k_n, 1) * np.sum(x - x_target[..., None, :], axis=-2)


def obstacle_gradient(
    x: ArrayLike,
    obstacles: ArrayLike,
    *,
    k_f: ArrayLike = 1.0,
    b: ArrayLike = 6.0,
    c: ArrayLike = 1.7,
) -> NDArray[np.float64]:
    """Gradient of the repulsive half of the pair term of eq. 44 with respect to ``x``,
    from bodies that repel but do not attract (not in the paper; used for a tracker whose
    controller is silent, see :mod:`apf_swarm_core.agents`).

    .. math::

        \\nabla_{x_i} \\, k_f \\sum_o \\tfrac{bc}{2} e^{-\\|x_i - x_o\\|^2/c}
            = k_f \\sum_o (x_i - x_o)\\,(0 - b\\,e^{-\\|x_i - x_o\\|^2/c})

    i.e. :func:`pair_weight` with ``a = 0``.

    Parameters
    ----------
    x : array, shape (m, 3)
        Positions whose gradient is wanted [m].
    obstacles : array, shape (k, 3)
        Positions of the repelling bodies [m] (k may be 0).
    k_f, b, c : float
        Formation weight and the repulsion parameters of eq. 44.

    Returns
    -------
    array, shape (m, 3) [m with unit gains]
    """
    x = np.asarray(x, dtype=float)
    obstacles = np.asarray(obstacles, dtype=float).reshape(-1, 3)
    d = x[:, None, :] - obstacles[None, :, :]
    w = pair_weight(np.einsum('mok,mok->mo', d, d), 0.0, b, c)
    return float(np.asarray(k_f)) * np.einsum('mok,mo->mk', d, w)
