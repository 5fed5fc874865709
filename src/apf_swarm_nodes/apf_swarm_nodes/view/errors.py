"""The live view's own error: what the command line prints as one line and exits 2 on."""

from __future__ import annotations

from apf_swarm_core.errors import ApfSwarmError

__all__ = ['ViewError']


class ViewError(ApfSwarmError):
    """The view cannot serve as asked: a busy port, a bag with no state to show."""
