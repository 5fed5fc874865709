"""Capacity probe: this machine's control-loop latency and cost per message, measured once and
cached, and what follows from them (``apf-swarm probe``).

Machines of one kind differ 3-4x in speed, so the realtime defaults come from a measurement
of the machine in use, not from constants measured elsewhere:

* **round trip**: a raw rclpy ping-pong between this process and an echo process (the echo
  takes the CDR bytes and publishes them back, as little work as a message can cost) with a
  ``SwarmOdometry`` of 16 trackers at the realtime rate: p50 / p90 / p99 [s];
* **CPU per message**: the echo process's CPU time (:mod:`.machine`) over the messages
  it took and sent [s];
* **command cost**: the core's :class:`~apf_swarm_core.agents.TrackerAgent` command of the
  ``realtime`` preset for 3, 16 and 32 trackers, in this process [s];
* **memory per process**: the echo node process's resident set [bytes], what every node
  process costs at least.

From them (:func:`derive`): the control-loop latency ``check`` and ``design`` assume (the
round trip's p90 plus a command, stretched by the machine's utilization), the most trackers
that fit in :data:`CPU_BUDGET` of the cores at a rate (each costs per period its state's
delivery, its command's publication, the plant's receipt and a command), and the default
rate (the highest of :data:`RATES` that fits); and the most tracker processes the bring-up
starts (:func:`process_limit`): as many one-tracker processes as fit in the CPU budget at the
lowest rate, and in :data:`MEMORY_BUDGET` of the memory available now. The cache is
``$XDG_CACHE_HOME/apf_swarm/probe.json`` (``~/.cache``), or ``$APF_SWARM_CACHE/probe.json``;
it is measured again when the machine (CPU model, cores, host name) differs, or with
``--refresh``.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import psutil

from .machine import identity, process_cpu_seconds, process_rss

__all__ = [
    'CPU_BUDGET',
    'MEMORY_BUDGET',
    'RATES',
    'add_arguments',
    'cache_path',
    'derive',
    'ensure',
    'load',
    'measure',
    'process_limit',
    'run',
]

#: the share of the machine's cores the swarm's messages and commands may take
CPU_BUDGET = 0.5
#: the share of the memory available at start that the node processes may take
MEMORY_BUDGET = 0.5
#: what a cached probe must hold; one without all of them is measured again
FIELDS = ('machine', 'rtt', 'cpu_per_message', 'command_cost', 'process_rss')
#: the rates the default is chosen from [Hz], highest first
RATES = (100.0, 50.0, 20.0)
#: tracker counts whose command cost is measured (others are interpolated)
COMMAND_SIZES = (3, 16, 32)
PING, PONG = '/apf_probe/ping', '/apf_probe/pong'


def cache_path() -> Path:
    """Where the probe is kept."""
    base = os.environ.get('APF_SWARM_CACHE')
    if base:
        return Path(base) / 'probe.json'
    xdg = os.environ.get('XDG_CACHE_HOME') or str(Path.home() / '.cache')
    return Path(xdg) / 'apf_swarm' / 'probe.json'


def command_cost(n: int, repeats: int = 200) -> float:
    """Median seconds of one :meth:`TrackerAgent.command` of the realtime preset, n trackers."""
    from apf_swarm_core.agents import TrackerAgent
    from apf_swarm_core.config import load_preset

    cfg = load_preset('realtime').replace(n_trackers=n)
    agent = TrackerAgent(cfg, 1)
    rng = np.random.default_rng(0)
    x = rng.normal(scale=2.0, size=(n, 3))
    ids = list(range(1, n + 1))
    times = []
    for k in range(repeats):
        agent.offer_swarm(
            -1,
            ids,
            x + 1e-3 * k,
            np.zeros((n, 3)),
            [True] * n,
            np.zeros(3),
            np.zeros(3),
            0.0,
            0.0,
            seq=k,
        )
        t0 = time.perf_counter()
        agent.command(-1)
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def _echo() -> int:
    """The echo process: every ping's bytes back as a pong, on the nodes' default executor
    (the events executor driven by spin_once, :func:`apf_swarm_nodes.node_common.spin`), so
    that its CPU per message is a node's."""
    import rclpy
    from rclpy.experimental import EventsExecutor
    from rclpy.qos import qos_profile_sensor_data

    from apf_swarm_msgs.msg import SwarmOdometry

    rclpy.init()
    node = rclpy.create_node('apf_probe_echo')
    pub = node.create_publisher(SwarmOdometry, PONG, qos_profile_sensor_data)
    node.create_subscription(SwarmOdometry, PING, pub.publish, qos_profile_sensor_data, raw=True)
    executor = EventsExecutor()
    executor.add_node(node)
    try:
        while rclpy.ok():
            executor.spin_once(timeout_sec=0.1)
    except KeyboardInterrupt:
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


def _ping_pong(seconds: float, rate: float, n: int) -> dict[str, Any]:
    """Round trips and the echo's CPU per message; rclpy initialized by the caller."""
    import rclpy
    from rclpy.qos import qos_profile_sensor_data

    from apf_swarm_msgs.msg import SwarmOdometry

    from .bringup.processes import stop_process
    from .conversions import swarm_odom_msg

    echo = subprocess.Popen(
        [sys.executable, '-m', 'apf_swarm_nodes.probe', '--echo'],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        start_new_session=True,
    )
    node = rclpy.create_node('apf_probe')
    sent: dict[int, float] = {}
    rtt: list[float] = []
    try:
        pub = node.create_publisher(SwarmOdometry, PING, qos_profile_sensor_data)

        def pong(msg: Any) -> None:
            t0 = sent.pop(int(msg.step), None)
            if t0 is not None:
                rtt.append(time.monotonic() - t0)

        node.create_subscription(SwarmOdometry, PONG, pong, qos_profile_sensor_data)
        msg = swarm_odom_msg(
            step=0,
            stamp=node.get_clock().now().to_msg(),
            uav_ids=list(range(1, n + 1)),
            x=np.zeros((n, 3)),
            v=np.zeros((n, 3)),
            target_x=np.zeros(3),
            target_v=np.zeros(3),
        )
        deadline = time.monotonic() + 30.0
        while (
            pub.get_subscription_count() < 1 or node.count_publishers(PONG) < 1
        ) and time.monotonic() < deadline:
            if echo.poll() is not None:
                err = (echo.stderr.read() if echo.stderr else b'').decode(errors='replace')
                raise RuntimeError(
                    f"the probe's echo process exited {echo.returncode}: {err[-500:]}"
                )
            rclpy.spin_once(node, timeout_sec=0.05)
        step, period = 0, 1.0 / rate

        def ping() -> None:
            nonlocal step
            msg.step = step
            sent[step] = time.monotonic()
            pub.publish(msg)
            step += 1

        # until the first pong: both sides of the best-effort topics are matched
        while not rtt and time.monotonic() < deadline:
            ping()
            rclpy.spin_once(node, timeout_sec=period)
        rtt.clear()
        cpu0, count0 = process_cpu_seconds(echo.pid), step
        end = time.monotonic() + seconds
        nxt = time.monotonic()
        while time.monotonic() < end:
            now = time.monotonic()
            if now >= nxt:
                ping()
                nxt += period
            rclpy.spin_once(node, timeout_sec=max(0.0, min(nxt - time.monotonic(), 0.05)))
        count = step - count0
        cpu1, rss = process_cpu_seconds(echo.pid), process_rss(echo.pid)
    finally:
        node.destroy_node()
        stop_process(echo)
    if cpu0 is None or cpu1 is None or rss is None:
        raise RuntimeError("the probe's echo process exited during the measurement")
    cpu = cpu1 - cpu0
    if len(rtt) < 10:
        raise RuntimeError(f'the probe got {len(rtt)} round trips back in {seconds:g} s')
    arr = np.asarray(rtt)
    return {
        'rate': rate,
        'messages': count,
        'round_trips': int(arr.size),
        'rtt': {
            q: round(float(np.quantile(arr, v)), 6)
            for q, v in (('p50', 0.5), ('p90', 0.9), ('p99', 0.99))
        },
        'cpu_per_message': round(cpu / max(1, 2 * count), 7),
        'process_rss': int(rss),
    }


def measure(seconds: float = 4.0, rate: float = 100.0, n: int = 16) -> dict[str, Any]:
    """Run the probe in this process (``python -m apf_swarm_nodes.probe --measure`` does it
    in a process of its own, on a free domain, localhost only: :func:`ensure`)."""
    import rclpy

    costs = {str(k): round(command_cost(k), 7) for k in COMMAND_SIZES}
    rclpy.init()
    try:
        pp = _ping_pong(seconds, rate, n)
    finally:
        rclpy.try_shutdown()
    return {
        'machine': identity(),
        'measured_at': time.strftime('%Y-%m-%dT%H:%M:%SZ', time.gmtime()),
        **pp,
        'command_cost': costs,
    }


def load() -> dict[str, Any] | None:
    """The cached probe of this machine, or None (none, unreadable, another machine)."""
    try:
        probe = json.loads(cache_path().read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(probe, dict) or any(k not in probe for k in FIELDS):
        return None
    return probe if probe['machine'] == identity() else None


def ensure(refresh: bool = False, say: Callable[[str], None] | None = None) -> dict[str, Any]:
    """The cached probe, measured (and cached) first when missing or ``refresh``."""
    probe = None if refresh else load()
    if probe is None:
        from .bringup.isolation import pick_domain_id

        if say is not None:
            say(f'measuring this machine (capacity probe, about 6 s; cached in {cache_path()})')
        env = {
            **os.environ,
            'ROS_DOMAIN_ID': str(pick_domain_id()),
            'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST',
        }
        env.pop('ROS_STATIC_PEERS', None)
        done = subprocess.run(
            [sys.executable, '-m', 'apf_swarm_nodes.probe', '--measure'],
            env=env,
            capture_output=True,
            text=True,
            timeout=120,
            check=False,
        )
        if done.returncode != 0:
            raise RuntimeError(
                f'the capacity probe failed (exit {done.returncode}): {done.stderr.strip()[-800:]}'
            )
        probe = json.loads(done.stdout)
        path = cache_path()
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(probe, indent=2) + '\n')
    return probe


def _command_cost_at(probe: dict[str, Any], n: int) -> float:
    sizes = np.array(sorted(int(k) for k in probe['command_cost']))
    costs = np.array([probe['command_cost'][str(k)] for k in sizes])
    # the Newton direction's eigendecomposition grows as n^3 past the measured sizes
    if n > sizes[-1]:
        return float(costs[-1] * (n / sizes[-1]) ** 3)
    return float(np.interp(n, sizes, costs))


def derive(probe: dict[str, Any], n: int, rate: float | None = None) -> dict[str, Any]:
    """What the probe implies for n trackers: ``capacity`` (trackers that fit in CPU_BUDGET
    of the cores, per rate), ``rate`` (the given one, or the default: the highest of RATES
    that fits n, else the lowest), the swarm's CPU ``utilization`` at that rate, and the
    ``latency`` [s] check and design assume: the idle round trip's p90 plus a command,
    stretched by ``1 / (1 - utilization)`` for the queueing of a busy machine (capped at
    0.9)."""
    cores = int(probe['machine']['cores'])
    msg = float(probe['cpu_per_message'])
    cmd = _command_cost_at(probe, n)
    per_tracker = 3.0 * msg + cmd  # its state in, its command out, the plant's in
    capacity = {f'{r:g}': int(CPU_BUDGET * cores / (r * per_tracker)) for r in RATES}
    if rate is None:
        rate = next((r for r in RATES if capacity[f'{r:g}'] >= n), RATES[-1])
    use = min(0.9, n * rate * per_tracker / cores)
    latency = (float(probe['rtt']['p90']) + cmd) / (1.0 - use)
    return {
        'latency': round(latency, 6),
        'capacity': capacity,
        'rate': float(rate),
        'utilization': round(use, 3),
        'per_tracker_cpu': round(per_tracker, 7),
    }


def process_limit(probe: dict[str, Any], available: int | None = None) -> dict[str, int]:
    """The most tracker processes the bring-up starts without ``--allow-overload``.

    ``cpu``: one-tracker processes that fit in :data:`CPU_BUDGET` of the cores at the lowest
    of :data:`RATES` (:func:`derive`; a process of K trackers costs less); ``memory``: node
    processes of the probe's resident set that fit in :data:`MEMORY_BUDGET` of ``available``
    bytes (default: the memory available now); ``processes``: the smaller, at least 1."""
    if available is None:
        available = int(psutil.virtual_memory().available)
    cpu = derive(probe, 1, RATES[-1])['capacity'][f'{RATES[-1]:g}']
    memory = int(MEMORY_BUDGET * available / max(1, int(probe['process_rss'])))
    return {'processes': max(1, min(cpu, memory)), 'cpu': cpu, 'memory': memory}


def add_arguments(p: Any) -> None:
    """The options of ``apf-swarm probe``."""
    p.add_argument('--refresh', action='store_true', help='measure again')
    p.add_argument(
        '--n-trackers',
        type=int,
        default=16,
        metavar='N',
        help='the swarm size to derive the latency and default rate for',
    )
    p.add_argument('--json', action='store_true')


def run(args: Any) -> int:
    """``apf-swarm probe``: measure (or read the cache) and print what follows."""
    probe = ensure(args.refresh, say=lambda s: print(f'apf-swarm probe: {s}', file=sys.stderr))
    d = derive(probe, args.n_trackers)
    if args.json:
        print(
            json.dumps(
                {
                    'probe': probe,
                    'derived': d,
                    'n_trackers': args.n_trackers,
                    'process_limit': process_limit(probe),
                },
                indent=2,
            )
        )
        return 0
    m, r = probe['machine'], probe['rtt']
    print(f'{m["cpu"]}, {m["cores"]} cores ({probe["measured_at"]}, {cache_path()})')
    print(
        f'  round trip at {probe["rate"]:g} Hz: p50 {1e3 * r["p50"]:.2f} ms, p90 '
        f'{1e3 * r["p90"]:.2f} ms, p99 {1e3 * r["p99"]:.2f} ms; CPU per message '
        f'{1e6 * probe["cpu_per_message"]:.0f} us'
    )
    print(
        '  tracker command: '
        + ', '.join(f'{1e6 * v:.0f} us for {k}' for k, v in probe['command_cost'].items())
    )
    lim = process_limit(probe)
    print(
        f'  memory per node process {probe["process_rss"] / 2**20:.0f} MiB; the bring-up '
        f'starts up to {lim["processes"]} tracker processes (CPU at {RATES[-1]:g} Hz: '
        f'{lim["cpu"]}, memory: {lim["memory"]})'
    )
    print(
        f'  {args.n_trackers} trackers: latency {1e3 * d["latency"]:.2f} ms, default rate '
        f'{d["rate"]:g} Hz; trackers that fit in {CPU_BUDGET:.0%} of the cores: '
        + ', '.join(f'{v} at {k} Hz' for k, v in d['capacity'].items())
    )
    return 0


if __name__ == '__main__':
    # ``--measure``: the probe's own process (JSON on stdout); ``--echo``: its echo
    if sys.argv[1:] == ['--measure']:
        print(json.dumps(measure()))
        sys.exit(0)
    sys.exit(_echo() if sys.argv[1:] == ['--echo'] else 2)
