"""The ``apf-swarm`` command: simulate, check, design, reproduce, sweep, up, bag.

Every expected failure (bad configuration, unknown preset, unreadable file...) prints one
line ``apf-swarm: error: ...`` and exits 2; ``check`` exits 0 / 1 / 2 for consistent /
warnings only / errors.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from apf_swarm_core.checks import check_config
from apf_swarm_core.config import (
    DEFAULT_LATENCY,
    REALTIME_RATE,
    SwarmConfig,
    load_preset,
    resolve,
)
from apf_swarm_core.design import b_for_spacing, equilibrium_formation, triangle_c_for_spacing
from apf_swarm_core.errors import ApfSwarmError
from apf_swarm_core.simulator import simulate

from .argtypes import add_config_args, nonneg_float, positive_float
from .progress import Progress
from .runio import format_summary, write_run

__all__ = ['build_parser', 'main']

PROG = 'apf-swarm'


def _load(args: argparse.Namespace, extra: dict[str, Any] | None = None) -> SwarmConfig:
    return resolve(args.config, args.preset, args.sets, **(extra or {}))


def _progress(args: argparse.Namespace, label: str) -> Progress | None:
    return None if getattr(args, 'quiet', False) else Progress(label)


def _latency_arg(text: str) -> float | Path:
    """``--latency``: seconds, or a JSON file of measured latencies."""
    try:
        return nonneg_float(text)
    except argparse.ArgumentTypeError:
        path = Path(text)
        if not path.is_file():
            raise argparse.ArgumentTypeError(
                f'{text!r}: expected a latency in seconds (e.g. 0.004) or a JSON file of '
                f'measured latencies (a list, or {{"latency_samples": [...]}})'
            ) from None
        return path


def latency_samples(path: Path) -> np.ndarray:
    """Measured latencies [s] from a JSON file: a list, or an object with
    ``latency_samples`` (a realtime run's summary.json holds them under ``prediction``)."""
    try:
        doc = json.loads(path.read_text())
    except ValueError as exc:
        raise ApfSwarmError(f'{path}: not JSON ({exc}); expected a list of latencies [s]') from exc
    if isinstance(doc, dict):
        doc = doc.get('latency_samples', doc.get('prediction', {}).get('latency_samples'))
    arr = np.asarray(doc if doc is not None else [], dtype=float).ravel()
    if arr.size == 0 or not np.all(np.isfinite(arr)) or np.any(arr < 0):
        raise ApfSwarmError(
            f'{path}: expected a non-empty list of latencies >= 0 s '
            '(or an object with "latency_samples")'
        )
    return arr


def _realtime_extra(args: argparse.Namespace) -> tuple[dict[str, Any], np.ndarray | None]:
    """--control-rate / --latency as configuration values, and latency samples."""
    extra: dict[str, Any] = {'control_rate': getattr(args, 'control_rate', None)}
    lat = getattr(args, 'latency', None)
    samples = None
    if isinstance(lat, Path):
        samples = latency_samples(lat)
        extra['latency'] = float(np.median(samples))
    else:
        extra['latency'] = lat
    return extra, samples


def machine_latency(n: int, rate: float | None = None) -> float:
    """The control-loop latency of this machine for n trackers at ``rate`` from its cached
    probe (``apf-swarm probe``), else DEFAULT_LATENCY (said on stderr)."""
    from . import probe

    cached = probe.load()
    if cached is None:
        print(
            f'{PROG}: no probe of this machine yet (`apf-swarm probe`): assuming '
            f'{DEFAULT_LATENCY * 1e3:g} ms of control-loop latency',
            file=sys.stderr,
        )
        return DEFAULT_LATENCY
    return float(probe.derive(cached, n, rate)['latency'])


def machine_rate(n: int) -> float:
    """The default realtime rate for n trackers from this machine's cached probe, else
    REALTIME_RATE."""
    from . import probe

    cached = probe.load()
    return REALTIME_RATE if cached is None else float(probe.derive(cached, n)['rate'])


def cmd_simulate(args: argparse.Namespace) -> int:
    extra, samples = _realtime_extra(args)
    cfg = _load(
        args,
        {
            'law': args.law,
            'n_trackers': args.n_trackers,
            'duration': args.duration,
            'dt': args.dt,
            'seed': args.seed,
            **extra,
        },
    )
    if samples is not None and cfg.control_rate <= 0:
        raise ApfSwarmError('--latency FILE emulates a realtime loop: give --control-rate HZ')
    report = check_config(cfg)
    res = simulate(cfg, progress=_progress(args, 'simulate'), latency_samples=samples)
    summary = res.summary(warnings=report.warnings)
    write_run(args.out, res.trajectory, summary, cfg)
    print(format_summary(summary))
    print(f'wrote {args.out / "trajectory.npz"} and {args.out / "summary.json"}')
    return 0


def cmd_check(args: argparse.Namespace) -> int:
    extra, samples = _realtime_extra(args)
    cfg = _load(args, {'n_trackers': args.n_trackers, **extra})
    if args.mode == 'realtime' and cfg.control_rate <= 0:
        cfg = cfg.replace(control_rate=machine_rate(cfg.n_trackers))
    if args.mode == 'realtime' and args.latency is None and cfg.latency == 0:
        cfg = cfg.replace(latency=machine_latency(cfg.n_trackers, cfg.control_rate))
    run = (
        None
        if args.no_run
        else simulate(
            cfg, progress=_progress(args, 'check run'), latency_samples=samples
        ).trajectory
    )
    rep = check_config(cfg, run, realtime=args.mode == 'realtime')
    if args.json:
        print(json.dumps(rep.as_dict(), indent=2))
    else:
        mark = {'ok': 'ok  ', 'info': 'info', 'warning': 'WARN', 'error': 'ERR '}
        for f in rep.findings:
            print(f'[{mark[f.level]}] {f.message}')
        verdict = {
            0: 'consistent',
            1: 'warnings: read them before flying',
            2: 'errors: this configuration cannot run',
        }[rep.exit_code]
        print(f'verdict: {verdict}')
    return rep.exit_code


def cmd_design_rate(args: argparse.Namespace, cfg: SwarmConfig) -> int:
    """``design --control-rate HZ``: gains that the sampled-data prediction passes."""
    from apf_swarm_core.sampled import predict, propose_gains

    latency = (
        args.latency
        if isinstance(args.latency, float)
        else (cfg.latency or machine_latency(cfg.n_trackers, args.control_rate))
    )
    try:
        gains = propose_gains(cfg, control_rate=args.control_rate, latency=latency)
    except ValueError as exc:
        raise ApfSwarmError(str(exc)) from None
    tuned = cfg.replace(control_rate=args.control_rate, latency=latency, **gains)
    pred = predict(tuned)
    if args.json:
        print(
            json.dumps(
                {
                    'n_trackers': cfg.n_trackers,
                    'control_rate': args.control_rate,
                    'latency': latency,
                    'gains': gains,
                    'prediction': pred.to_dict(),
                },
                indent=2,
            )
        )
        return 0
    print(
        f'{cfg.n_trackers} trackers at {args.control_rate:g} Hz with {latency * 1e3:g} ms '
        f'latency: lambda_max of the Hessian of J = {pred.hessian_max:.4g}'
    )
    print(
        '  '
        + '  '.join(
            f'--set {k}={v:.4g}' if isinstance(v, float) else f'--set {k}={v}'
            for k, v in gains.items()
        )
    )
    print(
        f'  K = alpha + beta/gamma = {pred.layer_gain:.4g} 1/s: K lambda_max = '
        f'{pred.formation_rate:.4g} 1/s of {pred.rate_allowed:.4g} allowed; softest mode '
        f'settles in {pred.settle_time:.3g} s (of {pred.settle_allowed:.3g}); lag '
        f'{pred.steady_lag:.3g} m'
    )
    for w in pred.warnings:
        print(f'  [WARN] {w}')
    print('verdict: ' + ('predicted to hold' if pred.holds else 'predicted to fail'))
    return 0 if pred.holds else 1


def cmd_design(args: argparse.Namespace) -> int:
    cfg = _load(args, {'n_trackers': args.n_trackers})
    if args.control_rate is not None:
        return cmd_design_rate(args, cfg)
    if args.spacing is None:
        raise ApfSwarmError(
            'design needs --spacing D (formation) or --control-rate HZ (gains for a realtime loop)'
        )
    n = cfg.n_trackers
    pp = cfg.potential_params()
    p = {'k_n': pp['k_n'], 'k_f': pp['k_f'], 'a': pp['a'], 'b': pp['b'], 'c': pp['c']}
    if args.solve == 'b':
        p['b'] = b_for_spacing(args.spacing, n, k_n=p['k_n'], k_f=p['k_f'], a=p['a'], c=p['c'])
    else:
        if n != 3:
            raise ApfSwarmError('--solve c has a closed form for 3 trackers only; use --solve b')
        p['c'] = triangle_c_for_spacing(args.spacing, p['a'], p['b'], p['k_n'], p['k_f'])
    form = equilibrium_formation(n, k_n=p['k_n'], k_f=p['k_f'], a=p['a'], b=p['b'], c=p['c'])
    out = {
        'n_trackers': n,
        'spacing': args.spacing,
        'solved_for': args.solve,
        args.solve: p[args.solve],
        'parameters': p,
        'relative_positions': np.round(form.relative_positions, 9).tolist(),
        'pair_distances': np.round(form.pair_distances, 9).tolist(),
        'potential': form.potential,
        'gradient_norm': form.gradient_norm,
    }
    if args.json:
        print(json.dumps(out, indent=2))
        return 0
    print(
        f'{args.solve} = {p[args.solve]:.9g} gives nearest-neighbour spacing {args.spacing:g} m '
        f'for {n} trackers (k_n = {p["k_n"]:g}, k_f = {p["k_f"]:g}, a = {p["a"]:g}, '
        f'b = {p["b"]:.6g}, c = {p["c"]:.6g})'
    )
    print('equilibrium positions relative to the target [m] (any rotation is an equilibrium too):')
    for i, row in enumerate(form.relative_positions, 1):
        print(
            f'  uav_{i}: ({row[0]: .4f}, {row[1]: .4f}, {row[2]: .4f})  '
            f'|r| = {np.linalg.norm(row):.4f}'
        )
    print('pair distances [m]: ' + ', '.join(f'{d:.4f}' for d in form.pair_distances))
    print(f'max |grad J| at the solution: {form.gradient_norm:.2e}')
    return 0


def cmd_reproduce(args: argparse.Namespace) -> int:
    from .studies import GAMMA_VALUES, reproduce

    presets = {name: load_preset(name) for name in ('triangle', 'paper')}
    if args.duration is not None:
        presets = {k: v.replace(duration=args.duration) for k, v in presets.items()}
    gammas = GAMMA_VALUES if not args.quick else (0.02, 0.2, 1.0)
    path = reproduce(args.out, presets, None if args.quiet else Progress, gammas)
    print(path.read_text().split('## Conclusion', 1)[-1].strip())
    print(f'wrote {path} and the figures next to it')
    return 0


def _parse_values(text: str) -> list[Any]:
    import yaml

    vals = []
    for raw in text.split(','):
        item = raw.strip()
        if not item:
            raise ApfSwarmError(f'--values {text!r}: empty value; expected V1,V2,...')
        vals.append(yaml.safe_load(item))
    return vals


def cmd_sweep(args: argparse.Namespace) -> int:
    from .studies import sweep, write_sweep

    cfg = _load(args, {'duration': args.duration})
    values = _parse_values(args.values)
    if args.seeds < 1:
        raise ApfSwarmError(f'--seeds {args.seeds}: must be >= 1')
    rows = sweep(
        cfg, args.param, values, args.seeds, progress=None if args.quiet else Progress('sweep')
    )
    paths = write_sweep(rows, args.param, args.out)
    print(
        f'{"law":12s} {args.param:>10s} {"centroid RMS":>13s} {"HF vel RMS":>11s} '
        f'{"heading rate":>13s}'
    )
    for law in ('proposed', 'traditional'):
        for v in values:
            sel = [r for r in rows if r['law'] == law and r['value'] == v]
            print(
                f'{law:12s} {v!s:>10s} '
                f'{np.mean([r["centroid_rms"] for r in sel]):13.4g} '
                f'{np.mean([r["hf_velocity_rms"] for r in sel]):11.4g} '
                f'{np.mean([r["heading_rate"] for r in sel]):13.4g}'
            )
    print(f'wrote {paths["csv"]} and {paths["png"]}')
    return 0


# --- bags ------------------------------------------------------------------------------------


def cmd_bag_info(args: argparse.Namespace) -> int:
    from .bags import format_info, info_dict, open_bag

    info = open_bag(args.bag)
    print(json.dumps(info_dict(info), indent=2) if args.json else format_info(info))
    return 0


def cmd_bag_metrics(args: argparse.Namespace) -> int:
    from .bags import bag_metrics

    summary = bag_metrics(args.bag, args.config)
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
    from .bags import bag_trajectory
    from .plots import paper_figures

    traj, cfg, _mode, _acc = bag_trajectory(args.bag, args.config)
    if len(traj['t']) < 2:
        raise ApfSwarmError(
            f'{args.bag}: /swarm/state has {len(traj["t"])} sample; a figure needs two'
        )
    paths = paper_figures({cfg.law: traj}, args.out)
    print(f'wrote {len(paths)} figures into {args.out}: ' + ', '.join(p.name for p in paths))
    return 0


def cmd_bag_export(args: argparse.Namespace) -> int:
    from .bags import export_csv

    if args.csv is None:
        n = export_csv(args.bag, args.topic, sys.stdout)
        return 0 if n >= 0 else 1
    if args.csv.exists() and not args.force:
        raise ApfSwarmError(f'{args.csv} exists; choose another file or pass --force')
    tmp = args.csv.with_name(args.csv.name + '.tmp')
    with open(tmp, 'w', newline='') as fh:
        try:
            n = export_csv(args.bag, args.topic, fh)
        except BaseException:
            fh.close()
            tmp.unlink(missing_ok=True)
            raise
    tmp.replace(args.csv)
    print(f'wrote {n} rows of {args.topic} to {args.csv}', file=sys.stderr)
    return 0


def cmd_bag_reindex(args: argparse.Namespace) -> int:
    from .bags import reindex

    reindex(args.bag, stream=sys.stdout)
    return 0


def cmd_bag_play(args: argparse.Namespace) -> int:
    from .bags import open_bag

    info = open_bag(args.bag)  # bad input: one line and exit 2, before ROS starts
    from .player_node import msg_class

    for t in args.topics or [t.name for t in info.topics]:
        msg_class(info.topic(t).type)  # a type that is not installed: one line, exit 2
    for rule in args.remap:
        if ':=' not in rule:
            raise ApfSwarmError(f'--remap {rule!r}: expected FROM:=TO')
    ros = [
        '--ros-args',
        '-p',
        f'bag:={info.path.resolve()}',
        '-p',
        f'rate:={args.rate!r}',
        '-p',
        f'loop:={str(args.loop).lower()}',
        '-p',
        f'start_offset:={args.start_offset!r}',
        '-p',
        f'clock:={float(args.clock or 0.0)!r}',
    ]
    if args.topics:
        ros += ['-p', 'topics:=[' + ','.join(args.topics) + ']']
    if args.wait_for:
        ros += ['-p', 'wait_for:=[' + ','.join(args.wait_for) + ']']
    for rule in args.remap:
        ros += ['-r', rule]
    from .node_common import run_node
    from .player_node import PlayerNode, _run

    return run_node(PROG, PlayerNode, [PROG, *ros], run=_run)


def _add_bag_parser(sub: Any) -> None:
    p = sub.add_parser(
        'bag',
        help='inspect, replay and repair rosbag2 (MCAP) bags',
        description='Bags recorded by `apf-swarm up --record` (BAG = the bag '
        'directory, e.g. runs/r/bag). Every command but play works without a ROS '
        'graph.',
    )
    bsub = p.add_subparsers(dest='bag_command', required=True, metavar='BAG_COMMAND')

    q = bsub.add_parser(
        'info',
        help='storage, duration, size, counts; per topic type, count, '
        'frequency, QoS (from the summaries, fast on big bags)',
    )
    q.add_argument('bag', type=Path, metavar='BAG')
    q.add_argument('--json', action='store_true')
    q.set_defaults(func=cmd_bag_info)

    q = bsub.add_parser('metrics', help="the run's summary.json computed from /swarm/state")
    q.add_argument('bag', type=Path, metavar='BAG')
    q.add_argument(
        '--config',
        type=Path,
        metavar='FILE',
        help='parameter file of the run (default: the one stored in the bag)',
    )
    q.add_argument('--json', action='store_true')
    q.set_defaults(func=cmd_bag_metrics)

    q = bsub.add_parser('plot', help='the figures of `apf-swarm reproduce` from /swarm/state')
    q.add_argument('bag', type=Path, metavar='BAG')
    q.add_argument('--out', type=Path, required=True, metavar='DIR')
    q.add_argument('--config', type=Path, metavar='FILE')
    q.set_defaults(func=cmd_bag_plot)

    q = bsub.add_parser('export', help='flattened fields of one topic as CSV')
    q.add_argument('bag', type=Path, metavar='BAG')
    q.add_argument('--topic', required=True, metavar='T')
    q.add_argument('--csv', type=Path, metavar='FILE', help='output file (default: stdout)')
    q.add_argument('--force', action='store_true', help='overwrite FILE')
    q.set_defaults(func=cmd_bag_export)

    q = bsub.add_parser(
        'reindex',
        help='rebuild metadata.yaml (and truncated MCAP files) from '
        'the MCAP files; keeps a backup of what it replaces',
    )
    q.add_argument('bag', type=Path, metavar='BAG')
    q.set_defaults(func=cmd_bag_reindex)

    q = bsub.add_parser('play', help='republish the bag with its recorded timing (ROS graph)')
    q.add_argument('bag', type=Path, metavar='BAG')
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
    q.set_defaults(func=cmd_bag_play)


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
        type=_latency_arg,
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
    p.add_argument('--duration', type=float, metavar='S')
    p.add_argument('--dt', type=float, metavar='S')
    p.add_argument('--seed', type=int)
    _add_realtime_args(p)
    p.add_argument('--out', type=Path, required=True, metavar='DIR')
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
        '--spacing', type=float, metavar='D', help='wanted nearest-neighbour distance [m]'
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
    p.add_argument('--duration', type=float, metavar='S', help="override the presets' duration")
    p.add_argument('--quick', action='store_true', help='3 gamma values instead of 8')
    p.add_argument('--quiet', action='store_true')
    p.set_defaults(func=cmd_reproduce)

    p = sub.add_parser('sweep', help='both laws over values of one key, batched')
    add_config_args(p, required=False, default_preset='triangle')
    p.add_argument('--param', required=True, metavar='NAME')
    p.add_argument('--values', required=True, metavar='V1,V2,...')
    p.add_argument('--seeds', type=int, default=1, metavar='K')
    p.add_argument('--duration', type=float, metavar='S')
    p.add_argument('--out', type=Path, required=True, metavar='DIR')
    p.add_argument('--quiet', action='store_true')
    p.set_defaults(func=cmd_sweep)

    from . import bringup  # no rclpy import until a bring-up actually runs

    p = sub.add_parser(
        'up',
        help='bring up the ROS 2 graph (target, plant, trackers) and '
        'record a run (exit 0 ok, 2 bad input / not ready, 3 a node died)',
    )
    bringup.add_arguments(p)
    p.set_defaults(func=lambda args: bringup.run(args, prog=f'{PROG} up'))
    from . import probe

    p = sub.add_parser(
        'probe',
        help="measure this machine's control-loop latency and cost "
        '(cached): the realtime defaults come from it',
    )
    probe.add_arguments(p)
    p.set_defaults(func=probe.run)
    _add_bag_parser(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    for attr in ('spacing', 'duration', 'dt'):
        val = getattr(args, attr, None)
        if val is not None and not val > 0:
            parser.error(f'--{attr} {val}: must be a positive number')
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


if __name__ == '__main__':
    sys.exit(main())
