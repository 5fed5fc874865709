"""The ``apf-swarm`` parser and ``main``."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from apf_swarm_core.config import DEFAULT_LATENCY
from apf_swarm_core.errors import ApfSwarmError

from ..argtypes import add_animation_args, add_config_args, positive_float
from .bag import add_bag_parser
from .commands import (
    PROG,
    cmd_check,
    cmd_design,
    cmd_reproduce,
    cmd_simulate,
    cmd_sweep,
    latency_arg,
)

__all__ = ['build_parser', 'main']


def _add_realtime_args(p: argparse.ArgumentParser, help_rate: str = '') -> None:
    p.add_argument(
        '--control-rate',
        type=positive_float,
        metavar='HZ',
        help=help_rate
        or 'sample and hold the control at this rate (the control_rate key; real time emulated)',
    )
    p.add_argument(
        '--latency',
        type=latency_arg,
        metavar='S|FILE',
        help='control-loop delay [s], or a JSON file of measured latencies to '
        "draw from (a list, or a realtime run's summary.json); default for "
        "check and design: the latency key, else this machine's probe "
        f'(`apf-swarm probe`), else {DEFAULT_LATENCY:g} s',
    )


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=PROG,
        description='APF formation tracking with '
        'sliding-mode control: simulate, check, design, reproduce.',
    )
    sub = parser.add_subparsers(dest='command', required=True, metavar='COMMAND')

    p = sub.add_parser('simulate', help='run the headless simulator')
    add_config_args(p)
    p.add_argument('--law', choices=('proposed', 'traditional'))
    p.add_argument('--n-trackers', type=int)
    p.add_argument('--duration', type=positive_float, metavar='S')
    p.add_argument('--dt', type=positive_float, metavar='S')
    p.add_argument('--seed', type=int)
    _add_realtime_args(p)
    p.add_argument('--out', type=Path, required=True, metavar='DIR')
    p.add_argument(
        '--animate', type=Path, metavar='FILE', help='also write an animation (.gif or .mp4)'
    )
    add_animation_args(p)
    p.add_argument('--quiet', action='store_true', help='no progress line')
    p.set_defaults(func=cmd_simulate)

    p = sub.add_parser(
        'check', help='validation and gain report (exit 0 ok, 1 warnings, 2 errors)'
    )
    add_config_args(p)
    p.add_argument(
        '--mode',
        choices=('lockstep', 'realtime'),
        default='lockstep',
        help='realtime: also predict the sampled loop (control rate, latency)',
    )
    p.add_argument('--n-trackers', type=int)
    _add_realtime_args(p)
    p.add_argument(
        '--no-run',
        action='store_true',
        help='skip the simulation that measures J_bar (a priori bounds only)',
    )
    p.add_argument('--json', action='store_true')
    p.add_argument('--quiet', action='store_true')
    p.set_defaults(func=cmd_check)

    p = sub.add_parser('design', help='b (or c) for a spacing, and the equilibrium shape')
    add_config_args(p, required=False, default_preset='triangle')
    p.add_argument(
        '--spacing', type=positive_float, metavar='D', help='wanted nearest-neighbour distance [m]'
    )
    p.add_argument('--n-trackers', type=int)
    _add_realtime_args(
        p, help_rate='propose the gains of a realtime loop at this rate (instead of --spacing)'
    )
    p.add_argument('--solve', choices=('b', 'c'), default='b')
    p.add_argument('--json', action='store_true')
    p.set_defaults(func=cmd_design)

    p = sub.add_parser('reproduce', help="the paper's Figures 1-7 and report.md")
    p.add_argument('--out', type=Path, required=True, metavar='DIR')
    p.add_argument(
        '--duration', type=positive_float, metavar='S', help="override the presets' duration"
    )
    p.add_argument('--quick', action='store_true', help='3 gamma values instead of 8')
    p.add_argument(
        '--no-animations', action='store_true', help='skip the animation of each law (GIF)'
    )
    p.add_argument('--quiet', action='store_true')
    p.set_defaults(func=cmd_reproduce)

    p = sub.add_parser('sweep', help='both laws over values of one key, batched')
    add_config_args(p, required=False, default_preset='triangle')
    p.add_argument('--param', required=True, metavar='NAME')
    p.add_argument('--values', required=True, metavar='V1,V2,...')
    p.add_argument('--seeds', type=int, default=1, metavar='K')
    p.add_argument('--duration', type=positive_float, metavar='S')
    p.add_argument('--out', type=Path, required=True, metavar='DIR')
    p.add_argument('--quiet', action='store_true')
    p.set_defaults(func=cmd_sweep)

    from .. import bringup  # no rclpy import until a bring-up actually runs

    p = sub.add_parser(
        'up',
        help='bring up the ROS 2 graph (target, plant, trackers) and '
        'record a run (exit 0 ok, 2 bad input / not ready, 3 a node died)',
    )
    bringup.add_arguments(p)
    p.set_defaults(func=lambda args: bringup.run(args, prog=f'{PROG} up'))
    from ..capacity import probe

    p = sub.add_parser(
        'probe',
        help="measure this machine's control-loop latency and cost "
        '(cached): the realtime defaults come from it',
    )
    probe.add_arguments(p)
    p.set_defaults(func=probe.run)
    from ..dds import cleanup

    p = sub.add_parser(
        'clean',
        help='remove what killed runs left: stale Fast DDS shared memory (/dev/shm), '
        'node processes whose bring-up is gone',
    )
    cleanup.add_arguments(p)
    p.set_defaults(func=cleanup.run)
    add_bag_parser(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return int(args.func(args))
    except ApfSwarmError as exc:
        print(f'{PROG}: error: {exc}', file=sys.stderr)
        return 2
    except OSError as exc:
        print(f'{PROG}: error: {exc.strerror or exc}: {exc.filename or ""}', file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f'{PROG}: interrupted', file=sys.stderr)
        return 130
