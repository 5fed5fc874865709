"""Compiled kernels of the control hot path (numba): the gradient rows of J (eq. 2 / 44),
the trackers' own Hessian blocks and the block-preconditioned direction of ``precondition =
block``. The numpy-facing functions (:func:`~apf_swarm_core.gradients.gradient`,
:func:`~apf_swarm_core.newton.hessian_blocks`, :func:`~apf_swarm_core.newton.block_direction`)
shape their arguments and call these; the simulator, the emulation and the tracker nodes all
reach the same machine code.

Every kernel takes one batch axis first (``B`` runs; per-run gains as arrays of shape
``(B,)``), computes each selected row on its own and sums over j = 0, 1, ..., n-1 in that
order, so a row's value does not depend on which other rows or runs are computed with it:
``rows=[i]`` in a tracker node equals row i of the simulator's all-rows call bit for bit.
No ``fastmath``: the same bits on every call path. ``cache=True`` keeps the compiled code
beside this module (numba's cache), so a process loads it instead of compiling it; the
fork-based start loads it once in the zygote (:func:`warm`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any, NamedTuple, TypeVar, cast

import numpy as np
from numba import njit
from numpy.typing import ArrayLike, NDArray

from .potential import Rows

__all__ = [
    'Args',
    'block_rows',
    'block_steps',
    'gradient_rows',
    'hessian_rows',
    'kernel_args',
    'warm',
]

_F = TypeVar('_F', bound=Callable[..., Any])
_A = NDArray[np.float64]
_I = NDArray[np.int64]
_M = NDArray[np.bool_]


def _jit(fn: _F) -> _F:
    """numba's ``njit`` as every kernel here is compiled: cached, without the GIL, numpy's
    error model, no fastmath."""
    return cast(_F, njit(cache=True, nogil=True, error_model='numpy')(fn))


@_jit
def _row_sums(
    x: _A,
    r: int,
    i: int,
    mask: _M,
    mr: int,
    k: int,
    a: float,
    b: float,
    c: float,
    want_h: bool,
    s: _A,
    h: _A,
) -> None:
    """Pair sums of row ``i`` of run ``r``: ``s = sum_j d_ij (a - b e_ij)`` (eq. 2 / 44) and,
    with ``want_h``, ``h = [count, sum e, sum e d d^T (6 entries: xx yy zz xy xz yz)]``;
    ``d_ij = x_i - x_j``, ``e_ij = exp(-|d_ij|^2 / c)``, j over every other tracker or the
    row's neighbours in ``mask[mr, k]`` (an empty mask: all)."""
    n = x.shape[1]
    masked = mask.shape[0] > 0
    xi, yi, zi = x[r, i, 0], x[r, i, 1], x[r, i, 2]
    sx = sy = sz = 0.0
    cnt = se = hxx = hyy = hzz = hxy = hxz = hyz = 0.0
    for j in range(n):
        if j == i:
            continue
        if masked and not mask[mr, k, j]:
            continue
        dx = xi - x[r, j, 0]
        dy = yi - x[r, j, 1]
        dz = zi - x[r, j, 2]
        e = math.exp(-(dx * dx + dy * dy + dz * dz) / c)
        w = a - b * e
        sx += dx * w
        sy += dy * w
        sz += dz * w
        if want_h:
            cnt += 1.0
            se += e
            hxx += e * dx * dx
            hyy += e * dy * dy
            hzz += e * dz * dz
            hxy += e * dx * dy
            hxz += e * dx * dz
            hyz += e * dy * dz
    s[0], s[1], s[2] = sx, sy, sz
    if want_h:
        h[0], h[1], h[2], h[3] = cnt, se, hxx, hyy
        h[4], h[5], h[6], h[7] = hzz, hxy, hxz, hyz


@_jit
def _block(h: _A, kn: float, kf: float, a: float, b: float, c: float, out: _A) -> None:
    """The Hessian block ``H_ii = k_N I + k_f [(a n_i - b sum e) I + (2b/c) sum e d d^T]``
    from the sums ``h`` of :func:`_row_sums`, into ``out`` (3, 3)."""
    iso = kf * (a * h[0] - b * h[1]) + kn
    curv = kf * 2.0 * b / c
    out[0, 0] = iso + curv * h[2]
    out[1, 1] = iso + curv * h[3]
    out[2, 2] = iso + curv * h[4]
    out[0, 1] = out[1, 0] = curv * h[5]
    out[0, 2] = out[2, 0] = curv * h[6]
    out[1, 2] = out[2, 1] = curv * h[7]


@_jit
def _step(H: _A, g: _A, gbar: _A, kn: float, mu: float, trust: float, out: _A) -> None:
    """``out = gbar / k_N + |H|_mu^-1 (g - gbar)`` for one tracker (the formula of
    :func:`~apf_swarm_core.newton.block_direction`): ``|H|_mu = V diag(max(|lambda|, mu_i))
    V^T``, ``mu_i = max(mu, |g - gbar| / trust)`` with a trust radius."""
    w, v = np.linalg.eigh(H)
    r0, r1, r2 = g[0] - gbar[0], g[1] - gbar[1], g[2] - gbar[2]
    floor = mu
    if trust > 0.0:
        floor = max(floor, math.sqrt(r0 * r0 + r1 * r1 + r2 * r2) / trust)
    for q in range(3):
        out[q] = gbar[q] / kn
    for p in range(3):
        coef = (v[0, p] * r0 + v[1, p] * r1 + v[2, p] * r2) / max(abs(w[p]), floor)
        for q in range(3):
            out[q] += v[q, p] * coef


@_jit
def gradient_rows(x: _A, tx: _A, rows: _I, mask: _M, gains: _A) -> _A:
    """Gradient rows of J (eq. 2 / 44), shape (B, m, 3): ``k_N (x_i - x_N) + k_f sum_j
    d_ij (a - b e_ij)``.

    x (B, n, 3) [m]; tx (B, 3) [m]; rows (m,) int64; mask (Bm, m, n) bool with Bm in
    {0 (none), 1, B}; gains (B, 5): k_n, k_f, a, b, c of each run.
    """
    B, m = x.shape[0], rows.shape[0]
    out = np.empty((B, m, 3))
    s = np.empty(3)
    h = np.empty(8)
    for r in range(B):
        mr = r if mask.shape[0] > 1 else 0
        kn, kf, a, b, c = gains[r, 0], gains[r, 1], gains[r, 2], gains[r, 3], gains[r, 4]
        for k in range(m):
            i = rows[k]
            _row_sums(x, r, i, mask, mr, k, a, b, c, False, s, h)
            for q in range(3):
                out[r, k, q] = kn * (x[r, i, q] - tx[r, q]) + kf * s[q]
    return out


@_jit
def hessian_rows(x: _A, rows: _I, mask: _M, gains: _A) -> _A:
    """The trackers' own Hessian blocks ``H_ii``, shape (B, m, 3, 3) (arguments as
    :func:`gradient_rows`)."""
    B, m = x.shape[0], rows.shape[0]
    out = np.empty((B, m, 3, 3))
    s = np.empty(3)
    h = np.empty(8)
    for r in range(B):
        mr = r if mask.shape[0] > 1 else 0
        kn, kf, a, b, c = gains[r, 0], gains[r, 1], gains[r, 2], gains[r, 3], gains[r, 4]
        for k in range(m):
            _row_sums(x, r, rows[k], mask, mr, k, a, b, c, True, s, h)
            _block(h, kn, kf, a, b, c, out[r, k])
    return out


@_jit
def block_steps(blocks: _A, grad: _A, gbar: _A, kn: _A, mu: float, trust: float) -> _A:
    """The block direction from given blocks (B, m, 3, 3), gradient rows (B, m, 3) and
    centroid gradients (B, 3); kn (B,); shape (B, m, 3)."""
    B, m = grad.shape[0], grad.shape[1]
    out = np.empty((B, m, 3))
    for r in range(B):
        for k in range(m):
            _step(blocks[r, k], grad[r, k], gbar[r], kn[r], mu, trust, out[r, k])
    return out


@_jit
def block_rows(x: _A, tx: _A, rows: _I, mask: _M, gains: _A, mu: float, trust: float) -> _A:
    """The direction of ``precondition = block`` for the rows, shape (B, m, 3), in one pass
    over each row's pairs: its gradient row (:func:`gradient_rows`), its Hessian block
    (:func:`hessian_rows`) and the step of :func:`block_steps` with ``g_bar = k_N (mean x -
    x_N)`` over every tracker in ``x``."""
    B, n, m = x.shape[0], x.shape[1], rows.shape[0]
    out = np.empty((B, m, 3))
    s = np.empty(3)
    h = np.empty(8)
    g = np.empty(3)
    gbar = np.empty(3)
    H = np.empty((3, 3))
    for r in range(B):
        mr = r if mask.shape[0] > 1 else 0
        kn, kf, a, b, c = gains[r, 0], gains[r, 1], gains[r, 2], gains[r, 3], gains[r, 4]
        for q in range(3):
            acc = 0.0
            for j in range(n):
                acc += x[r, j, q]
            gbar[q] = kn * (acc / n - tx[r, q])
        for k in range(m):
            i = rows[k]
            _row_sums(x, r, i, mask, mr, k, a, b, c, True, s, h)
            for q in range(3):
                g[q] = kn * (x[r, i, q] - tx[r, q]) + kf * s[q]
            _block(h, kn, kf, a, b, c, H)
            _step(H, g, gbar, kn, mu, trust, out[r, k])
    return out


def warm() -> None:
    """Load (or compile, the first time on a machine) every kernel for the argument types
    the hot path uses, so that no control step pays for it: called by the zygote before it
    forks the nodes, and by ``make setup``."""
    x = np.zeros((1, 2, 3))
    x[0, 1, 0] = 1.0
    tx = np.zeros((1, 3))
    rows = np.arange(2, dtype=np.int64)
    gains = np.ones((1, 5))
    for mask in (np.zeros((0, 2, 2), dtype=np.bool_), np.ones((1, 2, 2), dtype=np.bool_)):
        gradient_rows(x, tx, rows, mask, gains)
        hessian_rows(x, rows, mask, gains)
        block_rows(x, tx, rows, mask, gains, 0.1, 0.0)
        block_rows(x, tx, rows, mask, gains, 0.1, 0.5)
    blocks = hessian_rows(x, rows, np.zeros((0, 2, 2), dtype=np.bool_), gains)
    block_steps(blocks, np.zeros((1, 2, 3)), np.zeros((1, 3)), np.ones(1), 0.1, 0.0)


class Args(NamedTuple):
    """The arguments of a kernel call, shaped: see :func:`kernel_args`."""

    x: NDArray[np.float64]  # (B, n, 3)
    tx: NDArray[np.float64]  # (B, 3)
    rows: NDArray[np.int64]  # (m,)
    mask: NDArray[np.bool_]  # (Bm, m, n), Bm in {0, 1, B}
    gains: NDArray[np.float64]  # (B, 5): k_n, k_f, a, b, c of each run
    shape: tuple[int, ...]  # the result's leading shape: (..., m) or (...) for an int row


_NO_MASK: dict[tuple[int, int], NDArray[np.bool_]] = {}


def _rows(rows: Rows, n: int) -> tuple[NDArray[np.int64], bool]:
    """The row numbers (m,) int64 and whether ``rows`` was a single int."""
    if rows is None:
        return np.arange(n, dtype=np.int64), False
    if type(rows) is list and all(type(r) is int and 0 <= r < n for r in rows):
        return np.array(rows, dtype=np.int64), False
    idx = np.arange(n, dtype=np.int64)[rows]
    return np.ascontiguousarray(idx.reshape(-1)), idx.ndim == 0


def _no_mask(m: int, n: int) -> NDArray[np.bool_]:
    """The empty mask (0, m, n) of 'every other tracker' (shared; it has no element to
    write, and a writeable array keeps the kernels' one compiled signature)."""
    out = _NO_MASK.get((m, n))
    if out is None:
        out = _NO_MASK[m, n] = np.zeros((0, m, n), dtype=np.bool_)
    return out


def kernel_args(
    x: ArrayLike,
    x_target: ArrayLike | None,
    gains: Sequence[ArrayLike],
    rows: Rows,
    mask: ArrayLike | None,
) -> Args:
    """Positions, target, rows, mask and per-run gains (``k_n, k_f, a, b, c``, floats or
    arrays of the runs' shape ``(...)``) as the kernels take them, every run axis of the
    batch broadcast together and flattened into one of length ``B``."""
    x = np.asarray(x, dtype=np.float64)
    n = x.shape[-2]
    idx, single = _rows(rows, n)
    m = idx.size
    tx = np.zeros(3) if x_target is None else np.asarray(x_target, dtype=np.float64)
    if x.ndim == 2 and tx.ndim == 1 and mask is None:
        try:  # one run with one value of each gain: the tracker node's call
            g = np.array([[float(v) for v in gains]])  # type: ignore[arg-type]
        except TypeError:
            pass
        else:
            return Args(
                np.ascontiguousarray(x).reshape(1, n, 3),
                tx.reshape(1, 3),
                idx,
                _no_mask(m, n),
                g,
                () if single else (m,),
            )
    arrays = [np.asarray(v, dtype=np.float64) for v in gains]
    mk = None if mask is None else np.asarray(mask, dtype=np.bool_)
    lead = x.shape[:-2]
    if (
        tx.shape[:-1] != lead
        or any(v.ndim and v.shape != lead for v in arrays)
        or (mk is not None and mk.ndim > 2 and mk.shape[:-2] != lead)
    ):  # broadcast every run axis together (the arrays' own shapes are the usual case)
        lead = np.broadcast_shapes(
            lead,
            tx.shape[:-1],
            *(v.shape for v in arrays),
            () if mk is None or mk.ndim <= 2 else mk.shape[:-2],
        )
        x = np.broadcast_to(x, (*lead, n, 3))
        tx = np.broadcast_to(tx, (*lead, 3))
        arrays = [v if not v.ndim else np.broadcast_to(v, lead) for v in arrays]
        if mk is not None and mk.ndim > 2:
            mk = np.broadcast_to(mk, (*lead, m, n))
    runs = math.prod(lead)
    xs = np.ascontiguousarray(x).reshape(runs, n, 3)
    ts = np.ascontiguousarray(tx).reshape(runs, 3)
    if mk is None:
        ms = _no_mask(m, n)
    elif mk.ndim <= 2:
        ms = np.ascontiguousarray(np.broadcast_to(mk, (1, m, n)))
    else:
        ms = np.ascontiguousarray(mk).reshape(runs, m, n)
    g = np.empty((runs, len(arrays)))
    for q, v in enumerate(arrays):
        g[:, q] = v.reshape(runs) if v.ndim else v
    return Args(xs, ts, idx, ms, g, lead if single else (*lead, m))
