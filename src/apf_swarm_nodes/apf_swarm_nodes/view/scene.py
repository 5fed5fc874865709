"""One ``/swarm/state`` sample as Foxglove messages (:class:`SceneBuilder`): the 3-D scene in
frame ``world``, the frame ``target`` that follows the target, and the time series as JSON
(what each shows: docs/USAGE.md, *Watching a run*).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from apf_swarm_core.command_hold import STALE_AFTER
from numpy.typing import NDArray

from ..analysis.style import STATE_COLOURS, TARGET_COLOUR, edge_colour
from ..conversions import WORLD

__all__ = ['SceneBuilder', 'UavStates']

#: the frame that follows the target (``/swarm/frames``)
TARGET_FRAME = 'target'

#: how long a UAV that came back is shown as respawned [s]
RESPAWN_SHOWN = 3.0


@dataclass
class UavStates:
    """Each UAV's state for the picture, from what ``/swarm/state`` says of it: ``inactive``
    (the plant left it out: its commands missing past the deadline), ``stale`` (active, but
    its latest command answered a state older than ``stale_after``: its ``command_latency``,
    realtime), ``respawned`` (active again after being inactive, for :data:`RESPAWN_SHOWN`
    seconds), else ``active``. Time going back (a looped bag) starts afresh."""

    stale_after: float
    _was_inactive: dict[int, bool] = field(default_factory=dict)
    _back_at: dict[int, float] = field(default_factory=dict)
    _t: float = -np.inf

    def update(
        self,
        t: float,
        uav_ids: Sequence[int],
        active: Sequence[bool],
        latency: Sequence[float],
    ) -> list[str]:
        if t < self._t:
            self._was_inactive.clear()
            self._back_at.clear()
        self._t = t
        out = []
        for j, uid in enumerate(uav_ids):
            on = bool(active[j]) if j < len(active) else True
            if not on:
                self._was_inactive[uid] = True
                self._back_at.pop(uid, None)
                out.append('inactive')
                continue
            if self._was_inactive.pop(uid, False):
                self._back_at[uid] = t
            if t - self._back_at.get(uid, -np.inf) < RESPAWN_SHOWN:
                out.append('respawned')
            elif j < len(latency) and latency[j] > self.stale_after:
                out.append('stale')
            else:
                out.append('active')
        return out


class SceneBuilder:
    """Builds the view's messages from successive samples (a SwarmSample each).

    ``designs``: the pair distances of the design minima (the edges are judged against the
    one nearest to the current positions); ``stale_after``: see :class:`UavStates`."""

    #: how long a trail is [s] and a UAV's drawn radius [m]
    trail = 5.0
    radius = 0.15

    def __init__(
        self, designs: Sequence[NDArray[np.float64]] = (), *, stale_after: float = STALE_AFTER
    ) -> None:
        self.designs = [np.asarray(d, dtype=float) for d in designs]
        self.states = UavStates(stale_after)
        self._trails: dict[int, deque[tuple[float, NDArray[np.float64]]]] = {}
        self.last_states: list[str] = []

    def _trail(self, t: float, uid: int, p: NDArray[np.float64]) -> list[Any]:
        q = self._trails.setdefault(uid, deque())
        if q and t < q[-1][0]:
            q.clear()  # time went back: a looped bag or a new run
        q.append((t, p.copy()))
        while q and t - q[0][0] > self.trail:
            q.popleft()
        return [_point(a) for _, a in q]

    def scene(self, sample: Any, stamp_ns: int) -> Any:
        """A ``foxglove.SceneUpdate`` of the sample, stamped ``stamp_ns``."""
        from apf_swarm_core.metrics import formation_edges, nearest_design
        from foxglove.messages import (
            ArrowPrimitive,
            KeyValuePair,
            LinePrimitive,
            LinePrimitiveLineType,
            SceneEntity,
            SceneUpdate,
            SpherePrimitive,
            Vector3,
        )

        ts = _timestamp(stamp_ns)
        origin = _pose((0.0, 0.0, 0.0))

        def entity(id: str, **kw: Any) -> Any:
            return SceneEntity(timestamp=ts, frame_id=WORLD, id=id, **kw)

        def sphere(p: Any, d: float, rgba: tuple[float, float, float, float]) -> Any:
            return SpherePrimitive(pose=_pose(p), size=Vector3(x=d, y=d, z=d), color=_colour(rgba))

        def line(kind: Any, width: float, rgba: Any, points: list[Any]) -> Any:
            c = _colour(rgba)
            return LinePrimitive(type=kind, pose=origin, thickness=width, color=c, points=points)

        x = np.asarray(sample.x, dtype=float)
        t = float(sample.t)
        states = self.states.update(t, sample.uav_ids, sample.active, sample.command_latency)
        self.last_states = states
        entities = []
        for j, uid in enumerate(sample.uav_ids):
            rgba = STATE_COLOURS[states[j]]
            trail = self._trail(t, int(uid), x[j])
            strip = LinePrimitiveLineType.LineStrip
            entities.append(
                entity(
                    f'uav_{uid}',
                    metadata=[
                        KeyValuePair(key='state', value=states[j]),
                        KeyValuePair(key='step', value=str(int(sample.step))),
                    ],
                    spheres=[sphere(x[j], 2.0 * self.radius, rgba)],
                    lines=[line(strip, 0.02, (*rgba[:3], 0.5), trail)] if len(trail) > 1 else [],
                )
            )
        target = sphere(sample.target_x, 2.6 * self.radius, TARGET_COLOUR)
        entities.append(entity('target', spheres=[target]))
        edges = []
        design = nearest_design(x[None], list(self.designs)) if self.designs else None
        if design is not None and len(design) == len(x) * (len(x) - 1) // 2:
            i, k, dist, err = formation_edges(x, design)
            for a, b, dd, e in zip(i, k, dist, err, strict=True):
                rgba = edge_colour(float(e / dd))
                pair = [_point(x[a]), _point(x[b])]
                edges.append(line(LinePrimitiveLineType.LineList, 0.03, rgba, pair))
        entities.append(entity('formation', lines=edges))
        h = float(np.sqrt(0.5))  # x, y, z: +x turned by 0, +90 deg about z, -90 deg about y
        turns = ((0.0, 0.0, 0.0, 1.0), (0.0, 0.0, h, h), (0.0, -h, 0.0, h))
        axes = [
            ArrowPrimitive(
                pose=_pose((0.0, 0.0, 0.0), q),
                shaft_length=0.8,
                shaft_diameter=0.04,
                head_length=0.2,
                head_diameter=0.1,
                color=_colour((*rgb, 1.0)),
            )
            for q, rgb in zip(turns, ((1, 0, 0), (0, 1, 0), (0, 0, 1)), strict=True)
        ]
        entities.append(entity('world_axes', arrows=axes))
        return SceneUpdate(entities=entities)

    @staticmethod
    def target_frame(sample: Any, stamp_ns: int) -> Any:
        """``foxglove.FrameTransform`` world -> target (the target's position)."""
        from foxglove.messages import FrameTransform

        return FrameTransform(
            timestamp=_timestamp(stamp_ns),
            parent_frame_id=WORLD,
            child_frame_id=TARGET_FRAME,
            translation=_point(sample.target_x, 'Vector3'),
            rotation=_quaternion(),
        )

    def metrics(self, sample: Any) -> dict[str, Any]:
        """The time series of one frame (JSON): the plant's measures and the UAV counts by
        state (the states :meth:`scene` found for the same sample, which comes first)."""
        counts = {k: self.last_states.count(k) for k in STATE_COLOURS}
        return {
            'step': int(sample.step),
            't': float(sample.t),
            'centroid_error': _finite(sample.centroid_error),
            'formation_error': _finite(sample.formation_error),
            'potential': _finite(sample.potential),
            'missed_deadlines': int(sample.missed_deadlines),
            'stale_inputs': int(sample.stale_inputs),
            'rejected_inputs': int(sample.rejected_inputs),
            'uavs': counts,
        }


def _finite(v: float) -> float | None:
    """JSON has no NaN: a missing measure (no design spacing) is null."""
    v = float(v)
    return v if np.isfinite(v) else None


def _timestamp(ns: int) -> Any:
    from foxglove.messages import Timestamp

    return Timestamp(sec=ns // 1_000_000_000, nsec=ns % 1_000_000_000)


def _point(p: Any, cls: str = 'Point3') -> Any:
    """``p`` as a ``foxglove.messages`` Point3 (or Vector3, ``cls``)."""
    import foxglove.messages as fm

    return getattr(fm, cls)(x=float(p[0]), y=float(p[1]), z=float(p[2]))


def _quaternion(q: Sequence[float] = (0.0, 0.0, 0.0, 1.0)) -> Any:
    """``(x, y, z, w)`` as a ``foxglove.Quaternion`` (default: no rotation)."""
    from foxglove.messages import Quaternion

    return Quaternion(x=q[0], y=q[1], z=q[2], w=q[3])


def _pose(p: Any, rotation: Sequence[float] = (0.0, 0.0, 0.0, 1.0)) -> Any:
    """The pose at position ``p``, turned by the quaternion ``rotation`` (x, y, z, w)."""
    from foxglove.messages import Pose

    return Pose(position=_point(p, 'Vector3'), orientation=_quaternion(rotation))


def _colour(c: Sequence[float]) -> Any:
    from foxglove.messages import Color

    return Color(r=float(c[0]), g=float(c[1]), b=float(c[2]), a=float(c[3]))
