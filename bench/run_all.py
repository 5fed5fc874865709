#!/usr/bin/env python3
"""Run the workspace's benchmarks with one command.

    python bench/run_all.py [--quick | --smoke] [--timeout S] [NAME ...]

Runs ``bench/soak.py`` and every ``bench/bench_<NAME>.py`` (all of them, or only the NAMEs
given, e.g. ``simulator``, ``control``, ``soak``) one after the other, each in its own
interpreter (the one running this script) and its own session, from the workspace root, with
``src/apf_swarm_core`` prepended to ``PYTHONPATH`` and ``--quick`` or ``--smoke`` passed on.
Each benchmark prints its own Markdown tables. ``--smoke`` runs each in seconds and is what CI
runs, so that a benchmark that breaks fails CI; without it the soak is left out (it takes
30 minutes). A benchmark still running after ``--timeout`` seconds (default: 300 with
``--smoke``, none otherwise) is stopped with its whole process group (SIGTERM, then
SIGKILL) and counts as failed. Benchmarks of the ROS graph need the ROS environment
(``source scripts/activate.sh`` first).

Exit status: 1 if any benchmark fails a floor, crashes or times out, 2 for bad arguments,
else 0. A table of every benchmark's exit status and wall time ends the output.
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def scripts(names: list[str], with_soak: bool) -> list[Path]:
    """The benchmark scripts to run, by name (``bench_<name>.py``, or ``soak``)."""
    found = sorted((ROOT / 'bench').glob('bench_*.py'))
    if with_soak or 'soak' in names:
        found.append(ROOT / 'bench' / 'soak.py')
    if not names:
        return found
    by_name = {p.stem.removeprefix('bench_'): p for p in found}
    unknown = [n for n in names if n not in by_name]
    if unknown:
        raise SystemExit(
            f'run_all.py: unknown benchmark(s) {unknown}; choose from {sorted(by_name)}'
        )
    return [by_name[n] for n in names]


def run(script: Path, flags: list[str], env: dict[str, str], timeout: float | None) -> int:
    """One benchmark in its own session; on timeout its process group is stopped."""
    p = subprocess.Popen(
        [sys.executable, str(script), *flags], cwd=ROOT, env=env, start_new_session=True
    )
    try:
        return p.wait(timeout)
    except subprocess.TimeoutExpired:
        print(f'\n{script.name}: still running after {timeout:g} s: stopped', flush=True)
        for sig, grace in ((signal.SIGTERM, 10.0), (signal.SIGKILL, 5.0)):
            try:
                os.killpg(p.pid, sig)
            except ProcessLookupError:
                break
            try:
                p.wait(grace)
                break
            except subprocess.TimeoutExpired:
                continue
        return 124
    except BaseException:
        os.killpg(p.pid, signal.SIGKILL)
        p.wait()
        raise


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    mode = ap.add_mutually_exclusive_group()
    mode.add_argument('--quick', action='store_true', help='shorter runs (minutes)')
    mode.add_argument('--smoke', action='store_true', help='each in seconds: does it still run?')
    ap.add_argument('--timeout', type=float, default=None, metavar='S', help='per benchmark')
    ap.add_argument('names', nargs='*', metavar='NAME', help='e.g. simulator control soak')
    args = ap.parse_args(argv)
    flags = ['--smoke'] if args.smoke else ['--quick'] if args.quick else []
    timeout = args.timeout if args.timeout is not None else (300.0 if args.smoke else None)
    env = dict(os.environ)
    env['PYTHONPATH'] = os.pathsep.join(
        [str(ROOT / 'src' / 'apf_swarm_core')]
        + ([env['PYTHONPATH']] if env.get('PYTHONPATH') else [])
    )
    results = []
    for script in scripts(args.names, with_soak=args.smoke):
        print(f'\n## {script.relative_to(ROOT)} {" ".join(flags)}\n', flush=True)
        t0 = time.monotonic()
        rc = run(script, flags, env, timeout)
        results.append((script.name, rc, time.monotonic() - t0))
        if rc:
            print(f'\n{script.name} exited with status {rc}', flush=True)
    print('\n| benchmark | exit | wall [s] |\n|---|---:|---:|')
    for name, rc, wall in results:
        print(f'| {name} | {rc} | {wall:.0f} |')
    failed = [name for name, rc, _ in results if rc]
    print(
        f'\n{len(results) - len(failed)} of {len(results)} benchmarks ran'
        + (f'; failed: {", ".join(failed)}' if failed else '')
    )
    return 1 if failed else 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
