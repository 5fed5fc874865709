"""One ``/swarm/state`` sample as Foxglove messages: the 3-D scene, the target's frame and
the time series (:class:`SceneBuilder`).

The scene (``foxglove.SceneUpdate``, frame ``world``): a sphere per UAV coloured by its state
(``analysis.style``), the target, the formation's edges coloured by their error against
the nearest design minimum (:func:`apf_swarm_core.metrics.formation_edges`), a short trail
per UAV and the world axes. The frame ``target`` (a ``foxglove.FrameTransform`` from
``world``) lets the 3-D panel follow the target. The time series are one JSON message per
frame (:meth:`SceneBuilder.metrics`).
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
    one nearest to the current positions); ``trail``: how long a trail is [s];
    ``stale_after``: see :class:`UavStates`; ``radius``: a UAV's drawn radius [m]."""

    def __init__(
        self,
        designs: Sequence[NDArray[np.float64]] = (),
        *,
        trail: float = 5.0,
        stale_after: float = STALE_AFTER,
        radius: float = 0.15,
    ) -> None:
        self.designs = [np.asarray(d, dtype=float) for d in designs]
        self.trail = float(trail)
        self.radius = float(radius)
        self.states = UavStates(stale_after)
        self._trails: dict[int, deque[tuple[float, NDArray[np.float64]]]] = {}
        self.last_states: list[str] = []

    def _trail_points(self, t: float, uid: int, p: NDArray[np.float64]) -> list[Any]:
        from foxglove.messages import Point3

        q = self._trails.setdefault(uid, deque())
        if q and t < q[-1][0]:
            q.clear()  # time went back: a looped bag or a new run
        q.append((t, p.copy()))
        while q and t - q[0][0] > self.trail:
            q.popleft()
        return [Point3(x=float(a[0]), y=float(a[1]), z=float(a[2])) for _, a in q]

    def scene(self, sample: Any, stamp_ns: int) -> Any:
        """A ``foxglove.SceneUpdate`` of the sample, stamped ``stamp_ns``."""
        from apf_swarm_core.metrics import formation_edges, nearest_design
        from foxglove.messages import (
            ArrowPrimitive,
            Color,
            KeyValuePair,
            LinePrimitive,
            LinePrimitiveLineType,
            Point3,
            Pose,
            Quaternion,
            SceneEntity,
            SceneUpdate,
            SpherePrimitive,
            Timestamp,
            Vector3,
        )

        ts = Timestamp(sec=stamp_ns // 1_000_000_000, nsec=stamp_ns % 1_000_000_000)
        unit = Quaternion(x=0.0, y=0.0, z=0.0, w=1.0)

        def pose(p: Any, q: Any = unit) -> Any:
            return Pose(
                position=Vector3(x=float(p[0]), y=float(p[1]), z=float(p[2])), orientation=q
            )

        def colour(c: tuple[float, float, float, float]) -> Any:
            return Color(r=c[0], g=c[1], b=c[2], a=c[3])

        x = np.asarray(sample.x, dtype=float)
        t = float(sample.t)
        states = self.states.update(t, sample.uav_ids, sample.active, sample.command_latency)
        self.last_states = states
        entities = []
        d = 2.0 * self.radius
        for j, uid in enumerate(sample.uav_ids):
            rgba = STATE_COLOURS[states[j]]
            trail = self._trail_points(t, int(uid), x[j])
            entities.append(
                SceneEntity(
                    timestamp=ts,
                    frame_id=WORLD,
                    id=f'uav_{uid}',
                    metadata=[
                        KeyValuePair(key='state', value=states[j]),
                        KeyValuePair(key='step', value=str(int(sample.step))),
                    ],
                    spheres=[
                        SpherePrimitive(
                            pose=pose(x[j]), size=Vector3(x=d, y=d, z=d), color=colour(rgba)
                        )
                    ],
                    lines=[
                        LinePrimitive(
                            type=LinePrimitiveLineType.LineStrip,
                            pose=pose((0.0, 0.0, 0.0)),
                            thickness=0.02,
                            color=colour((*rgba[:3], 0.5)),
                            points=trail,
                        )
                    ]
                    if len(trail) > 1
                    else [],
                )
            )
        td = 2.6 * self.radius
        entities.append(
            SceneEntity(
                timestamp=ts,
                frame_id=WORLD,
                id='target',
                spheres=[
                    SpherePrimitive(
                        pose=pose(sample.target_x),
                        size=Vector3(x=td, y=td, z=td),
                        color=colour(TARGET_COLOUR),
                    )
                ],
            )
        )
        edges = []
        design = nearest_design(x[None], list(self.designs)) if self.designs else None
        if design is not None and len(design) == len(x) * (len(x) - 1) // 2:
            i, k, dist, err = formation_edges(x, design)
            for a, b, dd, e in zip(i, k, dist, err, strict=True):
                edges.append(
                    LinePrimitive(
                        type=LinePrimitiveLineType.LineList,
                        pose=pose((0.0, 0.0, 0.0)),
                        thickness=0.03,
                        color=colour(edge_colour(float(e / dd))),
                        points=[
                            Point3(x=float(x[a, 0]), y=float(x[a, 1]), z=float(x[a, 2])),
                            Point3(x=float(x[b, 0]), y=float(x[b, 1]), z=float(x[b, 2])),
                        ],
                    )
                )
        entities.append(SceneEntity(timestamp=ts, frame_id=WORLD, id='formation', lines=edges))
        axes = []
        for axis, (r, g, b) in zip(np.eye(3), ((1, 0, 0), (0, 1, 0), (0, 0, 1)), strict=True):
            axes.append(
                ArrowPrimitive(
                    pose=pose((0.0, 0.0, 0.0), _rotation_to(axis)),
                    shaft_length=0.8,
                    shaft_diameter=0.04,
                    head_length=0.2,
                    head_diameter=0.1,
                    color=Color(r=r, g=g, b=b, a=1.0),
                )
            )
        entities.append(SceneEntity(timestamp=ts, frame_id=WORLD, id='world_axes', arrows=axes))
        return SceneUpdate(entities=entities)

    @staticmethod
    def target_frame(sample: Any, stamp_ns: int) -> Any:
        """``foxglove.FrameTransform`` world -> target (the target's position)."""
        from foxglove.messages import FrameTransform, Quaternion, Timestamp, Vector3

        p = np.asarray(sample.target_x, dtype=float)
        return FrameTransform(
            timestamp=Timestamp(sec=stamp_ns // 1_000_000_000, nsec=stamp_ns % 1_000_000_000),
            parent_frame_id=WORLD,
            child_frame_id=TARGET_FRAME,
            translation=Vector3(x=float(p[0]), y=float(p[1]), z=float(p[2])),
            rotation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0),
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


def _rotation_to(axis: NDArray[np.float64]) -> Any:
    """The quaternion turning +x onto ``axis`` (one of the unit axes)."""
    from foxglove.messages import Quaternion

    s = float(np.sqrt(0.5))
    if axis[1] > 0:
        return Quaternion(x=0.0, y=0.0, z=s, w=s)  # +90 deg about z
    if axis[2] > 0:
        return Quaternion(x=0.0, y=-s, z=0.0, w=s)  # -90 deg about y
    return Quaternion(x=0.0, y=0.0, z=0.0, w=1.0)
