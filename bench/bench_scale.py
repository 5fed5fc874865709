#!/usr/bin/env python3
"""Scale benchmark (issue 7): how many trackers this machine flies, per hosting mode.

    source scripts/activate.sh
    python bench/bench_scale.py [--quick]

Runs the bring-up (``scripts/swarm_up.py``) as a user would, one case at a time, each in its
own ``ROS_DOMAIN_ID`` with ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``, and reads its
``summary.json``; samples every node's RSS from ``/proc`` while it runs. Cases:

* realtime at ``--rate`` Hz (plant publish rate = tracker control rate; default 50) for n
  trackers, one process per tracker (``K = 1``) and four per process (``K = 4``): missed
  deadlines (trackers the plant found silent), stale (brake) commands, samples received
  against expected; "flies" = no missed deadline, at most 3 stale commands per tracker (the
  watchdog's brakes before a tracker's first input), at least 95 % of the expected samples;
* lockstep steps/s for 3, 10 and 30 trackers (``K = 1``; 30 also with ``K = 5``);
* discovery: the bring-up's "graph ready" time (every node seen, every subscription
  matched) against n;
* RSS per tracker: the mean RSS of the tracker processes divided by the trackers each hosts.

Prints Markdown tables. Not timed assertions: numbers to compare, measured in one run.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_graph import machine, rss_mb  # noqa: E402
from soak import node_pids  # noqa: E402  (the same /proc lookup)

from apf_swarm_nodes.bringup import pick_domain_id  # noqa: E402


def log(msg: str) -> None:
    print(f'bench_scale: {msg}', file=sys.stderr, flush=True)


def node_rss(config: str) -> dict[str, float]:
    """{process name:pid: RSS MB} of the live node processes naming this run's config."""
    out = {}
    for pid, name in node_pids(config).items():
        rss = rss_mb(pid)
        if rss is not None:
            out[f'{name}:{pid}'] = rss
    return out


def run_case(mode: str, n: int, per_process: int, duration: float, rate: float,
             workdir: Path) -> dict[str, Any]:
    out = workdir / f'{mode}_n{n}_k{per_process}'
    preset = 'realtime' if mode == 'realtime' else 'triangle'
    cmd = [sys.executable, str(ROOT / 'scripts' / 'swarm_up.py'), '--preset', preset,
           '--mode', mode, '--n-trackers', str(n), '--trackers-per-process',
           str(per_process), '--duration', str(duration), '--domain-id',
           str(pick_domain_id(lo=202, hi=230)), '--out', str(out), '--no-plots',
           '--allow-overload']
    if mode == 'realtime':
        cmd += ['--node-param', f'publish_rate:={float(rate)!r}',
                '--node-param', f'control_rate:={float(rate)!r}']
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    t0 = time.monotonic()
    p = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=env,
                         cwd=ROOT)
    rss: dict[str, float] = {}
    config = str(out / 'config.yaml')
    while p.poll() is None:
        for k, v in node_rss(config).items():
            rss[k] = max(rss.get(k, 0.0), v)
        time.sleep(0.5)
    err = p.stderr.read().decode(errors='replace')
    res: dict[str, Any] = {'mode': mode, 'n': n, 'k': per_process, 'exit': p.returncode,
                           'wall': time.monotonic() - t0}
    try:
        summary = json.loads((out / 'summary.json').read_text())
    except OSError:
        res['error'] = err.strip().splitlines()[-1] if err.strip() else 'no summary.json'
        return res
    trackers = [v for k, v in rss.items() if k.startswith('tracker')]
    res.update({
        'missed': summary['missed_deadlines'], 'stale': summary['stale_inputs'],
        'received': summary['messages']['received'], 'ready_s': summary['timing']['ready'],
        'rate': summary['timing']['rate'],
        'rss_per_tracker': (sum(trackers) / len(trackers) / per_process) if trackers else None,
        'rss_plant': max((v for k, v in rss.items() if k.startswith('plant')), default=None)})
    if mode == 'realtime':
        expected = duration * rate
        res['expected'] = expected
        # stale commands from the watchdogs before a tracker's first input (they arrive at
        # the plant after its start): a few per tracker at most
        res['flies'] = (res['exit'] == 0 and res['missed'] == 0 and res['stale'] <= 3 * n
                        and res['received'] >= 0.95 * expected)
    return res


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--quick', action='store_true')
    ap.add_argument('--rate', type=float, default=50.0)
    args = ap.parse_args(argv)
    rt_ns = (8, 16) if args.quick else (8, 12, 16, 20, 24)
    rt_duration = 5.0 if args.quick else 10.0
    ls_cases = [(3, 1), (10, 1)] if args.quick else [(3, 1), (10, 1), (30, 1), (30, 5)]
    results = []
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        for k in (1, 4):
            for n in rt_ns:
                log(f'realtime {args.rate:g} Hz, n = {n}, K = {k}')
                r = run_case('realtime', n, k, rt_duration, args.rate, work)
                log(f'  {r}')
                results.append(r)
        for n, k in ls_cases:
            log(f'lockstep, n = {n}, K = {k}')
            r = run_case('lockstep', n, k, 2.0 if n <= 10 else 1.0, args.rate, work)
            log(f'  {r}')
            results.append(r)
    m = machine()
    print(f'Machine: {m["nproc"]} CPUs ({m["cpu"]}), Python {m["python"]}, {m["rmw"]}; load '
          f'average at the end {m["load"]}.\n')
    print(f'Realtime at {args.rate:g} Hz, {rt_duration:g} s per case ("flies": no missed '
          'deadline, <= 3 start-up brakes per tracker, >= 95 % of the samples):\n')
    print('| trackers | per process | flies | missed | stale | samples / expected | graph '
          'ready [s] | RSS per tracker [MB] | plant RSS [MB] |')
    print('|---:|---:|---|---:|---:|---:|---:|---:|---:|')
    for r in results:
        if r['mode'] != 'realtime':
            continue
        if 'error' in r:
            print(f"| {r['n']} | {r['k']} | no: {r['error']} | | | | | | |")
            continue
        print(f"| {r['n']} | {r['k']} | {'yes' if r['flies'] else 'no'} | {r['missed']} | "
              f"{r['stale']} | {r['received']} / {r['expected']:.0f} | {r['ready_s']:.1f} | "
              f"{r['rss_per_tracker']:.1f} | {r['rss_plant']:.0f} |")
    for k in (1, 4):
        flying = [r['n'] for r in results if r['mode'] == 'realtime' and r['k'] == k
                  and r.get('flies')]
        print(f'\nMost trackers flying at {args.rate:g} Hz with {k} per process: '
              f'{max(flying) if flying else "none of the sizes tried"}')
    print('\nLockstep (dt = 1 ms) through the bring-up:\n')
    print('| trackers | per process | steps/s | graph ready [s] | RSS per tracker [MB] |')
    print('|---:|---:|---:|---:|---:|')
    for r in results:
        if r['mode'] != 'lockstep':
            continue
        if 'error' in r:
            print(f"| {r['n']} | {r['k']} | failed: {r['error']} | | |")
            continue
        print(f"| {r['n']} | {r['k']} | {r['rate']:.0f} | {r['ready_s']:.1f} | "
              f"{r['rss_per_tracker']:.1f} |")
    return 0


if __name__ == '__main__':
    sys.exit(main())
