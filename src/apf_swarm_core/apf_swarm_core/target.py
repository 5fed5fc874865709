"""Target kinematics (paper eq. 1) and the trajectories the target can fly: each gives the
speed, yaw and pitch at a time, the velocity of :func:`target_velocity` (eq. 1) and the
closed-form integral of it, exact at any time in the simulator and in the ROS target node.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    'TRAJECTORIES',
    'BatchTarget',
    'Circle',
    'FigureEight',
    'Helix',
    'Straight',
    'Trajectory',
    'Waypoints',
    'make_trajectory',
    'target_velocity',
]

TRAJECTORIES = ('straight', 'circle', 'helix', 'figure_eight', 'waypoints', 'hover')


def target_velocity(speed: ArrayLike, yaw: ArrayLike, pitch: ArrayLike) -> NDArray[np.float64]:
    """Velocity of eq. 1, ``(v cos chi cos delta, v sin chi cos delta, v sin delta)``, shape
    (..., 3) [m/s], of ``speed`` v [m/s], ``yaw`` chi and ``pitch`` delta [rad], each (...)."""
    speed, yaw, pitch = np.broadcast_arrays(
        *(np.asarray(a, dtype=float) for a in (speed, yaw, pitch))
    )
    out = np.empty((*speed.shape, 3))
    cp = np.cos(pitch)
    out[..., 0] = speed * np.cos(yaw) * cp
    out[..., 1] = speed * np.sin(yaw) * cp
    out[..., 2] = speed * np.sin(pitch)
    return out


Times = ArrayLike  # float or array of times [s]


@dataclass(frozen=True)
class Trajectory(ABC):
    """Base class: ``state(t)`` gives position and velocity at a time or an array of times
    from the subclass's :meth:`heading` and :meth:`displacement`."""

    start: tuple[float, float, float] = (0.0, 0.0, 5.0)
    speed: float = 1.0

    @abstractmethod
    def heading(self, t: Times) -> tuple[NDArray[np.float64], ...]:
        """Speed [m/s], yaw [rad] and pitch [rad] at ``t``, each of shape ``np.shape(t)``."""

    @abstractmethod
    def displacement(self, t: Times) -> NDArray[np.float64]:
        """Integral of the eq. 1 velocity from 0 to ``t`` [m], shape ``np.shape(t) + (3,)``."""

    def state(self, t: Times) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Position [m] and velocity [m/s] at ``t`` [s]: shapes ``np.shape(t) + (3,)``."""
        t = np.asarray(t, dtype=float)
        x = np.asarray(self.start, dtype=float) + self.displacement(t)
        return x, target_velocity(*self.heading(t))

    @property
    def max_speed(self) -> float:
        """Upper bound of the speed, the ``v_N`` of the convergence condition ``beta >= v_N``."""
        return abs(self.speed)


def _full(t: Times, value: float) -> NDArray[np.float64]:
    return np.full(np.shape(t), float(value))


@dataclass(frozen=True)
class Straight(Trajectory):
    """Constant speed along a fixed yaw and pitch."""

    yaw: float = 0.0
    pitch: float = 0.0

    def heading(self, t: Times) -> tuple[NDArray[np.float64], ...]:
        return _full(t, self.speed), _full(t, self.yaw), _full(t, self.pitch)

    def displacement(self, t: Times) -> NDArray[np.float64]:
        return target_velocity(self.speed, self.yaw, self.pitch) * np.asarray(t)[..., None]


@dataclass(frozen=True)
class Helix(Trajectory):
    """Constant speed and pitch, yaw turning at ``speed cos(pitch) / radius`` about a centre
    ``radius`` to the left of the initial heading ``yaw``."""

    radius: float = 20.0
    yaw: float = 0.0
    pitch: float = 0.0

    @property
    def yaw_rate(self) -> float:
        """Turn rate [rad/s]."""
        return self.speed * math.cos(self.pitch) / self.radius

    def heading(self, t: Times) -> tuple[NDArray[np.float64], ...]:
        t = np.asarray(t, dtype=float)
        return _full(t, self.speed), self.yaw + self.yaw_rate * t, _full(t, self.pitch)

    def displacement(self, t: Times) -> NDArray[np.float64]:
        t = np.asarray(t, dtype=float)
        ang = self.yaw + self.yaw_rate * t
        out = np.empty((*t.shape, 3))
        out[..., 0] = self.radius * (np.sin(ang) - math.sin(self.yaw))
        out[..., 1] = -self.radius * (np.cos(ang) - math.cos(self.yaw))
        out[..., 2] = self.speed * math.sin(self.pitch) * t
        return out


@dataclass(frozen=True)
class Circle(Helix):
    """Horizontal circle: a helix with zero pitch."""

    def __post_init__(self) -> None:
        object.__setattr__(self, 'pitch', 0.0)


@dataclass(frozen=True)
class FigureEight(Trajectory):
    """Horizontal figure eight of half-width ``radius`` R, ``p(t) = (R sin(w t), (R/2)
    sin(2 w t), 0)`` turned by ``yaw``; its speed peaks at ``sqrt(2) R w = speed``."""

    radius: float = 20.0
    yaw: float = 0.0

    @property
    def omega(self) -> float:
        return self.speed / (math.sqrt(2.0) * self.radius)

    def heading(self, t: Times) -> tuple[NDArray[np.float64], ...]:
        t = np.asarray(t, dtype=float)
        w = self.omega
        vx, vy = self.radius * w * np.cos(w * t), self.radius * w * np.cos(2.0 * w * t)
        return np.hypot(vx, vy), self.yaw + np.arctan2(vy, vx), _full(t, 0.0)

    def displacement(self, t: Times) -> NDArray[np.float64]:
        t = np.asarray(t, dtype=float)
        w = self.omega
        px, py = self.radius * np.sin(w * t), 0.5 * self.radius * np.sin(2.0 * w * t)
        cy, sy = math.cos(self.yaw), math.sin(self.yaw)
        out = np.zeros((*t.shape, 3))
        out[..., 0] = cy * px - sy * py
        out[..., 1] = sy * px + cy * py
        return out


@dataclass(frozen=True)
class Waypoints(Trajectory):
    """Straight legs at constant ``speed`` from ``start`` through ``points`` (offsets from
    ``start`` [m]), then hover at the last."""

    points: tuple[tuple[float, float, float], ...] = field(default_factory=tuple)

    def _legs(self) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """Leg start points (L+1, 3), unit directions (L, 3) and start times (L+1,)."""
        pts = np.vstack([np.zeros(3)] + [np.asarray(p, dtype=float) for p in self.points])
        seg = np.diff(pts, axis=0)
        length = np.linalg.norm(seg, axis=-1)
        keep = length > 0
        pts = np.vstack([pts[:1], pts[1:][keep]])
        seg, length = seg[keep], length[keep]
        units = seg / length[:, None] if len(length) else np.zeros((0, 3))
        times = (
            np.concatenate([[0.0], np.cumsum(length / self.speed)])
            if self.speed > 0
            else np.zeros(len(length) + 1)
        )
        return pts, units, times

    def _leg_index(self, t: NDArray[np.float64]) -> tuple[NDArray[np.intp], NDArray[np.bool_]]:
        _, units, times = self._legs()
        idx = np.searchsorted(times, t, side='right') - 1
        moving = (idx < len(units)) & (t >= 0) & (len(units) > 0)
        return np.clip(idx, 0, max(0, len(units) - 1)), moving

    def heading(self, t: Times) -> tuple[NDArray[np.float64], ...]:
        t = np.asarray(t, dtype=float)
        _, units, _ = self._legs()
        if len(units) == 0:
            return _full(t, 0.0), _full(t, 0.0), _full(t, 0.0)
        idx, moving = self._leg_index(t)
        u = units[idx]
        return (
            np.where(moving, self.speed, 0.0),
            np.where(moving, np.arctan2(u[..., 1], u[..., 0]), 0.0),
            np.where(moving, np.arcsin(np.clip(u[..., 2], -1.0, 1.0)), 0.0),
        )

    def displacement(self, t: Times) -> NDArray[np.float64]:
        t = np.asarray(t, dtype=float)
        pts, units, times = self._legs()
        if len(units) == 0:
            return np.zeros((*t.shape, 3))
        idx, moving = self._leg_index(t)
        along = pts[idx] + units[idx] * (self.speed * (t - times[idx]))[..., None]
        return np.where(moving[..., None], along, pts[-1])


def _point(p: Sequence[float]) -> tuple[float, float, float]:
    x, y, z = (float(c) for c in p)
    return x, y, z


def make_trajectory(
    kind: str,
    *,
    start: Sequence[float] = (0.0, 0.0, 5.0),
    speed: float = 1.0,
    yaw: float = 0.0,
    pitch: float = 0.0,
    radius: float = 20.0,
    waypoints: Sequence[Sequence[float]] = (),
) -> Trajectory:
    """Build a trajectory by name (one of :data:`TRAJECTORIES`); angles in radians."""
    start_t = _point(start)
    if kind == 'straight':
        return Straight(start_t, speed, yaw=yaw, pitch=pitch)
    if kind == 'hover':
        return Straight(start_t, 0.0)
    if kind == 'circle':
        return Circle(start_t, speed, radius=radius, yaw=yaw)
    if kind == 'helix':
        return Helix(start_t, speed, radius=radius, yaw=yaw, pitch=pitch)
    if kind == 'figure_eight':
        return FigureEight(start_t, speed, radius=radius, yaw=yaw)
    if kind == 'waypoints':
        return Waypoints(start_t, speed, points=tuple(_point(p) for p in waypoints))
    raise ValueError(f'target trajectory must be one of {TRAJECTORIES}, got {kind!r}')


class BatchTarget:
    """The target states of R runs, one of ``trajectories`` each, at the steps ``k`` of a
    fixed-step run (``t = k dt``, dt [s]): evaluated :attr:`BLOCK` steps at once, once per
    distinct trajectory."""

    #: steps evaluated at once
    BLOCK = 1024

    def __init__(self, trajectories: Sequence[Trajectory], dt: float) -> None:
        self.dt = dt
        self.runs = len(trajectories)
        #: the distinct trajectories, and which one each run flies
        self.distinct: list[Trajectory] = list(dict.fromkeys(trajectories))
        self.index = np.array([self.distinct.index(tr) for tr in trajectories], dtype=int)
        # every run its own trajectory, in order: index the block directly (no gather)
        self.identity = len(self.distinct) == self.runs
        #: the current block: its first step, positions and velocities
        #: (BLOCK, distinct trajectories, 3)
        self.block: tuple[int, NDArray[np.float64], NDArray[np.float64]]
        self.block = (-1, np.empty((0, 0, 3)), np.empty((0, 0, 3)))

    def state(self, k: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Target position and velocity of every run at step k, shapes (R, 3)."""
        base, pos, vel = self.block
        if base < 0 or not base <= k < base + self.BLOCK:
            base = k
            t = np.arange(k, k + self.BLOCK) * self.dt
            states = [tr.state(t) for tr in self.distinct]
            pos = np.stack([s[0] for s in states], axis=1)  # (BLOCK, trajectories, 3)
            vel = np.stack([s[1] for s in states], axis=1)
            self.block = (base, pos, vel)
        p, v = pos[k - base], vel[k - base]
        if self.identity:
            return p, v
        if len(self.distinct) == 1:  # one trajectory for every run: a read-only view
            return np.broadcast_to(p[0], (self.runs, 3)), np.broadcast_to(v[0], (self.runs, 3))
        return p[self.index], v[self.index]
