#!/usr/bin/env python3
"""Soak of starts and stops: short runs ended four ways (it ends; a tracker, the bring-up
SIGTERMed, the bring-up SIGKILLed); none may hang or leave a process or shared memory.

Lockstep triangle with ``--respawn``, forked or executed nodes. Per cycle: a hang (not ended
within duration + 90 s), processes of the run alive 15 s after, Fast DDS ``/dev/shm`` entries
of its domain that no live process holds (``apf_swarm_nodes.dds.shm``). Exit 1 on any."""

import argparse
import contextlib
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
from _children import ROOT, exit_on_signals, log, start, swarm_up, table
from apf_swarm_nodes.bringup import pick_domain_id
from apf_swarm_nodes.dds.shm import fastdds_entries, unheld

WAYS = ('ends', 'node SIGKILL', 'bring-up SIGTERM', 'bring-up SIGKILL')


def mine(left: set[str], domain: int) -> tuple[set[str], set[str]]:
    """(this cycle's, other jobs') of the unheld entries: ports by their domain's range
    (7400 + 250 d); segments are the cycle's when any of its ports was left too."""

    def dom(name: str) -> int | None:
        m = re.match(r'^(?:sem\.)?fastrtps_port(\d+)', name)
        return None if m is None or int(m[1]) < 7400 else (int(m[1]) - 7400) // 250

    ports = {n for n in left if dom(n) == domain}
    foreign = {n for n in left if dom(n) not in (None, domain)}
    rest = left - ports - foreign
    return (ports | rest, foreign) if ports else (set(), foreign | rest)


def of_run(out: Path, extra: list[psutil.Process]) -> list[psutil.Process]:
    """Live processes whose command line names the run's directory, and ``extra``."""
    found = {}
    for p in [*psutil.process_iter(), *extra]:
        with contextlib.suppress(psutil.Error):
            named = str(out) in ' '.join(p.cmdline() or [])
            if (named or p in extra) and p.status() != psutil.STATUS_ZOMBIE:
                found[p.pid] = p
    return list(found.values())


def cycle(i: int, way: str, spawn: str, args: argparse.Namespace, tmp: Path, rng: random.Random):
    out, before, domain = tmp / f'cycle_{i}', fastdds_entries(), pick_domain_id()
    cmd = swarm_up('--preset', 'triangle', '--n-trackers', args.n_trackers, '--duration',
                   args.duration, '--respawn', '--domain-id', domain, '--spawn', spawn,
                   '--out', out)  # fmt: skip
    t0 = time.monotonic()
    p = start(cmd, 'KILL', stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=ROOT)
    helpers: list[psutil.Process] = []  # the zygote, the janitor
    while time.monotonic() < t0 + 60 and p.poll() is None:
        if len(of_run(out, [])) >= args.n_trackers + 2:
            with contextlib.suppress(psutil.Error):
                kids = psutil.Process(p.pid).children()
                helpers = [c for c in kids if re.search(r'zygote|janitor', ' '.join(c.cmdline()))]
            break
        time.sleep(0.1)
    t_signal = None
    if way != 'ends':
        time.sleep(rng.uniform(0.5, 1.0 + 0.5 * args.duration))
        t_signal = time.monotonic()
        if p.poll() is None and way == 'node SIGKILL':
            nodes = [q for q in of_run(out, []) if '/tracker' in ' '.join(q.cmdline())]
            if nodes:
                rng.choice(nodes).kill()
        elif p.poll() is None:
            p.send_signal(signal.SIGTERM if way == 'bring-up SIGTERM' else signal.SIGKILL)
    try:
        rc, hung = p.wait(args.duration + 90.0), False
    except subprocess.TimeoutExpired:
        os.killpg(p.pid, signal.SIGKILL)
        rc, hung = p.wait(), True
    ended = time.monotonic()
    while of_run(out, helpers) and time.monotonic() < ended + 15:
        time.sleep(0.1)
    left = of_run(out, helpers)
    stop_s = None
    if t_signal is not None and way.startswith('bring-up'):
        stop_s = (time.monotonic() if way == 'bring-up SIGKILL' else ended) - t_signal
    for q in left:
        with contextlib.suppress(psutil.Error):
            log(f'leftover {q.pid}: {" ".join(q.cmdline())[:200]}')
            q.kill()
    deadline = time.monotonic() + 15  # a killed bring-up's zygote cleans up after its nodes
    while mine(unheld(fastdds_entries() - before), domain)[0] and time.monotonic() < deadline:
        time.sleep(0.2)
    stale, foreign = mine(unheld(fastdds_entries() - before), domain)
    for name in sorted(stale) if args.verbose else ():
        log(f'/dev/shm left: {name}')
    return {'way': way, 'spawn': spawn, 'rc': rc, 'hung': hung, 'seconds': ended - t0,
            'leftover': len(left), 'shm': len(stale), 'foreign': len(foreign),
            'stop': stop_s}  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--cycles', type=int, default=100)
    ap.add_argument('--n-trackers', type=int, default=3)
    ap.add_argument('--duration', type=float, default=3.0, help='simulated seconds a run')
    ap.add_argument('--seed', type=int, default=1)
    ap.add_argument('--smoke', action='store_true', help='one cycle of each way, 2 s runs')
    ap.add_argument('--verbose', action='store_true', help='name what each cycle left')
    ap.add_argument('--spawn', choices=('fork', 'exec', 'both'), default='both')
    args = ap.parse_args(argv)
    exit_on_signals()
    rng = random.Random(args.seed)
    ways = list(WAYS) if args.smoke else [rng.choice(WAYS) for _ in range(args.cycles)]
    kinds = ['fork', 'exec'] if args.spawn == 'both' else [args.spawn]
    spawns = [kinds[i % len(kinds)] if args.smoke else rng.choice(kinds) for i in range(len(ways))]
    args.duration = 2.0 if args.smoke else args.duration
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    rows, t0, first = [], time.monotonic(), fastdds_entries()
    with tempfile.TemporaryDirectory(prefix='soak_cycles_') as tmp:
        for i, (way, spawn) in enumerate(zip(ways, spawns, strict=True), 1):
            rows.append(r := cycle(i, way, spawn, args, Path(tmp), rng))
            hung = ' HUNG' if r['hung'] else ''
            log(f'{i}/{len(ways)} {way} ({spawn}): exit {r["rc"]}, {r["seconds"]:.1f} s, '
                f'leftover {r["leftover"]}, /dev/shm {r["shm"]}{hung}')  # fmt: skip
    print(f'\n{len(rows)} cycles in {time.monotonic() - t0:.0f} s; /dev/shm: {len(first)} '
          f'Fast DDS entries before, {len(fastdds_entries())} after\n')  # fmt: skip
    out = []
    for way in (*WAYS, 'fork', 'exec', 'all'):
        rs = [r for r in rows if way in ('all', r['way'], r['spawn'])]
        stops = [r['stop'] for r in rs if r['stop'] is not None]
        if rs:
            out.append([way, len(rs), sum(r['hung'] for r in rs),
                        ', '.join(str(c) for c in sorted({r['rc'] for r in rs})),
                        f'{max(r["seconds"] for r in rs):.1f}',
                        f'{max(stops):.1f}' if stops else '', sum(r['leftover'] for r in rs),
                        sum(r['shm'] for r in rs), sum(r['foreign'] for r in rs)])  # fmt: skip
    head = 'ending | cycles: | hangs: | exit codes | longest [s]: | longest stop [s]: | '
    print(table(head + "leftover processes: | /dev/shm left: | other jobs' left:", out))
    return 1 if any(r['hung'] or r['leftover'] or r['shm'] for r in rows) else 0


if __name__ == '__main__':
    sys.exit(main())
