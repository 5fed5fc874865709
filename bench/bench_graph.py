#!/usr/bin/env python3
"""Benchmark of the ROS 2 graph: lockstep throughput, realtime control-loop latency, CPU, RSS.

    source scripts/activate.sh
    python bench/bench_graph.py [--quick] [--only lockstep|latency]

Every case starts the node processes itself (the command lines of the bring-up,
:func:`apf_swarm_nodes.bringup.node_commands`, plus ``-p executor:=X -p inputs:=Y`` on every
node), in its own ``ROS_DOMAIN_ID`` (202..230: away from ``make test`` 1..100, the bring-up's
default 1..101 and the integration tests' 102..201) with
``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``, observes them from an in-process rclpy node, and
stops every process it started (SIGINT, SIGTERM, SIGKILL, by process group; checked by PID).

Lockstep (``triangle`` preset, dt = 1 ms): the observer takes ``/swarm/state`` as raw CDR bytes
(no deserialization on the measuring side) and stamps each arrival with ``perf_counter``;
steps/s = (messages after the warm-up) / (time between the warm-up message and the last one).
Warm-up: the first 10 % of the steps. The last message is deserialized to report
``missed_deadlines``.

Realtime latency (``realtime`` preset, plant ``publish_rate:=100``, trackers
``trigger:=odom``): the plant stamps ``/swarm/odom`` with the system clock when it publishes;
the tracker stamps its ``ForceCommand`` with that stamp; the observer computes
latency = arrival time of ``/uav_1/force_cmd`` (``time.time_ns``) - header stamp. That path is
two inter-process hops (plant -> tracker -> observer) with the tracker's callback in between.
The raw reference is the same shape without the controller: the observer publishes a stamped
``nav_msgs/Odometry`` at 100 Hz, an echo process (this file, ``--echo``) republishes it as
received, and the observer computes arrival - stamp: the round trip, also two hops with one
callback in between. The ratio compared is control-loop latency p99 / ping-pong round trip p99
(one-way = RTT / 2 is printed for reference). Both use best-effort, keep-last-1 QoS (the
realtime control QoS) and the default single-threaded executor in the echo; they run one after
the other in the same invocation, with the machine otherwise as it was.

CPU and RSS: ``/proc/<pid>/stat`` (utime + stime over the measurement window, percent of one
core) and ``/proc/<pid>/status`` (VmRSS, the maximum sampled every 0.5 s) of every process,
grouped by role; the observer (this process) is listed too. "other load" is the machine's busy
time over the same window (``/proc/stat``) minus the processes of the case: what else ran.

Output: progress on stderr, markdown tables on stdout. Exit 0 when the 3-tracker lockstep
floor (500 steps/s) is met by the default configuration (executor single, inputs aggregate),
else 1; also 1 when a case or the ping-pong failed to run, or left processes behind.
"""

from __future__ import annotations

import argparse
import itertools
import math
import os
import platform
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from apf_swarm_nodes.capacity.machine import (
    cpu_model,
    machine_busy_seconds,
    process_cpu_seconds,
    process_rss,
)

FLOOR_N3 = 500.0  # steps/s, lockstep, 3 trackers, dt 1 ms
GOAL_N3 = 1000.0
GOAL_LATENCY_RATIO = 1.3  # control-loop p99 / raw ping-pong p99
DOMAIN_LO, DOMAIN_HI = 202, 230


def log(msg: str) -> None:
    print(f'bench_graph: {msg}', file=sys.stderr, flush=True)


# --------------------------------------------------------------------------------------------
# processes and machine (apf_swarm_nodes.capacity.machine)
# --------------------------------------------------------------------------------------------


def rss_mb(pid: int) -> float | None:
    """Resident set of a process [MiB] (None when it is gone)."""
    rss = process_rss(pid)
    return None if rss is None else rss / 2**20


def machine() -> dict[str, str]:
    load = os.getloadavg()
    return {
        'nproc': str(os.cpu_count()),
        'cpu': cpu_model(),
        'load': f'{load[0]:.2f}, {load[1]:.2f}, {load[2]:.2f}',
        'python': platform.python_version(),
        'rmw': os.environ.get('RMW_IMPLEMENTATION', 'rmw_fastrtps_cpp (default)'),
        'kernel': platform.release(),
    }


class ProcStats:
    """CPU over a window and maximum RSS of a set of named processes."""

    def __init__(self, pids: dict[str, int]) -> None:
        self.pids = dict(pids)
        self.t0: float | None = None
        self.cpu0: dict[str, float] = {}
        self.cpu: dict[str, float] = {}
        self.rss: dict[str, float] = dict.fromkeys(self.pids, 0.0)
        self._last_rss = 0.0

    def begin(self) -> None:
        self.t0 = time.monotonic()
        self.busy0 = machine_busy_seconds()
        self.cpu0 = {n: process_cpu_seconds(p) or 0.0 for n, p in self.pids.items()}
        self.sample_rss(force=True)

    def sample_rss(self, force: bool = False) -> None:
        now = time.monotonic()
        if not force and now - self._last_rss < 0.5:
            return
        self._last_rss = now
        for n, p in self.pids.items():
            r = rss_mb(p)
            if r is not None:
                self.rss[n] = max(self.rss[n], r)

    def end(self) -> None:
        if self.t0 is None:
            return
        wall = time.monotonic() - self.t0
        self.machine_cpu = 100.0 * (machine_busy_seconds() - self.busy0) / wall
        self.sample_rss(force=True)
        for n, p in self.pids.items():
            t = process_cpu_seconds(p)
            if t is not None and wall > 0:
                self.cpu[n] = 100.0 * (t - self.cpu0.get(n, 0.0)) / wall

    def by_role(self) -> dict[str, tuple[float, float, float, int]]:
        """role -> (mean CPU %, max CPU %, mean RSS MB, count); roles: plant, target, tracker,
        observer, echo."""
        roles: dict[str, list[str]] = {}
        for n in self.pids:
            roles.setdefault(n.split('_')[0], []).append(n)
        out = {}
        for role, names in roles.items():
            cpus = [self.cpu.get(n, float('nan')) for n in names]
            rss = [self.rss[n] for n in names]
            out[role] = (statistics.fmean(cpus), max(cpus), statistics.fmean(rss), len(names))
        return out

    def total_cpu(self) -> float:
        return sum(self.cpu.values())

    def other_cpu(self) -> float:
        """CPU % used by processes outside this measurement during the window (other load)."""
        return max(0.0, getattr(self, 'machine_cpu', float('nan')) - self.total_cpu())


# --------------------------------------------------------------------------------------------
# one graph: processes + observer
# --------------------------------------------------------------------------------------------


@dataclass
class Case:
    kind: str  # lockstep | latency
    n: int
    executor: str
    inputs: str
    steps: int = 0  # lockstep: steps of the run
    cap: float = 0.0  # lockstep: at most this long a measured window [s]
    seconds: float = 0.0  # latency: measured window (after 1 s of warm-up)
    pingpong: bool = False  # latency: a raw ping-pong in the same graph, concurrently
    result: dict[str, Any] = field(default_factory=dict)

    @property
    def label(self) -> str:
        return f'{self.kind} n={self.n} executor={self.executor} inputs={self.inputs}' + (
            ' +pingpong' if self.pingpong else ''
        )


class Graph:
    """The node processes of one case in their own domain and an observer node."""

    def __init__(
        self,
        workdir: Path,
        domain_id: int,
        preset: str,
        n: int,
        mode: str,
        duration: float,
        node_params: list[str],
    ) -> None:
        import rclpy
        import yaml
        from apf_swarm_core.config_files import apply_overrides, load_preset, to_ros_params
        from apf_swarm_nodes.bringup import Child, ProcessGroup, node_commands
        from apf_swarm_nodes.bringup.commands import package_prefix
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.node import Node

        self.dir = workdir
        self.domain_id = domain_id
        self.n, self.mode = n, mode
        cfg = apply_overrides(load_preset(preset), {'n_trackers': n, 'duration': duration})
        self.cfg = cfg
        self.config = workdir / 'config.yaml'
        self.config.write_text(yaml.safe_dump(to_ros_params(cfg), sort_keys=False))
        self.env = {
            **os.environ,
            'ROS_DOMAIN_ID': str(domain_id),
            'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST',
            'PYTHONUNBUFFERED': '1',
            'RCUTILS_COLORIZED_OUTPUT': '0',
            'ROS_LOG_DIR': str(workdir / 'ros_logs'),
        }
        self.env.pop('ROS_LOCALHOST_ONLY', None)
        self.group = ProcessGroup()
        self._Child = Child
        for name, argv in node_commands(package_prefix(), self.config, n, mode, node_params):
            self.group.add(Child(name, argv, workdir / f'{name}.log', self.env))
        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain_id)
        self.node = Node('bench_observer', context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.stats: ProcStats | None = None

    def add_process(self, name: str, argv: list[str]) -> None:
        self.group.add(self._Child(name, argv, self.dir / f'{name}.log', self.env))

    def start(self) -> None:
        self.group.start_all()

    def pids(self) -> dict[str, int]:
        out = {c.name: c.pid for c in self.group if c.pid is not None}
        out['observer'] = os.getpid()
        return out

    def check_children(self) -> None:
        for c, rc in self.group.poll():
            raise RuntimeError(c.death_report(rc))

    def spin_until(self, cond: Callable[[], bool], timeout: float, what: str) -> bool:
        """Spin the observer until ``cond()``; False after ``timeout`` s (never raises on it)."""
        end = time.monotonic() + timeout
        last_check = 0.0
        while not cond():
            now = time.monotonic()
            if now > end:
                return False
            if now - last_check > 0.2:
                last_check = now
                self.check_children()
                if self.stats is not None:
                    self.stats.sample_rss()
            self.executor.spin_once(timeout_sec=0.05)
        return True

    def missing(self, extra: Callable[[], list[str]] = list) -> list[str]:
        from apf_swarm_nodes.bringup import expected_graph, graph_missing

        node = self.node
        present = {
            (ns.rstrip('/') + '/' + name) for name, ns in node.get_node_names_and_namespaces()
        }
        nodes, topics = expected_graph(self.n, self.mode)
        counts = {
            t.topic: (node.count_publishers(t.topic), node.count_subscribers(t.topic))
            for t in topics
        }
        return graph_missing(present, counts, nodes, topics) + extra()

    def wait_ready(self, extra: Callable[[], list[str]], timeout: float = 60.0) -> float:
        t0 = time.monotonic()
        miss = ['(not checked)']

        def ready() -> bool:
            nonlocal miss
            miss = self.missing(extra)
            return not miss

        if not self.spin_until(ready, timeout, 'the graph'):
            raise RuntimeError(f'graph not complete after {timeout:g} s: {miss}')
        return time.monotonic() - t0

    def close(self) -> list[tuple[str, int]]:
        import rclpy

        how = self.group.stop_all()
        left = self.group.leftovers()
        bad = {k: v for k, v in how.items() if v not in ('SIGINT', 'exited')}
        if bad:
            log(f'  note: stopping needed {bad}')
        self.executor.shutdown(timeout_sec=1.0)
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)
        return left

    def log_tail(self, n: int = 15) -> str:
        return '\n'.join(f'--- {c.name} ---\n' + '\n'.join(c.tail(n)) for c in self.group)


# --------------------------------------------------------------------------------------------
# the measurements
# --------------------------------------------------------------------------------------------


def run_lockstep(g: Graph, case: Case) -> None:
    from apf_swarm_nodes.node_common import START_QOS, STATE_QOS
    from rclpy.serialization import deserialize_message
    from std_msgs.msg import Empty

    from apf_swarm_msgs.msg import SwarmState

    arrivals: list[float] = []
    last_raw: list[bytes] = [b'']

    def on_state(raw: bytes) -> None:
        arrivals.append(time.perf_counter())
        last_raw[0] = raw

    sub = g.node.create_subscription(SwarmState, '/swarm/state', on_state, STATE_QOS, raw=True)
    start = g.node.create_publisher(Empty, '/swarm/start', START_QOS)

    def own() -> list[str]:
        out = []
        if sub.get_publisher_count() < 1:
            out.append('/swarm/state not matched')
        if start.get_subscription_count() < 1:
            out.append('/swarm/start not matched')
        return out

    g.start()
    ready = g.wait_ready(own)
    g.stats = ProcStats(g.pids())
    start.publish(Empty())
    warm = max(1, case.steps // 10)
    if not g.spin_until(lambda: len(arrivals) > warm, 60.0, 'the warm-up'):
        raise RuntimeError(f'only {len(arrivals)} steps in 60 s after the start')
    g.stats.begin()
    complete = g.spin_until(lambda: len(arrivals) >= case.steps, case.cap, 'the steps')
    g.stats.end()
    t = arrivals[warm:]
    rate = (len(t) - 1) / (t[-1] - t[0]) if len(t) > 1 else float('nan')
    periods = sorted((b - a) * 1e3 for a, b in itertools.pairwise(t))
    last = deserialize_message(last_raw[0], SwarmState)
    case.result = {
        'rate': rate,
        'received': len(arrivals),
        'complete': complete,
        'ready': ready,
        'p50': pct(periods, 50),
        'p99': pct(periods, 99),
        'max': periods[-1] if periods else 0,
        'missed': int(last.missed_deadlines),
        'last_step': int(last.step),
        'roles': g.stats.by_role(),
        'total_cpu': g.stats.total_cpu(),
        'other_cpu': g.stats.other_cpu(),
    }


class PingPong:
    """Raw rclpy ping-pong: ``node`` publishes a stamped ``nav_msgs/Odometry`` on /bench/ping at
    ``rate`` Hz, an echo process (this file, ``--echo``) republishes it unchanged on
    /bench/pong; round trip = arrival (``time.time_ns``) - stamp. QoS: best effort, depth 1."""

    def __init__(self, node: Any, rate: float = 100.0) -> None:
        from apf_swarm_nodes.node_common import control_qos
        from nav_msgs.msg import Odometry

        qos = control_qos('realtime')
        self.node, self.rate = node, rate
        self.rtt: list[tuple[float, float]] = []  # (arrival monotonic, round trip ms)
        self.pub = node.create_publisher(Odometry, '/bench/ping', qos)
        self.sub = node.create_subscription(Odometry, '/bench/pong', self._on_pong, qos)
        self.msg = Odometry()
        self.msg.header.frame_id = 'world'
        self.timer = None

    @staticmethod
    def argv() -> list[str]:
        return [sys.executable, str(Path(__file__).resolve()), '--echo']

    def missing(self) -> list[str]:
        if self.pub.get_subscription_count() < 1 or self.sub.get_publisher_count() < 1:
            return ['/bench/ping or /bench/pong not matched (echo process)']
        return []

    def start(self) -> None:
        self.timer = self.node.create_timer(1.0 / self.rate, self._on_timer)

    def _on_timer(self) -> None:
        now = time.time_ns()
        self.msg.header.stamp.sec, self.msg.header.stamp.nanosec = divmod(now, 1_000_000_000)
        self.pub.publish(self.msg)

    def _on_pong(self, msg: Any) -> None:
        now_ns = time.time_ns()
        st = msg.header.stamp
        self.rtt.append((time.monotonic(), (now_ns - (st.sec * 1_000_000_000 + st.nanosec)) / 1e6))

    def result(self, t_begin: float, t_end: float) -> dict[str, Any]:
        return summarize_ms([v for t, v in self.rtt if t_begin <= t <= t_end], t_end - t_begin)


def summarize_ms(values: list[float], seconds: float) -> dict[str, Any]:
    vals = sorted(values)
    return {
        'samples': len(vals),
        'rate': len(vals) / seconds if seconds > 0 else float('nan'),
        'p50': pct(vals, 50),
        'p90': pct(vals, 90),
        'p99': pct(vals, 99),
        'max': vals[-1] if vals else float('nan'),
    }


def run_latency(g: Graph, case: Case) -> None:
    """Control-loop latency; with ``case.pingpong`` a ping-pong runs in the same graph, at the
    same time (its echo process is one more process on the machine)."""
    from apf_swarm_nodes.node_common import START_QOS, STATE_QOS, control_qos
    from std_msgs.msg import Empty

    from apf_swarm_msgs.msg import ForceCommand, SwarmState

    lat: list[tuple[float, float]] = []  # (arrival monotonic, latency ms)
    stale = [0]

    def on_force(msg: ForceCommand) -> None:
        now_ns = time.time_ns()
        if msg.stale:
            stale[0] += 1
            return
        st = msg.header.stamp
        lat.append((time.monotonic(), (now_ns - (st.sec * 1_000_000_000 + st.nanosec)) / 1e6))

    sub = g.node.create_subscription(
        ForceCommand, '/uav_1/force_cmd', on_force, control_qos('realtime')
    )
    # as the bring-up does (and the graph check expects): /swarm/state, taken raw
    g.node.create_subscription(SwarmState, '/swarm/state', lambda raw: None, STATE_QOS, raw=True)
    start = g.node.create_publisher(Empty, '/swarm/start', START_QOS)
    ping = None
    if case.pingpong:
        ping = PingPong(g.node)
        g.add_process('echo', PingPong.argv())

    def own() -> list[str]:
        out = ping.missing() if ping else []
        if sub.get_publisher_count() < 1:
            out.append('/uav_1/force_cmd not matched')
        if start.get_subscription_count() < 2:
            out.append('/swarm/start: need plant and target')
        return out

    g.start()
    ready = g.wait_ready(own)
    g.stats = ProcStats(g.pids())
    start.publish(Empty())
    if ping:
        ping.start()
    if not g.spin_until(lambda: len(lat) > 0, 30.0, 'the first command'):
        raise RuntimeError('no /uav_1/force_cmd within 30 s of the start')
    t_first = lat[0][0]
    g.spin_until(lambda: time.monotonic() > t_first + 1.0, 5.0, 'the warm-up')
    g.stats.begin()
    t_begin = time.monotonic()
    g.spin_until(
        lambda: time.monotonic() > t_begin + case.seconds, case.seconds + 5.0, 'the measurement'
    )
    t_end = time.monotonic()
    g.stats.end()
    case.result = summarize_ms([v for t, v in lat if t_begin <= t <= t_end], t_end - t_begin)
    case.result.update(
        {
            'ready': ready,
            'stale': stale[0],
            'roles': g.stats.by_role(),
            'total_cpu': g.stats.total_cpu(),
            'other_cpu': g.stats.other_cpu(),
        }
    )
    if ping:
        case.result['ping'] = ping.result(t_begin, t_end)


def run_pingpong(workdir: Path, domain_id: int, seconds: float) -> dict[str, Any]:
    """The ping-pong alone (no swarm running): observer <-> echo process at 100 Hz."""
    import rclpy
    from apf_swarm_nodes.bringup import Child, ProcessGroup
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node

    env = {
        **os.environ,
        'ROS_DOMAIN_ID': str(domain_id),
        'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST',
        'ROS_LOG_DIR': str(workdir / 'ros_logs'),
    }
    env.pop('ROS_LOCALHOST_ONLY', None)
    group = ProcessGroup()
    echo = group.add(Child('echo', PingPong.argv(), workdir / 'echo.log', env))
    context = Context()
    rclpy.init(context=context, domain_id=domain_id)
    node = Node('bench_ping', context=context)
    ex = SingleThreadedExecutor(context=context)
    ex.add_node(node)
    ping = PingPong(node)
    stats = None
    res: dict[str, Any] = {}
    try:
        group.start_all()
        end = time.monotonic() + 60.0
        while ping.missing():
            if time.monotonic() > end:
                raise RuntimeError('echo process not matched after 60 s')
            for c, rc in group.poll():
                raise RuntimeError(c.death_report(rc))
            ex.spin_once(timeout_sec=0.05)
        stats = ProcStats({'echo': echo.pid, 'observer': os.getpid()})
        ping.start()
        t_warm = time.monotonic() + 1.0
        while time.monotonic() < t_warm:
            ex.spin_once(timeout_sec=0.05)
        stats.begin()
        t_begin = time.monotonic()
        while time.monotonic() < t_begin + seconds:
            ex.spin_once(timeout_sec=0.05)
            stats.sample_rss()
        t_end = time.monotonic()
        stats.end()
        res = ping.result(t_begin, t_end)
        res['roles'] = stats.by_role()
        res['total_cpu'], res['other_cpu'] = stats.total_cpu(), stats.other_cpu()
    finally:
        group.stop_all()
        res['left'] = group.leftovers()
        ex.shutdown(timeout_sec=1.0)
        node.destroy_node()
        rclpy.try_shutdown(context=context)
    return res


def echo_main() -> int:
    """``--echo``: republish every /bench/ping as /bench/pong, unchanged."""
    import rclpy
    from apf_swarm_nodes.node_common import control_qos
    from nav_msgs.msg import Odometry
    from rclpy.executors import ExternalShutdownException
    from rclpy.node import Node

    rclpy.init()
    node = Node('bench_echo')
    qos = control_qos('realtime')
    pub = node.create_publisher(Odometry, '/bench/pong', qos)
    node.create_subscription(Odometry, '/bench/ping', pub.publish, qos)
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


def pct(sorted_vals: list[float], q: float) -> float:
    if not sorted_vals:
        return float('nan')
    i = min(len(sorted_vals) - 1, max(0, int(round(q / 100.0 * (len(sorted_vals) - 1)))))
    return sorted_vals[i]


# --------------------------------------------------------------------------------------------
# driver
# --------------------------------------------------------------------------------------------


def run_case(case: Case, used: set[int], keep: Path | None = None) -> list[tuple[str, int]]:
    from apf_swarm_nodes.bringup import pick_domain_id

    dom = pick_domain_id(exclude=used, lo=DOMAIN_LO, hi=DOMAIN_HI)
    used.add(dom)
    with tempfile.TemporaryDirectory(prefix='bench_graph_') as tmp:
        work = Path(tmp)
        if keep is not None:
            work = keep / (
                f'{case.kind}_n{case.n}_{case.executor}_{case.inputs}'
                + ('_pingpong' if case.pingpong else '')
            )
            work.mkdir(parents=True, exist_ok=True)
        if case.kind == 'lockstep':
            params = [f'executor:={case.executor}', f'inputs:={case.inputs}']
            g = Graph(work, dom, 'triangle', case.n, 'lockstep', case.steps * 0.001, params)
            runner = run_lockstep
        else:
            params = [
                f'executor:={case.executor}',
                f'inputs:={case.inputs}',
                'publish_rate:=100.0',
                'trigger:=odom',
            ]
            g = Graph(work, dom, 'realtime', case.n, 'realtime', case.seconds + 30.0, params)
            runner = run_latency
        try:
            runner(g, case)
        except RuntimeError as exc:
            case.result = {'error': str(exc).splitlines()[0]}
            log(f'  FAILED: {exc}\n{g.log_tail()}')
        finally:
            left = g.close()
    if left:
        log(f'  ERROR: processes left behind: {left}')
    return left


def fmt(v: float, spec: str = '.0f') -> str:
    return '-' if math.isnan(v) else format(v, spec)


def role_cells(res: dict[str, Any], roles: tuple[str, ...]) -> list[str]:
    r = res.get('roles', {})
    cells = []
    for role in roles:
        if role not in r:
            cells.append('-')
            continue
        mean, mx, rss, cnt = r[role]
        cpu = f'{mean:.0f}' if cnt == 1 else f'{mean:.0f} (max {mx:.0f})'
        cells.append(f'{cpu} / {rss:.0f}')
    return cells


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--quick', action='store_true', help='fewer steps, shorter windows')
    ap.add_argument(
        '--smoke',
        action='store_true',
        help='one lockstep case and one latency case with its ping-pong, briefly (seconds)',
    )
    ap.add_argument('--only', choices=('lockstep', 'latency'), help='one part only')
    ap.add_argument(
        '--case',
        metavar='TEXT',
        action='append',
        default=[],
        help='only the cases whose label contains TEXT (repeatable), e.g. "n=3 executor=multi"',
    )
    ap.add_argument(
        '--keep', metavar='DIR', type=Path, help="keep every case's config and node logs under DIR"
    )
    ap.add_argument('--echo', action='store_true', help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.echo:
        return echo_main()

    t_start = time.monotonic()
    m = machine()
    log(f'machine: {m["nproc"]} CPUs, {m["cpu"]}, load average {m["load"]} (before measuring)')
    q = args.quick
    s3, s10, cap, lat_s = (600, 200, 5.0, 4.0) if q else (2000, 500, 12.0, 8.0)
    if args.smoke:
        s3, cap, lat_s = 200, 5.0, 2.0
    cases: list[Case] = []
    if args.only in (None, 'lockstep'):
        for inputs in ('aggregate', 'odom'):
            for ex in ('single', 'events', 'multi'):
                cases.append(Case('lockstep', 3, ex, inputs, steps=s3, cap=cap))
        for ex in ('single', 'events', 'multi'):
            cases.append(Case('lockstep', 10, ex, 'aggregate', steps=s10, cap=cap))
    if args.only in (None, 'latency'):
        for ex in ('single', 'events'):
            cases.append(Case('latency', 3, ex, 'aggregate', seconds=lat_s))
        cases.append(Case('latency', 3, 'single', 'aggregate', seconds=lat_s, pingpong=True))
    if args.case:
        cases = [c for c in cases if any(t in c.label for t in args.case)]
    if args.smoke:
        cases = [
            c
            for c in cases
            if (
                c.kind == 'lockstep'
                and c.n == 3
                and c.executor == 'events'
                and c.inputs == 'aggregate'
            )
            or (c.kind == 'latency' and c.pingpong)
        ]
    used: set[int] = set()
    leftovers: list[tuple[str, int]] = []
    for i, case in enumerate(cases, 1):
        log(f'[{i}/{len(cases)}] {case.label} ({time.monotonic() - t_start:.0f} s elapsed)')
        leftovers += run_case(case, used, args.keep)
        r = case.result
        if 'error' not in r:
            if case.kind == 'lockstep':
                log(
                    f'  {r["rate"]:.0f} steps/s, {r["received"]} steps, missed {r["missed"]}, '
                    f'graph ready after {r["ready"]:.1f} s, CPU total {r["total_cpu"]:.0f} %, '
                    f'other load {r["other_cpu"]:.0f} %'
                )
            else:
                log(
                    f'  latency p50 {r["p50"]:.2f} ms, p99 {r["p99"]:.2f} ms over '
                    f'{r["samples"]} commands'
                    + (
                        f'; concurrent ping-pong round trip p50 {r["ping"]["p50"]:.2f} ms, p99 '
                        f'{r["ping"]["p99"]:.2f} ms'
                        if 'ping' in r
                        else ''
                    )
                )
    ping, ping_failed = None, False
    if args.only in (None, 'latency'):
        from apf_swarm_nodes.bringup import pick_domain_id

        dom = pick_domain_id(exclude=used, lo=DOMAIN_LO, hi=DOMAIN_HI)
        log(f'[ping-pong] raw rclpy Odometry ping-pong at 100 Hz, {lat_s:g} s')
        with tempfile.TemporaryDirectory(prefix='bench_graph_') as tmp:
            try:
                ping = run_pingpong(Path(tmp), dom, lat_s)
                leftovers += ping['left']
                log(f'  round trip p50 {ping["p50"]:.2f} ms, p99 {ping["p99"]:.2f} ms')
            except RuntimeError as exc:
                log(f'  FAILED: {exc}')
                ping_failed = True

    # ---- tables ----------------------------------------------------------------------------
    out = [
        (
            f'Machine: {m["nproc"]} CPUs ({m["cpu"]}), Linux {m["kernel"]}, Python {m["python"]}, '
            f'{m["rmw"]}; load average before measuring: {m["load"]}.'
        ),
        '',
    ]
    floor_ok = None
    lock = [c for c in cases if c.kind == 'lockstep']
    if lock:
        out += [
            (
                'Lockstep throughput (triangle preset, dt = 1 ms; steps/s after a 10 % warm-up; '
                'step period = time between consecutive /swarm/state arrivals):'
            ),
            '',
            (
                '| trackers | executor | inputs | steps | steps/s | period p50 / p99 / max '
                '[ms] | missed | floor / goal |'
            ),
            '|---:|---|---|---:|---:|---|---:|---|',
        ]
        for c in lock:
            r = c.result
            if 'error' in r:
                out.append(
                    f'| {c.n} | {c.executor} | {c.inputs} | {c.steps} | failed: '
                    f'{r["error"]} | | | |'
                )
                continue
            verdict = ''
            if c.n == 3:
                verdict = (
                    'goal met'
                    if r['rate'] >= GOAL_N3
                    else 'floor met'
                    if r['rate'] >= FLOOR_N3
                    else 'below floor'
                )
                if c.executor == 'single' and c.inputs == 'aggregate':
                    floor_ok = r['rate'] >= FLOOR_N3
            done = '' if r['complete'] else f' (bounded: {r["received"]} in {c.cap:g} s)'
            out.append(
                f'| {c.n} | {c.executor} | {c.inputs} | {c.steps}{done} | '
                f'{r["rate"]:.0f} | {r["p50"]:.2f} / {r["p99"]:.2f} / {r["max"]:.1f} | '
                f'{r["missed"]} | {verdict} |'
            )
        out += [
            '',
            (
                'CPU (% of one core, over the measured window) / RSS (MB, max) per process, '
                'lockstep; trackers: mean (max) over the tracker processes:'
            ),
            '',
            (
                '| trackers | executor | inputs | plant | target | tracker | observer | '
                'total CPU % | other load CPU % |'
            ),
            '|---:|---|---|---|---|---|---|---:|---:|',
        ]
        for c in lock:
            if 'error' in c.result:
                continue
            cells = role_cells(c.result, ('plant', 'target', 'tracker', 'observer'))
            out.append(
                f'| {c.n} | {c.executor} | {c.inputs} | '
                + ' | '.join(cells)
                + f' | {c.result["total_cpu"]:.0f} | {fmt(c.result["other_cpu"])} |'
            )
        out.append('')
    lat = [c for c in cases if c.kind == 'latency']
    if lat:
        out += [
            (
                'Realtime control-loop latency at 100 Hz (realtime preset, 3 trackers, '
                'trigger:=odom, inputs:=aggregate): arrival of /uav_1/force_cmd at the observer '
                '- its header stamp, which is the time the plant published the triggering '
                "/swarm/odom; two hops (plant -> tracker -> observer) with the tracker's "
                'callback between them. Raw reference: rclpy ping-pong at 100 Hz, observer -> '
                'echo process -> observer, nav_msgs/Odometry, best effort depth 1, round trip = '
                'arrival - stamp, also two hops with one callback between them. "alone": no '
                'swarm running; "concurrent": in the same graph during the control-loop run of '
                'that row. Ratio = control-loop p99 / round-trip p99 of the named reference '
                f'(goal <= {GOAL_LATENCY_RATIO}).'
            ),
            '',
            (
                '| path | executor | samples | p50 [ms] | p90 [ms] | p99 [ms] | max [ms] | '
                'p99 ratio (reference) |'
            ),
            '|---|---|---:|---:|---:|---:|---:|---|',
        ]
        raw99 = ping['p99'] if ping else float('nan')

        def row(path: str, ex: str, r: dict[str, Any], ratio: str) -> str:
            return (
                f'| {path} | {ex} | {r["samples"]} | {r["p50"]:.2f} | {r["p90"]:.2f} | '
                f'{r["p99"]:.2f} | {r["max"]:.2f} | {ratio} |'
            )

        for c in lat:
            r = c.result
            if 'error' in r:
                out.append(f'| control loop | {c.executor} | failed: {r["error"]} | | | | | |')
                continue
            if 'ping' in r:
                cp = r['ping']
                ratio = f'{r["p99"] / cp["p99"]:.2f} (concurrent ping-pong)'
                out.append(row('control loop, ping-pong running', c.executor, r, ratio))
                out.append(row('ping-pong round trip, concurrent', 'single', cp, '-'))
            else:
                ratio = f'{fmt(r["p99"] / raw99, ".2f")} (ping-pong alone)'
                out.append(row('control loop', c.executor, r, ratio))
        if ping:
            out.append(row('ping-pong round trip, alone', 'single', ping, '-'))
            half = {
                k: (v / 2 if k in ('p50', 'p90', 'p99', 'max') else v) for k, v in ping.items()
            }
            out.append(row('ping-pong one way (round trip / 2), alone', 'single', half, '-'))
        out += [
            '',
            'CPU (% of one core) / RSS (MB, max) per process during the latency runs:',
            '',
            (
                '| run | executor | plant | target | tracker | observer | echo | '
                'total CPU % | other load CPU % |'
            ),
            '|---|---|---|---|---|---|---|---:|---:|',
        ]
        for c in lat:
            if 'error' not in c.result:
                name = 'control loop + ping-pong' if c.pingpong else 'control loop'
                out.append(
                    f'| {name} | {c.executor} | '
                    + ' | '.join(
                        role_cells(c.result, ('plant', 'target', 'tracker', 'observer', 'echo'))
                    )
                    + f' | {c.result["total_cpu"]:.0f} | {fmt(c.result["other_cpu"])} |'
                )
        if ping:
            out.append(
                '| ping-pong alone | single | - | - | - | '
                + ' | '.join(role_cells(ping, ('observer', 'echo')))
                + f' | {ping["total_cpu"]:.0f} | '
                f'{fmt(ping["other_cpu"])} |'
            )
        out.append('')
    load = os.getloadavg()
    out.append(
        f'Load average after: {load[0]:.2f}, {load[1]:.2f}, {load[2]:.2f}. Wall time of '
        f'the bench: {time.monotonic() - t_start:.0f} s. Processes left behind: '
        f'{len(leftovers)}.'
    )
    print('\n'.join(out))
    failed = [c.label for c in cases if 'error' in c.result]
    if ping_failed:
        failed.append('ping-pong')
    if failed:
        print(f'\nFailed to run: {", ".join(failed)}.')
    if leftovers or failed:
        return 1
    return 0 if floor_ok in (None, True) else 1


if __name__ == '__main__':
    sys.exit(main())
