#!/usr/bin/env python3
"""Controller options against each other in the headless emulation of real time.

Run from the workspace root (numpy only, no ROS):

    python bench/bench_flight.py [--n 16 32] [--points 100:0.008 50:0.017 20:0.020]
                                 [--variants B C D E] [--seeds 5] [--duration 25]
                                 [--set KEY=VALUE ...]

Each case is the ``realtime`` preset with one variant's keys, ``n`` trackers, a control
rate and a fixed latency (``RATE:LATENCY``, e.g. the bring-up's measured p50), its gains
scheduled as the bring-up schedules them (:func:`apf_swarm_core.sampled.schedule_gains`),
run for ``--seeds`` seeds in one batch (:func:`apf_swarm_core.simulator.simulate_batch`)
and judged by flight (:func:`apf_swarm_core.metrics.flight`, the criteria of bench_scale:
formation error RMS <= 3 % of the mean design spacing, closest pair >= 90 % of the
design's, converged, over the last 40 %). The table gives per case how many seeds fly, the
median and worst formation error, the worst closest pair, the median and latest time to
converge, and the gains flown. ``--set`` applies to every variant (for example
``--set init_spread=2``); ``--variant NAME=KEY:VALUE,...`` adds one.

Output: a Markdown table on stdout, progress on stderr; ``--json FILE`` keeps the rows.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path
from typing import Any

try:
    import apf_swarm_core  # noqa: F401
except ImportError:  # run from the workspace root without PYTHONPATH
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / 'src' / 'apf_swarm_core'))

from apf_swarm_core.config_files import apply_overrides, load_preset, parse_set
from apf_swarm_core.formation import design_pair_sets
from apf_swarm_core.metrics import flight
from apf_swarm_core.sampled import schedule_gains
from apf_swarm_core.simulator import simulate_batch
from bench_simulator import machine

#: the variants of docs/PERFORMANCE.md, "Real-time flight": keys over the realtime preset
VARIANTS: dict[str, dict[str, Any]] = {
    'B': {'newton_mu': 0.1, 'newton_trust': 0.0, 'compensation': 'none'},
    'C': {'newton_mu': 0.003, 'newton_trust': 0.0, 'compensation': 'none'},
    'D': {'newton_mu': 0.003, 'newton_trust': 0.02, 'compensation': 'none'},
    'E': {},
}
LABELS = {
    'B': 'B newton mu=0.1',
    'C': 'C mu=0.003',
    'D': 'D mu=0.003 + trust',
    'E': 'E the preset',
}


def log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def _point(text: str) -> tuple[float, float]:
    try:
        rate, latency = (float(v) for v in text.split(':'))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f'{text!r}: expected RATE:LATENCY, e.g. 50:0.017'
        ) from None
    if rate <= 0 or latency < 0:
        raise argparse.ArgumentTypeError(
            f'{text!r}: the rate must be > 0 Hz and the latency >= 0 s'
        )
    return rate, latency


def _variant(text: str) -> tuple[str, dict[str, Any]]:
    name, _, body = text.partition('=')
    if not name or not body:
        raise argparse.ArgumentTypeError(f'{text!r}: expected NAME=KEY:VALUE,...')
    try:
        keys = parse_set([item.replace(':', '=', 1) for item in body.split(',')])
    except Exception as exc:  # ConfigError names the key
        raise argparse.ArgumentTypeError(f'{text!r}: {exc}') from None
    return name, keys


def case(
    n: int,
    rate: float,
    latency: float,
    keys: dict[str, Any],
    seeds: int,
    duration: float,
    common: dict[str, Any],
) -> dict[str, Any]:
    """One row: the variant at this size, rate and latency over ``seeds`` seeds."""
    base = apply_overrides(
        load_preset('realtime'),
        {
            **common,
            **keys,
            'n_trackers': n,
            'control_rate': rate,
            'latency': latency,
            'duration': duration,
        },
    )
    cfg, _pred, gains, _ = schedule_gains(base, latency=latency)
    cfgs = [cfg.replace(seed=cfg.seed + k) for k in range(seeds)]
    res = simulate_batch(cfgs)
    pairs = design_pair_sets(cfg)
    judged, conv = [], []
    for j in range(seeds):
        traj = {k: (v if k == 't' else v[j]) for k, v in res.trajectory.items()}
        judged.append(flight(traj, pairs))
        conv.append(res.summary(run=j)['time_to_converge'])
    fe = [100 * f['formation_error_rms'] for f in judged if f['formation_error_rms'] is not None]
    cp = [100 * f['closest_pair'] for f in judged if f['closest_pair'] is not None]
    done = [c for c in conv if c is not None]
    return {
        'n': n,
        'rate': rate,
        'latency': latency,
        'flies': sum(f['flies'] for f in judged),
        'seeds': seeds,
        'formation_median': statistics.median(fe) if fe else None,
        'formation_worst': max(fe) if fe else None,
        'closest_worst': min(cp) if cp else None,
        'converge_median': statistics.median(done) if len(done) == seeds else None,
        'converge_last': max(done) if len(done) == seeds else None,
        'gains': gains,
    }


def _fmt(v: float | None, digits: int = 2, unit: str = '') -> str:
    return '—' if v is None else f'{v:.{digits}g}{unit}'


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('--n', type=int, nargs='+', default=[16, 32])
    p.add_argument(
        '--points',
        type=_point,
        nargs='+',
        default=[(100.0, 0.008), (50.0, 0.017), (20.0, 0.020)],
        metavar='RATE:LATENCY',
    )
    p.add_argument('--variants', nargs='+', default=list(VARIANTS), metavar='NAME')
    p.add_argument(
        '--variant',
        type=_variant,
        action='append',
        default=[],
        metavar='NAME=KEY:VALUE,...',
        help='an extra variant',
    )
    p.add_argument('--seeds', type=int, default=5)
    p.add_argument('--duration', type=float, default=25.0)
    p.add_argument('--set', dest='sets', action='append', default=[], metavar='KEY=VALUE')
    p.add_argument('--json', type=Path, metavar='FILE')
    p.add_argument(
        '--smoke', action='store_true', help='8 trackers, one point, one seed, 5 s (seconds)'
    )
    args = p.parse_args(argv)
    if args.smoke:
        args.n, args.points, args.seeds, args.duration = [8], [(50.0, 0.01)], 1, 5.0
        args.variants = args.variants[:1]
    variants = {**VARIANTS, **dict(args.variant)}
    chosen = [*args.variants, *(name for name, _ in args.variant if name not in args.variants)]
    unknown = [v for v in chosen if v not in variants]
    if unknown:
        p.error(
            f'unknown variant(s) {unknown}: choose from {sorted(variants)} or add one '
            f'with --variant NAME=KEY:VALUE,...'
        )
    try:
        common = parse_set(args.sets)
    except Exception as exc:
        p.error(str(exc))
    cases = [(n, r, lat, v) for n in args.n for r, lat in args.points for v in chosen]
    rows, t0 = [], time.perf_counter()
    for i, (n, rate, lat, v) in enumerate(cases, 1):
        t = time.perf_counter()
        row = {
            'variant': LABELS.get(
                v, v + ' ' + ', '.join(f'{k}={x}' for k, x in variants[v].items())
            ),
            **case(n, rate, lat, variants[v], args.seeds, args.duration, common),
        }
        rows.append(row)
        log(
            f'[{i}/{len(cases)}] n={n} {rate:g} Hz {1e3 * lat:g} ms {v}: {row["flies"]}/'
            f'{args.seeds} fly ({time.perf_counter() - t:.0f} s)'
        )
    print(
        f'Emulation, {args.seeds} seeds, {args.duration:g} s, gains scheduled as the '
        f'bring-up does; {machine()}, {time.perf_counter() - t0:.0f} s'
        + (f'; --set {" ".join(args.sets)}' if args.sets else '')
        + '\n'
    )
    print(
        '| trackers | rate, latency | variant | flies | formation error RMS (median, worst) '
        '| closest pair (worst) | converged after (median, last) | gains |'
    )
    print('|---:|---|---|---:|---|---|---|---|')
    for r in rows:
        gains = (
            'preset'
            if not r['gains']
            else ', '.join(f'{k} {v:.3g}' for k, v in r['gains'].items() if isinstance(v, float))
        )
        print(
            f'| {r["n"]} | {r["rate"]:g} Hz, {1e3 * r["latency"]:g} ms | {r["variant"]} | '
            f'{r["flies"]}/{r["seeds"]} | {_fmt(r["formation_median"], unit=" %")}, '
            f'{_fmt(r["formation_worst"], unit=" %")} | {_fmt(r["closest_worst"], 3, " %")} '
            f'| {_fmt(r["converge_median"], 3, " s")}, {_fmt(r["converge_last"], 3, " s")} '
            f'| {gains} |'
        )
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2) + '\n')
    return 0


if __name__ == '__main__':
    sys.exit(main())
