#!/usr/bin/env python3
"""Run the workspace's benchmarks with one command.

    python bench/run_all.py [--quick | --smoke] [--timeout S] [NAME ...]

Runs every script of ``bench/`` (``bench_<NAME>.py``, ``soak.py``, ``soak_cycles.py``; not
``_*.py``), or the NAMEs given (e.g. ``simulator``, ``soak``), one after the other, each in its
own session and dying with this script (``apf_swarm_nodes.lifetime``), from the workspace root
with ``src/apf_swarm_core`` on ``PYTHONPATH``, ``--quick`` or ``--smoke`` passed on. A plain run
leaves the soaks out unless named (30 minutes and more). A benchmark still running after
``--timeout`` s (default 120 with ``--smoke``) is stopped with its process group and fails.
Exit 1 if any benchmark fails, 2 for bad arguments; a table of exits and wall times ends it.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / 'bench'))
from _children import exit_on_signals, start, stop, table  # noqa: E402

LONG = ('soak', 'soak_cycles')  # run by --smoke or when named


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    mode = ap.add_mutually_exclusive_group()
    mode.add_argument('--quick', action='store_true', help='shorter runs (minutes)')
    mode.add_argument('--smoke', action='store_true', help='each in seconds: does it still run?')
    ap.add_argument('--timeout', type=float, default=None, metavar='S', help='per benchmark')
    ap.add_argument('names', nargs='*', metavar='NAME', help='e.g. simulator control soak')
    args = ap.parse_args(argv)
    found = sorted(p for p in (ROOT / 'bench').glob('*.py') if p.name[0] != '_')
    found.remove(Path(__file__).resolve())
    by_name = {p.stem.removeprefix('bench_'): p for p in found}
    if set(args.names) - set(by_name):
        ap.error(f'unknown benchmark(s) {set(args.names) - set(by_name)}; see {sorted(by_name)}')
    scripts = [by_name[n] for n in args.names] or [
        p for n, p in by_name.items() if args.smoke or n not in LONG
    ]
    exit_on_signals()
    flags = ['--smoke'] if args.smoke else ['--quick'] if args.quick else []
    timeout = args.timeout if args.timeout is not None else (120.0 if args.smoke else None)
    env = dict(os.environ)
    env['PYTHONPATH'] = os.pathsep.join(
        [str(ROOT / 'src' / 'apf_swarm_core'), *filter(None, [env.get('PYTHONPATH')])]
    )
    results = []
    for script in scripts:
        print(f'\n## {script.relative_to(ROOT)} {" ".join(flags)}\n', flush=True)
        t0 = time.monotonic()
        p = start([sys.executable, str(script), *flags], cwd=ROOT, env=env)
        try:
            rc = p.wait(timeout)
        except subprocess.TimeoutExpired:
            print(f'\n{script.name}: still running after {timeout:g} s: stopped', flush=True)
            stop(p, 10.0)
            rc = 124
        finally:
            stop(p, 10.0)
        results.append([script.name, rc, f'{time.monotonic() - t0:.1f}'])
    print('\n' + table('benchmark | exit: | wall [s]:', results))
    failed = [name for name, rc, _ in results if rc]
    print(f'\n{len(results) - len(failed)} of {len(results)} benchmarks ran'
          + (f'; failed: {", ".join(failed)}' if failed else ''))  # fmt: skip
    return 1 if failed else 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
