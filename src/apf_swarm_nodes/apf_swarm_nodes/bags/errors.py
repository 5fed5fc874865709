"""The bags' own error: what the command line prints as one line (``apf-swarm: error: ...``,
exit 2), raised here without knowing it."""

from __future__ import annotations

from apf_swarm_core.errors import ApfSwarmError

__all__ = ['BagError']


class BagError(ApfSwarmError):
    """A bag cannot be opened, read, written or recovered as asked: the message names the
    path (or the topic, or the type) and says what to do."""
