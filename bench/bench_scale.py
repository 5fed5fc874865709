#!/usr/bin/env python3
"""Scale benchmark (issue 7): how many trackers this machine flies, per rate, executor, inputs
and hosting mode; latency per topology against a raw ping-pong; discovery time; RSS; CPU.

    source scripts/activate.sh
    python bench/bench_scale.py [--quick] [--only ladder,latency,discovery,lockstep] [--keep DIR]

Every swarm case runs the bring-up (``scripts/swarm_up.py``) as a user would, one case at a
time, each in its own ``ROS_DOMAIN_ID`` (202..230) with ``ROS_AUTOMATIC_DISCOVERY_RANGE=
LOCALHOST``, reads its ``summary.json`` and samples the case's processes from ``/proc`` every
0.25 s (node processes found by the run's config path in their command line). Parts:

* **ladder**: realtime at 50 and 100 Hz (``--set control_rate=HZ``: the plant's publish rate
  and the trackers' watchdog; the bring-up schedules the gains for n and rate),
  executor ``single`` / ``events`` x inputs ``aggregate`` / ``odom`` with one tracker per
  process (``K = 1``), and for events / aggregate also ``K = 4`` (``--trackers-per-process
  4``) and the control topics' QoS depth 10 instead of 1 (``qos_depth:=10``); n
  climbs 4, 8, ..., 24, 32, 40 and stops at the first size that does not fly. "Flies": exit 0, no
  missed deadline (trackers the plant found silent), at most 3 stale (brake) commands per
  tracker (the watchdogs' brakes before a tracker's first input), at least 95 % of the
  expected ``/swarm/state`` samples, and the formation held (``apf_swarm_core.metrics.
  flight`` over the last 40 %: formation error RMS <= 3 % of the mean design spacing,
  closest pair >= 90 % of the design's, converged), shown next to the headless emulation at
  the same rate with the run's measured latencies. ``multi`` (MultiThreadedExecutor, documented as
  pathological) once: n = 4, 50 Hz.
* **latency**: bench_graph's control-loop latency (events executor, 3 trackers, 100 Hz,
  ``trigger:=odom``) for inputs aggregate and odom, each with bench_graph's raw rclpy
  ping-pong running in the same graph at the same time, and the ping-pong once alone.
* **discovery**: the bring-up's "graph ready" time (``timing.ready``: process start to every
  node seen and every subscription matched) against n, K = 1 and 4, realtime 50 Hz events /
  aggregate, with the node processes forked from the bring-up's zygote (``--spawn fork``, the
  default) and, the baseline of the same run, executed (``--spawn exec``); a ladder case of
  that configuration is reused, else a 1 s flight is run. The zygote's CPU counts as the
  nodes'.
* **lockstep** steps/s (``triangle``, dt = 1 ms) for 3 (K = 1 and 3), 10 and 30 (K = 1, 5)
  trackers.
* **RSS per tracker** per hosting mode: the tracker processes' RSS (max sampled) summed and
  divided by n, over every case with that K.

CPU per case (percent of one core; the machine has ``nproc`` x 100): utime + stime of the
node processes over the flight (from the sample after the bring-up's "published
/swarm/start" to the last sample inside the flight with every node alive), of the harness
(the bring-up and this process), and "other": the machine's busy time (``/proc/stat``) over the
same window minus both, i.e. whatever else ran. Discovery rows give the same split over the
start-up (launch to graph ready).

Prints progress on stderr and Markdown tables on stdout. Numbers to compare within one run,
not timed assertions. Exit 1 when a process of a case was left behind (checked by PID at the
end; they are killed), or with ``--smoke`` when its case crashed (no summary), else 0.
"""

from __future__ import annotations

import argparse
import contextlib
import itertools
import json
import math
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from collections import deque
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import psutil

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_graph  # noqa: E402
from _children import dying_with_parent, exit_on_signals  # noqa: E402
from apf_swarm_nodes.bringup import pick_domain_id  # noqa: E402
from apf_swarm_nodes.capacity.machine import machine_busy_seconds, process_cpu_seconds  # noqa: E402
from bench_graph import Case, machine, rss_mb, run_pingpong  # noqa: E402
from soak import node_pids  # noqa: E402  (the same /proc lookup)

DOMAIN_LO, DOMAIN_HI = 202, 230
POLL = 0.25  # s between /proc samples of a case
READY_TIMEOUT = 90.0  # --ready-timeout of every bring-up (32 processes on 2 cores)
READY_LINE = 'published /swarm/start'
STALE_PER_TRACKER = 3
MIN_SAMPLES = 0.95
LADDER = (4, 8, 16, 24, 32, 48, 64, 96, 128)
DISCOVERY_RATE = 50.0
DISCOVERY_FLIGHT = 1.0
PARTS = ('ladder', 'latency', 'discovery', 'lockstep')


def log(msg: str) -> None:
    print(f'bench_scale: {msg}', file=sys.stderr, flush=True)


# --------------------------------------------------------------------------------------------
# one bring-up case
# --------------------------------------------------------------------------------------------


@dataclass
class UpCase:
    """One run of the bring-up; ``flight``: wall seconds (realtime) or simulated (lockstep)."""

    mode: str
    n: int
    k: int = 1
    flight: float = 6.0
    rate: float = 50.0
    executor: str = 'events'
    inputs: str = 'aggregate'
    part: str = 'ladder'
    depth: int = 1  # realtime qos_depth of the control topics
    spawn: str = 'fork'  # the bring-up's --spawn: forked from its zygote, or executed
    result: dict[str, Any] = field(default_factory=dict)

    @property
    def label(self) -> str:
        if self.mode == 'lockstep':
            return f'lockstep n={self.n} K={self.k} ({self.flight:g} s simulated)'
        return (
            f'realtime {self.rate:g} Hz n={self.n} K={self.k} executor={self.executor} '
            f'inputs={self.inputs} depth={self.depth} spawn={self.spawn} ({self.flight:g} s)'
        )

    @property
    def slug(self) -> str:
        return (
            f'{self.part}_{self.mode}_{self.rate:g}hz_{self.executor}_{self.inputs}'
            f'_d{self.depth}_n{self.n}_k{self.k}_{self.spawn}'
        )

    @property
    def processes(self) -> int:
        """Node processes: target, plant and ceil(n / K) tracker processes."""
        return 2 + -(-self.n // self.k)

    @property
    def key(self) -> tuple[float, str, str, int, int]:
        return (self.rate, self.executor, self.inputs, self.k, self.depth)


def bringup_argv(case: UpCase, out: Path, domain: int) -> list[str]:
    preset = 'realtime' if case.mode == 'realtime' else 'triangle'
    cmd = [
        sys.executable,
        str(ROOT / 'scripts' / 'swarm_up.py'),
        '--preset',
        preset,
        '--mode',
        case.mode,
        '--n-trackers',
        str(case.n),
        '--trackers-per-process',
        str(case.k),
        '--duration',
        str(case.flight),
        '--domain-id',
        str(domain),
        '--out',
        str(out),
        '--no-plots',
        '--allow-overload',
        '--ready-timeout',
        str(READY_TIMEOUT),
        '--spawn',
        case.spawn,
    ]
    params = [f'executor:={case.executor}', f'inputs:={case.inputs}', f'qos_depth:={case.depth}']
    if case.mode == 'realtime':
        cmd += ['--set', f'control_rate={float(case.rate)!r}']
    for p in params:
        cmd += ['--node-param', p]
    return cmd


def case_timeout(case: UpCase) -> float:
    """Wall seconds after which a bring-up is stopped: start-up, flight, stall, shutdown."""
    flight = case.flight if case.mode == 'realtime' else 150.0
    return READY_TIMEOUT + flight + 60.0


@dataclass
class Snapshot:
    t: float
    busy: float  # machine busy CPU time [s]
    ticks: dict[int, float]  # pid -> user + system CPU time [s]
    alive: set[int]  # node pids with a resident set (not gone)


class CaseSampler:
    """CPU and memory of one case: its node processes, the harness (bring-up, this process)."""

    def __init__(self, config: str, bringup_pid: int, expected: int) -> None:
        self.config, self.expected = config, expected
        self.harness = [bringup_pid, os.getpid()]
        self.bringup_pid = bringup_pid
        self.zygote: list[int] = []  # the bring-up's zygote: node start-up work, counted as nodes
        self.names: dict[int, str] = {}
        self.rss: dict[int, float] = {}
        self.start = self.snapshot()
        self.ready: Snapshot | None = None
        self.last: Snapshot | None = None  # last sample inside the flight window

    def snapshot(self) -> Snapshot:
        if len(self.names) < self.expected:
            self.names.update(node_pids(self.config))
        if not self.zygote:
            self.zygote = zygote_pids(self.bringup_pid)
        ticks: dict[int, float] = {}
        alive: set[int] = set()
        for pid in [*self.names, *self.harness, *self.zygote]:
            t = process_cpu_seconds(pid)
            if t is not None:
                ticks[pid] = t
            if pid in self.names:
                r = rss_mb(pid)
                if r is not None:
                    alive.add(pid)
                    self.rss[pid] = max(self.rss.get(pid, 0.0), r)
        return Snapshot(time.monotonic(), machine_busy_seconds(), ticks, alive)

    def sample(self, ready_seen: bool, flight_limit: float | None) -> None:
        """One sample; ``ready_seen``: the bring-up has published /swarm/start; a sample counts
        as flight end while every node is alive and (realtime) within ``flight_limit`` s."""
        s = self.snapshot()
        if self.ready is None:
            if ready_seen:
                self.ready = self.last = s
            return
        if not set(self.ready.alive) <= s.alive:
            return
        if flight_limit is not None and s.t > self.ready.t + flight_limit:
            return
        self.last = s

    def window(self, a: Snapshot | None, b: Snapshot | None) -> dict[str, float] | None:
        """CPU % of one core of the nodes, the harness and the rest of the machine, a -> b."""
        if a is None or b is None or b.t - a.t < 0.2:
            return None
        dt = b.t - a.t

        def pct(ticks: float) -> float:
            return 100.0 * ticks / dt

        nodes = [p for p in [*self.names, *self.zygote] if p in b.ticks]
        node = pct(sum(b.ticks[p] - a.ticks.get(p, 0) for p in nodes))
        harness = pct(sum(b.ticks[p] - a.ticks.get(p, 0) for p in self.harness if p in b.ticks))
        total = pct(b.busy - a.busy)
        return {
            'nodes': node,
            'harness': harness,
            'other': max(0.0, total - node - harness),
            'seconds': dt,
        }

    def flight_cpu(self) -> dict[str, float] | None:
        return self.window(self.ready, self.last)

    def startup_cpu(self) -> dict[str, float] | None:
        return self.window(self.start, self.ready)

    def rss_by_role(self) -> tuple[list[float], float | None]:
        """(RSS of each tracker process, plant RSS) in MB."""
        trackers = [v for p, v in self.rss.items() if self.names[p].startswith('tracker')]
        plant = [v for p, v in self.rss.items() if self.names[p].startswith('plant')]
        return trackers, (max(plant) if plant else None)


def zygote_pids(parent: int) -> list[int]:
    """The bring-up's zygote (``--spawn fork``), a child of ``parent``; [] before it starts."""
    try:
        children = psutil.Process(parent).children()
    except psutil.Error:
        return []
    out = []
    for c in children:
        with contextlib.suppress(psutil.Error):
            if any('bringup.zygote' in a for a in c.cmdline()):
                out.append(c.pid)
    return out


class LogWatcher:
    """Reads a growing log file incrementally and remembers whether a line was seen."""

    def __init__(self, path: Path, needle: str) -> None:
        self.path, self.needle = path, needle.encode()
        self.offset, self.buf, self.seen = 0, b'', False

    def poll(self) -> bool:
        if self.seen:
            return True
        try:
            with open(self.path, 'rb') as f:
                f.seek(self.offset)
                data = f.read()
        except OSError:
            return False
        self.offset += len(data)
        self.buf = (self.buf + data)[-4096:]
        self.seen = self.needle in self.buf
        return self.seen


def stop_bringup(p: subprocess.Popen[bytes]) -> str:
    """Stop a bring-up that overran its time: SIGINT (it stops its nodes), SIGTERM, SIGKILL."""
    for sig, wait in ((signal.SIGINT, 30.0), (signal.SIGTERM, 15.0), (signal.SIGKILL, 5.0)):
        p.send_signal(sig)
        try:
            p.wait(timeout=wait)
            return sig.name
        except subprocess.TimeoutExpired:
            continue
    return 'not stopped'


def last_line(path: Path) -> str:
    try:
        lines = [ln for ln in path.read_text(errors='replace').splitlines() if ln.strip()]
    except OSError:
        return 'no log'
    return lines[-1].strip() if lines else 'no output'


def failure_reasons(case: UpCase, r: dict[str, Any]) -> list[str]:
    """Why a realtime case does not fly (empty when it flies)."""
    why = []
    if r['exit'] != 0:
        why.append(f'exit {r["exit"]} ({r.get("status", "?")})')
    if 'missed' not in r:
        return why or ['no summary.json']
    if r['missed'] > 0:
        why.append(f'{r["missed"]} missed')
    if r['stale'] > STALE_PER_TRACKER * case.n:
        why.append(f'{r["stale"]} stale')
    if r['received'] < MIN_SAMPLES * r['expected']:
        why.append(f'{r["received"]}/{r["expected"]:.0f} samples')
    run = (r.get('prediction') or {}).get('run') or {}
    if not run.get('flies'):
        why.append(
            'formation lost'
            if run.get('formation_error_rms') is not None
            else 'no flight judgement'
        )
    return why


def summarize(
    case: UpCase, rc: int, summary: dict[str, Any] | None, sampler: CaseSampler
) -> dict[str, Any]:
    trackers, plant = sampler.rss_by_role()
    res: dict[str, Any] = {
        'exit': rc,
        'cpu': sampler.flight_cpu(),
        'cpu_startup': sampler.startup_cpu(),
        'rss_plant': plant,
        'rss_per_tracker': sum(trackers) / case.n if trackers else None,
        'rss_tracker_process': statistics.fmean(trackers) if trackers else None,
    }
    if summary is not None:
        res.update(
            {
                'status': summary.get('status'),
                'missed': summary['missed_deadlines'],
                'stale': summary['stale_inputs'],
                'received': summary['messages']['received'],
                'ready_s': summary['timing']['ready'],
                'rate': summary['timing']['rate'],
                'prediction': {
                    k: v
                    for k, v in (summary.get('prediction') or {}).items()
                    if k != 'latency_samples'
                },
            }
        )
    if case.mode == 'realtime':
        res['expected'] = case.flight * case.rate
        res['why'] = failure_reasons(case, res)
        res['flies'] = not res['why']
    return res


# --------------------------------------------------------------------------------------------
# the bench: domains, cases, leftovers
# --------------------------------------------------------------------------------------------


class Bench:
    def __init__(self, work: Path) -> None:
        self.work = work
        self.t0 = time.monotonic()
        self.recent: deque[int] = deque(maxlen=10)  # domains not reused right away
        self.configs: list[str] = []
        self.graph_left: list[tuple[str, int]] = []
        self.count = 0

    def elapsed(self) -> str:
        return f'{time.monotonic() - self.t0:.0f} s'

    def domain(self) -> int:
        d = pick_domain_id(exclude=self.recent, lo=DOMAIN_LO, hi=DOMAIN_HI)
        self.recent.append(d)
        return d

    def up(self, case: UpCase) -> UpCase:
        """Run one bring-up case and fill ``case.result``."""
        self.count += 1
        log(f'[{self.count}] {case.label} ({self.elapsed()} elapsed)')
        out = self.work / case.slug
        log_path = self.work / f'{case.slug}.log'
        config = str(out / 'config.yaml')
        self.configs.append(config)
        env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
        env.pop('ROS_LOCALHOST_ONLY', None)
        with open(log_path, 'wb') as f:
            p = subprocess.Popen(
                dying_with_parent(bringup_argv(case, out, self.domain())),
                stdin=subprocess.DEVNULL,
                stdout=f,
                stderr=subprocess.STDOUT,
                env=env,
                cwd=ROOT,
            )
        sampler = CaseSampler(config, p.pid, case.processes)
        ready = LogWatcher(log_path, READY_LINE)
        limit = case.flight - POLL if case.mode == 'realtime' else None
        deadline = time.monotonic() + case_timeout(case)
        rc: int | None = None
        while rc is None:
            try:
                rc = p.wait(timeout=POLL)
            except subprocess.TimeoutExpired:
                sampler.sample(ready.poll(), limit)
                if time.monotonic() > deadline:
                    log(f'  overran {case_timeout(case):.0f} s: stopped with {stop_bringup(p)}')
                    rc = p.returncode if p.returncode is not None else -9
        try:
            summary = json.loads((out / 'summary.json').read_text())
        except (OSError, ValueError):
            summary = None
        case.result = summarize(case, rc, summary, sampler)
        if summary is None:
            case.result['error'] = last_line(log_path)
        log('  ' + short(case))
        return case

    def graph_case(self, case: Case) -> Case:
        """A bench_graph case (its own processes and in-process observer)."""
        self.count += 1
        log(f'[{self.count}] bench_graph {case.label} ({self.elapsed()} elapsed)')
        used = set(self.recent)
        before = set(used)
        self.graph_left += bench_graph.run_case(case, used)
        self.recent.extend(sorted(used - before))
        r = case.result
        if 'error' not in r:
            log(
                f'  p50 {r["p50"]:.2f} / p99 {r["p99"]:.2f} ms ({r["samples"]} commands)'
                + (
                    f'; ping-pong p50 {r["ping"]["p50"]:.2f} / p99 {r["ping"]["p99"]:.2f} ms'
                    if 'ping' in r
                    else ''
                )
            )
        return case

    def pingpong(self, seconds: float) -> dict[str, Any] | None:
        self.count += 1
        log(
            f'[{self.count}] raw ping-pong alone, 100 Hz, {seconds:g} s ({self.elapsed()} elapsed)'
        )
        with tempfile.TemporaryDirectory(prefix='bench_scale_', dir=self.work) as tmp:
            try:
                res = run_pingpong(Path(tmp), self.domain(), seconds)
            except RuntimeError as exc:
                log(f'  FAILED: {exc}')
                return None
        self.graph_left += res.get('left', [])
        log(f'  round trip p50 {res["p50"]:.2f} / p99 {res["p99"]:.2f} ms')
        return res

    def leftovers(self) -> list[tuple[str, int]]:
        """Live processes of any case (by the config path in their command line, and
        bench_graph's own check); each one found is killed by PID."""
        left = list(self.graph_left)
        for config in self.configs:
            left += [(name, pid) for pid, name in node_pids(config).items()]
        for name, pid in left:
            log(f'ERROR: left behind: {name} pid {pid}; killing it')
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
        return left


def short(case: UpCase) -> str:
    r = case.result
    if 'missed' not in r:
        return f'failed: exit {r["exit"]}: {r.get("error", "")}'
    text = (
        f'exit {r["exit"]}, missed {r["missed"]}, stale {r["stale"]}, received '
        f'{r["received"]}, ready {r["ready_s"]} s, {cpu_cell(r["cpu"])} % CPU '
        '(nodes / harness / other)'
    )
    if case.mode == 'realtime':
        text += f' -> {"flies" if r["flies"] else "does not fly: " + ", ".join(r["why"])}'
    else:
        text += f', {r["rate"]} steps/s'
    return text


# --------------------------------------------------------------------------------------------
# the parts
# --------------------------------------------------------------------------------------------


def run_ladder(
    bench: Bench,
    rate: float,
    executor: str,
    inputs: str,
    k: int,
    depth: int,
    sizes: Iterable[int],
    flight: float,
    climb: bool = True,
) -> list[UpCase]:
    """Climb n until the first size that does not fly (``climb``; else every size);
    ``k`` = 0: the bring-up's default trackers per process for each n
    (:func:`apf_swarm_nodes.capacity.probe.trackers_per_process`)."""
    from apf_swarm_nodes.capacity import probe

    cases = []
    for n in sizes:
        kn = k or probe.trackers_per_process(probe.load(), n, rate)
        c = bench.up(UpCase('realtime', n, kn, flight, rate, executor, inputs, depth=depth))
        cases.append(c)
        if climb and not c.result.get('flies'):
            break
    return cases


def ladder_plan(quick: bool, rates: list[float]) -> list[tuple[float, str, str, int, int]]:
    """(rate, executor, inputs, K, QoS depth) of every ladder."""
    if quick:
        return [(rates[0], 'events', 'aggregate', k, 1) for k in (1, 0)]
    plan = []
    for rate in rates:
        for executor in ('single', 'events'):
            for inputs in ('aggregate', 'odom'):
                plan.append((rate, executor, inputs, 1, 1))
        plan.append((rate, 'events', 'aggregate', 1, 10))
        plan.append((rate, 'events', 'aggregate', 4, 1))
        plan.append((rate, 'events', 'aggregate', 0, 1))  # K: the bring-up's default
    return plan


def run_discovery(
    bench: Bench, done: list[UpCase], sizes: Iterable[int]
) -> list[tuple[UpCase, str]]:
    """(case, source) per (n, K, spawn): for fork, a ladder case of the discovery
    configuration when there is one, else a short flight of its own; exec (each node process
    runs its executable) always a flight of its own, the baseline of the same run."""
    rows = []
    for k, n, spawn in itertools.product((1, 4), sizes, ('fork', 'exec')):
        found = [
            c
            for c in done
            if c.mode == 'realtime'
            and c.n == n
            and c.k == k
            and c.spawn == spawn
            and c.key == (DISCOVERY_RATE, 'events', 'aggregate', k, 1)
            and c.result.get('ready_s') is not None
        ]
        if found:
            rows.append((found[0], 'ladder case'))
            continue
        case = UpCase(
            'realtime', n, k, DISCOVERY_FLIGHT, DISCOVERY_RATE, part='discovery', spawn=spawn
        )
        rows.append((bench.up(case), f'{DISCOVERY_FLIGHT:g} s flight'))
    return rows


def run_latency(bench: Bench, seconds: float) -> tuple[list[Case], dict[str, Any] | None]:
    cases = [
        bench.graph_case(Case('latency', 3, 'events', inputs, seconds=seconds, pingpong=True))
        for inputs in ('aggregate', 'odom')
    ]
    return cases, bench.pingpong(seconds)


def run_lockstep(bench: Bench, quick: bool) -> list[UpCase]:
    plan = [(3, 1), (3, 3), (10, 1)] + ([] if quick else [(30, 1), (30, 5)])
    return [
        bench.up(UpCase('lockstep', n, k, 2.0 if n <= 10 else 1.0, part='lockstep'))
        for n, k in plan
    ]


# --------------------------------------------------------------------------------------------
# tables
# --------------------------------------------------------------------------------------------


def f1(v: float | None, spec: str = '.1f') -> str:
    return '-' if v is None or math.isnan(v) else format(v, spec)


def cpu_cell(cpu: dict[str, float] | None) -> str:
    if not cpu:
        return '-'
    return f'{cpu["nodes"]:.0f} / {cpu["harness"]:.0f} / {cpu["other"]:.0f}'


def ladder_summary(ladders: list[list[UpCase]], multi: UpCase | None) -> list[str]:
    out = [
        (
            '| rate [Hz] | executor | inputs | QoS depth | trackers per process | largest '
            'flying / first failing | why the first failing size fails | sizes tried |'
        ),
        '|---:|---|---|---:|---:|---|---|---|',
    ]
    for cases in ladders:
        c0 = cases[0]
        flying = [c.n for c in cases if c.result.get('flies')]
        failing = [c for c in cases if not c.result.get('flies')]
        top = str(max(flying)) if flying else 'none'
        first = f'{failing[0].n}' if failing else f'none up to {cases[-1].n}'
        why = ', '.join(failing[0].result.get('why', [])) if failing else '-'
        out.append(
            f'| {c0.rate:g} | {c0.executor} | {c0.inputs} | {c0.depth} | {c0.k} | '
            f'{top} / {first} | '
            f'{why} | {", ".join(str(c.n) for c in cases)} |'
        )
    if multi is not None:
        r = multi.result
        verdict = 'flies' if r.get('flies') else 'does not fly'
        out.append(
            f'| {multi.rate:g} | multi | {multi.inputs} | {multi.depth} | {multi.k} | '
            f'n = {multi.n} '
            f'only: {verdict} | {", ".join(r.get("why", [])) or "-"} | {multi.n} |'
        )
    return out


def flight_cell(f: dict[str, Any] | None) -> str:
    """``2.1 % / 95 %``: formation error RMS and closest pair of a flight judgement."""
    if not f or f.get('formation_error_rms') is None:
        return '-'
    return f'{100 * f["formation_error_rms"]:.1f} % / {100 * f["closest_pair"]:.0f} %'


def realtime_rows(cases: list[UpCase], ping: dict[str, Any] | None = None) -> list[str]:
    """One row per case; with ``ping`` (the raw ping-pong alone in the same run) the control
    latency's p50 and p99 against the round trip's."""
    out = [
        (
            '| rate [Hz] | executor | inputs | depth | K | trackers | flies | exit | missed | '
            'stale | samples / expected | formation err / closest pair (run; headless) | '
            'latency p50 / p99 [ms] | latency / ping-pong p50, p99 | graph ready [s] | '
            'CPU nodes / harness / other [%] | RSS per tracker [MB] | plant RSS [MB] |'
        ),
        '|---:|---|---|---:|---:|---:|---|---:|---:|---:|---:|---|---:|---:|---:|---|---:|---:|',
    ]
    for c in cases:
        r = c.result
        head = f'| {c.rate:g} | {c.executor} | {c.inputs} | {c.depth} | {c.k} | {c.n} |'
        if 'missed' not in r:
            out.append(f'{head} no | {r["exit"]} | failed: {r.get("error", "")} | | | | | | |')
            continue
        pr = r.get('prediction') or {}
        lat = pr.get('latency') or {}
        out.append(
            f'{head} {"yes" if r["flies"] else "no"} | {r["exit"]} | {r["missed"]} | '
            f'{r["stale"]} | {r["received"]} / {r["expected"]:.0f} | '
            f'{flight_cell(pr.get("run"))}; {flight_cell(pr.get("emulation"))} | '
            f'{f1(1e3 * lat["p50"]) if lat else "-"} / '
            f'{f1(1e3 * lat["p99"]) if lat else "-"} | '
            f'{ratio_cell(lat, ping)} | '
            f'{f1(r["ready_s"])} | {cpu_cell(r["cpu"])} | '
            f'{f1(r["rss_per_tracker"])} | {f1(r["rss_plant"], ".0f")} |'
        )
    return out


def ratio_cell(lat: dict[str, float] | None, ping: dict[str, Any] | None) -> str:
    """``12x, 9x``: the control latency's p50 and p99 [s] over the ping-pong's [ms]."""
    if not lat or not ping:
        return '-'
    return f'{1e3 * lat["p50"] / ping["p50"]:.0f}x, {1e3 * lat["p99"] / ping["p99"]:.0f}x'


def latency_rows(cases: list[Case], alone: dict[str, Any] | None) -> list[str]:
    out = [
        (
            '| inputs | executor | commands | control loop p50 / p99 [ms] | ping-pong in the '
            'same graph p50 / p99 [ms] | p50 ratio | p99 ratio | p99 ratio against the '
            'ping-pong alone | CPU total / other [%] |'
        ),
        '|---|---|---:|---|---|---:|---:|---:|---|',
    ]
    a99 = alone['p99'] if alone else float('nan')
    for c in cases:
        r = c.result
        if 'error' in r:
            out.append(f'| {c.inputs} | {c.executor} | failed: {r["error"]} | | | | | | |')
            continue
        pp = r.get('ping', {})
        p50, p99 = pp.get('p50', float('nan')), pp.get('p99', float('nan'))
        out.append(
            f'| {c.inputs} | {c.executor} | {r["samples"]} | {r["p50"]:.2f} / '
            f'{r["p99"]:.2f} | {f1(p50, ".2f")} / {f1(p99, ".2f")} | '
            f'{f1(r["p50"] / p50, ".2f")} | {f1(r["p99"] / p99, ".2f")} | '
            f'{f1(r["p99"] / a99, ".2f")} | {r["total_cpu"]:.0f} / '
            f'{f1(r["other_cpu"], ".0f")} |'
        )
    if alone:
        out.append(
            f'| (ping-pong alone) | single | {alone["samples"]} | - | {alone["p50"]:.2f} '
            f'/ {alone["p99"]:.2f} | - | - | - | {alone["total_cpu"]:.0f} / '
            f'{f1(alone["other_cpu"], ".0f")} |'
        )
    return out


def discovery_rows(rows: list[tuple[UpCase, str]]) -> list[str]:
    """One row per (n, K): graph ready with the node processes forked from the bring-up's
    zygote and executed, their ratio, and the start-up CPU split of each."""
    out = [
        (
            '| trackers | per process | node processes | graph ready, fork [s] | '
            'graph ready, exec [s] | exec / fork | start-up CPU nodes / harness / other [%], '
            'fork; exec | from |'
        ),
        '|---:|---:|---:|---:|---:|---:|---|---|',
    ]
    by_size: dict[tuple[int, int], dict[str, tuple[UpCase, str]]] = {}
    for c, src in rows:
        by_size.setdefault((c.n, c.k), {})[c.spawn] = (c, src)
    for (n, k), pair in sorted(by_size.items()):
        ready: dict[str, float | None] = {}
        cells, cpus, srcs = [], [], []
        for spawn in ('fork', 'exec'):
            if spawn not in pair:
                ready[spawn] = None
                cells.append('-')
                continue
            c, src = pair[spawn]
            r = c.result
            ready[spawn] = r.get('ready_s') if 'missed' in r else None
            cells.append(
                f1(r.get('ready_s')) if 'missed' in r else f'failed: {r.get("error", "")}'
            )
            cpus.append(cpu_cell(r.get('cpu_startup')))
            srcs.append(src)
        fork, exe = ready['fork'], ready['exec']
        ratio = f'{exe / fork:.1f}' if fork and exe else ''
        procs = 2 + -(-n // k)
        out.append(
            f'| {n} | {k} | {procs} | {cells[0]} | {cells[1]} | {ratio} | '
            f'{"; ".join(cpus)} | {"; ".join(sorted(set(srcs)))} |'
        )
    return out


def lockstep_rows(cases: list[UpCase]) -> list[str]:
    out = [
        (
            '| trackers | per process | steps/s | exit | missed | graph ready [s] | CPU nodes / '
            'harness / other [%] | RSS per tracker [MB] |'
        ),
        '|---:|---:|---:|---:|---:|---:|---|---:|',
    ]
    for c in cases:
        r = c.result
        if 'missed' not in r:
            out.append(f'| {c.n} | {c.k} | failed: {r.get("error", "")} | {r["exit"]} | | | | |')
            continue
        out.append(
            f'| {c.n} | {c.k} | {f1(r["rate"], ".0f")} | {r["exit"]} | {r["missed"]} | '
            f'{f1(r["ready_s"])} | {cpu_cell(r["cpu"])} | {f1(r["rss_per_tracker"])} |'
        )
    return out


def rss_rows(cases: list[UpCase]) -> list[str]:
    out = [
        (
            '| trackers per process | cases | trackers | RSS per tracker [MB] mean (min-max) | '
            'tracker process RSS [MB] mean | plant RSS [MB] min-max |'
        ),
        '|---:|---:|---|---|---:|---|',
    ]

    def span(vals: list[float], spec: str = '.1f') -> str:
        return f'{min(vals):{spec}}-{max(vals):{spec}}'

    for k in sorted({c.k for c in cases}):
        own = [c for c in cases if c.k == k and c.result.get('rss_per_tracker') is not None]
        if not own:
            continue
        per = [c.result['rss_per_tracker'] for c in own]
        proc = [c.result['rss_tracker_process'] for c in own]
        plant = [c.result['rss_plant'] for c in own if c.result['rss_plant'] is not None]
        ns = sorted({c.n for c in own})
        out.append(
            f'| {k} | {len(own)} | {ns[0]}-{ns[-1]} | {statistics.fmean(per):.1f} '
            f'({span(per)}) | {statistics.fmean(proc):.1f} | '
            f'{span(plant, ".0f") if plant else "-"} |'
        )
    return out


# --------------------------------------------------------------------------------------------
# driver
# --------------------------------------------------------------------------------------------


def parse_parts(text: str) -> list[str]:
    parts = [p.strip() for p in text.split(',') if p.strip()]
    bad = [p for p in parts if p not in PARTS]
    if bad:
        raise argparse.ArgumentTypeError(f'unknown part(s) {bad}; choose from {PARTS}')
    return parts


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument(
        '--quick',
        action='store_true',
        help='50 Hz, events / aggregate only, n in (8, 16), short windows',
    )
    ap.add_argument(
        '--smoke',
        action='store_true',
        help='one ladder step: 3 trackers at 50 Hz, the default K, 3 s of flight (seconds)',
    )
    ap.add_argument(
        '--rates',
        type=float,
        nargs='+',
        metavar='HZ',
        help='realtime rates of the ladders (default 50 100; --quick 50)',
    )
    ap.add_argument(
        '--flight',
        type=float,
        metavar='S',
        help='wall seconds of flight per ladder case (default 25; --quick 5)',
    )
    ap.add_argument(
        '--only',
        type=parse_parts,
        default=list(PARTS),
        metavar='PARTS',
        help=f'comma-separated subset of {",".join(PARTS)}',
    )
    ap.add_argument(
        '--ladder',
        metavar='TEXT',
        action='append',
        default=[],
        help='only the ladders whose label contains TEXT (repeatable), e.g. '
        '"depth=10"; labels: "<rate> Hz <executor> <inputs> K=<k> depth=<d>"',
    )
    ap.add_argument(
        '--sizes',
        metavar='N',
        type=int,
        nargs='+',
        help='fly exactly these swarm sizes in each ladder (no stop at the first failing '
        'one) and measure the raw rclpy ping-pong alone in the same run: the control '
        'latency of each size against it, e.g. --sizes 3 32 64 128',
    )
    ap.add_argument(
        '--keep',
        type=Path,
        metavar='DIR',
        help="keep every bring-up case's output and logs under DIR",
    )
    return ap


def run_parts(bench: Bench, args: argparse.Namespace) -> dict[str, Any]:
    q = args.quick or args.smoke
    rates = args.rates or ([50.0] if q else [50.0, 100.0])
    flight = args.flight or (3.0 if args.smoke else 5.0 if q else 25.0)  # judged: last 40 %
    sizes = args.sizes or ((3,) if args.smoke else (8, 16) if q else LADDER)
    if args.smoke:
        args.only = ['ladder']
    res: dict[str, Any] = {
        'rates': rates,
        'flight': flight,
        'ladders': [],
        'multi': None,
        'latency': ([], None),
        'discovery': [],
        'lockstep': [],
        'pingpong': None,
    }
    if args.sizes:  # the raw round trip of this machine, in the same run as the sizes
        res['pingpong'] = bench.pingpong(4.0 if q else 8.0)
    if 'ladder' in args.only:
        plan = ladder_plan(q, rates)
        for rate, executor, inputs, k, depth in plan[-1:] if args.smoke else plan:
            label = f'{rate:g} Hz {executor} {inputs} K={k or "auto"} depth={depth}'
            if args.ladder and not any(t in label for t in args.ladder):
                continue
            res['ladders'].append(
                run_ladder(bench, rate, executor, inputs, k, depth, sizes, flight, not args.sizes)
            )
        if not q and not args.ladder:
            res['multi'] = bench.up(UpCase('realtime', 4, 1, flight, 50.0, 'multi'))
    if 'discovery' in args.only:
        done = [c for cases in res['ladders'] for c in cases]
        res['discovery'] = run_discovery(bench, done, (3, 8, 16) if q else (3, 8, 16, 24, 32))
    if 'latency' in args.only:
        res['latency'] = run_latency(bench, 4.0 if q else 8.0)
    if 'lockstep' in args.only:
        res['lockstep'] = run_lockstep(bench, q)
    return res


def report(res: dict[str, Any], m_before: dict[str, str], wall: float, left: int) -> str:
    load = os.getloadavg()
    out = [
        (
            f'Machine: {m_before["nproc"]} CPUs ({m_before["cpu"]}), Linux {m_before["kernel"]}, '
            f'Python {m_before["python"]}, {m_before["rmw"]}; load average before: '
            f'{m_before["load"]}; after: {load[0]:.2f}, {load[1]:.2f}, {load[2]:.2f}. CPU '
            "figures are % of one core over the flight window: the case's node processes / the "
            'harness (bring-up + this bench) / other load on the machine.'
        ),
        '',
    ]
    ladders = res['ladders']
    if ladders:
        out += [
            (
                f'Max trackers in realtime, {res["flight"]:g} s per case ("flies": exit 0, no '
                f'missed deadline, <= {STALE_PER_TRACKER} stale commands per tracker, >= '
                f'{MIN_SAMPLES:.0%} of the expected samples, the formation held over the '
                f'last 40 %; each ladder stops at its first '
                'failing size):'
            ),
            '',
            *ladder_summary(ladders, res['multi']),
            '',
            'Every realtime case:',
            '',
            *realtime_rows(
                [c for cases in ladders for c in cases] + ([res['multi']] if res['multi'] else []),
                res['pingpong'],
            ),
            '',
        ]
        if res['pingpong']:
            pp = res['pingpong']
            out += [
                (
                    'Raw rclpy ping-pong alone in the same run (observer -> echo -> observer, '
                    f'100 Hz): round trip p50 {pp["p50"]:.2f} ms, p99 {pp["p99"]:.2f} ms.'
                ),
                '',
            ]
    lat, alone = res['latency']
    if lat:
        out += [
            (
                'Control-loop latency at 100 Hz (bench_graph: events executor, 3 trackers, '
                'trigger:=odom; plant /swarm/odom stamp -> /uav_1/force_cmd at the observer) '
                'against the raw rclpy ping-pong (observer -> echo -> observer, round trip), '
                'run in the same graph at the same time, and alone; ratio = control loop / '
                'ping-pong:'
            ),
            '',
            *latency_rows(lat, alone),
            '',
        ]
    if res['discovery']:
        out += [
            (
                f'Discovery: the bring-up\'s "graph ready" (process start to every node seen and '
                f'every subscription matched), realtime {DISCOVERY_RATE:g} Hz, events / '
                'aggregate:'
            ),
            '',
            *discovery_rows(res['discovery']),
            '',
        ]
    if res['lockstep']:
        out += [
            'Lockstep (triangle, dt = 1 ms) through the bring-up:',
            '',
            *lockstep_rows(res['lockstep']),
            '',
        ]
    every = (
        [c for cases in ladders for c in cases]
        + [c for c, src in res['discovery'] if src != 'ladder case']
        + res['lockstep']
        + ([res['multi']] if res['multi'] else [])
    )
    if every:
        out += [
            (
                "RSS per tracker by hosting mode (sum of the tracker processes' max RSS / n, "
                'over every case above):'
            ),
            '',
            *rss_rows(every),
            '',
        ]
    out.append(f'Wall time of the bench: {wall:.0f} s. Processes left behind: {left}.')
    return '\n'.join(out)


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    exit_on_signals()
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'  # the in-process observers too
    os.environ.pop('ROS_LOCALHOST_ONLY', None)
    m = machine()
    log(f'machine: {m["nproc"]} CPUs, {m["cpu"]}, load average {m["load"]} (before)')
    with tempfile.TemporaryDirectory(prefix='bench_scale_') as tmp:
        work = args.keep if args.keep is not None else Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        bench = Bench(work)
        try:
            res = run_parts(bench, args)
        finally:
            left = bench.leftovers()
    print(report(res, m, time.monotonic() - bench.t0, len(left)))
    # --smoke: a case that ran but wrote no summary (a crash) is a broken benchmark; in a
    # full run a ladder's failing size is its result
    crashed = args.smoke and any('error' in c.result for cs in res['ladders'] for c in cs)
    return 1 if left or crashed else 0


if __name__ == '__main__':
    sys.exit(main())
