"""The bring-up's own error: a run that cannot start as asked. The command line prints it as
one line (``swarm_up.py: error: ...``) and exits with EXIT_BAD_INPUT."""

from __future__ import annotations

from apf_swarm_core.errors import ApfSwarmError

__all__ = ['BringupError']


class BringupError(ApfSwarmError):
    """A run cannot start as asked (this machine's limit, a missing executable, a bag that
    exists already...): the message names the value and says what to do."""
