"""Exceptions raised by :mod:`apf_swarm_core`.

Every error message names the offending key or value and says what is allowed, so that a
command-line front end can print it as one line without a traceback.
"""

from __future__ import annotations

__all__ = ['ApfSwarmError', 'ConfigError', 'UnknownPresetError']


class ApfSwarmError(Exception):
    """Base class of every error raised on purpose by apf_swarm."""


class ConfigError(ApfSwarmError, ValueError):
    """A configuration key is missing, unknown, of the wrong type or out of range."""


class UnknownPresetError(ConfigError):
    """A preset name does not match any file in the preset directories."""
