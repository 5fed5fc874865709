#!/usr/bin/env python3
"""Soak test of the realtime swarm: memory and CPU per node over a long run.

Samples every node process of a ``swarm_up.py --mode realtime`` run: per node the RSS after the
warm-up against the end (the run's own baseline), its maximum, the mean CPU; the run's deadlines
and drops (summary.json). ``soak.csv``, ``soak.json``, ``soak_rss.png`` in ``--out``. Exit 1 on
5 % growth, a missed deadline, a drop or a failed run."""

import argparse
import csv
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from statistics import fmean
from typing import Any

from _children import ROOT, exit_on_signals, start, stop, swarm_up, table
from apf_swarm_nodes.bringup import pick_domain_id
from apf_swarm_nodes.capacity import machine

GROWTH_LIMIT = 5.0  # percent


def node_pids(config: str) -> dict[int, str]:
    """{pid: tracker_<id> | plant | ...} of the live processes naming the run's config."""
    out = {}
    for pid in (int(e) for e in os.listdir('/proc') if e.isdigit()):
        args = machine.process_args(pid) or []
        if any(config in a for a in args) and not any('swarm_up.py' in a for a in args):
            exe = Path(args[1] if args[0].endswith('python') and len(args) > 1 else args[0])
            ids = [a.split(':=', 1)[1] for a in args if a.startswith('uav_id:=')]
            out[pid] = f'{exe.name}_{ids[0]}' if ids else exe.name
    return out


def analyse(samples: list[dict[str, Any]], args: argparse.Namespace) -> list[dict[str, Any]]:
    rows, d = [], args.duration
    for name in sorted({s['node'] for s in samples}):
        own = [s for s in samples if s['node'] == name and s['t'] <= d]
        t0, t1, end = args.warmup * d, (args.warmup + args.window) * d, own[-1]['t']
        early = fmean([s['rss_mb'] for s in own if t0 <= s['t'] < t1] or [float('nan')])
        late = fmean([s['rss_mb'] for s in own if s['t'] >= end - args.window * d])
        cpu = [s for s in own if s['t'] >= t0]
        span = cpu[-1]['t'] - cpu[0]['t'] if cpu else 0.0
        rows.append({
            'node': name,
            'rss_after_warmup_mb': round(early, 2),
            'rss_end_mb': round(late, 2),
            'growth_pct': round(100.0 * (late - early) / early, 2),
            'rss_max_mb': round(max(s['rss_mb'] for s in own), 2),
            'cpu_pct': round(100 * (cpu[-1]['cpu_s'] - cpu[0]['cpu_s']) / span, 1)
            if span > 0 else float('nan'),
            'samples': len(own),
        })  # fmt: skip
    return rows


def plot(samples: list[dict[str, Any]], path: Path, title: str) -> None:
    from apf_swarm_nodes.analysis.plots import plt, save_figure  # Agg, the figures' dpi

    fig, ax = plt.subplots(figsize=(8, 4.5))
    for name in sorted({s['node'] for s in samples}):
        own = [s for s in samples if s['node'] == name]
        ax.plot([s['t'] / 60 for s in own], [s['rss_mb'] for s in own], label=name, lw=1)
    ax.set(xlabel='time since the swarm started [min]', ylabel='RSS [MB]', title=title)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, ncol=2)
    save_figure(fig, path)


def soak(args: argparse.Namespace, out: Path) -> int:
    out.mkdir(parents=True, exist_ok=True)
    run_dir, domain = out / 'run', args.domain_id or pick_domain_id(lo=231, hi=232)
    cmd = swarm_up('--preset', 'realtime', '--mode', 'realtime', '--duration', args.duration,
                   '--n-trackers', args.n_trackers, '--domain-id', domain,
                   '--out', run_dir)  # fmt: skip
    err_path, config = out / 'bringup.stderr', str(run_dir / 'config.yaml')
    with err_path.open('wb') as err:
        proc = start(cmd, stdin=subprocess.DEVNULL, stdout=err, stderr=err, cwd=ROOT)
    samples: list[dict[str, Any]] = []
    t_start, nxt = None, time.monotonic()
    try:
        while proc.poll() is None:
            now = time.monotonic()
            if t_start is None and re.search(rb'(steps|msgs)/s', err_path.read_bytes()):
                t_start = now
            if t_start is not None and now >= nxt:
                nxt += args.every
                for pid, name in node_pids(config).items():
                    rss, cpu_s = machine.process_rss(pid), machine.process_cpu_seconds(pid)
                    if rss is not None and cpu_s is not None:
                        t, mb = round(now - t_start, 3), round(rss / 2**20, 3)
                        row = {'t': t, 'node': name, 'pid': pid, 'rss_mb': mb, 'cpu_s': cpu_s}
                        samples.append(row)
            time.sleep(0.2)
    finally:
        rc = stop(proc, 60.0)
    path = run_dir / 'summary.json'
    s = json.loads(path.read_text()) if path.exists() else {}
    with (out / 'soak.csv').open('w', newline='') as f:
        w = csv.DictWriter(f, fieldnames=['t', 'node', 'pid', 'rss_mb', 'cpu_s'])
        w.writeheader()
        w.writerows(samples)
    rows = analyse(samples, args) if samples else []
    msgs = s.get('messages') or {}
    counts = ('missed_deadlines', 'stale_inputs', 'rejected_inputs')
    run = {'bringup_exit': rc, 'status': s.get('status'), 'dropped': msgs.get('dropped'),
           'samples_received': msgs.get('received'), **{k: s.get(k) for k in counts}}  # fmt: skip
    worst = max((r['growth_pct'] for r in rows), default=float('nan'))
    ok = bool(rc == 0 and rows and (args.smoke or worst < GROWTH_LIMIT))  # 10 s: start-up
    ok = ok and run['missed_deadlines'] == 0 and run['dropped'] == 0
    result = {'machine': {'cpu': machine.cpu_model(), 'nproc': os.cpu_count()},
              'duration_s': args.duration, 'n_trackers': args.n_trackers, 'nodes': rows,
              'run': run, 'max_growth_pct': worst, 'pass': ok}  # fmt: skip
    (out / 'soak.json').write_text(json.dumps(result, indent=2) + '\n')
    if samples:
        plot(samples, out / 'soak_rss.png', f'RSS per node, {args.n_trackers} trackers')
    print(f'Soak: {args.n_trackers} trackers, {args.duration:g} s; {machine.cpu_model()}\n')
    head = 'node | RSS after warm-up [MB]: | RSS at the end [MB]: | growth [%]: | max RSS [MB]: '
    print(table(head + '| CPU [% of a core]:', [
        [r['node'], f'{r["rss_after_warmup_mb"]:.1f}', f'{r["rss_end_mb"]:.1f}',
         f'{r["growth_pct"]:+.2f}', f'{r["rss_max_mb"]:.1f}', f'{r["cpu_pct"]:.1f}']
        for r in rows]))  # fmt: skip
    limit = 'not judged in a smoke' if args.smoke else f'limit {GROWTH_LIMIT:g} %'
    print(f'\nRun: {run}. Largest growth {worst:+.2f} % ({limit}): '
          f'{"pass" if ok else "FAIL"}. Files in {out}')  # fmt: skip
    return 0 if ok else 1


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('--duration', type=float, default=1800.0, help='run length [s]')
    p.add_argument('--n-trackers', type=int, default=3)
    p.add_argument('--every', type=float, default=5.0, help='sampling period [s]')
    p.add_argument('--warmup', type=float, default=0.1, help='fraction of the run skipped')
    p.add_argument('--window', type=float, default=0.1, help='fraction averaged at each end')
    p.add_argument('--out', type=Path, default=None, help='output directory')
    p.add_argument('--domain-id', type=int, default=None)
    p.add_argument('--smoke', action='store_true', help='a 10 s soak, sampled every 1 s')
    args = p.parse_args(argv)
    exit_on_signals()
    if args.smoke:
        args.duration, args.every = 10.0, 1.0
        if args.out is None:
            with tempfile.TemporaryDirectory(prefix='soak_smoke_') as tmp:
                return soak(args, Path(tmp))
    out = (args.out or ROOT / 'runs' / time.strftime('soak-%Y%m%d-%H%M%S')).resolve()
    if out.exists() and any(out.iterdir()):
        p.error(f'{out} is not empty; choose a new --out')
    return soak(args, out)


if __name__ == '__main__':
    sys.exit(main())
