#!/usr/bin/env python3
"""Controller options against each other in the headless emulation of real time.

Each case: the ``realtime`` preset with a variant's keys (E, the preset, is the baseline),
gains scheduled as the bring-up does, ``--seeds`` seeds in one ``simulate_batch``, judged by
``apf_swarm_core.metrics.flight`` (seeds that fly, error, closest pair, convergence)."""

import argparse
import contextlib
import itertools
import json
import statistics
import sys
import time
from pathlib import Path
from typing import Any

from _children import log, table
from apf_swarm_core.config_files import apply_overrides, load_preset, parse_set
from apf_swarm_core.formation import design_pair_sets
from apf_swarm_core.metrics import flight
from apf_swarm_core.sampled import schedule_gains
from apf_swarm_core.simulator import simulate_batch
from apf_swarm_nodes.capacity.machine import cpu_model

#: the variants of docs/PERFORMANCE.md, "Real-time flight": keys over the realtime preset
VARIANTS: dict[str, dict[str, Any]] = {
    'B': {'newton_mu': 0.1, 'newton_trust': 0.0, 'compensation': 'none'},
    'C': {'newton_mu': 0.003, 'newton_trust': 0.0, 'compensation': 'none'},
    'D': {'newton_mu': 0.003, 'newton_trust': 0.02, 'compensation': 'none'},
    'E': {},
}
LABELS = {'B': 'B newton mu=0.1', 'C': 'C mu=0.003', 'D': 'D mu=0.003 + trust',
          'E': 'E the preset'}  # fmt: skip


def _point(text: str) -> tuple[float, float]:
    rate, _, latency = text.partition(':')
    with contextlib.suppress(ValueError):
        if float(rate) > 0 and float(latency) >= 0:
            return float(rate), float(latency)
    raise argparse.ArgumentTypeError(f'{text!r}: expected RATE:LATENCY, e.g. 50:0.017')


def _variant(text: str) -> tuple[str, dict[str, Any]]:
    name, _, body = text.partition('=')
    try:
        return name, parse_set([item.replace(':', '=', 1) for item in body.split(',')])
    except Exception as exc:  # ConfigError names the key
        raise argparse.ArgumentTypeError(f'{text!r}: NAME=KEY:VALUE,... ({exc})') from None


def case(n: int, rate: float, latency: float, keys: dict[str, Any], args: Any) -> list[Any]:
    """One row: the variant at this size, rate and latency over ``args.seeds`` seeds."""
    over = {**args.common, **keys, 'n_trackers': n, 'control_rate': rate, 'latency': latency}
    base = apply_overrides(load_preset('realtime'), {**over, 'duration': args.duration})
    cfg, _pred, gains, _ = schedule_gains(base, latency=latency)
    res = simulate_batch([cfg.replace(seed=cfg.seed + k) for k in range(args.seeds)])
    pairs, seeds = design_pair_sets(cfg), range(args.seeds)
    runs = [{k: v if k == 't' else v[j] for k, v in res.trajectory.items()} for j in seeds]
    judged = [flight(run, pairs) for run in runs]
    conv = [res.summary(run=j)['time_to_converge'] for j in seeds]
    fe = [100 * f['formation_error_rms'] for f in judged if f['formation_error_rms'] is not None]
    cp = [100 * f['closest_pair'] for f in judged if f['closest_pair'] is not None]
    done = [c for c in conv if c is not None] if None not in conv else []
    gains = ', '.join(f'{k} {v:.3g}' for k, v in (gains or {}).items() if isinstance(v, float))
    flies = f'{sum(f["flies"] for f in judged)}/{args.seeds}'
    return [n, f'{rate:g} Hz, {1e3 * latency:g} ms', '', flies, _fmt(fe, 2, ' %'),
            _fmt(cp, 3, ' %', min), _fmt(done, 3, ' s'), gains or 'preset']  # fmt: skip


def _fmt(v: list[float], digits: int, unit: str, *how: Any) -> str:
    """'median, worst' (``how``: the one given, e.g. min) of ``v``, '—' when empty."""
    how = how or (statistics.median, max)
    return ', '.join('—' if not v else f'{h(v):.{digits}g}{unit}' for h in how)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('--n', type=int, nargs='+', default=[16, 32])
    p.add_argument('--points', type=_point, nargs='+', metavar='RATE:LATENCY',
                   default=[(100.0, 0.008), (50.0, 0.017), (20.0, 0.020)])  # fmt: skip
    p.add_argument('--variants', nargs='+', default=list(VARIANTS), metavar='NAME')
    p.add_argument('--variant', type=_variant, action='append', default=[],
                   metavar='NAME=KEY:VALUE,...', help='an extra variant')  # fmt: skip
    p.add_argument('--seeds', type=int, default=5)
    p.add_argument('--duration', type=float, default=25.0)
    p.add_argument('--set', dest='sets', action='append', default=[], metavar='KEY=VALUE')
    p.add_argument('--json', type=Path, metavar='FILE')
    p.add_argument('--smoke', action='store_true', help='8 trackers, one point, one seed, 5 s')
    args = p.parse_args(argv)
    if args.smoke:
        args.n, args.points, args.seeds, args.duration = [8], [(50.0, 0.01)], 1, 5.0
        args.variants = args.variants[:1]
    variants = {**VARIANTS, **dict(args.variant)}
    chosen = [*args.variants, *(name for name, _ in args.variant if name not in args.variants)]
    if set(chosen) - set(variants):
        p.error(f'unknown variant(s) {set(chosen) - set(variants)}: see {sorted(variants)}')
    try:
        args.common = parse_set(args.sets)
    except Exception as exc:
        p.error(str(exc))
    rows, t0 = [], time.perf_counter()
    for n, (rate, lat), v in itertools.product(args.n, args.points, chosen):
        row = case(n, rate, lat, variants[v], args)
        row[2] = LABELS.get(v, v + ' ' + ', '.join(f'{k}={x}' for k, x in variants[v].items()))
        rows.append(row)
        log(f'n={n} {rate:g} Hz {v}: {row[3]} fly')
    print(f'Emulation, {args.seeds} seeds, {args.duration:g} s, gains scheduled as the bring-up '
          f'does; {cpu_model()}, {time.perf_counter() - t0:.0f} s'
          + (f'; --set {" ".join(args.sets)}' if args.sets else '') + '\n')  # fmt: skip
    head = 'trackers: | rate, latency | variant | flies: | formation error RMS (median, worst) '
    print(table(head + '| closest pair (worst) | converged after (median, last) | gains', rows))
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2) + '\n')
    return 0


if __name__ == '__main__':
    sys.exit(main())
