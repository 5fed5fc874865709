"""The live view of a run or a bag in the Foxglove app, over the Foxglove WebSocket protocol
(``foxglove-sdk``; no ROS install needed on the viewing side).

* :mod:`.scene` -- a ``/swarm/state`` sample as the scene, the target frame and the time
  series;
* :mod:`.server` -- :class:`LiveView`, the server and its channels, fed by the bring-up
  (``apf-swarm up --view``) or the player (``apf-swarm bag play --view``);
* :mod:`.bag` -- :func:`serve_bag`, a bag served without a ROS graph (``apf-swarm bag view``).
"""

from .server import DEFAULT_PORT, VIEW_RATE, LiveView

__all__ = ['DEFAULT_PORT', 'VIEW_RATE', 'LiveView']
