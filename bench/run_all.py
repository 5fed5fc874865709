#!/usr/bin/env python3
"""Run the workspace's benchmarks with one command.

    python bench/run_all.py [--quick | --smoke] [--timeout S] [NAME ...]

Runs every script of ``bench/`` (``bench_<NAME>.py``, ``soak.py``, ``soak_cycles.py``; not
the modules ``_*.py``; all of them, or only the NAMEs given, e.g. ``simulator``, ``control``,
``soak``, ``soak_cycles``) one after the other, each in its own interpreter (the one running
this script) and its own session, from the workspace root, with ``src/apf_swarm_core``
prepended to ``PYTHONPATH`` and ``--quick`` or ``--smoke`` passed on. Each benchmark prints
its own Markdown tables. ``--smoke`` runs each in seconds and is what CI runs, so that a
benchmark that breaks fails CI; without it the soaks are left out unless named (they take
30 minutes and more). A benchmark still running after ``--timeout`` seconds (default: 120
with ``--smoke``, none otherwise) is stopped with its whole process group (SIGTERM, then
SIGKILL) and counts as failed. A benchmark dies with this script: it gets SIGTERM when this
process ends, however it ends (``setpriv --pdeathsig``), and SIGTERM, SIGHUP or Ctrl-C here
stop the running benchmark's group first. Benchmarks of the ROS graph need the ROS
environment (``source scripts/activate.sh`` first).

Exit status: 1 if any benchmark fails a floor, crashes or times out, 2 for bad arguments,
else 0. A table of every benchmark's exit status and wall time ends the output.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / 'bench'))

from _children import dying_with_parent, exit_on_signals  # noqa: E402

#: scripts run by --smoke or when named, not by a plain run (30 minutes and more)
LONG = ('soak', 'soak_cycles')


def scripts(names: list[str], with_long: bool) -> list[Path]:
    """The benchmark scripts to run, by name (``bench_<name>.py``, else ``<name>.py``)."""
    found = sorted(
        p
        for p in (ROOT / 'bench').glob('*.py')
        if not p.name.startswith('_') and p.name != Path(__file__).name
    )
    by_name = {p.stem.removeprefix('bench_'): p for p in found}
    unknown = [n for n in names if n not in by_name]
    if unknown:
        raise SystemExit(
            f'run_all.py: unknown benchmark(s) {unknown}; choose from {sorted(by_name)}'
        )
    if names:
        return [by_name[n] for n in names]
    return [p for name, p in by_name.items() if with_long or name not in LONG]


def stop_group(p: subprocess.Popen[bytes]) -> None:
    """SIGTERM to the benchmark's process group (it unwinds and stops its children), then
    SIGKILL to whatever of the group is left."""
    for sig, grace in ((signal.SIGTERM, 10.0), (signal.SIGKILL, 5.0)):
        try:
            os.killpg(p.pid, sig)
        except ProcessLookupError:
            break
        try:
            p.wait(grace)
        except subprocess.TimeoutExpired:
            continue
        if sig == signal.SIGTERM:  # the leader is gone; its group may not be
            with contextlib.suppress(ProcessLookupError):
                os.killpg(p.pid, signal.SIGKILL)
        break


def run(script: Path, flags: list[str], env: dict[str, str], timeout: float | None) -> int:
    """One benchmark in its own session; on timeout its process group is stopped."""
    p = subprocess.Popen(
        dying_with_parent([sys.executable, str(script), *flags], 'TERM'),
        cwd=ROOT,
        env=env,
        start_new_session=True,
    )
    try:
        return p.wait(timeout)
    except subprocess.TimeoutExpired:
        print(f'\n{script.name}: still running after {timeout:g} s: stopped', flush=True)
        stop_group(p)
        return 124
    except BaseException:
        stop_group(p)
        raise


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    mode = ap.add_mutually_exclusive_group()
    mode.add_argument('--quick', action='store_true', help='shorter runs (minutes)')
    mode.add_argument('--smoke', action='store_true', help='each in seconds: does it still run?')
    ap.add_argument('--timeout', type=float, default=None, metavar='S', help='per benchmark')
    ap.add_argument(
        'names', nargs='*', metavar='NAME', help='e.g. simulator control soak soak_cycles'
    )
    args = ap.parse_args(argv)
    exit_on_signals()
    flags = ['--smoke'] if args.smoke else ['--quick'] if args.quick else []
    timeout = args.timeout if args.timeout is not None else (120.0 if args.smoke else None)
    env = dict(os.environ)
    env['PYTHONPATH'] = os.pathsep.join(
        [str(ROOT / 'src' / 'apf_swarm_core')]
        + ([env['PYTHONPATH']] if env.get('PYTHONPATH') else [])
    )
    results = []
    for script in scripts(args.names, with_long=args.smoke):
        print(f'\n## {script.relative_to(ROOT)} {" ".join(flags)}\n', flush=True)
        t0 = time.monotonic()
        rc = run(script, flags, env, timeout)
        results.append((script.name, rc, time.monotonic() - t0))
        if rc:
            print(f'\n{script.name} exited with status {rc}', flush=True)
    print('\n| benchmark | exit | wall [s] |\n|---|---:|---:|')
    for name, rc, wall in results:
        print(f'| {name} | {rc} | {wall:.1f} |')
    failed = [name for name, rc, _ in results if rc]
    print(
        f'\n{len(results) - len(failed)} of {len(results)} benchmarks ran'
        + (f'; failed: {", ".join(failed)}' if failed else '')
    )
    return 1 if failed else 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
