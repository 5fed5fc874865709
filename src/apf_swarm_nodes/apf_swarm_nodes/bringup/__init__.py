"""Bring-up of the ROS 2 swarm without ``launch``: ``scripts/swarm_up.py`` / ``apf-swarm up``
(docs/ROS.md, "The ROS 2 swarm"). :mod:`.cli` makes a :class:`.commands.Plan`, which a
:class:`.session.Bringup` runs. Only :func:`run` imports rclpy."""

from ..analysis.samples import StateAccumulator
from ..lifetime import stop_process
from .cli import add_arguments, main, run
from .commands import node_commands
from .graph import expected_graph, graph_missing
from .isolation import check_capacity, pick_domain_id
from .processes import Child, ProcessGroup

__all__ = [
    'Child',
    'ProcessGroup',
    'StateAccumulator',
    'add_arguments',
    'check_capacity',
    'expected_graph',
    'graph_missing',
    'main',
    'node_commands',
    'pick_domain_id',
    'run',
    'stop_process',
]
