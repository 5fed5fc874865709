"""The middleware's own error: what the command line prints as one line and exits 2 on."""

from __future__ import annotations

from apf_swarm_core.errors import ApfSwarmError

__all__ = ['DdsError']


class DdsError(ApfSwarmError):
    """The middleware cannot carry the run as asked: not Fast DDS, an unknown discovery
    range, a domain that already carries a swarm, a secure run's missing or wrong file."""
