"""Bring-up of the ROS 2 swarm without ``launch``: ``scripts/swarm_up.py`` / ``apf-swarm up``.

What a run does, in order:

1. resolve the configuration (preset or ``--config`` file, ``--set``, ``--n-trackers``,
   ``--seed``, ``--duration``) and write it to ``DIR/config.yaml`` -- the one parameter file
   every node reads;
2. isolate the run: ``ROS_DOMAIN_ID`` (``--domain-id`` or a random free-looking domain in
   1..101, never the inherited one) and ``ROS_AUTOMATIC_DISCOVERY_RANGE`` (``LOCALHOST``
   unless ``--discovery-range`` says otherwise), set in this process's environment before
   ``rclpy.init`` and inherited by every child, with the run's Fast DDS profile
   (:func:`apf_swarm_nodes.dds.profiles.isolate_dds`: in LOCALHOST every socket on 127.0.0.1, the
   discovery timing; a domain that already carries a swarm is refused);
3. start one OS process per node (``target``, ``plant``, ``tracker`` x n), each in its own
   process group, output to ``DIR/logs/<name>.log``;
4. wait, bounded by ``--ready-timeout``, until the ROS graph shows every node and every
   expected publisher / subscriber (:func:`expected_graph`), polling the graph API from a
   ``spin_once`` loop; then publish ``/swarm/start`` once (reliable, transient local);
5. accumulate ``/swarm/state`` (:class:`StateAccumulator`) with a progress line about once a
   second, supervising the children (respawn or stop), until the run ends: lockstep when the
   sample of step ``steps - 1`` arrived, realtime when the plant's final state arrived (its
   clock starts once every tracker commands from its inputs, node parameter ``arm_timeout``);
6. stop every child (:class:`ProcessGroup`: SIGINT to its group, then SIGTERM, then SIGKILL,
   each bounded) and check by PID that nothing is left;
7. write ``trajectory.npz`` and ``summary.json`` (the schema of ``apf-swarm simulate`` plus the
   run fields listed in :func:`run_fields`) and the figures.

With ``--record`` the recorder (``recorder`` executable, bag ``DIR/bag/``) starts first, in a
group of its own; step 4 also waits until its ``/recorder/status`` shows every swarm topic
recorded with every publisher matched; it is stopped last (SIGINT, it drains and closes the
bag) and its received / written / dropped counts go into ``summary.json`` (``recording``).
A recorder that dies stops the run (a restarted one could not continue the bag).

Exit codes: 0 success, 2 bad input or graph not ready in time, 3 a child died (without
``--respawn``, or after ``--max-respawns``), 4 no ``/swarm/state`` for ``--stall-timeout``,
5 a lockstep run completed but ``/swarm/state`` samples were lost (``trajectory.npz`` has gaps),
130 interrupted (SIGINT or SIGTERM).

This package imports rclpy only inside :func:`run`, so the ``apf-swarm`` parser stays light, and
the process supervision (:class:`Child`, :class:`ProcessGroup`), the graph expectations
(:func:`expected_graph`, :func:`graph_missing`) and the accumulation
(:class:`StateAccumulator`) are usable and testable without ROS.
"""

from ..analysis.samples import StateAccumulator
from ..lifetime import stop_process
from .cli import add_arguments, build_parser, main, resolve_config, run
from .commands import node_commands
from .graph import TopicExpectation, expected_graph, graph_missing
from .isolation import DOMAIN_LEASE, check_capacity, domain_looks_busy, pick_domain_id
from .processes import (
    EXIT_BAD_INPUT,
    EXIT_CHILD_DIED,
    EXIT_INTERRUPTED,
    EXIT_OK,
    EXIT_STALLED,
    Child,
    ProcessGroup,
)

__all__ = [
    'DOMAIN_LEASE',
    'EXIT_BAD_INPUT',
    'EXIT_CHILD_DIED',
    'EXIT_INTERRUPTED',
    'EXIT_OK',
    'EXIT_STALLED',
    'Child',
    'ProcessGroup',
    'StateAccumulator',
    'TopicExpectation',
    'add_arguments',
    'build_parser',
    'check_capacity',
    'domain_looks_busy',
    'expected_graph',
    'graph_missing',
    'main',
    'node_commands',
    'pick_domain_id',
    'resolve_config',
    'run',
    'stop_process',
]
