"""argparse ``type=`` converters shared by ``apf-swarm`` and the bring-up: each names what it
expected in the message argparse prints."""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable
from pathlib import Path

from apf_swarm_core.config_files import preset_names

__all__ = [
    'add_animation_args',
    'add_config_args',
    'add_view_args',
    'domain_id',
    'node_param',
    'nonneg_float',
    'nonneg_int',
    'port_number',
    'positive_float',
    'positive_int',
]


def _number(
    kind: type, lo: float, strict: bool, what: str, hi: float = math.inf
) -> Callable[[str], float]:
    def convert(text: str) -> float:
        try:
            val = kind(text)
        except ValueError:
            name = 'a number' if kind is float else 'an integer'
            raise argparse.ArgumentTypeError(f'{text!r} is not {name}') from None
        if not (math.isfinite(val) and (val > lo if strict else val >= lo) and val <= hi):
            raise argparse.ArgumentTypeError(f'{text}: {what}')
        return val

    return convert


positive_float = _number(float, 0.0, True, 'must be a positive number')
nonneg_float = _number(float, 0.0, False, 'must be >= 0')
positive_int = _number(int, 1, False, 'must be >= 1')
nonneg_int = _number(int, 0, False, 'must be >= 0')
#: a TCP port (0: any free port) and a ROS domain id
port_number = _number(int, 0, False, 'a TCP port is 0..65535', hi=65535)
domain_id = _number(int, 0, False, 'a ROS domain id is 0..232', hi=232)


def node_param(text: str) -> str:
    """``--node-param NAME:=VALUE``: a parameter name (letters, digits, ``_``, ``.``) and a
    value (ArgumentTypeError naming the form otherwise)."""
    name, sep, value = text.partition(':=')
    if not sep or not value or not name.replace('_', 'a').replace('.', 'a').isalnum():
        raise argparse.ArgumentTypeError(
            f'{text!r}: expected NAME:=VALUE, e.g. executor:=events or stale_after:=0.2'
        )
    return text


def add_config_args(
    p: argparse.ArgumentParser, *, required: bool = True, default_preset: str | None = None
) -> None:
    """``--preset NAME | --config FILE`` and ``--set KEY=VALUE``: the configuration options of
    every command (resolved by :func:`apf_swarm_core.config_files.resolve`)."""
    g = p.add_mutually_exclusive_group(required=required)
    g.add_argument(
        '--preset',
        metavar='NAME',
        default=default_preset,
        help='named preset (config/NAME.yaml): ' + ', '.join(preset_names()),
    )
    g.add_argument('--config', metavar='FILE', type=Path, help='ROS 2 parameter file')
    p.add_argument(
        '--set',
        metavar='KEY=VALUE',
        action='append',
        default=[],
        dest='sets',
        help='override a configuration key (repeatable), e.g. --set gamma=0.5',
    )


def add_animation_args(p: argparse.ArgumentParser) -> None:
    """``--speed``, ``--fps``, ``--projection`` of the commands that write an animation."""
    p.add_argument(
        '--speed',
        type=positive_float,
        metavar='X',
        help='speed-up against real time (default: the run in at most 20 s)',
    )
    p.add_argument(
        '--fps', type=positive_int, default=15, metavar='F', help='frames per second (15)'
    )
    p.add_argument(
        '--projection', choices=('3d', 'top'), default='3d', help='3-D (default) or from above'
    )


def add_view_args(
    p: argparse.ArgumentParser, *, flag: str = '--view', default: int | None = None
) -> None:
    """The live view's port (``flag``; ``--view [PORT]`` when ``default`` is None: off unless
    given, 8765 when given without a value) and ``--view-host``."""
    from .view.server import DEFAULT_PORT

    if default is None:
        p.add_argument(
            flag,
            dest='view',
            type=port_number,
            nargs='?',
            const=DEFAULT_PORT,
            default=None,
            metavar='PORT',
            help=f'serve the run to the Foxglove app on ws://HOST:PORT (default {DEFAULT_PORT}; '
            '0: any free port, printed)',
        )
    else:
        p.add_argument(
            flag,
            dest='port',
            type=port_number,
            default=default,
            metavar='PORT',
            help=f'WebSocket port of the view (default {default}; 0: any free port, printed)',
        )
    p.add_argument(
        '--view-host',
        dest='view_host',
        default='127.0.0.1',
        metavar='ADDR',
        help='address the view binds to (default 127.0.0.1: this machine only)',
    )
