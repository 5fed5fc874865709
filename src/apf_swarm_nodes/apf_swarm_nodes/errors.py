"""Exceptions of :mod:`apf_swarm_nodes`; the CLI prints them as one line and exits 2."""

from __future__ import annotations

from apf_swarm_core.errors import ApfSwarmError

__all__ = ['CliError']


class CliError(ApfSwarmError):
    """A command-line usage or input problem (bad path, bad value, unknown topic...)."""
