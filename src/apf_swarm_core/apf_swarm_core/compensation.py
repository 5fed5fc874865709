"""Delay compensation of a sampled control loop (``compensation = predict``; not in the paper;
docs/THEORY.md, "Sampled-data control"): a command computed from the state sampled at ``t_k``
acts from ``t_k + tau``, so it is computed from the state predicted by that age. Every
position, the target's included, moves on at its sampled velocity (the same prediction in
every tracker: they still descend one potential); a tracker's own velocity moves on with the
force it holds. The horizon follows the latency the plant reports (:class:`LatencyEstimate`).
"""

from __future__ import annotations

from collections import deque

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    'COMPENSATIONS',
    'LATENCY_WINDOW',
    'LatencyEstimate',
    'Predictor',
    'compensation_horizon',
    'predict_positions',
    'predict_velocity',
]

#: values of the ``compensation`` configuration key
COMPENSATIONS = ('none', 'predict')

#: commands whose reported latency :class:`LatencyEstimate` takes the median of
LATENCY_WINDOW = 50


def compensation_horizon(latency: float) -> float:
    """How far ahead to predict a sample [s]: ``h = tau``, the age ``latency`` it has when
    its command arrives at the plant (not ``tau + T/2``: docs/THEORY.md, Sampled-data
    control)."""
    return float(latency)


def predict_positions(x: ArrayLike, v: ArrayLike, horizon: float) -> NDArray[np.float64]:
    """Positions after ``horizon`` seconds at constant velocity: ``x + h v``.

    Parameters
    ----------
    x, v : arrays of one shape (..., 3) [m], [m/s]
    horizon : float [s]
    """
    return np.asarray(x, dtype=float) + horizon * np.asarray(v, dtype=float)


def predict_velocity(
    v: ArrayLike, force: ArrayLike, horizon: float, mass: float
) -> NDArray[np.float64]:
    """A tracker's velocity after ``horizon`` seconds under the force it holds:
    ``v + h u / M`` (eq. 19 without drag and disturbance, which the controller does not
    know).

    Parameters
    ----------
    v, force : arrays of one shape (..., 3) [m/s], [N]
    horizon : float [s]
    mass : float [kg]: the nominal mass, (M_lo + M_hi) / 2
    """
    return np.asarray(v, dtype=float) + (horizon / mass) * np.asarray(force, dtype=float)


class Predictor:
    """The state a command will act on, for :func:`~apf_swarm_core.control.control_step`.

    Holds the horizon and each controlled tracker's last command (zero before the first,
    or after :meth:`hold` with a brake).

    Parameters
    ----------
    horizon : float [s]: :func:`compensation_horizon`; updated by the caller as the latency
        estimate changes
    mass : float [kg]: the nominal mass
    """

    def __init__(self, horizon: float, mass: float) -> None:
        self.horizon, self.mass = float(horizon), float(mass)
        self.held: NDArray[np.float64] | None = None

    def state(
        self,
        x: ArrayLike,
        velocities: ArrayLike,
        v: ArrayLike,
        target_x: ArrayLike,
        target_v: ArrayLike,
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """(positions (..., n, 3), own velocities (..., m, 3), target position (..., 3))
        predicted by the horizon; ``velocities`` are those of every position in ``x``, ``v``
        those of the controlled trackers."""
        h = self.horizon
        v = np.asarray(v, dtype=float)
        held = (
            self.held if self.held is not None and self.held.shape == v.shape else np.zeros_like(v)
        )
        return (
            predict_positions(x, velocities, h),
            predict_velocity(v, held, h, self.mass),
            predict_positions(target_x, target_v, h),
        )

    def hold(self, force: ArrayLike) -> None:
        """The command the controlled trackers now hold."""
        self.held = np.array(force, dtype=float)


class LatencyEstimate:
    """The loop's latency [s]: the median over the last :data:`LATENCY_WINDOW` reports of
    the median latency the plant reported for the swarm's commands (a late command shows in
    it, one outlier does not). Every tracker that reads the same reports holds the same
    estimate, so the trackers of a process predict the same state and share its Newton
    direction."""

    def __init__(self, initial: float, window: int = LATENCY_WINDOW) -> None:
        self.initial = float(initial)
        self.values: deque[float] = deque(maxlen=window)

    def add(self, latencies: ArrayLike) -> None:
        """One report: the latest latency of each tracker's command; values that are not
        finite and positive are left out (0: a command not yet measured)."""
        lat = np.asarray(latencies, dtype=float).ravel()
        lat = lat[np.isfinite(lat) & (lat > 0.0)]
        if lat.size:
            self.values.append(float(np.median(lat)))

    @property
    def value(self) -> float:
        """The estimate: the median, or ``initial`` before any report."""
        return float(np.median(self.values)) if self.values else self.initial
