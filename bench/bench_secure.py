#!/usr/bin/env python3
"""What a secure multi-host run costs against an open one (the baseline): ``scripts/
multihost.py --hosts 3`` with ``--open`` and secure (TLS), in the order given.

    sudo python bench/bench_secure.py [--quick | --smoke] [--n-trackers 32 --duration 25]
        [--order open,secure] [--out runs/secure_cost]

Per run: graph ready, latency, CPU per simulated host, flight, missed deadlines, rate;
``bench_secure.json`` in ``--out``. Without root and iproute2 it says why and exits 0.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib.util
import json
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / 'bench'))
from _children import exit_on_signals, start, stop, table  # noqa: E402


def one(out: Path, mode: str, args: argparse.Namespace) -> list[str]:
    cmd = [sys.executable, str(ROOT / 'scripts' / 'multihost.py'), '--hosts', '3',
           '--n-trackers', str(args.n_trackers), '--trackers-per-process',
           str(min(args.trackers_per_process, args.n_trackers)), '--mode', 'realtime',
           '--duration', str(args.duration), '--out', str(out)]  # fmt: skip
    p = start(cmd + (['--open'] if mode == 'open' else []), 'TERM', cwd=ROOT,
              stdout=subprocess.PIPE, stderr=subprocess.STDOUT)  # fmt: skip
    try:
        log, _ = p.communicate(timeout=600)
    finally:
        stop(p)
    if p.returncode != 0:
        print(log[-3000:].decode(errors='replace'), file=sys.stderr)
        raise SystemExit(f'bench_secure: the {mode} run failed ({p.returncode})')
    s = json.loads((out / 'summary.json').read_text())
    cpu = [h['cpu_pct'] for h in json.loads((out / 'multihost.json').read_text())['hosts']]
    lat, run = s['prediction']['latency'], s['prediction']['run']
    verdict = 'flies' if run['flies'] else 'does not fly'
    flight = f'{100 * run["formation_error_rms"]:.2f} % / {100 * run["closest_pair"]:.1f} %'
    ms = f'{1e3 * lat["p50"]:.1f} / {1e3 * lat["p99"]:.1f} ms'
    return [mode, f'{s["timing"]["ready"]:.2f} s', ms,
            ' / '.join(f'{c:.0f}' for c in cpu), f'{flight} ({verdict})', s['missed_deadlines'],
            f'{s["timing"]["rate"]:g} Hz']  # fmt: skip


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
    args.n_trackers, args.duration = args.n_trackers or n, args.duration or duration
    spec = importlib.util.spec_from_file_location('multihost', ROOT / 'scripts' / 'multihost.py')
    assert spec is not None and spec.loader is not None
    multihost = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(multihost)
    why = multihost.unavailable()
    if why is not None:
        print(f'bench_secure: skipped, simulated hosts unavailable: {why}')
        return 0
    exit_on_signals()
    with contextlib.ExitStack() as stack:
        if args.out is None:
            args.out = Path(stack.enter_context(tempfile.TemporaryDirectory(prefix='secure_')))
        rows = [one(args.out / mode, mode, args) for mode in args.order.split(',')]
        head = 'run | graph ready: | latency p50 / p99: | CPU host 1 / 2 / 3 [%]: | formation '
        print(table(head + 'error / closest pair | missed: | rate:', rows))
        (args.out / 'bench_secure.json').write_text(json.dumps(rows, indent=2) + '\n')
    return 0


if __name__ == '__main__':
    sys.exit(main())
