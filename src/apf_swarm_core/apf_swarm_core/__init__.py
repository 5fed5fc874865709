"""apf_swarm_core: the mathematics of APF formation tracking with sliding-mode control.

numpy (and scipy for formation design) only; no ROS import anywhere in this package.
"""

from .config import SwarmConfig
from .config_files import load_config, load_preset
from .errors import ApfSwarmError, ConfigError, UnknownPresetError
from .simulator import simulate, simulate_batch

__all__ = [
    'ApfSwarmError',
    'ConfigError',
    'SwarmConfig',
    'UnknownPresetError',
    'load_config',
    'load_preset',
    'simulate',
    'simulate_batch',
]
