#!/usr/bin/env python3
"""Run the workspace's benchmarks with one command.

Every script of ``bench/`` but ``_*.py`` (the soaks only with ``--smoke`` or when named), or
the NAMEs given (``bench_NAME.py``, ``soak.py``), one after the other, each in its own session
dying with this script, from the workspace root with ``src/apf_swarm_core`` on ``PYTHONPATH``.
Exit 1 if any fails or outlives ``--timeout``, 2 for bad arguments."""

import argparse
import os
import subprocess
import sys
import time

from _children import ROOT, exit_on_signals, start, stop, table

LONG = ('soak', 'soak_cycles')  # run by --smoke or when named


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    mode = ap.add_mutually_exclusive_group()
    mode.add_argument('--quick', action='store_true', help='shorter runs (minutes)')
    mode.add_argument('--smoke', action='store_true', help='each in seconds: does it still run?')
    ap.add_argument('--timeout', type=float, metavar='S', help='per benchmark (120 with --smoke)')
    ap.add_argument('names', nargs='*', metavar='NAME', help='e.g. simulator control soak')
    args = ap.parse_args(argv)
    by_name = {p.stem.removeprefix('bench_'): p for p in sorted(ROOT.glob('bench/[!_]*.py'))}
    del by_name['run_all']
    if set(args.names) - set(by_name):
        ap.error(f'unknown benchmark(s) {set(args.names) - set(by_name)}; see {sorted(by_name)}')
    long = [] if args.smoke else LONG
    scripts = [by_name[n] for n in args.names] or [p for n, p in by_name.items() if n not in long]
    exit_on_signals()
    flags = ['--smoke'] if args.smoke else ['--quick'] if args.quick else []
    timeout = args.timeout if args.timeout is not None else (120.0 if args.smoke else None)
    path = [str(ROOT / 'src' / 'apf_swarm_core'), *filter(None, [os.environ.get('PYTHONPATH')])]
    env = {**os.environ, 'PYTHONPATH': os.pathsep.join(path)}
    results = []
    for script in scripts:
        print(f'\n## {script.relative_to(ROOT)} {" ".join(flags)}\n', flush=True)
        t0 = time.monotonic()
        p = start([sys.executable, str(script), *flags], cwd=ROOT, env=env)
        try:
            rc = p.wait(timeout)
        except subprocess.TimeoutExpired:
            print(f'\n{script.name}: still running after {timeout:g} s: stopped', flush=True)
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
