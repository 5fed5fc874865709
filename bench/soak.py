#!/usr/bin/env python3
"""Soak test of the realtime swarm: memory and CPU per node over a long run.

    source scripts/activate.sh
    python bench/soak.py [--duration 1800] [--n-trackers 3] [--every 5] [--out DIR]

Brings up the realtime swarm (``scripts/swarm_up.py --preset realtime --mode realtime``) in
its own ``ROS_DOMAIN_ID`` for ``--duration`` seconds (default 30 minutes), samples every node
process every ``--every`` seconds from ``/proc`` (VmRSS, utime + stime), and prints progress
on stderr and, at the end, a Markdown table per node: RSS after the warm-up and at the end,
the growth between them, the maximum, the mean CPU; and the run's missed deadlines, stale and
rejected inputs and dropped samples (its summary.json). Writes ``soak.csv`` (every sample),
``soak.json`` (the table) and ``soak_rss.png`` into ``--out``.

Memory growth of a node = mean RSS over the last ``--window`` fraction of the run against
the mean over the same length right after the warm-up (``--warmup`` fraction), in percent.
Exit status 1 when a node grew by 5 % or more, a deadline was missed, a sample was dropped,
or the bring-up did not complete; 0 otherwise. Not part of ``bench/run_all.py`` (it takes
half an hour); ``test/integration/test_soak.py`` runs a 20 s version.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import re
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))
from _children import dying_with_parent, exit_on_signals  # noqa: E402
from apf_swarm_nodes.bringup import pick_domain_id  # noqa: E402
from apf_swarm_nodes.capacity.machine import process_args, process_cpu_seconds  # noqa: E402
from bench_graph import machine, rss_mb  # noqa: E402

GROWTH_LIMIT = 5.0  # percent


def log(msg: str) -> None:
    print(f'soak: {msg}', file=sys.stderr, flush=True)


def node_name(cmdline: list[str]) -> str:
    """A readable name from a node's command line: tracker_<id>, plant, target, recorder."""
    exe = Path(
        cmdline[1] if cmdline[0].endswith('python') and len(cmdline) > 1 else cmdline[0]
    ).name
    for arg in cmdline:
        if arg.startswith('uav_id:='):
            return f'{exe}_{arg.split(":=", 1)[1]}'
    return exe


def node_pids(config: str) -> dict[int, str]:
    """{pid: name} of the live processes whose command line names this run's config file."""
    out = {}
    for entry in os.listdir('/proc'):
        if not entry.isdigit():
            continue
        args = process_args(int(entry))
        if args is None:
            continue
        if any(config in a for a in args) and not any('swarm_up.py' in a for a in args):
            out[int(entry)] = node_name(args)
    return out


def mean(values: list[float]) -> float:
    return sum(values) / len(values) if values else float('nan')


def analyse(
    samples: list[dict[str, Any]], warmup: float, window: float, duration: float
) -> list[dict[str, Any]]:
    """Per node: RSS after the warm-up and at the end (means over ``window`` of the run),
    growth in percent, maximum RSS, mean CPU (% of one core)."""
    rows = []
    for name in sorted({s['node'] for s in samples}):
        # samples after the run's end would see the nodes shutting down
        own = [s for s in samples if s['node'] == name and s['t'] <= duration]
        t0, t1 = warmup * duration, (warmup + window) * duration
        # the end window ends at the node's last sample: a realtime run ends with the
        # plant's final state, up to a sampling period or two before ``duration``
        end = max((s['t'] for s in own), default=duration)
        early = [s['rss_mb'] for s in own if t0 <= s['t'] < t1]
        late = [s['rss_mb'] for s in own if s['t'] >= end - window * duration]
        cpu = [s for s in own if s['t'] >= t0]
        cpu_pct = (
            100.0 * (cpu[-1]['cpu_s'] - cpu[0]['cpu_s']) / (cpu[-1]['t'] - cpu[0]['t'])
            if len(cpu) > 1 and cpu[-1]['t'] > cpu[0]['t']
            else float('nan')
        )
        e, lt = mean(early), mean(late)
        rows.append(
            {
                'node': name,
                'rss_after_warmup_mb': round(e, 2),
                'rss_end_mb': round(lt, 2),
                'growth_pct': round(100.0 * (lt - e) / e, 2) if e > 0 else float('nan'),
                'rss_max_mb': round(max(s['rss_mb'] for s in own), 2),
                'cpu_pct': round(cpu_pct, 1),
                'samples': len(own),
            }
        )
    return rows


def plot(samples: list[dict[str, Any]], path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 4.5))
    for name in sorted({s['node'] for s in samples}):
        own = [s for s in samples if s['node'] == name]
        ax.plot([s['t'] / 60 for s in own], [s['rss_mb'] for s in own], label=name, lw=1)
    ax.set_xlabel('time since the swarm started [min]')
    ax.set_ylabel('RSS [MB]')
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('--duration', type=float, default=1800.0, help='run length [s]')
    p.add_argument('--n-trackers', type=int, default=3)
    p.add_argument('--every', type=float, default=5.0, help='sampling period [s]')
    p.add_argument('--warmup', type=float, default=0.1, help='fraction of the run skipped')
    p.add_argument(
        '--window', type=float, default=0.1, help='fraction of the run averaged at each end'
    )
    p.add_argument('--out', type=Path, default=None, help='output directory')
    p.add_argument('--domain-id', type=int, default=None)
    p.add_argument('--smoke', action='store_true', help='a 10 s soak, sampled every 1 s')
    args = p.parse_args(argv)
    exit_on_signals()
    if args.smoke:
        args.duration, args.every = 10.0, 1.0
        if args.out is None:  # a smoke run keeps nothing
            with tempfile.TemporaryDirectory(prefix='soak_smoke_') as tmp:
                args.out = Path(tmp) / 'soak'
                return soak(p, args)
    return soak(p, args)


def soak(p: argparse.ArgumentParser, args: argparse.Namespace) -> int:
    """The soak of :func:`main`'s arguments."""
    out = (args.out or ROOT / 'runs' / time.strftime('soak-%Y%m%d-%H%M%S')).resolve()
    if out.exists() and any(out.iterdir()):
        p.error(f'{out} is not empty; choose a new --out')
    out.mkdir(parents=True, exist_ok=True)
    run_dir = out / 'run'
    domain = args.domain_id if args.domain_id is not None else pick_domain_id(lo=231, hi=232)
    cmd = [
        sys.executable,
        str(ROOT / 'scripts' / 'swarm_up.py'),
        '--preset',
        'realtime',
        '--mode',
        'realtime',
        '--duration',
        str(args.duration),
        '--n-trackers',
        str(args.n_trackers),
        '--domain-id',
        str(domain),
        '--out',
        str(run_dir),
        '--no-plots',
    ]
    log(f'{" ".join(cmd[1:])}')
    err_path = out / 'bringup.stderr'
    with open(err_path, 'wb') as err, open(out / 'bringup.stdout', 'wb') as sout:
        proc = subprocess.Popen(
            dying_with_parent(cmd),
            stdin=subprocess.DEVNULL,
            stdout=sout,
            stderr=err,
            cwd=ROOT,
            start_new_session=True,
        )
    config = str(run_dir / 'config.yaml')
    samples: list[dict[str, Any]] = []
    t_start: float | None = None
    next_sample = time.monotonic()
    next_report = time.monotonic() + 60
    try:
        while proc.poll() is None:
            now = time.monotonic()
            if t_start is None and re.search(rb'(steps|msgs)/s', err_path.read_bytes()):
                t_start = now
                log('swarm running; sampling')
            if t_start is not None and now >= next_sample:
                next_sample += args.every
                for pid, name in node_pids(config).items():
                    rss, cpu_s = rss_mb(pid), process_cpu_seconds(pid)
                    if rss is not None and cpu_s is not None:
                        samples.append(
                            {
                                't': round(now - t_start, 3),
                                'node': name,
                                'pid': pid,
                                'rss_mb': round(rss, 3),
                                'cpu_s': cpu_s,
                            }
                        )
            if t_start is not None and now >= next_report:
                next_report += 60
                total = sum(s['rss_mb'] for s in samples if s['t'] == samples[-1]['t'])
                log(f'{now - t_start:7.0f} / {args.duration:g} s, {total:.0f} MB in all nodes')
            time.sleep(0.2)
    except KeyboardInterrupt:
        os.killpg(proc.pid, signal.SIGINT)
        proc.wait(60)
        log('interrupted')
    rc = proc.returncode
    summary_path = run_dir / 'summary.json'
    summary = json.loads(summary_path.read_text()) if summary_path.exists() else {}
    with open(out / 'soak.csv', 'w', newline='') as f:
        w = csv.DictWriter(f, fieldnames=['t', 'node', 'pid', 'rss_mb', 'cpu_s'])
        w.writeheader()
        w.writerows(samples)
    rows = analyse(samples, args.warmup, args.window, args.duration) if samples else []
    run = {
        'bringup_exit': rc,
        'status': summary.get('status'),
        'missed_deadlines': summary.get('missed_deadlines'),
        'stale_inputs': summary.get('stale_inputs'),
        'rejected_inputs': summary.get('rejected_inputs'),
        'dropped': (summary.get('messages') or {}).get('dropped'),
        'samples_received': (summary.get('messages') or {}).get('received'),
    }
    worst = max((r['growth_pct'] for r in rows), default=float('nan'))
    ok = (
        rc == 0
        and rows
        and worst < GROWTH_LIMIT
        and run['missed_deadlines'] == 0
        and run['dropped'] == 0
    )
    result = {
        'machine': machine(),
        'duration_s': args.duration,
        'n_trackers': args.n_trackers,
        'every_s': args.every,
        'nodes': rows,
        'run': run,
        'max_growth_pct': worst,
        'pass': bool(ok),
    }
    (out / 'soak.json').write_text(json.dumps(result, indent=2) + '\n')
    if samples:
        plot(
            samples,
            out / 'soak_rss.png',
            f'RSS per node, realtime swarm of {args.n_trackers}, {args.duration / 60:g} min',
        )
    m = result['machine']
    print(
        f'Soak: realtime swarm, {args.n_trackers} trackers, {args.duration:g} s, sampled every '
        f'{args.every:g} s; machine: {m["nproc"]} CPUs ({m["cpu"]}), Python {m["python"]}, '
        f'{m["rmw"]}, load average at the end {m["load"]}.\n'
    )
    print(
        '| node | RSS after warm-up [MB] | RSS at the end [MB] | growth [%] | max RSS [MB] '
        '| CPU [% of a core] |'
    )
    print('|---|---:|---:|---:|---:|---:|')
    for r in rows:
        print(
            f'| {r["node"]} | {r["rss_after_warmup_mb"]:.1f} | {r["rss_end_mb"]:.1f} | '
            f'{r["growth_pct"]:+.2f} | {r["rss_max_mb"]:.1f} | {r["cpu_pct"]:.1f} |'
        )
    print(
        f'\nRun: exit {rc}, status {run["status"]}, missed deadlines {run["missed_deadlines"]}, '
        f'stale inputs {run["stale_inputs"]}, rejected {run["rejected_inputs"]}, samples '
        f'{run["samples_received"]} received / {run["dropped"]} dropped. Largest growth '
        f'{worst:+.2f} % (limit {GROWTH_LIMIT:g} %): {"pass" if ok else "FAIL"}.'
    )
    print(f'Files: {out}/soak.csv, soak.json, soak_rss.png, run/')
    return 0 if ok else 1


if __name__ == '__main__':
    sys.exit(main())
