"""The swarm for RViz / Foxglove: ``visualization_msgs/MarkerArray`` from the positions
(visualization_msgs is imported on the first call: most processes never build markers)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np
from builtin_interfaces.msg import Time
from numpy.typing import NDArray

from .fields import WORLD, set_vec

if TYPE_CHECKING:
    from visualization_msgs.msg import MarkerArray

__all__ = ['markers_msg']


def markers_msg(
    x: NDArray[np.float64], target_x: NDArray[np.float64], stamp: Time, uav_ids: Sequence[int]
) -> MarkerArray:
    """``visualization_msgs/MarkerArray`` for RViz / Foxglove: a sphere per tracker (blue),
    the target (red) and the formation outline (a closed line through the trackers)."""
    from geometry_msgs.msg import Point
    from visualization_msgs.msg import Marker, MarkerArray

    def marker(mid: int, kind: int, rgb: tuple[float, float, float], scale: float) -> Marker:
        m = Marker()
        m.header.stamp = stamp
        m.header.frame_id = WORLD
        m.ns = 'apf_swarm'
        m.id = mid
        m.type = kind
        m.action = Marker.ADD
        m.pose.orientation.w = 1.0
        m.scale.x = m.scale.y = m.scale.z = scale
        m.color.r, m.color.g, m.color.b = rgb
        m.color.a = 1.0
        return m

    out = MarkerArray()
    for uid, p in zip(uav_ids, x, strict=False):
        m = marker(int(uid), Marker.SPHERE, (0.2, 0.4, 1.0), 0.3)
        set_vec(m.pose.position, p)
        out.markers.append(m)
    t = marker(0, Marker.SPHERE, (1.0, 0.2, 0.2), 0.4)
    set_vec(t.pose.position, target_x)
    out.markers.append(t)
    if len(x) > 1:
        line = marker(10_000, Marker.LINE_STRIP, (0.6, 0.6, 0.6), 0.05)
        line.points = [set_vec(Point(), p) for p in [*list(x), x[0]]]
        out.markers.append(line)
    return out
