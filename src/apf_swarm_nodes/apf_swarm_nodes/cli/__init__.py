"""The ``apf-swarm`` command: simulate, check, design, reproduce, sweep, up, bag.

Every expected failure (bad configuration, unknown preset, unreadable file...) prints one
line ``apf-swarm: error: ...`` and exits 2; ``check`` exits 0 / 1 / 2 for consistent /
warnings only / errors.
"""

from .commands import PROG
from .parser import build_parser, main

__all__ = ['PROG', 'build_parser', 'main']
