"""Run metrics: centroid error, pair distances, formation error, J(t), chattering, summary.

Arrays follow the trajectory schema: ``t (T,)``, ``x (T, n, 3)``, ``v (T, n, 3)``,
``target_x (T, 3)``, ``target_v (T, 3)``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from functools import lru_cache
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

if TYPE_CHECKING:
    from .potential import PotentialParams

__all__ = [
    'FLIGHT_CRITERIA',
    'SUMMARY_KEYS',
    'centroid_error',
    'flight',
    'flight_verdict',
    'formation_edges',
    'formation_error',
    'heading_rate',
    'hf_velocity_rms',
    'moving_average',
    'nearest_design',
    'pair_distances',
    'per_sample',
    'potential_series',
    'steady_slice',
    'summarize',
    'time_to_converge',
]

#: top-level keys of summary.json, in order (a stable schema shared with the bag tools)
SUMMARY_KEYS = (
    'law',
    'n_trackers',
    'dt',
    'duration',
    'seed',
    'centroid_error',
    'formation',
    'chattering',
    'potential',
    'converged',
    'time_to_converge',
    'warnings',
)


def centroid_error(x: ArrayLike, target_x: ArrayLike) -> NDArray[np.float64]:
    """Distance between the formation centroid and the target, ``||mean_i x_i - x_N||``
    [m], (T,)."""
    x = np.asarray(x, dtype=float)
    return np.linalg.norm(x.mean(axis=-2) - np.asarray(target_x, dtype=float), axis=-1)


def pair_distances(x: ArrayLike) -> NDArray[np.float64]:
    """Distances of every unordered pair, ``(..., n(n-1)/2)`` in ``triu`` order [m]."""
    x = np.asarray(x, dtype=float)
    i, j = _pairs(x.shape[-2])
    return np.linalg.norm(x[..., i, :] - x[..., j, :], axis=-1)


@lru_cache(maxsize=64)
def _pairs(n: int) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """``np.triu_indices(n, 1)``, computed once per n (read-only: shared between calls)."""
    i, j = np.triu_indices(n, 1)
    i.flags.writeable = j.flags.writeable = False
    return i, j


def formation_error(x: ArrayLike, expected_pairs: ArrayLike) -> NDArray[np.float64]:
    """RMS difference between the sorted pair distances and the design's sorted pair distances.

    For 3 trackers the design pairs are three copies of the triangle side, so this is the RMS of
    ``d_ij - d``. Sorting makes the measure blind to relabelling and rotation. (T,) [m].
    """
    d = np.sort(pair_distances(x), axis=-1)
    e = np.sort(np.asarray(expected_pairs, dtype=float))
    return np.sqrt(np.mean((d - e) ** 2, axis=-1))


def formation_edges(
    x: ArrayLike, expected_pairs: ArrayLike, neighbour_ratio: float = 1.5
) -> tuple[NDArray[np.intp], NDArray[np.intp], NDArray[np.float64], NDArray[np.float64]]:
    """The formation's edges at one instant and each one's error against the design.

    Pairs are matched to the design as :func:`formation_error` matches them: the k-th shortest
    pair distance of ``x (n, 3)`` against the k-th shortest of ``expected_pairs``, so the RMS
    of the errors over every pair (``neighbour_ratio = inf``) is :func:`formation_error`.
    An edge is a pair whose design distance is at most ``neighbour_ratio`` times the design's
    nearest-neighbour spacing (the neighbours a viewer draws).

    Returns ``(i, j, design, error)``: tracker rows ``(E,)``, design distances ``(E,)`` [m]
    and ``d_ij - design`` ``(E,)`` [m].
    """
    x = np.asarray(x, dtype=float)
    i, j = _pairs(x.shape[0])
    d = pair_distances(x)
    e = np.sort(np.asarray(expected_pairs, dtype=float))
    if e.shape != d.shape:
        raise ValueError(f'{len(e)} design pair distances for {len(d)} pairs of trackers')
    design = np.empty_like(d)
    design[np.argsort(d, kind='stable')] = e
    keep = design <= neighbour_ratio * e[0] if len(e) else np.zeros(0, dtype=bool)
    return i[keep], j[keep], design[keep], (d - design)[keep]


#: pairs times samples of one chunk of a per-sample series (:func:`per_sample`): 128
#: trackers over 30 000 samples have 2.4e8 pair distances (2 GB, and a summary holds several
#: such arrays at once); a chunk keeps each near 32 MB
_CHUNK_PAIRS = 1 << 22


def per_sample(fn: Callable[..., NDArray[Any]], x: ArrayLike, *others: ArrayLike) -> NDArray[Any]:
    """``fn(x, *others)`` of a per-sample function along a trajectory ``x (T, n, 3)`` (and
    arrays ``(T, ...)`` sampled with it), evaluated over chunks of samples so that the
    memory of its pair arrays stays bounded whatever the swarm's size; concatenated along
    axis 0."""
    x = np.asarray(x, dtype=float)
    n = x.shape[-2]
    step = max(1, _CHUNK_PAIRS // max(1, n * (n - 1) // 2))
    if x.shape[0] <= step:
        return fn(x, *others)
    parts = [
        fn(x[k : k + step], *(np.asarray(o)[k : k + step] for o in others))
        for k in range(0, x.shape[0], step)
    ]
    return np.concatenate(parts, axis=0)


def potential_series(
    x: ArrayLike, target_x: ArrayLike, params: PotentialParams
) -> NDArray[np.float64]:
    """J(t) of eq. 2 / 44 along a trajectory, (T,)."""
    from .potential import potential

    return per_sample(lambda xs, ts: potential(xs, ts, **params), x, target_x)


def _pair_stats(x: NDArray[np.float64]) -> NDArray[np.float64]:
    """Per sample the smallest, largest and mean pair distance, (T, 3) [m]."""
    pd = pair_distances(x)
    return np.stack([pd.min(axis=-1), pd.max(axis=-1), pd.mean(axis=-1)], axis=-1)


def moving_average(y: ArrayLike, width: int) -> NDArray[np.float64]:
    """Centred moving average over ``width`` samples along axis 0 (edges use shorter windows)."""
    y = np.asarray(y, dtype=float)
    width = max(1, int(width))
    csum = np.cumsum(np.concatenate([np.zeros((1, *y.shape[1:])), y]), axis=0)
    idx = np.arange(y.shape[0])
    lo = np.clip(idx - width // 2, 0, y.shape[0])
    hi = np.clip(idx - width // 2 + width, 0, y.shape[0])
    shape = (-1,) + (1,) * (y.ndim - 1)
    return (csum[hi] - csum[lo]) / (hi - lo).reshape(shape)


def hf_velocity_rms(v: ArrayLike, dt: float, window: float = 0.1) -> float:
    """High-frequency velocity energy: RMS of ``v - moving_average(v, window)`` [m/s].

    The residual after removing a centred moving average of ``window`` seconds is the part of
    the velocity above roughly ``1/window`` Hz: the switching ripple of the inner loop
    (about ``u0 dt / M``, docs/THEORY.md section 2) and any buffeting of the manifold. Computed
    over all trackers and samples given; (T, n, 3) input.
    """
    v = np.asarray(v, dtype=float)
    resid = v - moving_average(v, round(window / dt))
    return float(np.sqrt(np.mean(np.sum(resid**2, axis=-1))))


def heading_rate(v: ArrayLike, dt: float, window: float = 0.1) -> float:
    """Mean absolute turn rate of the smoothed velocity direction [rad/s].

    The velocity is smoothed with the same ``window`` as :func:`hf_velocity_rms` (so the
    switching ripple does not count), then the angle between successive smoothed velocity
    vectors is divided by ``dt`` and averaged over trackers and samples. A target on a circle of
    radius R at speed v turns at v/R; anything above that is rotation buffeting.
    """
    vs = moving_average(np.asarray(v, dtype=float), round(window / dt))
    a, b = vs[:-1], vs[1:]
    na, nb = np.linalg.norm(a, axis=-1), np.linalg.norm(b, axis=-1)
    ok = (na > 1e-9) & (nb > 1e-9)
    cos = np.clip(np.sum(a * b, axis=-1) / np.where(ok, na * nb, 1.0), -1.0, 1.0)
    ang = np.where(ok, np.arccos(cos), 0.0)
    return float(np.mean(ang) / dt) if ang.size else 0.0


def steady_slice(n_samples: int, fraction: float) -> slice:
    """The last ``fraction`` of ``n_samples`` (at least one sample)."""
    start = min(n_samples - 1, int(math.floor(n_samples * (1.0 - fraction))))
    return slice(max(0, start), n_samples)


def time_to_converge(t: ArrayLike, ok: ArrayLike) -> float | None:
    """First time after which ``ok`` stays true to the end, or ``None``."""
    ok = np.asarray(ok, dtype=bool)
    if ok.size == 0 or not ok[-1]:
        return None
    bad = np.flatnonzero(~ok)
    return float(np.asarray(t)[0 if bad.size == 0 else bad[-1] + 1])


#: when a swarm flies, judged over the last ``window`` of a run: formation error RMS at most
#: ``formation_rms`` of the mean design spacing, closest pair at least ``closest`` of the
#: design's, and converged (:func:`summarize`): at every sample the centroid within
#: ``centroid_tol`` m, the formation error within ``formation_tol`` of the design's closest
#: pair and the closest pair at least ``closest`` of it -- judged by distances, never by J
FLIGHT_CRITERIA = {
    'window': 0.4,
    'formation_rms': 0.03,
    'closest': 0.9,
    'centroid_tol': 0.5,
    'formation_tol': 0.05,
}


def flight(
    traj: Mapping[str, Any],
    expected_pairs: ArrayLike | list[ArrayLike] | None,
) -> dict[str, Any]:
    """Whether a run flies by :data:`FLIGHT_CRITERIA`, with the numbers it is judged by.

    Returns ``flies`` and, over the window, ``formation_error_rms`` (relative to the mean
    design spacing), ``closest_pair`` (relative to the design's closest),
    ``centroid_error_rms`` [m] and ``converged``. Without a design (``expected_pairs``
    None or empty) nothing flies. ``expected_pairs`` may be a list of designs (the minima
    of J a larger swarm may settle in, :func:`~apf_swarm_core.formation.design_pair_sets`):
    the run is judged against the one its pair distances are nearest to.
    """
    criteria = FLIGHT_CRITERIA
    x = np.asarray(traj['x'], dtype=float)
    tx = np.asarray(traj['target_x'], dtype=float)
    st = steady_slice(x.shape[0], criteria['window'])
    if isinstance(expected_pairs, list):
        expected_pairs = nearest_design(x[st], expected_pairs) if x.shape[1] > 1 else None
    out: dict[str, Any] = {
        'window': criteria['window'],
        'flies': False,
        'formation_error_rms': None,
        'closest_pair': None,
        'centroid_error_rms': None,
        'converged': False,
    }
    if expected_pairs is None or x.shape[0] == 0 or x.shape[1] < 2:
        return out
    exp = np.asarray(expected_pairs, dtype=float)
    fe = per_sample(lambda xs: formation_error(xs, exp), x[st])
    ce = centroid_error(x[st], tx[st])
    rms = float(np.sqrt(np.mean(fe**2))) / float(exp.mean())
    closest = float(per_sample(_pair_stats, x[st])[:, 0].min()) / float(exp.min())
    converged = bool(
        np.all(ce <= criteria['centroid_tol'])
        and np.all(fe <= criteria['formation_tol'] * float(exp.min()))
        and closest >= criteria['closest']
    )
    out.update(
        flies=converged and rms <= criteria['formation_rms'],  # converged: the closest pair
        formation_error_rms=_f(rms),
        closest_pair=_f(closest),
        centroid_error_rms=_f(float(np.sqrt(np.mean(ce**2)))),
        converged=converged,
    )
    return out


def flight_verdict(f: Mapping[str, Any]) -> str:
    """One line of a :func:`flight` result: whether the run flies, and by which numbers."""
    if f.get('formation_error_rms') is None:
        return 'no design to judge by'
    return (
        ('flies' if f['flies'] else 'does not fly') + f': formation error '
        f'{100 * f["formation_error_rms"]:.2g} %, closest pair '
        f'{100 * f["closest_pair"]:.3g} %, centroid {f["centroid_error_rms"]:.3g} m'
    )


def _f(value: float | None) -> float | None:
    return None if value is None or not math.isfinite(value) else float(value)


def nearest_design(x: ArrayLike, designs: Sequence[ArrayLike]) -> NDArray[np.float64] | None:
    """Of several designs' pair distances (the minima of J a swarm may settle in), the one
    whose :func:`formation_error` over the positions ``x (T, n, 3)``, divided by the design's
    mean spacing, has the smallest RMS; ``None`` when there is none. :func:`flight` and
    :func:`summarize` both pick by it over the flight window."""
    best, best_rms = None, math.inf
    for design in designs:
        e = np.asarray(design, dtype=float)
        fe = per_sample(lambda xs, e=e: formation_error(xs, e), x)
        rms = float(np.sqrt(np.mean(fe**2))) / float(e.mean())
        if best is None or rms < best_rms:
            best, best_rms = e, rms
    return best


def summarize(
    traj: Mapping[str, Any],
    *,
    law: str,
    dt: float,
    seed: int,
    potential_params: PotentialParams,
    expected_pairs: ArrayLike | list[ArrayLike] | None,
    steady_fraction: float = 0.25,
    warnings: list[str] | None = None,
) -> dict[str, Any]:
    """The summary.json document (schema :data:`SUMMARY_KEYS`) of a trajectory.

    ``converged`` is true when, over the steady window, the centroid error, the formation
    error and the closest pair stay within :data:`FLIGHT_CRITERIA`.
    ``time_to_converge`` is the first time after which all hold until the end.
    ``expected_pairs`` may be a list of designs, as for :func:`flight`: the run is
    summarized against the one :func:`flight` judges it by (:func:`nearest_design` over the
    flight window).
    """
    t = np.asarray(traj['t'], dtype=float)
    x = np.asarray(traj['x'], dtype=float)
    v = np.asarray(traj['v'], dtype=float)
    tx = np.asarray(traj['target_x'], dtype=float)
    n = x.shape[1]
    sample_dt = float(t[1] - t[0]) if t.size > 1 else dt
    st = steady_slice(t.size, steady_fraction)
    ce = centroid_error(x, tx)
    pd = per_sample(_pair_stats, x) if n > 1 else np.zeros((t.size, 0))  # (T, 3): min, max, mean
    j = potential_series(x, tx, potential_params)
    dj = np.diff(j)
    crit = FLIGHT_CRITERIA
    ok = ce <= crit['centroid_tol']
    if isinstance(expected_pairs, list):
        window = steady_slice(t.size, crit['window'])
        expected_pairs = nearest_design(x[window], expected_pairs) if n > 1 else None
    formation: dict[str, Any] = {
        'pair_distance_min': _f(pd[st, 0].min()) if pd.size else None,
        'pair_distance_max': _f(pd[st, 1].max()) if pd.size else None,
        'pair_distance_mean': _f(pd[st, 2].mean()) if pd.size else None,
        # the whole run's, start included: how near two vehicles ever came
        'closest_approach': _f(pd[:, 0].min()) if pd.size else None,
        'pair_distance_expected': None,
        'error_rms_steady': None,
    }
    if expected_pairs is not None and pd.size:
        exp = np.asarray(expected_pairs, dtype=float)
        fe = per_sample(lambda xs: formation_error(xs, exp), x)
        formation['pair_distance_expected'] = (
            _f(float(exp.min()))
            if np.allclose(exp, exp.min())
            else [float(e) for e in np.sort(exp)]
        )
        formation['error_rms_steady'] = _f(float(np.sqrt(np.mean(fe[st] ** 2))))
        ok = ok & (fe <= crit['formation_tol'] * float(exp.min()))
        ok = ok & (pd[:, 0] >= crit['closest'] * float(exp.min()))
    summary: dict[str, Any] = {
        'law': law,
        'n_trackers': int(n),
        'dt': float(dt),
        'duration': round(float(t[-1] - t[0] + sample_dt), 9) if t.size else 0.0,
        'seed': int(seed),
        'centroid_error': {
            'rms_steady': _f(float(np.sqrt(np.mean(ce[st] ** 2)))),
            'max_steady': _f(float(ce[st].max())),
            'final': _f(float(ce[-1])),
        },
        'formation': formation,
        'chattering': {
            'hf_velocity_rms': _f(hf_velocity_rms(v[st], sample_dt)),
            'heading_rate': _f(heading_rate(v[st], sample_dt)),
        },
        'potential': {
            'initial': _f(float(j[0])),
            'final': _f(float(j[-1])),
            'decreasing_fraction': _f(float(np.mean(dj <= 0))) if dj.size else None,
        },
        'converged': bool(ok[st].all()),
        'time_to_converge': time_to_converge(t, ok),
        'warnings': list(warnings or []),
    }
    if not np.all(np.isfinite(x)):
        summary['warnings'].append('the trajectory contains non-finite positions')
    return summary
