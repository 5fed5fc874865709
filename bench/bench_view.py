#!/usr/bin/env python3
"""What the live view costs a realtime run: no ``--view`` (the baseline), a view nobody
watches, and a Foxglove client subscribed to every channel.

    source scripts/activate.sh
    python bench/bench_view.py [--n 8] [--duration 15] [--rounds 2] [--json FILE] [--smoke]

Each round runs the three cases interleaved (``apf-swarm up --preset realtime --mode realtime``,
``--n`` trackers four to a process). Per case: command latency p50 / p99 (``trajectory.npz``),
missed deadlines, CPU of the bring-up (the view lives there) and of every process of the run,
frames the client received; the CPU ratio is against the no-view run of the same round.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import re
import statistics
import subprocess
import sys
import tempfile
import threading
from pathlib import Path
from typing import Any

import numpy as np
import psutil
from apf_swarm_nodes.capacity.machine import cpu_model

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _children import exit_on_signals, start, stop, table

CASES = ('no view', 'view, no client', 'view, watched')


def log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def watch(url: str, stop: threading.Event, counts: dict[str, int]) -> None:
    """A Foxglove client that subscribes to every channel and counts scene frames."""
    from websockets.exceptions import ConnectionClosed
    from websockets.sync.client import connect

    with connect(url, subprotocols=['foxglove.sdk.v1'], open_timeout=30) as ws:
        channels: list[dict[str, Any]] = []
        while len(channels) < 3:
            msg = json.loads(ws.recv(timeout=30))
            if msg['op'] == 'advertise':
                channels += msg['channels']
        subs = [{'id': k, 'channelId': c['id']} for k, c in enumerate(channels)]
        ws.send(json.dumps({'op': 'subscribe', 'subscriptions': subs}))
        scene = next(k for k, c in enumerate(channels) if c['topic'] == '/swarm/scene')
        while not stop.is_set():
            try:
                m = ws.recv(timeout=0.5)
            except TimeoutError:
                continue
            except ConnectionClosed:
                return
            if isinstance(m, bytes) and m[0] == 1 and int.from_bytes(m[1:5], 'little') == scene:
                counts['frames'] += 1


def run_case(case: str, args: argparse.Namespace, out: Path) -> dict[str, Any]:
    cmd = ['apf-swarm', 'up', '--preset', 'realtime', '--mode', 'realtime', '--n-trackers',
           str(args.n), '--trackers-per-process', '4', '--duration', str(args.duration),
           '--no-plots', '--out', str(out)]  # fmt: skip
    cmd += ['--view', '0'] if case != 'no view' else []
    proc = start(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    cpu: dict[int, float] = {}
    done, counts = threading.Event(), {'frames': 0}
    client: threading.Thread | None = None
    try:
        me = psutil.Process(proc.pid)
        for line in proc.stderr or ():
            found = re.search(r'view: (ws://\S+)', line)
            if found and case == 'view, watched' and client is None:
                client = threading.Thread(target=watch, args=(found[1], done, counts), daemon=True)
                client.start()
            for p in [me, *me.children(recursive=True)]:
                with contextlib.suppress(psutil.Error):
                    cpu[p.pid] = sum(p.cpu_times()[:2])
        proc.wait()
    finally:
        stop(proc)
        done.set()
    if client is not None:
        client.join(timeout=10)
    summary = json.loads((out / 'summary.json').read_text())
    with np.load(out / 'trajectory.npz') as npz:
        lat = np.asarray(npz['command_latency'], dtype=float)
    lat = lat[lat > 0] * 1e3 if (lat > 0).any() else np.array([np.nan])
    return {'case': case, 'p50': float(np.percentile(lat, 50)), 'rc': proc.returncode,
            'p99': float(np.percentile(lat, 99)), 'missed': int(summary['missed_deadlines']),
            'cpu_bringup': cpu.get(proc.pid, float('nan')), 'cpu_all': sum(cpu.values()),
            'frames': counts['frames']}  # fmt: skip


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--n', type=int, default=8)
    ap.add_argument('--duration', type=float, default=15.0)
    ap.add_argument('--rounds', type=int, default=2)
    ap.add_argument('--json', type=Path)
    ap.add_argument('--smoke', action='store_true', help='4 trackers, 3 s, one round (seconds)')
    args = ap.parse_args()
    exit_on_signals()
    if args.smoke:
        args.n, args.duration, args.rounds = 4, 3.0, 1
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    rows: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(args.rounds):
            for k, case in enumerate(CASES):
                log(f'round {r + 1}/{args.rounds}: {case}')
                row = run_case(case, args, Path(tmp) / f'{r}-{k}')
                row['round'] = r + 1
                rows.append(row)
    med = statistics.median
    out = []
    for case in CASES:
        mine = [r for r in rows if r['case'] == case]
        base = [r for r in rows if r['case'] == 'no view']
        ratio = med(m['cpu_all'] / b['cpu_all'] for m, b in zip(mine, base, strict=True))
        out.append([case, f'{med(r["p50"] for r in mine):.1f} / {med(r["p99"] for r in mine):.1f}',
                    max(r['missed'] for r in mine), f'{med(r["cpu_bringup"] for r in mine):.1f}',
                    f'{med(r["cpu_all"] for r in mine):.1f}', f'{ratio:.3f}',
                    f'{med(r["frames"] for r in mine):.0f}'])  # fmt: skip
    print(f'\n{cpu_model()}; {args.n} trackers four to a process, {args.duration:g} s each\n')
    head = 'case | latency p50 / p99 [ms] | missed deadlines: | bring-up CPU [s]: | all CPU [s]: '
    print(table(head + '| CPU ratio (all): | frames received:', out))
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2) + '\n')
    return 0 if all(r['rc'] == 0 for r in rows) else 1


if __name__ == '__main__':
    sys.exit(main())
