"""The analysis' own error: samples, files or arguments it cannot make a trajectory, a
study or a figure of. A command line prints it as one line and exits 2."""

from __future__ import annotations

from apf_swarm_core.errors import ApfSwarmError

__all__ = ['AnalysisError']


class AnalysisError(ApfSwarmError):
    """The samples, a file or a value cannot be analysed as asked: the message names it."""
