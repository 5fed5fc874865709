#!/usr/bin/env python3
"""What a secure multi-host run costs against an open one, side by side in one invocation:
``scripts/multihost.py`` twice with the same swarm, ``--open`` (UDP, multicast discovery)
and secure (TCP with TLS, the bring-up's discovery server), in the order given.

    sudo python bench/bench_secure.py [--quick | --smoke] [--n-trackers 32 --duration 25]
        [--out runs/secure_cost]

Per run: graph-ready time (the bring-up's ``timing.ready``), the control latency the plant
measured (p50 / p99, ``prediction.latency``), each simulated host's CPU (% of a core over
the wall time, start-up included), the formation judged by flight, missed deadlines.
Prints a Markdown table and writes ``bench_secure.json`` into ``--out`` (default: a
temporary directory, removed). ``--quick``: 8 trackers, 10 s; ``--smoke``: 3 trackers, 3 s.
Needs root and iproute2 (simulated hosts): without them it says why and exits 0.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib.util
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def one(out: Path, mode: str, args: argparse.Namespace) -> dict:
    cmd = [
        sys.executable,
        str(ROOT / 'scripts' / 'multihost.py'),
        '--hosts',
        '3',
        '--n-trackers',
        str(args.n_trackers),
        '--trackers-per-process',
        str(args.trackers_per_process),
        '--mode',
        'realtime',
        '--duration',
        str(args.duration),
        '--out',
        str(out),
        *(['--open'] if mode == 'open' else []),
    ]
    t0 = time.monotonic()
    p = subprocess.run(cmd, capture_output=True, text=True, timeout=600, cwd=ROOT)
    wall = time.monotonic() - t0
    if p.returncode != 0:
        print(p.stdout[-3000:], p.stderr[-3000:], file=sys.stderr)
        raise SystemExit(f'bench_secure: the {mode} run failed ({p.returncode})')
    summary = json.loads((out / 'summary.json').read_text())
    hosts = json.loads((out / 'multihost.json').read_text())['hosts']
    pred = summary['prediction']
    return {
        'mode': mode,
        'ready_s': summary['timing']['ready'],
        'latency_p50_ms': 1e3 * pred['latency']['p50'],
        'latency_p99_ms': 1e3 * pred['latency']['p99'],
        'cpu_pct': [h['cpu_pct'] for h in hosts],
        'flies': pred['run']['flies'],
        'formation_error_pct': 100 * pred['run']['formation_error_rms'],
        'closest_pair_pct': 100 * pred['run']['closest_pair'],
        'missed_deadlines': summary['missed_deadlines'],
        'rate_hz': summary['timing']['rate'],
        'wall_s': round(wall, 1),
    }


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('--n-trackers', type=int, default=None, help='default 32')
    p.add_argument('--trackers-per-process', type=int, default=4)
    p.add_argument('--duration', type=float, default=None, help='wall seconds, default 25')
    p.add_argument('--order', default='open,secure', help='the runs, in order')
    p.add_argument('--out', type=Path, default=None, help='default: a temporary directory')
    size = p.add_mutually_exclusive_group()
    size.add_argument('--quick', action='store_true', help='8 trackers, 10 s')
    size.add_argument('--smoke', action='store_true', help='3 trackers, 3 s: does it run?')
    args = p.parse_args()
    n, duration = (3, 3.0) if args.smoke else (8, 10.0) if args.quick else (32, 25.0)
    args.n_trackers = args.n_trackers or n
    args.duration = args.duration or duration
    args.trackers_per_process = min(args.trackers_per_process, args.n_trackers)
    spec = importlib.util.spec_from_file_location('multihost', ROOT / 'scripts' / 'multihost.py')
    assert spec is not None and spec.loader is not None
    multihost = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(multihost)
    why = multihost.unavailable()
    if why is not None:
        print(f'bench_secure: skipped, simulated hosts unavailable: {why}')
        return 0
    with contextlib.ExitStack() as stack:
        if args.out is None:
            args.out = Path(stack.enter_context(tempfile.TemporaryDirectory(prefix='secure_')))
        return report(args, [one(args.out / mode, mode, args) for mode in args.order.split(',')])


def report(args: argparse.Namespace, rows: list[dict]) -> int:
    print(
        '| run | graph ready | latency p50 / p99 | CPU host 1 / 2 / 3 [% of a core] | '
        'formation error / closest pair | missed | rate |'
    )
    print('|---|---:|---:|---:|---|---:|---:|')
    for r in rows:
        cpu = ' / '.join(f'{c:.0f}' for c in r['cpu_pct'])
        print(
            f'| {r["mode"]} | {r["ready_s"]:.2f} s | {r["latency_p50_ms"]:.1f} / '
            f'{r["latency_p99_ms"]:.1f} ms | {cpu} | {r["formation_error_pct"]:.2f} % / '
            f'{r["closest_pair_pct"]:.1f} % ({"flies" if r["flies"] else "does not fly"}) | '
            f'{r["missed_deadlines"]} | {r["rate_hz"]:g} Hz |'
        )
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / 'bench_secure.json').write_text(json.dumps(rows, indent=2) + '\n')
    return 0


if __name__ == '__main__':
    sys.exit(main())
