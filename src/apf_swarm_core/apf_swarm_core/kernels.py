"""Compiled kernels of the control hot path (numba): the gradient rows of J (eq. 2 / 44), the
trackers' own Hessian blocks, the block-preconditioned direction, the sliding-mode step (eq.
20-31), the plant (eq. 19-21) and the simulator's closed loop; the simulator, the emulation and
the tracker nodes all run this machine code (docs/THEORY.md tables the equations).

Every kernel takes one batch axis first (``B`` runs; per-run gains as arrays of shape
``(B,)``) and sums over j = 0, 1, ..., n-1 in that order, so a row's value does not depend on
which other rows or runs are computed with it: ``rows=[i]`` in a tracker node equals row i of
the simulator's all-rows call bit for bit. No ``fastmath``: the same bits on every call path.
``cache=True`` keeps the compiled code beside this module; :func:`warm` loads it.
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
    'CTL_COLUMNS',
    'Args',
    'as_kernel',
    'block_rows',
    'gradient_rows',
    'hessian_rows',
    'kernel_args',
    'plant_rows',
    'simulate_steps',
    'smc_rows',
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
def _step(
    H: _A, g: _A, gbar: _A, kn: float, mu: float, trust: float, out: _A, r: int, k: int
) -> None:
    """``out[r, k] = gbar / k_N + |H|_mu^-1 (g - gbar)`` for one tracker (docs/THEORY.md,
    Large swarms): ``|H|_mu = V diag(max(|lambda|, mu_i)) V^T``, ``mu_i = max(mu, |g - gbar| /
    trust)`` with a trust radius."""
    w, v = np.linalg.eigh(H)
    r0, r1, r2 = g[0] - gbar[0], g[1] - gbar[1], g[2] - gbar[2]
    floor = mu
    if trust > 0.0:
        floor = max(floor, math.sqrt(r0 * r0 + r1 * r1 + r2 * r2) / trust)
    for q in range(3):
        out[r, k, q] = gbar[q] / kn
    for p in range(3):
        coef = (v[0, p] * r0 + v[1, p] * r1 + v[2, p] * r2) / max(abs(w[p]), floor)
        for q in range(3):
            out[r, k, q] += v[q, p] * coef


@_jit
def _scratch() -> tuple[_A, _A, _A, _A, _A]:
    """Work arrays of :func:`_directions`: pair sums (3,), Hessian sums (8,), a gradient
    row (3,), the centroid's gradient (3,), a Hessian block (3, 3)."""
    return np.empty(3), np.empty(8), np.empty(3), np.empty(3), np.empty((3, 3))


@_jit
def _directions(
    x: _A,
    r: int,
    tx: _A,
    tr: int,
    rows: _I,
    mask: _M,
    gains: _A,
    block: bool,
    mu: float,
    trust: float,
    out: _A,
    s: _A,
    h: _A,
    g: _A,
    gbar: _A,
    H: _A,
) -> None:
    """Run ``r``'s direction for each row into ``out[r]`` (out (B, m, 3)): its gradient
    row, ``k_N (x_i - x_N) + k_f sum_j d_ij (a - b e_ij)`` (eq. 2 / 44), or with ``block``
    the step of :func:`_step` from it, its Hessian block and ``g_bar = k_N (mean x -
    x_N)``. ``tx[tr]`` (tx (., 3)) the run's target; s, h, g, gbar, H scratch
    (:func:`_scratch`)."""
    n, m = x.shape[1], rows.shape[0]
    mr = r if mask.shape[0] > 1 else 0
    kn, kf, a, b, c = gains[r, 0], gains[r, 1], gains[r, 2], gains[r, 3], gains[r, 4]
    if block:
        for q in range(3):
            acc = 0.0
            for j in range(n):
                acc += x[r, j, q]
            gbar[q] = kn * (acc / n - tx[tr, q])
    for k in range(m):
        i = rows[k]
        _row_sums(x, r, i, mask, mr, k, a, b, c, block, s, h)
        for q in range(3):
            g[q] = kn * (x[r, i, q] - tx[tr, q]) + kf * s[q]
        if block:
            _block(h, kn, kf, a, b, c, H)
            _step(H, g, gbar, kn, mu, trust, out, r, k)
        else:
            for q in range(3):
                out[r, k, q] = g[q]


@_jit
def gradient_rows(x: _A, tx: _A, rows: _I, mask: _M, gains: _A) -> _A:
    """Gradient rows of J (eq. 2 / 44), shape (B, m, 3): ``k_N (x_i - x_N) + k_f sum_j
    d_ij (a - b e_ij)``.

    x (B, n, 3) [m]; tx (B, 3) [m]; rows (m,) int64; mask (Bm, m, n) bool with Bm in
    {0 (none), 1, B}; gains (B, 5): k_n, k_f, a, b, c of each run.
    """
    B, m = x.shape[0], rows.shape[0]
    out = np.empty((B, m, 3))
    s, h, g, gbar, H = _scratch()
    for r in range(B):
        _directions(x, r, tx, r, rows, mask, gains, False, 0.0, 0.0, out, s, h, g, gbar, H)
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
def block_rows(x: _A, tx: _A, rows: _I, mask: _M, gains: _A, mu: float, trust: float) -> _A:
    """The direction of ``precondition = block`` for the rows, shape (B, m, 3), in one pass
    over each row's pairs: its gradient row (:func:`gradient_rows`), its Hessian block
    (:func:`hessian_rows`) and the step of :func:`_step` with ``g_bar = k_N (mean x - x_N)``
    over every tracker in ``x``."""
    B, m = x.shape[0], rows.shape[0]
    out = np.empty((B, m, 3))
    s, h, g, gbar, H = _scratch()
    for r in range(B):
        _directions(x, r, tx, r, rows, mask, gains, True, mu, trust, out, s, h, g, gbar, H)
    return out


#: the columns of the controller's per-run gains (B, 10) that :func:`smc_rows` takes
CTL_COLUMNS = ('alpha', 'beta', 'gamma', 'layer_gain', 'neg_u0', 'drag', 'decay', 'gain_in')
CTL_COLUMNS += ('inv_phi', 'feedforward')
CTL_ALPHA, CTL_BETA, CTL_GAMMA, CTL_LAYER_GAIN, CTL_NEG_U0 = 0, 1, 2, 3, 4
CTL_DRAG, CTL_DECAY, CTL_GAIN_IN, CTL_INV_PHI, CTL_FEEDFORWARD = 5, 6, 7, 8, 9


@_jit
def _sign(value: float) -> float:
    """numpy's sign: 1, -1, 0 for either zero, NaN for NaN (eq. 8, 24, 26)."""
    if value > 0.0:
        return 1.0
    if value < 0.0:
        return -1.0
    if value == 0.0:
        return 0.0
    return value


@_jit
def _smc(
    v: _A,
    g: _A,
    z: _A,
    vref: _A,
    ctl: _A,
    r: int,
    i: int,
    tr: int,
    manifold: int,
    layer: bool,
    feedforward: bool,
    force: _A,
    s: _A,
    znew: _A,
) -> bool:
    """Tracker ``i`` of run ``r``: its sliding-mode step; returns whether ``|g| >= gamma``
    (outside the boundary layer of eq. 8).

    The manifold on ``v_s = v - w v_ref`` (``w`` the feed-forward weight, 0 without): with
    ``manifold`` 0 the proposed one, eq. 28 ``v_s + alpha g + z`` outside the layer and eq.
    31 ``v_s + (alpha + beta / gamma) g`` inside; 1 the traditional ``v_s + alpha g + z``;
    2 eq. 22 with the continuous sat, ``v_s + alpha g + beta g / max(|g|, gamma)``. The force
    of eq. 24, ``-u0 sign(s)`` or with ``layer`` ``-u0 clip(s / phi, -1, 1)``, plus ``f_known
    = drag v`` (eq. 20); the filter of eq. 26 over the step, ``decay z + (1 - decay) beta
    sign(g)``. v, g, z, force, s, znew (B, m, 3) at [r, i]; vref (., 3) at [tr]; ctl (B, 10)
    at [r] (``CTL_*`` columns)."""
    g0, g1, g2 = g[r, i, 0], g[r, i, 1], g[r, i, 2]
    n2 = g0 * g0 + g1 * g1
    norm = math.sqrt(n2 + g2 * g2)  # as np.linalg.norm sums it
    outside = norm >= ctl[r, CTL_GAMMA]
    den = max(norm, ctl[r, CTL_GAMMA])
    alpha, neg_u0, drag = ctl[r, CTL_ALPHA], ctl[r, CTL_NEG_U0], ctl[r, CTL_DRAG]
    for q in range(3):
        gq, vq, zq = g[r, i, q], v[r, i, q], z[r, i, q]
        vs = vq - ctl[r, CTL_FEEDFORWARD] * vref[tr, q] if feedforward else vq
        if manifold == 1 or (manifold == 0 and outside):
            sq = (vs + alpha * gq) + zq
        elif manifold == 0:
            sq = vs + ctl[r, CTL_LAYER_GAIN] * gq
        else:
            sq = (vs + alpha * gq) + ctl[r, CTL_BETA] * (gq / den)
        s[r, i, q] = sq
        switch = min(max(sq * ctl[r, CTL_INV_PHI], -1.0), 1.0) if layer else _sign(sq)
        force[r, i, q] = neg_u0 * switch + drag * vq
        znew[r, i, q] = ctl[r, CTL_DECAY] * zq + ctl[r, CTL_GAIN_IN] * _sign(gq)
    return outside


@_jit
def smc_rows(
    v: _A, grad: _A, z: _A, vref: _A, ctl: _A, manifold: int, layer: bool, feedforward: bool
) -> tuple[_A, _A, _A, NDArray[np.bool_]]:
    """:func:`_smc` for every tracker: v, grad, z (B, m, 3); vref (B, 3); ctl (B, 10).
    Returns the force, the manifold s, the next filter state (B, m, 3) and ``outside``
    (B, m)."""
    B, m = v.shape[0], v.shape[1]
    force = np.empty((B, m, 3))
    s = np.empty((B, m, 3))
    znew = np.empty((B, m, 3))
    outside = np.empty((B, m), dtype=np.bool_)
    for r in range(B):
        for k in range(m):
            outside[r, k] = _smc(
                v, grad, z, vref, ctl, r, k, r, manifold, layer, feedforward, force, s, znew
            )
    return force, s, znew, outside


@_jit
def _plant(
    x: float, v: float, f: float, d: float, mass: float, drag: float, h: float, half_h2: float
) -> tuple[float, float]:
    """Eq. 19-21 for one coordinate over one step ``h`` with the force ``f`` held:
    ``acc = ((f - drag v) - d) / M``; returns ``x + v h + acc h^2 / 2`` and ``v + acc h``."""
    acc = ((f - drag * v) - d) / mass
    return (x + v * h) + half_h2 * acc, v + acc * h


@_jit
def plant_rows(
    x: _A, v: _A, force: _A, dist: _A, mass: _A, drag: _A, h: float, half_h2: float
) -> tuple[_A, _A]:
    """:func:`_plant` for every coordinate: x, v, force (B, n, 3); dist and mass of that
    shape or with axes of length 1 (broadcast); drag (B,) or (1,). Returns the next
    positions and velocities (B, n, 3)."""
    B, n = x.shape[0], x.shape[1]
    xn = np.empty((B, n, 3))
    vn = np.empty((B, n, 3))
    db, dn, dq = dist.shape[0] > 1, dist.shape[1] > 1, dist.shape[2] > 1
    mb, mn, mq = mass.shape[0] > 1, mass.shape[1] > 1, mass.shape[2] > 1
    for r in range(B):
        dr = drag[r] if drag.shape[0] > 1 else drag[0]
        for i in range(n):
            for q in range(3):
                xn[r, i, q], vn[r, i, q] = _plant(
                    x[r, i, q],
                    v[r, i, q],
                    force[r, i, q],
                    dist[r if db else 0, i if dn else 0, q if dq else 0],
                    mass[r if mb else 0, i if mn else 0, q if mq else 0],
                    dr,
                    h,
                    half_h2,
                )
    return xn, vn


@_jit
def simulate_steps(
    x: _A,
    v: _A,
    z: _A,
    held: _A,
    outside: NDArray[np.bool_],
    have_out: bool,
    k0: int,
    i0: int,
    steps: int,
    hold: int,
    dist: _A,
    tpos: _A,
    tvel: _A,
    tindex: _I,
    gains: _A,
    block: bool,
    mu: float,
    trust: float,
    ctl: _A,
    manifold: int,
    layer: bool,
    feedforward: bool,
    mass: _A,
    drag: _A,
    h: float,
    half_h2: float,
    every: int,
    record: bool,
    rec_x: _A,
    rec_v: _A,
    rec_u: _A,
    rec_s: _A,
    rec_sat: NDArray[np.bool_],
    rec_tx: _A,
    rec_tv: _A,
) -> bool:
    """``steps`` steps of the closed loop of every run, in place, with the functions the
    step-by-step path calls (:func:`_directions`, :func:`_smc`, :func:`_plant`): the same
    bits as :meth:`~apf_swarm_core.simulator.BatchSimulator.step` in a loop.

    x, v, z (B, n, 3): state and filter; ``held`` (4, B, n, 3): the command being held
    (force, s, direction, the filter state it was computed with) and ``outside`` (B, n),
    valid if ``have_out``; a new command at the first step without one and every ``hold``
    steps (k0 + t); dist (steps or 1, B, n, 3) [N]; tpos, tvel (steps, trajectories, 3)
    and ``tindex`` (B,) each run's trajectory; recording every ``every``-th step k into row
    (i0 + t) // every of the step-major rec arrays. Returns ``have_out``."""
    B, n = x.shape[0], x.shape[1]
    rows = np.arange(n)
    nomask = np.zeros((0, n, n), dtype=np.bool_)
    sc, hc, gc, gbar, H = _scratch()
    force, surface, grad, zold = held[0], held[1], held[2], held[3]
    for t in range(steps):
        k = k0 + t
        if not have_out or k % hold == 0:
            tx, tv = tpos[t], tvel[t]
            for r in range(B):
                tr = tindex[r]
                _directions(
                    x,
                    r,
                    tx,
                    tr,
                    rows,
                    nomask,
                    gains,
                    block,
                    mu,
                    trust,
                    grad,
                    sc,
                    hc,
                    gc,
                    gbar,
                    H,
                )
                for i in range(n):
                    for q in range(3):
                        zold[r, i, q] = z[r, i, q]
                    outside[r, i] = _smc(
                        v,
                        grad,
                        zold,
                        tv,
                        ctl,
                        r,
                        i,
                        tr,
                        manifold,
                        layer,
                        feedforward,
                        force,
                        surface,
                        z,
                    )
            have_out = True
        if record and k % every == 0:
            j = (i0 + t) // every
            for r in range(B):
                tr = tindex[r]
                for q in range(3):
                    rec_tx[j, r, q] = tpos[t, tr, q]
                    rec_tv[j, r, q] = tvel[t, tr, q]
                for i in range(n):
                    rec_sat[j, r, i] = outside[r, i]
                    for q in range(3):
                        rec_x[j, r, i, q] = x[r, i, q]
                        rec_v[j, r, i, q] = v[r, i, q]
                        rec_u[j, r, i, q] = force[r, i, q]
                        rec_s[j, r, i, q] = surface[r, i, q]
        dd = 1 if dist.shape[0] > 1 else 0
        for r in range(B):
            for i in range(n):
                for q in range(3):
                    x[r, i, q], v[r, i, q] = _plant(
                        x[r, i, q],
                        v[r, i, q],
                        force[r, i, q],
                        dist[t * dd, r, i, q],
                        mass[r, i, q],
                        drag[r],
                        h,
                        half_h2,
                    )
    return have_out


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
    ctl = np.ones((1, len(CTL_COLUMNS)))
    v = np.zeros((1, 2, 3))
    for manifold in range(3):
        smc_rows(v, v, v, tx, ctl, manifold, manifold == 1, manifold == 2)
    plant_rows(x, v, v, v, np.ones((1, 2, 3)), np.ones(1), 0.001, 5e-7)
    # the simulator's loop, recording into step-major views of (R, T, ...) arrays or not (an
    # empty view is C-contiguous, a full one is not: two signatures); arguments in the order
    # of simulate_steps: state and held command, the loop and its inputs, law and plant, records
    ones = np.ones((1, 2, 3))
    for steps in (0, 1):
        rec = np.empty((1, steps, 2, 3)).swapaxes(0, 1)
        sat = np.empty((1, steps, 2), dtype=np.bool_).swapaxes(0, 1)
        trec = np.empty((1, steps, 3)).swapaxes(0, 1)
        state = (x.copy(), v.copy(), v.copy(), np.zeros((4, 1, 2, 3)), np.zeros((1, 2), np.bool_))
        loop = (False, 0, 0, 1, 1, v[None], tx[None], tx[None], np.zeros(1, np.int64), gains)
        law = (steps == 1, 0.1, 0.0, ctl, 0, True, True, ones, np.ones(1), 0.001, 5e-7, 1)
        records = (steps == 1, rec, rec, rec, rec, sat, trec, trec)
        simulate_steps(*(state + loop + law + records))


def as_kernel(
    arr: ArrayLike, shape: tuple[int, ...] | None = None, dtype: type = np.float64
) -> NDArray[Any]:
    """``arr`` (broadcast to ``shape``) as the kernels take it: C-contiguous, writeable, of
    ``dtype``; a copy only where it is not already. (A read-only or strided array is
    another numba type: the kernel would be compiled again, at run time, for it.)"""
    a: NDArray[Any] = np.asarray(arr, dtype=dtype)
    if shape is not None and a.shape != shape:
        a = np.broadcast_to(a, shape)
    if not (a.flags.c_contiguous and a.flags.writeable):
        a = np.array(a, dtype=dtype, order='C')
    return a


class Args(NamedTuple):
    """The arguments of a kernel call, shaped: see :func:`kernel_args`."""

    x: NDArray[np.float64]  # (B, n, 3)
    tx: NDArray[np.float64]  # (B, 3)
    rows: NDArray[np.int64]  # (m,)
    mask: NDArray[np.bool_]  # (Bm, m, n), Bm in {0, 1, B}
    gains: NDArray[np.float64]  # (B, 5): k_n, k_f, a, b, c of each run
    shape: tuple[int, ...]  # the result's leading shape: (..., m) or (...) for an int row


def _rows(rows: Rows, n: int) -> tuple[NDArray[np.int64], bool]:
    """The row numbers (m,) int64 and whether ``rows`` was a single int."""
    if rows is None:
        return np.arange(n, dtype=np.int64), False
    if type(rows) is list and all(type(r) is int and 0 <= r < n for r in rows):
        return np.array(rows, dtype=np.int64), False
    idx = np.arange(n, dtype=np.int64)[rows]
    return as_kernel(idx.reshape(-1), dtype=np.int64), idx.ndim == 0


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
                as_kernel(x).reshape(1, n, 3),
                as_kernel(tx).reshape(1, 3),
                idx,
                np.zeros((0, m, n), dtype=np.bool_),
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
    xs = as_kernel(x).reshape(runs, n, 3)
    ts = as_kernel(tx).reshape(runs, 3)
    if mk is None:
        ms = np.zeros((0, m, n), dtype=np.bool_)
    elif mk.ndim <= 2:
        ms = as_kernel(mk, (1, m, n), np.bool_)
    else:
        ms = as_kernel(mk, dtype=np.bool_).reshape(runs, m, n)
    g = np.empty((runs, len(arrays)))
    for q, v in enumerate(arrays):
        g[:, q] = v.reshape(runs) if v.ndim else v
    return Args(xs, ts, idx, ms, g, lead if single else (*lead, m))
