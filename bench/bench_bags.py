#!/usr/bin/env python3
"""Benchmark of the bags: recorder throughput and CPU against its ceiling, drops while
recording the realtime swarm, playback timing, ``bag info`` on a bag of 1 M messages.

    source scripts/activate.sh
    python bench/bench_bags.py [--quick | --smoke]

* **ceiling**: :class:`apf_swarm_nodes.bags.BagWriter` fed directly in this process with the
  same serialized ``nav_msgs/Odometry`` bytes the recorder gets (no DDS): messages/s and CPU
  per message. It bounds any recorder built on it.
* **recorder**: the ``recorder`` executable (its own process, ``topics:=[/bench/odom]``) while
  this process publishes those bytes (reliable, keep last 1000) at a paced offered rate; per
  rate: what it received, wrote and lost (publication sequence gaps), its CPU per message
  (``/proc/<pid>/stat``) and the ratio of that CPU to the ceiling's. Each rate is a fresh
  recorder and bag.
* **realtime swarm**: ``swarm_up.py --preset realtime --mode realtime --record`` with the
  plant's ``publish_rate`` at 100 Hz (default) and higher; the recorder's counts and
  ``/swarm/state`` recorded against what the bring-up received.
* **play**: a bag of ``std_msgs/Int64`` at 100 Hz played by the ``player`` executable into a
  listener in this process; error = DDS reception time - scheduled time, minus its median;
  p50 / p99 / max of its absolute value, and the player's own lateness (its last log line).
* **info**: a bag of 1 M ``std_msgs/Int64`` (100 k with ``--quick``) written with BagWriter;
  ``apf-swarm bag info`` wall time (a new interpreter, as a user runs it) and ``open_bag`` in
  this process.

Domains: two that look unused (no bound UDP / shared-memory port of their range,
:func:`apf_swarm_nodes.bringup.pick_domain_id`) in 202..232, away from make test (1..100) and
the integration tests (102..201); one for the recorder and play cases, one for the swarm runs
(a swarm of another job on the same domain once doubled the recorded /swarm/state).
Output: progress on stderr, Markdown tables on stdout. Exit 0 unless a case failed to run.
"""

from __future__ import annotations

import json
import os
import platform
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from apf_swarm_nodes.capacity.machine import process_cpu_seconds
from apf_swarm_nodes.dds.qos import qos_from_dict

ROOT = Path(__file__).resolve().parents[1]

from _children import dying_with_parent, exit_on_signals  # noqa: E402  (bench/ is on sys.path)

T0 = 1_700_000_000_000_000_000


def log(msg: str) -> None:
    print(f'[bench_bags] {msg}', file=sys.stderr, flush=True)


def cpu_seconds(pid: int) -> float:
    t = process_cpu_seconds(pid)
    if t is None:
        raise RuntimeError(f'process {pid} exited while it was measured')
    return t


def odom_bytes() -> bytes:
    from nav_msgs.msg import Odometry
    from rclpy.serialization import serialize_message

    m = Odometry()
    m.header.frame_id = 'world'
    m.child_frame_id = 'uav_1'
    m.pose.pose.position.x = 1.5
    m.pose.pose.orientation.w = 1.0
    return serialize_message(m)


def qos_reliable():

    return qos_from_dict(
        {
            'history': 'keep_last',
            'depth': 1000,
            'reliability': 'reliable',
            'durability': 'volatile',
        }
    )


# --------------------------------------------------------------------------------------------


def bench_ceiling(tmp: Path, n: int) -> dict:
    from apf_swarm_nodes import bags

    data = odom_bytes()
    w = bags.BagWriter(tmp / 'ceiling')
    w.open()
    conn = w.add_topic('/bench/odom', 'nav_msgs/msg/Odometry', offered_qos=[qos_reliable()])
    c0, t0 = time.process_time(), time.perf_counter()
    for i in range(n):
        w.write(conn, T0 + i * 1000, data)
    w.close()
    cpu, wall = time.process_time() - c0, time.perf_counter() - t0
    return {
        'n': n,
        'size': len(data),
        'rate': n / wall,
        'cpu_us': 1e6 * cpu / n,
        'mb_s': n * len(data) / wall / 1e6,
    }


class Ros:
    """An rclpy context of its own in one domain."""

    def __init__(self, domain: int) -> None:
        import rclpy
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.node import Node

        self.domain = domain
        self.env = {
            **os.environ,
            'ROS_DOMAIN_ID': str(domain),
            'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST',
        }
        self.ctx = Context()
        rclpy.init(context=self.ctx, domain_id=domain)
        self.node = Node('bench_bags', context=self.ctx)
        self.ex = SingleThreadedExecutor(context=self.ctx)
        self.ex.add_node(self.node)

    def spin_until(self, cond, timeout: float, what: str) -> None:
        end = time.monotonic() + timeout
        while not cond():
            if time.monotonic() > end:
                raise RuntimeError(f'timed out waiting for {what}')
            self.ex.spin_once(timeout_sec=0.01)

    def close(self) -> None:
        import rclpy

        self.ex.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.ctx)


def exe(name: str) -> str:
    from ament_index_python.packages import get_package_prefix

    return str(Path(get_package_prefix('apf_swarm_nodes')) / 'lib' / 'apf_swarm_nodes' / name)


def stop(p: subprocess.Popen, timeout: float = 30.0) -> int | None:
    from apf_swarm_nodes.bringup import stop_process

    return stop_process(p, ((signal.SIGINT, timeout), (signal.SIGKILL, 5.0)))


def bench_recorder(tmp: Path, ros: Ros, rate: float, seconds: float) -> dict:
    from nav_msgs.msg import Odometry
    from rclpy.qos import QoSProfile

    bag = tmp / f'rec_{int(rate)}'
    log_path = tmp / f'rec_{int(rate)}.log'
    with open(log_path, 'wb') as lf:
        p = subprocess.Popen(
            dying_with_parent(
                [
                    exe('recorder'),
                    '--ros-args',
                    '-p',
                    f'output:={bag}',
                    '-p',
                    'topics:=[/bench/odom]',
                ]
            ),
            env=ros.env,
            stdout=lf,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
    pub = ros.node.create_publisher(Odometry, '/bench/odom', QoSProfile(depth=1000))
    try:
        ros.spin_until(lambda: pub.get_subscription_count() >= 1, 30, 'the recorder')
        time.sleep(0.5)  # let its discovery settle before measuring CPU
        idle0 = cpu_seconds(p.pid)
        time.sleep(1.0)
        idle = cpu_seconds(p.pid) - idle0  # CPU per second with nothing to record
        data = odom_bytes()
        n = int(rate * seconds)
        cpu0 = cpu_seconds(p.pid)
        t0 = time.perf_counter()
        for i in range(n):
            due = t0 + i / rate
            while time.perf_counter() < due:
                pass
            pub.publish(data)
        wall = time.perf_counter() - t0
        # wait until it has taken everything (status counts) or 5 s
        time.sleep(2.0)
        cpu = cpu_seconds(p.pid) - cpu0
        busy = max(0.0, cpu - idle * (wall + 2.0))
        rc = stop(p)
    finally:
        ros.node.destroy_publisher(pub)
        if p.poll() is None:
            stop(p)
    import yaml

    meta = yaml.safe_load((bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    c = json.loads(meta['custom_data']['apf_swarm.recorder'])
    return {
        'rate': rate,
        'achieved': n / wall,
        'sent': n,
        'received': c['received'],
        'written': c['written'],
        'lost': c['lost'],
        'dropped': n - c['written'],
        'cpu_us': 1e6 * busy / max(1, c['written']),
        'cpu_pct': 100 * cpu / (wall + 2.0),
        'idle_pct': 100 * idle,
        'rc': rc,
    }


def bench_swarm(tmp: Path, publish_rate: float, seconds: float, domain: int) -> dict:
    out = tmp / f'swarm_{int(publish_rate)}'
    argv = [
        sys.executable,
        str(ROOT / 'scripts' / 'swarm_up.py'),
        '--preset',
        'realtime',
        '--mode',
        'realtime',
        '--duration',
        str(seconds),
        '--record',
        '--no-plots',
        '--domain-id',
        str(domain),
        '--out',
        str(out),
        '--node-param',
        f'publish_rate:={publish_rate}',
    ]
    t0 = time.perf_counter()
    p = subprocess.run(
        dying_with_parent(argv),
        capture_output=True,
        text=True,
        timeout=seconds + 120,
        cwd=ROOT,
    )
    wall = time.perf_counter() - t0
    if p.returncode != 0:
        log(f'swarm at {publish_rate} Hz exited {p.returncode}: {p.stderr[-2000:]}')
        return {'publish_rate': publish_rate, 'error': f'exit {p.returncode}'}
    s = json.loads((out / 'summary.json').read_text())
    from apf_swarm_nodes import bags

    info = bags.open_bag(out / 'bag')
    r = s['recording']
    return {
        'publish_rate': publish_rate,
        'wall': wall,
        'messages': info.count,
        'rate': info.count / max(info.duration, 1e-9),
        'received': r['received'],
        'written': r['written'],
        'lost': r['lost'],
        'dropped': r['dropped'],
        'state_live': s['messages']['received'],
        'state_bag': info.topic('/swarm/state').count,
    }


def bench_play(tmp: Path, ros: Ros, n: int, hz: float) -> dict:
    from rclpy.qos import QoSProfile
    from rclpy.serialization import serialize_message
    from std_msgs.msg import Int64

    from apf_swarm_nodes import bags

    path = tmp / f'play_{n}'
    stamps = []
    with bags.BagWriter(path) as w:
        conn = w.add_topic('/bench/play', 'std_msgs/msg/Int64', offered_qos=[qos_reliable()])
        for i in range(n):
            ts = T0 + int(round(i * 1e9 / hz))
            w.write(conn, ts, serialize_message(Int64(data=i)))
            stamps.append(ts)
    got: list[tuple[int, int]] = []
    sub = ros.node.create_subscription(
        Int64,
        '/bench/play',
        lambda m, info: got.append((m.data, info['received_timestamp'])),
        QoSProfile(depth=1000),
    )
    log_path = tmp / 'player.log'
    with open(log_path, 'wb') as lf:
        p = subprocess.Popen(
            dying_with_parent(
                [
                    exe('player'),
                    '--ros-args',
                    '-p',
                    f'bag:={path}',
                    '-p',
                    'wait_for:=[/bench/play]',
                ]
            ),
            env=ros.env,
            stdout=lf,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
    try:
        ros.spin_until(lambda: len(got) >= n, n / hz + 30, 'the played messages')
        p.wait(20)
    finally:
        stop(p)
        ros.node.destroy_subscription(sub)
    order_ok = [d for d, _ in got] == list(range(n))
    recv = np.array([r for _, r in got], dtype=np.int64)
    err = (recv - recv[0]) - (np.array(stamps) - stamps[0])
    e = np.abs(err - np.median(err)) / 1e6
    m = re.search(r'p50 ([\d.]+) ms, p99 ([\d.]+) ms, max ([\d.]+) ms', log_path.read_text())
    return {
        'n': n,
        'hz': hz,
        'in_order': order_ok,
        'p50': float(np.percentile(e, 50)),
        'p99': float(np.percentile(e, 99)),
        'max': float(e.max()),
        'drift_ms': float((err[-1] - err[0]) / 1e6),
        'player_p99': float(m.group(2)) if m else float('nan'),
        'player_max': float(m.group(3)) if m else float('nan'),
    }


def bench_info(tmp: Path, n: int) -> dict:
    from rclpy.serialization import serialize_message
    from std_msgs.msg import Int64

    from apf_swarm_nodes import bags

    path = tmp / f'info_{n}'
    data = serialize_message(Int64(data=7))
    t0 = time.perf_counter()
    with bags.BagWriter(path) as w:
        conn = w.add_topic('/bench/info', 'std_msgs/msg/Int64', offered_qos=[qos_reliable()])
        for i in range(n):
            w.write(conn, T0 + i * 1_000_000, data)
    write_s = time.perf_counter() - t0
    size = sum(f.stat().st_size for f in path.glob('*.mcap'))
    t0 = time.perf_counter()
    info = bags.open_bag(path)
    inproc = time.perf_counter() - t0
    assert info.count == n
    apf = shutil.which('apf-swarm') or 'apf-swarm'
    t0 = time.perf_counter()
    p = subprocess.run([apf, 'bag', 'info', str(path)], capture_output=True, text=True)
    cli = time.perf_counter() - t0
    assert p.returncode == 0, p.stderr
    t0 = time.perf_counter()
    p = subprocess.run([apf, '--help'], capture_output=True, text=True)
    startup = time.perf_counter() - t0
    return {
        'n': n,
        'size_mb': size / 1e6,
        'write_s': write_s,
        'inproc_s': inproc,
        'cli_s': cli,
        'startup_s': startup,
    }


# --------------------------------------------------------------------------------------------


def main(argv: list[str]) -> int:
    import argparse

    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--quick', action='store_true', help='fewer rates, shorter windows')
    ap.add_argument('--smoke', action='store_true', help='one short case of each (seconds)')
    args = ap.parse_args(argv)
    exit_on_signals()
    quick, smoke = args.quick or args.smoke, args.smoke
    rates = (1000,) if smoke else (1000, 4000) if quick else (1000, 4000, 8000, 16000)
    seconds = 1.0 if smoke else 2.0 if quick else 4.0
    swarm_rates = (100.0,) if quick else (100.0, 500.0)
    from apf_swarm_nodes.bringup import pick_domain_id

    domain = pick_domain_id(lo=202, hi=232)
    load0 = os.getloadavg()[0]
    log(f'{platform.node()}: {os.cpu_count()} cores, load {os.getloadavg()[0]:.2f}')
    with tempfile.TemporaryDirectory(prefix='bench_bags_') as tmpd:
        tmp = Path(tmpd)
        log('ceiling: BagWriter fed directly')
        ceiling = bench_ceiling(tmp, 2000 if smoke else 20000 if quick else 100000)
        ros = Ros(domain)
        try:
            recs = []
            for r in rates:
                log(f'recorder at {r} msg/s offered')
                recs.append(bench_recorder(tmp, ros, float(r), seconds))
            log('play at 100 Hz')
            play = bench_play(tmp, ros, 100 if smoke else 300 if quick else 1000, 100.0)
        finally:
            ros.close()
        swarms = []
        for _i, pr in enumerate(swarm_rates):
            log(f'realtime swarm, publish_rate {pr:g} Hz, recorded')
            swarms.append(
                bench_swarm(
                    tmp,
                    pr,
                    3.0 if smoke else 5.0 if quick else 10.0,
                    pick_domain_id(exclude=[domain], lo=202, hi=232),
                )
            )
        log('info on a big bag')
        info = bench_info(tmp, 10_000 if smoke else 100_000 if quick else 1_000_000)

    print(
        f'Machine: {os.cpu_count()} cores, load average at the start {load0:.2f}, at the end '
        f'{os.getloadavg()[0]:.2f}; {"--quick" if quick else "full"} run; ROS_DOMAIN_ID '
        f"{domain} (recorder, play) and the swarm runs' own.\n"
    )
    print(
        f'### Recorder throughput against its ceiling (nav_msgs/Odometry, {ceiling["size"]} B)\n'
    )
    print(
        '| case | offered msg/s | achieved msg/s | received | written | lost | dropped | '
        'CPU µs/msg (net of idle) | CPU % of a core (idle %) | one core would take msg/s | '
        'ceiling / recorder |'
    )
    print('|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|')
    ceil_cap = 1e6 / ceiling['cpu_us']
    print(
        f'| ceiling: BagWriter in-process | - | {ceiling["rate"]:,.0f} | {ceiling["n"]} | '
        f'{ceiling["n"]} | - | 0 | {ceiling["cpu_us"]:.1f} | '
        f'{100 * ceiling["cpu_us"] * ceiling["rate"] / 1e6:.0f} | {ceil_cap:,.0f} | 1.0 |'
    )
    for r in recs:
        cap = 1e6 / r['cpu_us'] if r['cpu_us'] > 0 else float('inf')
        print(
            f'| recorder process | {r["rate"]:,.0f} | {r["achieved"]:,.0f} | {r["received"]} | '
            f'{r["written"]} | {r["lost"]} | {r["dropped"]} | {r["cpu_us"]:.1f} | '
            f'{r["cpu_pct"]:.0f} ({r["idle_pct"]:.1f}) | {cap:,.0f} | '
            f'{r["cpu_us"] / ceiling["cpu_us"]:.1f} |'
        )
    print(
        f'\nCeiling: {ceiling["rate"]:,.0f} msg/s ({ceiling["mb_s"]:.1f} MB/s) measured, '
        f'{ceil_cap:,.0f} msg/s per core of CPU. "ceiling / recorder" is the ratio of CPU per '
        'message (robust to other load); "one core would take" = 1e6 / CPU µs per message. '
        'lost = publication sequence gaps the recorder saw (samples overwritten in the '
        'keep-last-1000 publisher history before it took them).\n'
    )
    print('### Recording the realtime swarm\n')
    print(
        '| plant publish_rate | messages | msg/s recorded | received | written | lost | '
        'dropped | /swarm/state live / bag |'
    )
    print('|---:|---:|---:|---:|---:|---:|---:|---:|')
    for s in swarms:
        if 'error' in s:
            print(f'| {s["publish_rate"]:g} Hz | {s["error"]} | | | | | | |')
            continue
        print(
            f'| {s["publish_rate"]:g} Hz | {s["messages"]} | {s["rate"]:,.0f} | '
            f'{s["received"]} | {s["written"]} | {s["lost"]} | {s["dropped"]} | '
            f'{s["state_live"]} / {s["state_bag"]} |'
        )
    print('\n### Playback timing at 100 Hz\n')
    print(
        '| messages | in order | error p50 | p99 | max | drift first→last | player lateness '
        'p99 / max |'
    )
    print('|---:|---|---:|---:|---:|---:|---:|')
    print(
        f'| {play["n"]} | {play["in_order"]} | {play["p50"]:.3f} ms | {play["p99"]:.3f} ms | '
        f'{play["max"]:.3f} ms | {play["drift_ms"]:+.3f} ms | {play["player_p99"]:.3f} / '
        f'{play["player_max"]:.3f} ms |'
    )
    print('\n### `apf-swarm bag info` on a big bag\n')
    print(
        '| messages | bag size | write (BagWriter) | `bag info` (new process) | '
        '`apf-swarm --help` (start-up alone) | `open_bag` in-process |'
    )
    print('|---:|---:|---:|---:|---:|---:|')
    print(
        f'| {info["n"]:,} | {info["size_mb"]:.1f} MB | {info["write_s"]:.1f} s | '
        f'{info["cli_s"]:.2f} s | {info["startup_s"]:.2f} s | {info["inproc_s"] * 1e3:.0f} ms |'
    )
    failed = [f'swarm at {s["publish_rate"]:g} Hz' for s in swarms if 'error' in s]
    if failed:
        print(f'\nFailed to run: {", ".join(failed)}.')
    return 1 if failed else 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
