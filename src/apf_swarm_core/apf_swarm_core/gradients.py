"""The gradients of J (eq. 2 / 44): with respect to the trackers (:func:`gradient`, the
simulator's hot path), to the target (:func:`target_gradient`) and to bodies that only repel
(:func:`obstacle_gradient`).

Shapes and gains as in :mod:`apf_swarm_core.potential`: ``x`` of shape ``(..., n, 3)``,
``x_target`` of shape ``(..., 3)``, gains floats or arrays of shape ``(...)`` (one value per
run of a batch). How :func:`gradient` is organized, and why row ``i`` of the full gradient
equals ``gradient(..., rows=[i])`` bit for bit, is described in its docstring.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .gains import shaped
from .potential import _F64, Rows, _pair_weight_neg, pair_weight

__all__ = ['gradient', 'obstacle_gradient', 'target_gradient']

#: elements of the pair arrays (3, rows, n, runs) of one block of rows in :func:`gradient`
_PAIR_BLOCK = 1 << 16
#: below this many trackers :func:`gradient` sums over j left to right whatever the layout
#: (numpy reduces fewer than 8 elements sequentially), and uses the pair arrays in the
#: arrays' own layout for fewer than ``_LOOP_MIN_RUNS`` runs, a loop over the pairs
#: vectorized over the runs otherwise
_SMALL_N = 8
_LOOP_MIN_RUNS = 64
#: three trackers, all rows (the paper's swarm): pairs (i, i+1 mod 3) along the tracker axis
_NEXT3 = np.array([1, 2, 0])
_PREV3 = np.array([2, 0, 1])
_ZERO3 = np.zeros(3, dtype=np.intp)


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
