#!/usr/bin/env python3
"""Scale benchmark: the swarm as the bring-up starts it, sizes climbed until it stops flying.

Each case: a ``scripts/swarm_up.py`` run, its ``summary.json``, its processes' CPU and RSS.
ladder: per rate and ladder ("EXECUTOR INPUTS K=k|auto depth=d"), n climbs ``--sizes`` until it
does not fly (``flight_check.run.flies``, no missed deadline, 95 % of the states), each size after
the raw ping-pong of its odometry. latency: 3 trackers at 100 Hz (``trigger:=odom``) against the
ping-pong, beside and alone. discovery: forked nodes against executed. lockstep: steps/s, floor
500 for 3 trackers. view: none, unwatched, watched. secure: open against TLS, 3 simulated hosts
(root). Exit 1 on a leftover process, a missed floor, or (``--smoke``) a crash."""

import argparse
import contextlib
import json
import os
import re
import runpy
import statistics
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import psutil
from _children import ROOT, exit_on_signals, log, start, stop, swarm_up, table
from apf_swarm_nodes.bringup import pick_domain_id

VIEWS = ('no view', 'view, no client', 'view, watched')
FLOOR_LOCKSTEP = 500.0  # steps/s, 3 trackers
DEFAULT_LADDER = 'events aggregate K=auto depth=1'


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
        states = self.get('messages', 'received', default=0) >= 0.95 * self.rate * self.duration
        return self.rc == 0 and self.get('missed_deadlines') == 0 and states and bool(
            self.get('flight_check', 'run', 'flies'))  # fmt: skip

    def verdict(self) -> str:
        if not self.summary:
            return f'crashed (exit {self.rc})'
        if self.flies():
            return 'flies'
        run = self.get('flight_check', 'run', default={})
        return (f'does not fly: exit {self.rc}, {self.get("missed_deadlines")} missed, '
                f'{self.get("messages", "received")} states, error '
                f'{100 * run.get("formation_error_rms", float("nan")):.2g} %, closest pair '
                f'{100 * run.get("closest_pair", float("nan")):.0f} %')  # fmt: skip

    def latency(self) -> str:
        return p50_p99(self.get('flight_check', 'latency', default={}))  # of the control loop [ms]


class Bench:
    def __init__(self, runs: Path) -> None:
        self.dir = runs
        self.count = self.leftover = self.crashed = 0  # cases, processes left, cases crashed
        self.missed_floor = False

    def up(self, case: Case, beside: Any = None) -> Case:
        """Run the bring-up for ``case``; ``beside(domain, out)`` runs once it started."""
        self.count += 1
        out = self.last = self.dir / f'{self.count:02d}_{case.mode}_{case.n}'
        domain = pick_domain_id(lo=202, hi=230)
        common = ['--n-trackers', case.n, '--duration', f'{case.duration:g}', '--out', out]
        if case.label in ('open', 'secure'):  # scripts/multihost.py, the probe's rate
            argv = [sys.executable, str(ROOT / 'scripts' / 'multihost.py'), '--hosts', '3',
                    '--mode', 'realtime', *map(str, common)]  # fmt: skip
            argv += ['--open'] if case.label == 'open' else []
        else:
            preset = 'triangle' if case.mode == 'lockstep' else 'realtime'
            argv = swarm_up('--preset', preset, '--mode', case.mode, '--spawn', case.spawn,
                            '--domain-id', domain, *common)  # fmt: skip
            if case.mode == 'realtime':
                argv += ['--set', f'control_rate={case.rate:g}']
        if case.k != 'auto':
            argv += ['--trackers-per-process', case.k]
        argv += case.extra
        argv += [a for p in case.params for a in ('--node-param', p)]
        params = ' '.join(case.params)
        log(f'{case.label or case.mode} n={case.n} K={case.k} {case.spawn} {params}')
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
                    cpu[p.pid] = sum(p.cpu_times()[:2])  # user + system
                    total += p.memory_info().rss
        return total


def ping_pong(domain: int, seconds: float, rate: float = 100.0, n: int = 16) -> dict[str, Any]:
    """The capacity probe's raw rclpy ping-pong of n trackers' odometry [s]."""
    import rclpy
    from apf_swarm_nodes.capacity.measure import ping_pong as measure

    os.environ['ROS_DOMAIN_ID'] = str(domain)
    rclpy.init()
    try:
        return measure(seconds, rate, n)
    finally:
        rclpy.try_shutdown()


def ms(v: float | None) -> str:
    return '-' if v is None else f'{1e3 * v:.2f}'


def p50_p99(lat: dict[str, float]) -> str:
    return f'{ms(lat.get("p50"))} / {ms(lat.get("p99"))}'


def ladders(bench: Bench, args: argparse.Namespace) -> str:
    rows = []
    for rate in args.rates:
        for text in args.ladder.split(';'):
            words = dict(w.split('=', 1) for w in text.split() if '=' in w)
            executor, inputs = [w for w in text.split() if '=' not in w][:2]
            depth = f'qos_depth:={words.get("depth", "1")}'
            params = (f'executor:={executor}', f'inputs:={inputs}', depth)
            for n in args.sizes:  # the raw round trip of n trackers' odometry, then the swarm
                rtt = ping_pong(pick_domain_id(lo=202, hi=230), 5 - 3 * args.smoke, rate, n)['rtt']
                case = bench.up(Case(n, rate=rate, duration=args.flight, params=params,
                                     k=words.get('K', 'auto'), label='ladder'))  # fmt: skip
                k = case.get('flight_check', 'machine', 'trackers_per_process', default=case.k)
                states = f'{case.get("messages", "received")} / {rate * args.flight:.0f}'
                lat = case.get('flight_check', 'latency', default={})
                ratio = ', '.join(f'{lat[q] / rtt[q]:.1f}' for q in ('p50', 'p99')) if lat else '-'
                rows.append([f'{rate:g}', text.strip(), n, k, case.latency(), p50_p99(rtt), ratio,
                             states, f'{case.cpu:.0f}', case.verdict()])  # fmt: skip
                if not case.flies():
                    break
    head = 'rate: | ladder | trackers: | K: | latency p50 / p99 [ms] | ping-pong p50 / p99 [ms] | '
    head += '/ ping-pong p50, p99 | states: | CPU [%]: | result'
    return table(head, rows)


def latency(bench: Bench, args: argparse.Namespace) -> str:
    seconds = 2.0 if args.smoke else 10.0
    alone = ping_pong(pick_domain_id(lo=202, hi=230), seconds)['rtt']
    rows = [['ping-pong alone', '-', p50_p99(alone), '-']]
    for inputs in ('aggregate', 'odom'):
        pp: dict[str, Any] = {}
        case = Case(3, rate=100.0, duration=seconds + 4, k='1', label='latency',
                    params=('trigger:=odom', f'inputs:={inputs}'))  # fmt: skip
        bench.up(case, beside=lambda d, _, pp=pp: pp.update(ping_pong(d, seconds)))
        lat, rtt = case.get('flight_check', 'latency', default={}), pp.get('rtt', {})
        p99 = lat.get('p99')
        ratio = f'{p99 / rtt["p99"]:.2f}, {p99 / alone["p99"]:.2f}' if p99 and rtt else '-'
        rows.append(['control loop', inputs, p50_p99(lat), ratio])
        rows.append(['ping-pong, swarm running', inputs, p50_p99(rtt), '-'])
    return table('path | inputs | p50 / p99 [ms] | p99 / ping-pong p99 (concurrent, alone)', rows)


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
        frame = bytes([1, *scene.to_bytes(4, 'little')])  # message data of that subscription
        while not done.is_set():
            with contextlib.suppress(TimeoutError):
                m = ws.recv(timeout=0.5)
                if isinstance(m, bytes) and m.startswith(frame):
                    counts['frames'] += 1


def views(bench: Bench, args: argparse.Namespace) -> str:
    """The live view's cost: rounds of no view (the baseline), unwatched, watched."""
    runs: dict[str, list[tuple[Case, dict[str, int]]]] = {v: [] for v in VIEWS}
    for _ in range(args.rounds):
        for v in VIEWS:
            done, counts, clients = threading.Event(), {'frames': 0}, []

            def beside(_: int, out: Path, v: str = v, c: Any = (done, counts), t: Any = clients):
                if v == 'view, watched':
                    t.append(threading.Thread(target=watch, args=(out, *c), daemon=True))
                    t[0].start()

            extra = ('--view', '0') if v != 'no view' else ()
            case = Case(args.sizes[0], duration=args.flight, k='4', extra=extra, label=v)
            runs[v].append((bench.up(case, beside=beside), counts))
            done.set()
            for t in clients:
                t.join(timeout=10)
    med, rows = statistics.median, []
    for v, cases in runs.items():
        lat = [c.get('flight_check', 'latency', default={}) for c, _ in cases]
        base = [b for b, _ in runs['no view']]
        ratio = med(c.cpu_s[1] / b.cpu_s[1] for (c, _), b in zip(cases, base, strict=True))
        p50, p99 = (ms(med(x.get(q, 0) for x in lat)) for q in ('p50', 'p99'))
        missed = max(c.get('missed_deadlines', default=-1) for c, _ in cases)
        rows.append([v, f'{p50} / {p99}', missed,
                     *(f'{med(c.cpu_s[k] for c, _ in cases):.1f}' for k in (0, 1)),
                     f'{ratio:.3f}', med(f['frames'] for _, f in cases)])  # fmt: skip
    head = 'case | latency p50 / p99 [ms] | missed: | bring-up CPU [s]: | all CPU [s]: | CPU '
    return table(head + 'ratio (all): | frames:', rows)


def secure(bench: Bench, args: argparse.Namespace) -> str:
    """A secure multi-host run (TLS) against an open one (the baseline), 3 simulated hosts."""
    multihost = runpy.run_path(str(ROOT / 'scripts' / 'multihost.py'))
    if (why := multihost['unavailable']()) is not None:
        return f'secure: skipped, simulated hosts unavailable: {why}'
    rows = []
    for mode in args.order.split(','):
        c = bench.up(Case(args.sizes[0], duration=args.flight, k='4', label=mode))
        hosts = json.loads((bench.last / 'multihost.json').read_text())['hosts']
        run = c.get('flight_check', 'run')
        fly = f'{100 * run["formation_error_rms"]:.2f} / {100 * run["closest_pair"]:.1f} %'
        rows.append([mode, c.get('timing', 'ready'), c.latency(),
                     ' / '.join(f'{h["cpu_pct"]:.0f}' for h in hosts),
                     f'{fly} ({"flies" if run["flies"] else "no flight"})',
                     c.get('missed_deadlines'), c.get('timing', 'rate')])  # fmt: skip
    head = 'run | graph ready [s]: | latency p50 / p99 [ms] | CPU host 1 / 2 / 3 [%] | error / '
    return table(head + 'closest pair | missed: | rate:', rows)


def discovery(bench: Bench, args: argparse.Namespace) -> str:
    rows = []
    for k in ('1', '4'):
        for n in [3, 8] if args.quick else [3, 8, 16, 32]:
            fork, exe = (bench.up(Case(n, duration=1.0, k=k, spawn=s, label='discovery'))
                         for s in ('fork', 'exec'))  # fmt: skip
            a, b = fork.get('timing', 'ready'), exe.get('timing', 'ready')
            rows.append([n, k, a, b, f'{b / a:.1f}' if a and b else '-', f'{fork.rss_mb:.0f}'])
    head = 'trackers: | K: | graph ready, fork [s]: | exec [s]: | exec / fork: | RSS, fork [MB]:'
    return table(head, rows)


def lockstep(bench: Bench, args: argparse.Namespace) -> str:
    plan = [(3, '1', ()), (3, '3', ()), (3, '1', ('executor:=single',)),
            (3, '1', ('inputs:=odom',)), (10, '1', ()), (30, '1', ()), (30, '5', ())]  # fmt: skip
    plan = plan[:1] if args.smoke else plan[:5] if args.quick else plan
    rows = []
    for n, k, params in plan:
        case = bench.up(Case(n, 'lockstep', duration=2.0, k=k, params=params, label='lockstep'))
        rate = case.get('timing', 'rate')
        rows.append([n, k, ' '.join(params) or '-', rate, f'{case.cpu:.0f}'])
        if n == 3 and k == '1' and not params:
            bench.missed_floor = rate is None or rate < FLOOR_LOCKSTEP
    floor = f'\n\nlockstep floor, 3 trackers: {FLOOR_LOCKSTEP:g} steps/s'
    return table('trackers: | K: | node params | steps/s: | CPU [%]:', rows) + floor


#: the parts, in the order they run
PARTS = {'ladder': ladders, 'latency': latency, 'view': views, 'secure': secure,
         'discovery': discovery, 'lockstep': lockstep}  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    mode = ap.add_mutually_exclusive_group()
    mode.add_argument('--quick', action='store_true', help='one ladder, fewer cases')
    mode.add_argument('--smoke', action='store_true',
                      help='3 trackers at 50 Hz, seconds (ladder, view, secure)')  # fmt: skip
    ap.add_argument('--only', default='ladder,latency,discovery,lockstep',
                    help=f'comma-separated: {", ".join(PARTS)}')  # fmt: skip
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
        ap.error(f'--only: choose from {", ".join(PARTS)}')
    exit_on_signals()
    if args.smoke:
        args.sizes, args.rates, args.flight, args.rounds = [3], [50.0], 3.0, 1
        parts = parts if '--only' in (argv or sys.argv) else ['ladder', 'view', 'secure']
    with tempfile.TemporaryDirectory(prefix='bench_scale_', ignore_cleanup_errors=True) as tmp:
        bench = Bench(args.keep or Path(tmp))
        print(f'CPU: {psutil.cpu_count()} cores, load {os.getloadavg()[0]:.1f}', end='')
        print(f'; runs in {bench.dir}\n')
        for name, part in PARTS.items():
            if name in parts:
                print(part(bench, args) + '\n')
    if bench.leftover:
        print(f'{bench.leftover} processes outlived their case (killed)')
    failed = bench.leftover or (args.smoke and bench.crashed)
    return 1 if failed or (bench.missed_floor and not args.smoke) else 0


if __name__ == '__main__':
    sys.exit(main())
