"""The ``apf-swarm`` commands that need no ROS graph: ``simulate``, ``check``, ``design``,
``reproduce``, ``sweep``, and the machine-derived rate and latency they use."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np
from apf_swarm_core.checks import check_config
from apf_swarm_core.config import DEFAULT_LATENCY, REALTIME_RATE, SwarmConfig
from apf_swarm_core.config_files import load_preset, resolve
from apf_swarm_core.design import b_for_spacing, equilibrium_formation, triangle_c_for_spacing
from apf_swarm_core.errors import ApfSwarmError
from apf_swarm_core.formation import design_pair_sets
from apf_swarm_core.metrics import flight, flight_verdict
from apf_swarm_core.simulator import simulate

from ..advice import CLI_ADVICE
from ..analysis.runio import format_summary, write_run
from ..argtypes import nonneg_float
from ..progress import Progress

__all__ = [
    'PROG',
    'cmd_check',
    'cmd_design',
    'cmd_design_rate',
    'cmd_reproduce',
    'cmd_simulate',
    'cmd_sweep',
    'latency_arg',
    'latency_samples',
    'machine_latency',
    'machine_rate',
    'write_animation',
]

PROG = 'apf-swarm'


def _load(args: argparse.Namespace, extra: dict[str, Any] | None = None) -> SwarmConfig:
    return resolve(args.config, args.preset, args.sets, **(extra or {}))


def _progress(args: argparse.Namespace, label: str) -> Progress | None:
    return None if getattr(args, 'quiet', False) else Progress(label)


def latency_arg(text: str) -> float | Path:
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
    """Measured latencies [s] from a JSON file: a list, an object with ``latency_samples``,
    or a realtime run's summary.json (under ``flight_check``; ``prediction`` before)."""
    try:
        doc = json.loads(path.read_text())
    except ValueError as exc:
        raise ApfSwarmError(f'{path}: not JSON ({exc}); expected a list of latencies [s]') from exc
    while isinstance(doc, dict):  # down to the samples: a summary holds its flight check's
        doc = doc.get('latency_samples', doc.get('flight_check', doc.get('prediction')))
    try:
        arr = np.asarray(doc if doc is not None else [], dtype=float).ravel()
    except (TypeError, ValueError):  # strings, objects, ragged lists: refused below
        arr = np.array([np.nan])
    if arr.size == 0 or not np.all(np.isfinite(arr)) or np.any(arr < 0):
        raise ApfSwarmError(
            f'{path}: expected a non-empty list of latencies >= 0 s '
            '(or an object with "latency_samples")'
        )
    return arr


def _realtime_extra(args: argparse.Namespace) -> tuple[dict[str, Any], np.ndarray | None]:
    """--control-rate / --latency as configuration values, and latency samples."""
    lat, samples = args.latency, None
    if isinstance(lat, Path):
        samples = latency_samples(lat)
        lat = float(np.median(samples))
    return {'control_rate': args.control_rate, 'latency': lat}, samples


def machine_latency(n: int, rate: float | None = None) -> float:
    """The control-loop latency of this machine for n trackers at ``rate`` from its cached
    probe (``apf-swarm probe``), else DEFAULT_LATENCY (said on stderr)."""
    from ..capacity import probe

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
    from ..capacity import probe

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
    if args.animate is not None:
        from ..analysis.animate import check_path

        check_path(args.animate)
    report = check_config(cfg, advice=CLI_ADVICE)
    res = simulate(cfg, progress=_progress(args, 'simulate'), latency_samples=samples)
    summary = res.summary(warnings=report.warnings)
    if cfg.control_rate > 0:  # a realtime loop emulated: judged as a run is
        summary['flight'] = flight(res.trajectory, design_pair_sets(cfg))
    write_run(args.out, res.trajectory, summary, cfg)
    print(format_summary(summary))
    if 'flight' in summary:
        print(f'  flight           {flight_verdict(summary["flight"])}')
    print(f'wrote {args.out / "trajectory.npz"} and {args.out / "summary.json"}')
    if args.animate is not None:
        write_animation(args, res.trajectory, cfg, args.animate)
    return 0


def write_animation(args: argparse.Namespace, traj: Any, cfg: SwarmConfig, path: Path) -> None:
    """The animation of a run as the options ``--speed``, ``--fps``, ``--projection`` say."""
    from ..analysis.animate import animate, auto_speed

    t = traj['t']
    speed = args.speed or auto_speed(float(t[-1] - t[0]) if len(t) else 0.0)
    progress = None if args.quiet else Progress('animate', unit='frames')
    frames = animate(
        traj,
        path,
        designs=design_pair_sets(cfg),
        speed=speed,
        fps=args.fps,
        view=args.projection,
        title=f'{cfg.n_trackers} trackers, {cfg.law} law',
        progress=progress,
    )
    print(f'wrote {path} ({frames} frames, {speed:g}x)')


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
    rep = check_config(cfg, run, realtime=args.mode == 'realtime', advice=CLI_ADVICE)
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
    pred = predict(tuned, advice=CLI_ADVICE)
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
        f'{pred.formation_rate:.4g} 1/s of {pred.rate_allowed:.4g} allowed; '
        f'{pred.settling()}; lag '
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
    from ..analysis.studies import GAMMA_VALUES, reproduce

    presets = {name: load_preset(name) for name in ('triangle', 'paper')}
    if args.duration is not None:
        presets = {k: v.replace(duration=args.duration) for k, v in presets.items()}
    gammas = GAMMA_VALUES if not args.quick else (0.02, 0.2, 1.0)
    path = reproduce(
        args.out, presets, None if args.quiet else Progress, gammas, not args.no_animations
    )
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
    from ..analysis.studies import sweep, write_sweep

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
