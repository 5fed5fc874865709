"""Exceptions of :mod:`apf_swarm_nodes` outside its subpackages (which have their own
``errors.py``). Each names the value and what to do; only a command line turns one into a
message and an exit code (``apf-swarm: error: ...``, exit 2), a node into its exit status."""

from __future__ import annotations

from apf_swarm_core.errors import ApfSwarmError

__all__ = ['NodeParameterError']


class NodeParameterError(ApfSwarmError):
    """A node cannot start with its parameters: a bag or a file missing, a regular
    expression that does not compile, a message type not installed."""
