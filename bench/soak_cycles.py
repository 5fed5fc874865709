#!/usr/bin/env python3
"""Soak of starts and stops: many short runs, each ended a different way, none may hang or
leave anything behind.

    source scripts/activate.sh
    python bench/soak_cycles.py [--cycles 100] [--n-trackers 3] [--duration 3] [--smoke]

Each cycle brings up the lockstep triangle (``swarm_up.py --preset triangle --respawn``),
its nodes forked or executed (``--spawn``, drawn at random unless ``--spawn`` says), and
ends it one of four ways, drawn at random (seeded): it runs to its end; a node is killed
with SIGKILL mid-run (the bring-up respawns it and the run completes); the bring-up gets
SIGTERM mid-run; the bring-up is killed with SIGKILL mid-run (nothing of it can clean up:
the nodes' parent-death signal must). Per cycle it records whether the bring-up ended
within ``duration + 90`` s (else: a hang, and it is killed), whether any process of the run
is still alive 15 s after (a leftover, killed; the bring-up's zygote included), and how
many Fast DDS entries of ``/dev/shm`` created during the cycle no live process holds 15 s
after that (``apf_swarm_nodes.dds.shm.unheld``: ``/dev/shm`` is the machine's, and the entries
other jobs' live participants create meanwhile are held by them; what a run of another job
on another domain left meanwhile is told apart by its ports' domain and reported apart).

Output: a Markdown table per way of ending and the totals, with the CPU and the count of
``/dev/shm`` before and after; exit 1 if any cycle hung, left a process or left shared
memory. ``--smoke``: one cycle of each way, 2 s runs.
"""

from __future__ import annotations

import argparse
import os
import random
import re
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import psutil

sys.path.insert(0, str(Path(__file__).resolve().parent))
import contextlib

from _children import dying_with_parent, exit_on_signals

ROOT = Path(__file__).resolve().parents[1]
WAYS = ('ends', 'node SIGKILL', 'bring-up SIGTERM', 'bring-up SIGKILL')


def cpu_model() -> str:
    for line in Path('/proc/cpuinfo').read_text().splitlines():
        if line.startswith('model name'):
            return line.split(':', 1)[1].strip()
    return 'unknown CPU'


def shm_entries() -> set[str]:
    from apf_swarm_nodes.dds.shm import fastdds_entries

    return fastdds_entries()


def shm_left(before: set[str]) -> set[str]:
    """The entries created since ``before`` that no live process holds."""
    from apf_swarm_nodes.dds.shm import unheld

    return unheld(shm_entries() - before)


def port_domain(name: str) -> int | None:
    """The domain whose port range (7400 + 250 d, 250 ports) a Fast DDS port entry is in;
    None for a participant segment or a port outside every domain's range."""
    m = re.match(r'^(?:sem\.)?fastrtps_port(\d+)', name)
    if m is None or int(m.group(1)) < 7400:
        return None
    return (int(m.group(1)) - 7400) // 250


def attribute(left: set[str], domain: int) -> tuple[set[str], set[str]]:
    """(this cycle's, another job's) of the unheld entries ``left``: a port is the cycle's
    when it lies in its domain's range; segments and ports of no domain are the cycle's
    when any of its ports is (a participant that did not leave DDS leaves its own domain's
    ports too), else another job's (a run on another domain killed meanwhile)."""
    ports = {n for n in left if port_domain(n) == domain}
    foreign = {n for n in left if port_domain(n) not in (None, domain)}
    rest = left - ports - foreign
    return (ports | rest, foreign) if ports else (set(), foreign | rest)


def run_processes(out: Path) -> list[psutil.Process]:
    """Live processes whose command line names the run's directory (its nodes)."""
    found = []
    for p in psutil.process_iter(['cmdline']):
        try:
            if str(out) in ' '.join(p.info['cmdline'] or []):
                found.append(p)
        except (psutil.Error, OSError):
            continue
    return found


def one_cycle(
    i: int, way: str, spawn: str, args: argparse.Namespace, tmp: Path, rng: random.Random
) -> dict:
    from apf_swarm_nodes.bringup import pick_domain_id

    out = tmp / f'cycle_{i}'
    before = shm_entries()
    domain = pick_domain_id()  # as the bring-up would, but known here: its ports are its own
    cmd = [
        sys.executable, str(ROOT / 'scripts' / 'swarm_up.py'), '--preset', 'triangle',
        '--n-trackers', str(args.n_trackers), '--duration', str(args.duration), '--respawn',
        '--no-plots', '--domain-id', str(domain), '--spawn', spawn, '--out', str(out),
    ]  # fmt: skip
    t0 = time.monotonic()
    p = subprocess.Popen(
        dying_with_parent(cmd),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
        cwd=ROOT,
    )
    helpers: list[psutil.Process] = []  # the bring-up's zygote or janitor
    # once the nodes are up (mid-run endings: then a random moment of the run)
    deadline = time.monotonic() + 60.0
    while time.monotonic() < deadline and p.poll() is None:
        if len(run_processes(out)) >= args.n_trackers + 2:
            with contextlib.suppress(psutil.Error):
                helpers = [
                    c
                    for c in psutil.Process(p.pid).children()
                    if re.search(r'bringup\.(zygote|janitor)', ' '.join(c.cmdline()))
                ]
            break
        time.sleep(0.1)
    if way != 'ends':
        time.sleep(rng.uniform(0.5, 1.0 + 0.5 * args.duration))
        t_signal = time.monotonic()
        if p.poll() is None:
            if way == 'node SIGKILL':
                nodes = [q for q in run_processes(out) if '/tracker' in ' '.join(q.cmdline())]
                if nodes:
                    rng.choice(nodes).kill()
            else:
                p.send_signal(signal.SIGTERM if way == 'bring-up SIGTERM' else signal.SIGKILL)
    else:
        t_signal = None
    hung = False
    try:
        rc = p.wait(args.duration + 90.0)
    except subprocess.TimeoutExpired:
        hung = True
        os.killpg(p.pid, signal.SIGKILL)
        rc = p.wait()
    ended = time.monotonic() - t0
    deadline = time.monotonic() + 15.0

    def alive() -> list[psutil.Process]:
        found = run_processes(out)
        for h in helpers:
            with contextlib.suppress(psutil.Error):
                if h.is_running() and h.status() != psutil.STATUS_ZOMBIE:
                    found.append(h)
        return found

    while alive() and time.monotonic() < deadline:
        time.sleep(0.1)
    left = alive()
    # from the signal to the bring-up's end (SIGTERM), or to its last process's (SIGKILL)
    stop_s = None
    if t_signal is not None and way.startswith('bring-up'):
        stop_s = (
            time.monotonic() - t_signal if way == 'bring-up SIGKILL' else t0 + ended - t_signal
        )
    for q in left:
        with contextlib.suppress(psutil.Error):
            print(
                f'soak_cycles: leftover pid {q.pid}: {" ".join(q.cmdline())[:200]}',
                file=sys.stderr,
            )
        q.kill()
    # (a killed bring-up's zygote removes what its nodes left once they are gone)
    deadline = time.monotonic() + 15.0
    while attribute(shm_left(before), domain)[0] and time.monotonic() < deadline:
        time.sleep(0.2)
    stale, foreign = attribute(shm_left(before), domain)
    if args.verbose:
        for name in sorted(stale):
            print(f'soak_cycles: /dev/shm left: {name}', file=sys.stderr)
        for name in sorted(foreign):
            print(f'soak_cycles: /dev/shm left by another job: {name}', file=sys.stderr)
    return {
        'way': way,
        'spawn': spawn,
        'rc': rc,
        'hung': hung,
        'seconds': ended,
        'leftover': len(left),
        'shm_left': len(stale),
        'shm_foreign': len(foreign),
        'stop_s': stop_s,
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--cycles', type=int, default=100)
    ap.add_argument('--n-trackers', type=int, default=3)
    ap.add_argument('--duration', type=float, default=3.0, help='simulated seconds a run')
    ap.add_argument('--seed', type=int, default=1)
    ap.add_argument('--smoke', action='store_true', help='one cycle of each way, 2 s runs')
    ap.add_argument('--verbose', action='store_true', help='name what each cycle left')
    ap.add_argument(
        '--spawn',
        choices=('fork', 'exec', 'both'),
        default='both',
        help='how the bring-up starts its nodes (both: drawn at random each cycle)',
    )
    args = ap.parse_args(argv)
    exit_on_signals()
    rng = random.Random(args.seed)
    ways = list(WAYS) if args.smoke else [rng.choice(WAYS) for _ in range(args.cycles)]
    kinds = ['fork', 'exec'] if args.spawn == 'both' else [args.spawn]
    spawns = [kinds[i % len(kinds)] if args.smoke else rng.choice(kinds) for i in range(len(ways))]
    if args.smoke:
        args.duration = 2.0
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    rows = []
    t0 = time.monotonic()
    first = shm_entries()
    with tempfile.TemporaryDirectory(prefix='soak_cycles_') as tmp:
        for i, (way, spawn) in enumerate(zip(ways, spawns, strict=True), 1):
            row = one_cycle(i, way, spawn, args, Path(tmp), rng)
            rows.append(row)
            print(
                f'soak_cycles: {i}/{len(ways)} {way} ({spawn}): exit {row["rc"]} after '
                f'{row["seconds"]:.1f} s, leftover {row["leftover"]}, /dev/shm left '
                f'{row["shm_left"]} (other jobs: {row["shm_foreign"]})'
                + (' HUNG' if row['hung'] else ''),
                file=sys.stderr,
                flush=True,
            )
    last = shm_entries()
    print(f'\nCPU: {cpu_model()}; {len(rows)} cycles in {time.monotonic() - t0:.0f} s')
    print(
        f'/dev/shm: {len(first)} Fast DDS entries before, {len(last)} after; '
        f'{len(shm_left(first))} created meanwhile that no live process holds\n'
    )
    print(
        '| ending | cycles | hangs | exit codes | longest [s] | longest stop [s] '
        "| leftover processes | /dev/shm left | other jobs' left meanwhile |"
    )
    print('|---|---:|---:|---|---:|---:|---:|---:|---:|')
    for way in (*WAYS, 'fork', 'exec', 'all'):
        mine = [r for r in rows if way in ('all', r['way'], r['spawn'])]
        if not mine:
            continue
        codes = ', '.join(str(c) for c in sorted({r['rc'] for r in mine}))
        stops = [r['stop_s'] for r in mine if r['stop_s'] is not None]
        stop = f'{max(stops):.1f}' if stops else ''
        print(
            f'| {way} | {len(mine)} | {sum(r["hung"] for r in mine)} | {codes} | '
            f'{max(r["seconds"] for r in mine):.1f} | {stop} | '
            f'{sum(r["leftover"] for r in mine)} | {sum(r["shm_left"] for r in mine)} | '
            f'{sum(r["shm_foreign"] for r in mine)} |'
        )
    bad = any(r['hung'] or r['leftover'] or r['shm_left'] for r in rows)
    return 1 if bad else 0


if __name__ == '__main__':
    sys.exit(main())
