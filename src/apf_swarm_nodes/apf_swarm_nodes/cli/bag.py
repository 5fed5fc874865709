"""The ``apf-swarm bag`` commands (info, metrics, plot, animate, view, export, reindex, play)
and their parser."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from apf_swarm_core.errors import ApfSwarmError

from ..analysis.runio import format_summary
from ..argtypes import add_animation_args, add_view_args, nonneg_float, positive_float
from ..view.server import DEFAULT_PORT
from .commands import PROG

__all__ = [
    'add_bag_parser',
    'cmd_bag_animate',
    'cmd_bag_export',
    'cmd_bag_info',
    'cmd_bag_metrics',
    'cmd_bag_play',
    'cmd_bag_plot',
    'cmd_bag_reindex',
    'cmd_bag_view',
]


def cmd_bag_info(args: argparse.Namespace) -> int:
    from ..bags import format_info, info_dict, open_bag

    info = open_bag(args.bag)
    print(json.dumps(info_dict(info), indent=2) if args.json else format_info(info))
    return 0


def cmd_bag_metrics(args: argparse.Namespace) -> int:
    from ..bags import bag_metrics

    summary = bag_metrics(args.bag, args.config, quiet=args.quiet)
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        print(format_summary(summary))
        m = summary['messages']
        print(
            f'  /swarm/state     {m["received"]} samples, {m["dropped"]} missing, mode '
            f'{summary["mode"]}'
        )
    return 0


def cmd_bag_plot(args: argparse.Namespace) -> int:
    from ..analysis.plots import paper_figures
    from ..bags import bag_trajectory

    traj, cfg, _mode, _acc = bag_trajectory(args.bag, args.config, quiet=args.quiet)
    if len(traj['t']) < 2:
        raise ApfSwarmError(
            f'{args.bag}: /swarm/state has {len(traj["t"])} sample; a figure needs two'
        )
    paths = paper_figures({cfg.law: traj}, args.out)
    print(f'wrote {len(paths)} figures into {args.out}: ' + ', '.join(p.name for p in paths))
    return 0


def cmd_bag_animate(args: argparse.Namespace) -> int:
    from ..analysis.animate import check_path
    from ..bags import bag_trajectory
    from .commands import write_animation

    check_path(args.out)
    traj, cfg, _mode, _acc = bag_trajectory(args.bag, args.config, quiet=args.quiet)
    write_animation(args, traj, cfg, args.out)
    return 0


def cmd_bag_view(args: argparse.Namespace) -> int:
    from ..view.bag import serve_bag

    frames = serve_bag(
        args.bag,
        host=args.view_host,
        port=args.port,
        rate=args.rate,
        loop=args.loop,
        wait_client=args.wait_client,
        config=args.config,
        say=lambda m: print(f'{PROG} bag view: {m}', file=sys.stderr, flush=True),
    )
    print(f'{PROG} bag view: sent {frames} frames', file=sys.stderr)
    return 0


def cmd_bag_export(args: argparse.Namespace) -> int:
    from ..bags import export_csv

    if args.csv is None:
        export_csv(args.bag, args.topic, sys.stdout, quiet=args.quiet)
        return 0
    if args.csv.exists() and not args.force:
        raise ApfSwarmError(f'{args.csv} exists; choose another file or pass --force')
    tmp = args.csv.with_name(args.csv.name + '.tmp')
    try:
        with open(tmp, 'w', newline='') as fh:
            n = export_csv(args.bag, args.topic, fh, quiet=args.quiet)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    tmp.replace(args.csv)
    print(f'wrote {n} rows of {args.topic} to {args.csv}', file=sys.stderr)
    return 0


def cmd_bag_reindex(args: argparse.Namespace) -> int:
    from ..bags import reindex

    reindex(args.bag, stream=sys.stdout)
    return 0


def cmd_bag_play(args: argparse.Namespace) -> int:
    from ..bags import open_bag

    info = open_bag(args.bag)  # bad input: one line and exit 2, before ROS starts
    from ..node_common import msg_class

    for t in args.topics or [t.name for t in info.topics]:
        msg_class(info.topic(t).type)  # a type that is not installed: one line, exit 2
    params = {
        'bag': info.path.resolve(),
        'rate': repr(args.rate),
        'loop': str(args.loop).lower(),
        'start_offset': repr(args.start_offset),
        'clock': repr(float(args.clock or 0.0)),
        'topics': f'[{",".join(args.topics)}]' if args.topics else None,
        'wait_for': f'[{",".join(args.wait_for)}]' if args.wait_for else None,
    }
    ros = ['--ros-args']
    for name, value in params.items():
        ros += ['-p', f'{name}:={value}'] if value is not None else []
    for rule in args.remap:
        if ':=' not in rule:
            raise ApfSwarmError(f'--remap {rule!r}: expected FROM:=TO')
        ros += ['-r', rule]
    from ..node_common import run_node
    from ..player_node import PlayerNode, run_player

    if args.view is None:
        return run_node(PROG, PlayerNode, [PROG, *ros], run=run_player)
    from ..view.bag import live_view_of_bag

    view, observe = live_view_of_bag(info, host=args.view_host, port=args.view, config=args.config)
    print(f'{PROG} bag play: view: {view.url}', file=sys.stderr, flush=True)

    def player() -> PlayerNode:
        node = PlayerNode()
        node.on_published = observe
        return node

    try:
        return run_node(PROG, player, [PROG, *ros], run=run_player)
    finally:
        view.close()


def add_bag_parser(sub: Any) -> None:
    p = sub.add_parser(
        'bag',
        help='inspect, replay and repair rosbag2 (MCAP) bags',
        description='Bags recorded by `apf-swarm up --record` (BAG = the bag '
        'directory, e.g. runs/r/bag). Every command but play works without a ROS '
        'graph.',
    )
    bsub = p.add_subparsers(dest='bag_command', required=True, metavar='BAG_COMMAND')

    def command(name: str, func: Any, help: str) -> argparse.ArgumentParser:
        q: argparse.ArgumentParser = bsub.add_parser(name, help=help)
        q.add_argument('bag', type=Path, metavar='BAG')
        q.set_defaults(func=func)
        return q

    def config(q: argparse.ArgumentParser, help: str | None = None) -> None:
        q.add_argument('--config', type=Path, metavar='FILE', help=help)

    def quiet(q: argparse.ArgumentParser) -> None:
        q.add_argument('--quiet', action='store_true', help='no progress bar')

    q = command(
        'info',
        cmd_bag_info,
        'storage, duration, size, counts; per topic type, count, '
        'frequency, QoS (from the summaries, fast on big bags)',
    )
    q.add_argument('--json', action='store_true')

    q = command('metrics', cmd_bag_metrics, "the run's summary.json computed from /swarm/state")
    config(q, 'parameter file of the run (default: the one stored in the bag)')
    q.add_argument('--json', action='store_true')
    quiet(q)

    q = command('plot', cmd_bag_plot, 'the figures of `apf-swarm reproduce` from /swarm/state')
    q.add_argument('--out', type=Path, required=True, metavar='DIR')
    config(q)
    quiet(q)

    q = command(
        'animate', cmd_bag_animate, 'an animation of the run (.gif or .mp4) from /swarm/state'
    )
    q.add_argument('--out', type=Path, required=True, metavar='FILE')
    config(q)
    add_animation_args(q)
    quiet(q)

    q = command(
        'view',
        cmd_bag_view,
        'serve the run to the Foxglove app (WebSocket) as a live run is served, no ROS graph',
    )
    add_view_args(q, flag='--port', default=DEFAULT_PORT)
    q.add_argument('--rate', type=positive_float, default=1.0, metavar='R', help='speed (1)')
    q.add_argument('--loop', action='store_true', help='play again until Ctrl-C')
    q.add_argument(
        '--wait-client',
        type=nonneg_float,
        default=None,
        metavar='S',
        help='give up when no client subscribed within S seconds (default: wait)',
    )
    config(q)

    q = command('export', cmd_bag_export, 'flattened fields of one topic as CSV')
    q.add_argument('--topic', required=True, metavar='T')
    q.add_argument('--csv', type=Path, metavar='FILE', help='output file (default: stdout)')
    q.add_argument('--force', action='store_true', help='overwrite FILE')
    quiet(q)

    command(
        'reindex',
        cmd_bag_reindex,
        'rebuild metadata.yaml (and truncated MCAP files) from '
        'the MCAP files; keeps a backup of what it replaces',
    )

    q = command('play', cmd_bag_play, 'republish the bag with its recorded timing (ROS graph)')
    q.add_argument('--rate', type=positive_float, default=1.0, metavar='R')
    q.add_argument('--loop', action='store_true')
    q.add_argument('--start-offset', type=nonneg_float, default=0.0, metavar='S')
    q.add_argument('--topics', nargs='+', metavar='T', help='play only these topics')
    q.add_argument(
        '--clock',
        type=positive_float,
        nargs='?',
        const=100.0,
        default=None,
        metavar='HZ',
        help='publish /clock at HZ (default 100) instead of the recorded /clock',
    )
    q.add_argument('--remap', nargs='+', default=[], metavar='FROM:=TO')
    q.add_argument(
        '--wait-for', nargs='+', metavar='T', help='start only when these topics have a subscriber'
    )
    config(q, "with --view: the run's parameter file")
    add_view_args(q)
