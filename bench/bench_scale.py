#!/usr/bin/env python3
"""Scale benchmark: the swarm as the bring-up starts it, sizes climbed until it stops flying.

    python bench/bench_scale.py [--quick | --smoke] [--only ladder,latency,discovery,lockstep]
        [--rates HZ ...] [--sizes N ...] [--ladder TEXT] [--flight S] [--keep DIR]

Every case is a ``scripts/swarm_up.py`` run read back from its ``summary.json``, plus its
processes' CPU and RSS. **ladder**: per rate and ladder ("EXECUTOR INPUTS K=k|auto depth=d",
``;`` between), n climbs ``--sizes`` until a size does not fly (exit, missed deadlines, 95 %
of the states, ``prediction.run.flies``). **latency**: 3 trackers at 100 Hz, ``trigger:=odom``,
against the capacity probe's raw rclpy ping-pong beside it and alone (the baselines).
**discovery**: graph ready, nodes forked against executed (the baseline). **lockstep**:
steps/s, the 3-tracker default must make 500. Exit 1 on a leftover process, a missed floor,
or (``--smoke``) a crash.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib.util
import json
import os
import re
import shutil
import statistics
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import psutil

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / 'bench'))
from _children import exit_on_signals, start, stop  # noqa: E402
from apf_swarm_nodes.bringup import pick_domain_id  # noqa: E402

PARTS = ('ladder', 'latency', 'discovery', 'lockstep', 'view', 'secure')
VIEWS = ('no view', 'view, no client', 'view, watched')
FLOOR_LOCKSTEP = 500.0  # steps/s, 3 trackers
DEFAULT_LADDER = 'events aggregate K=auto depth=1'


def log(msg: str) -> None:
    print(f'bench_scale: {msg}', file=sys.stderr, flush=True)


@dataclass
class Case:
    n: int
    mode: str = 'realtime'
    rate: float = 50.0
    duration: float = 3.0
    k: str = 'auto'
    spawn: str = 'fork'
    params: tuple[str, ...] = ()
    label: str = ''
    rc: int | None = None
    summary: dict[str, Any] = field(default_factory=dict)
    cpu: float = float('nan')  # % of one core, every process of the run
    rss_mb: float = float('nan')  # max of the summed RSS
    cpu_s: tuple[float, float] = (0.0, 0.0)  # CPU seconds: the bring-up, the whole run
    extra: tuple[str, ...] = ()  # more bring-up options

    def get(self, *path: str, default: Any = None) -> Any:
        d: Any = self.summary
        for key in path:
            d = d.get(key) if isinstance(d, dict) else None
        return default if d is None else d

    def flies(self) -> bool:
        expected = self.rate * self.duration
        states = self.get('messages', 'received', default=0) >= 0.95 * expected
        return self.rc == 0 and self.get('missed_deadlines') == 0 and states and bool(
            self.get('prediction', 'run', 'flies'))  # fmt: skip

    def verdict(self) -> str:
        if not self.summary:
            return f'crashed (exit {self.rc})'
        if self.flies():
            return 'flies'
        run = self.get('prediction', 'run', default={})
        return (
            f'does not fly: exit {self.rc}, {self.get("missed_deadlines")} missed, '
            f'{self.get("messages", "received")} states, error '
            f'{100 * run.get("formation_error_rms", float("nan")):.2g} %, closest pair '
            f'{100 * run.get("closest_pair", float("nan")):.0f} %'
        )


class Bench:
    def __init__(self, keep: Path | None) -> None:
        self.dir = keep or Path(tempfile.mkdtemp(prefix='bench_scale_'))
        self.count = 0
        self.leftover = 0
        self.crashed = 0

    def up(self, case: Case, beside: Any = None) -> Case:
        """Run the bring-up for ``case``; ``beside(domain, out)`` runs once it started."""
        self.count += 1
        out = self.last = self.dir / f'{self.count:02d}_{case.mode}_{case.n}'
        domain = pick_domain_id(lo=202, hi=230)
        argv = [
            sys.executable, str(ROOT / 'scripts' / 'swarm_up.py'), '--no-plots',
            '--preset', 'triangle' if case.mode == 'lockstep' else 'realtime',
            '--mode', case.mode, '--n-trackers', str(case.n), '--duration', f'{case.duration:g}',
            '--spawn', case.spawn, '--domain-id', str(domain), '--out', str(out),
        ]  # fmt: skip
        if case.label in ('open', 'secure'):  # scripts/multihost.py, the probe's rate
            argv = [sys.executable, str(ROOT / 'scripts' / 'multihost.py'), '--hosts', '3',
                    '--n-trackers', str(case.n), '--duration', f'{case.duration:g}',
                    '--mode', 'realtime', '--out', str(out)]  # fmt: skip
            argv += ['--open'] if case.label == 'open' else []
        elif case.mode == 'realtime':
            argv += ['--set', f'control_rate={case.rate:g}']
        if case.k != 'auto':
            argv += ['--trackers-per-process', case.k]
        argv += case.extra
        for p in case.params:
            argv += ['--node-param', p]
        log(
            f'{case.label or case.mode} n={case.n} K={case.k} {case.spawn} {" ".join(case.params)}'
        )
        out.mkdir(parents=True, exist_ok=True)
        with (out / 'bench.log').open('wb') as logf:
            proc = start(argv, stdout=logf, stderr=logf)
            seen: dict[int, psutil.Process] = {}
            cpu: dict[int, float] = {}
            t0, rss = time.monotonic(), 0.0
            try:
                if beside is not None:
                    time.sleep(2.0)
                    beside(domain, out)
                while proc.poll() is None:
                    if time.monotonic() - t0 > case.duration + 120:
                        log('  timed out: stopped')
                        break
                    rss = max(rss, self.sample(proc.pid, seen, cpu))
                    time.sleep(0.5)
            finally:
                case.rc = stop(proc)
        wall = time.monotonic() - t0
        for p in seen.values():  # anything of the run still alive is a leftover
            with contextlib.suppress(psutil.Error):
                if p.is_running() and p.status() != psutil.STATUS_ZOMBIE:
                    self.leftover += 1
                    p.kill()
        case.cpu, case.rss_mb = 100 * sum(cpu.values()) / wall, rss / 2**20
        case.cpu_s = (cpu.get(proc.pid, float('nan')), sum(cpu.values()))
        with contextlib.suppress(OSError, ValueError):
            case.summary = json.loads((out / 'summary.json').read_text())
        self.crashed += not case.summary
        log(f'  exit {case.rc}: {case.verdict()}')
        return case

    @staticmethod
    def sample(pid: int, seen: dict[int, psutil.Process], cpu: dict[int, float]) -> float:
        """CPU seconds per process (kept in ``cpu``) and the summed RSS [bytes] now."""
        total = 0.0
        with contextlib.suppress(psutil.Error):
            root = psutil.Process(pid)
            for p in [root, *root.children(recursive=True)]:
                with contextlib.suppress(psutil.Error):
                    seen.setdefault(p.pid, p)
                    t = p.cpu_times()
                    cpu[p.pid] = t.user + t.system
                    total += p.memory_info().rss
        return total


def ping_pong(domain: int, seconds: float, rate: float = 100.0) -> dict[str, Any]:
    """The capacity probe's raw rclpy ping-pong (observer -> echo -> observer) [s]."""
    import rclpy
    from apf_swarm_nodes.capacity.measure import _ping_pong

    os.environ['ROS_DOMAIN_ID'] = str(domain)
    rclpy.init()
    try:
        return _ping_pong(seconds, rate, 16)
    finally:
        rclpy.try_shutdown()


def ms(v: float | None) -> str:
    return '-' if v is None else f'{1e3 * v:.2f}'


def ladders(bench: Bench, args: argparse.Namespace) -> list[str]:
    out = ['| rate | ladder | trackers | K | latency p50 / p99 [ms] | states | CPU [%] | result |',
           '|---:|---|---:|---:|---|---:|---:|---|']  # fmt: skip
    for rate in args.rates:
        for text in args.ladder.split(';'):
            words = dict(w.split('=', 1) for w in text.split() if '=' in w)
            executor, inputs = [w for w in text.split() if '=' not in w][:2]
            depth = f'qos_depth:={words.get("depth", "1")}'
            params = (f'executor:={executor}', f'inputs:={inputs}', depth)
            for n in args.sizes:
                case = bench.up(
                    Case(n, rate=rate, duration=args.flight, k=words.get('K', 'auto'),
                         params=params, label='ladder')
                )  # fmt: skip
                k = case.get('prediction', 'machine', 'trackers_per_process', default=case.k)
                lat = case.get('prediction', 'latency', default={})
                out.append(
                    f'| {rate:g} | {text.strip()} | {n} | {k} | {ms(lat.get("p50"))} / '
                    f'{ms(lat.get("p99"))} | {case.get("messages", "received")} / '
                    f'{rate * args.flight:.0f} | {case.cpu:.0f} | {case.verdict()} |'
                )
                if not case.flies():
                    break
    return out


def latency(bench: Bench, seconds: float) -> list[str]:
    alone = ping_pong(pick_domain_id(lo=202, hi=230), seconds)['rtt']
    out = [
        '| path | inputs | p50 [ms] | p99 [ms] | p99 / ping-pong p99 (concurrent, alone) |',
        '|---|---|---:|---:|---|',
        f'| ping-pong alone | - | {ms(alone["p50"])} | {ms(alone["p99"])} | - |',
    ]
    for inputs in ('aggregate', 'odom'):
        pp: dict[str, Any] = {}
        case = bench.up(
            Case(3, rate=100.0, duration=seconds + 4, k='1', label='latency',
                 params=('trigger:=odom', f'inputs:={inputs}')),
            beside=lambda d, _, pp=pp: pp.update(ping_pong(d, seconds)),
        )  # fmt: skip
        lat, rtt = case.get('prediction', 'latency', default={}), pp.get('rtt', {})
        p99 = lat.get('p99')
        ratio = f'{p99 / rtt["p99"]:.2f}, {p99 / alone["p99"]:.2f}' if p99 and rtt else '-'
        out.append(f'| control loop | {inputs} | {ms(lat.get("p50"))} | {ms(p99)} | {ratio} |')
        rtts = f'{ms(rtt.get("p50"))} | {ms(rtt.get("p99"))}'
        out.append(f'| ping-pong, swarm running | {inputs} | {rtts} | - |')
    return out


def watch(out: Path, done: threading.Event, counts: dict[str, int]) -> None:
    """A Foxglove client of the run's view, subscribed to every channel: scene frames."""
    from websockets.exceptions import ConnectionClosed
    from websockets.sync.client import connect

    while not (url := re.search(r'view: (ws://\S+)', (out / 'bench.log').read_text())):
        if done.wait(0.1):
            return
    client = connect(url[1], subprotocols=['foxglove.sdk.v1'], open_timeout=30)
    with contextlib.suppress(ConnectionClosed), client as ws:
        channels: list[dict[str, Any]] = []
        while len(channels) < 3:
            msg = json.loads(ws.recv(timeout=30))
            channels += msg['channels'] if msg['op'] == 'advertise' else []
        subs = [{'id': k, 'channelId': c['id']} for k, c in enumerate(channels)]
        ws.send(json.dumps({'op': 'subscribe', 'subscriptions': subs}))
        scene = next(k for k, c in enumerate(channels) if c['topic'] == '/swarm/scene')
        while not done.is_set():
            with contextlib.suppress(TimeoutError):
                m = ws.recv(timeout=0.5)
                if (
                    isinstance(m, bytes)
                    and m[0] == 1
                    and int.from_bytes(m[1:5], 'little') == scene
                ):
                    counts['frames'] += 1


def views(bench: Bench, args: argparse.Namespace) -> list[str]:
    """The live view's cost: rounds of no view (the baseline), unwatched, watched."""
    rows: dict[str, list[tuple[Case, dict[str, int]]]] = {v: [] for v in VIEWS}
    for _ in range(args.rounds):
        for v in VIEWS:
            done, counts, clients = threading.Event(), {'frames': 0}, []

            def beside(_: int, out: Path, v: str = v, c: Any = (done, counts), t: Any = clients):
                if v == 'view, watched':
                    t.append(threading.Thread(target=watch, args=(out, *c), daemon=True))
                    t[0].start()

            extra = ('--view', '0') if v != 'no view' else ()
            case = Case(args.sizes[0], duration=args.flight, k='4', extra=extra, label=v)
            rows[v].append((bench.up(case, beside=beside), counts))
            done.set()
            for t in clients:
                t.join(timeout=10)
    med, out = statistics.median, []
    for v, cases in rows.items():
        lat = [c.get('prediction', 'latency', default={}) for c, _ in cases]
        base = [b for b, _ in rows['no view']]
        ratio = med(c.cpu_s[1] / b.cpu_s[1] for (c, _), b in zip(cases, base, strict=True))
        cpu = [f'{med(c.cpu_s[k] for c, _ in cases):.1f}' for k in (0, 1)]
        out.append(f'| {v} | {ms(med(x.get("p50", 0) for x in lat))} / '
                   f'{ms(med(x.get("p99", 0) for x in lat))} | '
                   f'{max(c.get("missed_deadlines", default=-1) for c, _ in cases)} | '
                   f'{cpu[0]} | {cpu[1]} | {ratio:.3f} | {med(f["frames"] for _, f in cases)} |'
                   )  # fmt: skip
    head = '| case | latency p50 / p99 [ms] | missed | bring-up CPU [s] | all CPU [s] | CPU '
    return [head + 'ratio (all) | frames |', '|---|---|---:|---:|---:|---:|---:|', *out]


def secure(bench: Bench, args: argparse.Namespace) -> list[str]:
    """A secure multi-host run (TLS) against an open one (the baseline), 3 simulated hosts."""
    spec = importlib.util.spec_from_file_location('mh', ROOT / 'scripts' / 'multihost.py')
    assert spec is not None and spec.loader is not None
    multihost = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(multihost)
    if (why := multihost.unavailable()) is not None:
        return [f'secure: skipped, simulated hosts unavailable: {why}']
    head = '| run | graph ready [s] | latency p50 / p99 [ms] | CPU host 1 / 2 / 3 [%] | error / '
    out = [head + 'closest pair | missed | rate |', '|---|---:|---|---|---|---:|---:|']
    for mode in args.order.split(','):
        c = bench.up(Case(args.sizes[0], duration=args.flight, k='4', label=mode))
        hosts = json.loads((bench.last / 'multihost.json').read_text())['hosts']
        lat, run = c.get('prediction', 'latency', default={}), c.get('prediction', 'run')
        cpu = [f'{h["cpu_pct"]:.0f}' for h in hosts]
        fly = f'{100 * run["formation_error_rms"]:.2f} / {100 * run["closest_pair"]:.1f} %'
        out.append(f'| {mode} | {c.get("timing", "ready")} | {ms(lat.get("p50"))} / '
                   f'{ms(lat.get("p99"))} | {" / ".join(cpu)} '
                   f'| {fly} ({"flies" if run["flies"] else "no flight"}) '
                   f'| {c.get("missed_deadlines")} '
                   f'| {c.get("timing", "rate")} |')  # fmt: skip
    return out


def discovery(bench: Bench, sizes: list[int]) -> list[str]:
    out = ['| trackers | K | graph ready, fork [s] | exec [s] | exec / fork | RSS, fork [MB] |',
           '|---:|---:|---:|---:|---:|---:|']  # fmt: skip
    for k in ('1', '4'):
        for n in sizes:
            fork, exe = (
                bench.up(Case(n, duration=1.0, k=k, spawn=s, label='discovery'))
                for s in ('fork', 'exec')
            )
            a, b = fork.get('timing', 'ready'), exe.get('timing', 'ready')
            ratio = f'{b / a:.1f}' if a and b else '-'
            out.append(f'| {n} | {k} | {a} | {b} | {ratio} | {fork.rss_mb:.0f} |')
    return out


def lockstep(bench: Bench, quick: bool) -> tuple[list[str], bool]:
    plan = [(3, '1', ()), (3, '3', ()), (3, '1', ('executor:=single',)),
            (3, '1', ('inputs:=odom',)), (10, '1', ())]  # fmt: skip
    plan = plan[:1] if quick is None else plan + ([] if quick else [(30, '1', ()), (30, '5', ())])
    out = ['| trackers | K | node params | steps/s | CPU [%] |', '|---:|---:|---|---:|---:|']
    ok = True
    for n, k, params in plan:
        case = bench.up(Case(n, 'lockstep', duration=2.0, k=k, params=params, label='lockstep'))
        rate = case.get('timing', 'rate')
        out.append(f'| {n} | {k} | {" ".join(params) or "-"} | {rate} | {case.cpu:.0f} |')
        if n == 3 and k == '1' and not params:
            ok = rate is not None and rate >= FLOOR_LOCKSTEP
    return out, ok


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    mode = ap.add_mutually_exclusive_group()
    mode.add_argument('--quick', action='store_true', help='one ladder, fewer cases')
    mode.add_argument('--smoke', action='store_true', help='3 trackers at 50 Hz, seconds')
    ap.add_argument('--only', default=','.join(PARTS[:4]), help=f'comma-separated: {PARTS}')
    ap.add_argument('--rates', type=float, nargs='+', default=[50.0], metavar='HZ')
    ap.add_argument('--sizes', type=int, nargs='+', default=[3, 16, 32, 64, 128], metavar='N')
    ap.add_argument('--ladder', default=DEFAULT_LADDER, metavar='TEXT', help="';' between")
    ap.add_argument('--flight', type=float, default=25.0, metavar='S', help='seconds a case')
    ap.add_argument('--rounds', type=int, default=2, help='view: rounds of the three cases')
    ap.add_argument('--order', default='open,secure', help='secure: the runs, in order')
    ap.add_argument('--keep', type=Path, default=None, metavar='DIR', help='keep the runs')
    args = ap.parse_args(argv)
    parts = [p for p in args.only.split(',') if p]
    if set(parts) - set(PARTS):
        ap.error(f'--only: choose from {PARTS}')
    exit_on_signals()
    if args.smoke:
        args.sizes, args.rates, args.flight, args.rounds = [3], [50.0], 3.0, 1
        parts = parts if '--only' in (argv or sys.argv) else ['ladder']
    bench = Bench(args.keep)
    try:
        return run(bench, parts, args)
    finally:
        if args.keep is None:
            shutil.rmtree(bench.dir, ignore_errors=True)


def run(bench: Bench, parts: list[str], args: argparse.Namespace) -> int:
    ok = True
    print(f'CPU: {psutil.cpu_count()} cores, load {os.getloadavg()[0]:.1f}; runs in {bench.dir}\n')
    if 'ladder' in parts:
        print('\n'.join(ladders(bench, args)) + '\n')
    if 'latency' in parts:
        print('\n'.join(latency(bench, 2.0 if args.smoke else 10.0)) + '\n')
    if 'view' in parts:
        print('\n'.join(views(bench, args)) + '\n')
    if 'secure' in parts:
        print('\n'.join(secure(bench, args)) + '\n')
    if 'discovery' in parts:
        print('\n'.join(discovery(bench, [3, 8] if args.quick else [3, 8, 16, 32])) + '\n')
    if 'lockstep' in parts:
        table, ok = lockstep(bench, None if args.smoke else args.quick)
        print('\n'.join(table) + f'\n\nlockstep floor, 3 trackers: {FLOOR_LOCKSTEP:g} steps/s\n')
    if bench.leftover:
        print(f'{bench.leftover} processes outlived their case (killed)')
    return 1 if bench.leftover or (args.smoke and bench.crashed) or not (ok or args.smoke) else 0


if __name__ == '__main__':
    sys.exit(main())
