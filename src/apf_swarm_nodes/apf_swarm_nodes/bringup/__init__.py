"""Bring-up of the ROS 2 swarm without ``launch``: ``scripts/swarm_up.py`` / ``apf-swarm up``
(what a run does, its exit codes: docs/ROS.md, "The ROS 2 swarm").

The command line (:mod:`.cli`) parses its arguments into a plan (:class:`.commands.Plan`);
the run (:class:`.session.Bringup`) prepares and isolates it (:mod:`.startup`), starts and
supervises its processes (:mod:`.processes`, :mod:`.supervision`), waits for the graph
(:mod:`.graph_watch`, :mod:`.graph`) and writes its outputs (:mod:`.outputs`). Only
:func:`run` imports rclpy, so the ``apf-swarm`` parser stays light.
"""

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
