#!/usr/bin/env python3
"""Benchmark of the bags: recorder against its ceiling (``BagWriter`` in-process); recorder: the
``recorder`` executable while this process publishes at paced rates (reliable, depth 1000): lost,
CPU per message net of idle, ratio to the ceiling; swarm: ``swarm_up.py --record``, plant at 100
(500) Hz; play: ``player`` at 100 Hz into this process, error against the schedule; info: ``bag
info`` against ``apf-swarm --help`` and ``open_bag`` in-process. Exit 1 when a case failed."""

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from _children import exit_on_signals, log, start, stop, swarm_up, table, timed
from apf_swarm_nodes.bringup import pick_domain_id
from apf_swarm_nodes.bringup.commands import executable_path, package_prefix
from apf_swarm_nodes.capacity.machine import process_cpu_seconds
from apf_swarm_nodes.dds.qos import qos_from_dict

from apf_swarm_nodes import bags

T0 = 1_700_000_000_000_000_000
QOS = {'history': 'keep_last', 'depth': 1000, 'reliability': 'reliable', 'durability': 'volatile'}


def cpu(pid: int) -> float:
    if (t := process_cpu_seconds(pid)) is None:
        raise RuntimeError(f'process {pid} exited while it was measured')
    return t


def odom_bytes() -> bytes:
    from nav_msgs.msg import Odometry
    from rclpy.serialization import serialize_message

    m = Odometry()
    m.header.frame_id, m.child_frame_id = 'world', 'uav_1'
    m.pose.pose.orientation.w = 1.0
    return serialize_message(m)


def write_bag(path: Path, topic: str, kind: str, msgs: list[bytes] | bytes, n: int, hz: float):
    with bags.BagWriter(path) as w:
        conn = w.add_topic(topic, kind, offered_qos=[qos_from_dict(QOS)])
        for i in range(n):
            w.write(conn, T0 + round(i * 1e9 / hz), msgs if isinstance(msgs, bytes) else msgs[i])


def ceiling(tmp: Path, n: int) -> list[Any]:
    c0, t0 = time.process_time(), time.perf_counter()
    write_bag(tmp / 'ceiling', '/bench/odom', 'nav_msgs/msg/Odometry', odom_bytes(), n, 1e6)
    wall, us = time.perf_counter() - t0, 1e6 * (time.process_time() - c0) / n
    return ['ceiling: BagWriter in-process', '-', f'{n / wall:,.0f}', '-', n, '-', f'{us:.1f}',
            '-', '1.0']  # fmt: skip


class Ros:
    """An rclpy context of its own in one domain."""

    def __init__(self, domain: int) -> None:
        import rclpy
        from rclpy.executors import SingleThreadedExecutor

        self.env = {**os.environ, 'ROS_DOMAIN_ID': str(domain)}
        self.env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
        self.ctx = rclpy.Context()
        rclpy.init(context=self.ctx, domain_id=domain)
        self.node = rclpy.create_node('bench_bags', context=self.ctx)
        self.ex = SingleThreadedExecutor(context=self.ctx)
        self.ex.add_node(self.node)

    def spin_until(self, cond: Any, timeout: float, what: str) -> None:
        end = time.monotonic() + timeout
        while not cond():
            if time.monotonic() > end:
                raise RuntimeError(f'timed out waiting for {what}')
            self.ex.spin_once(timeout_sec=0.01)

    def run(self, name: str, params: list[str], logf: Path) -> subprocess.Popen[bytes]:
        exe = executable_path(package_prefix(), name)
        argv = [str(exe), '--ros-args', *[a for p in params for a in ('-p', p)]]
        with logf.open('wb') as f:
            return start(argv, 'KILL', env=self.env, stdout=f, stderr=subprocess.STDOUT)

    def close(self) -> None:
        self.ex.shutdown()
        self.node.destroy_node()
        self.ctx.try_shutdown()


def recorder(tmp: Path, ros: Ros, rate: float, seconds: float, ceil: float) -> list[Any]:
    from nav_msgs.msg import Odometry
    from rclpy.qos import QoSProfile

    bag = tmp / f'rec_{rate:.0f}'
    p = ros.run('recorder', [f'output:={bag}', 'topics:=[/bench/odom]'], tmp / 'rec.log')
    pub = ros.node.create_publisher(Odometry, '/bench/odom', QoSProfile(depth=1000))
    try:
        ros.spin_until(lambda: pub.get_subscription_count() >= 1, 30, 'the recorder')
        time.sleep(0.5)
        idle0 = cpu(p.pid)
        time.sleep(1.0)
        idle, data, n = cpu(p.pid) - idle0, odom_bytes(), int(rate * seconds)
        cpu0, t0 = cpu(p.pid), time.perf_counter()
        for i in range(n):
            while time.perf_counter() < t0 + i / rate:
                pass
            pub.publish(data)
        wall = time.perf_counter() - t0
        time.sleep(2.0)  # it takes the rest
        used = cpu(p.pid) - cpu0
    finally:
        ros.node.destroy_publisher(pub)
        stop(p)
    meta = yaml.safe_load((bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    c = json.loads(meta['custom_data']['apf_swarm.recorder'])
    us = 1e6 * max(0.0, used - idle * (wall + 2.0)) / max(1, c['written'])  # net of idle
    return ['recorder', f'{rate:,.0f}', f'{n / wall:,.0f}', c['received'], c['written'],
            c['lost'], f'{us:.1f}', f'{100 * used / (wall + 2):.0f}',
            f'{us / ceil:.1f}']  # fmt: skip


def swarm(tmp: Path, publish_rate: float, seconds: float, domain: int) -> list[Any]:
    out = tmp / f'swarm_{publish_rate:.0f}'
    argv = swarm_up('--preset', 'realtime', '--mode', 'realtime', '--duration', f'{seconds:g}',
                    '--record', '--domain-id', domain, '--out', out,
                    '--node-param', f'publish_rate:={publish_rate}')  # fmt: skip
    p = start(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        _, err = p.communicate(timeout=seconds + 120)
    except subprocess.TimeoutExpired:
        err = b'timed out'
    finally:
        stop(p)
    if p.returncode != 0:
        log(f'swarm at {publish_rate:g} Hz exited {p.returncode}: {err[-2000:].decode()}')
        return [f'{publish_rate:g} Hz', *(['failed'] * 6)]
    s, info = json.loads((out / 'summary.json').read_text()), bags.open_bag(out / 'bag')
    r, state = s['recording'], f'{s["messages"]["received"]} / {info.topic("/swarm/state").count}'
    rate = f'{info.count / max(info.duration, 1e-9):,.0f}'
    return [f'{publish_rate:g} Hz', info.count, rate, r['written'], r['lost'], r['dropped'], state]


def play(tmp: Path, ros: Ros, n: int, hz: float) -> list[Any]:
    from rclpy.qos import QoSProfile
    from rclpy.serialization import serialize_message
    from std_msgs.msg import Int64

    path = tmp / 'play'
    msgs = [serialize_message(Int64(data=i)) for i in range(n)]
    write_bag(path, '/bench/play', 'std_msgs/msg/Int64', msgs, n, hz)
    got: list[tuple[int, int]] = []
    sub = ros.node.create_subscription(
        Int64, '/bench/play', lambda m, info: got.append((m.data, info['received_timestamp'])),
        QoSProfile(depth=1000))  # fmt: skip
    p = ros.run('player', [f'bag:={path}', 'wait_for:=[/bench/play]'], tmp / 'player.log')
    try:
        ros.spin_until(lambda: len(got) >= n, n / hz + 30, 'the played messages')
        p.wait(20)
    finally:
        stop(p)
        ros.node.destroy_subscription(sub)
    recv = np.array([r for _, r in got], dtype=np.int64)
    err = (recv - recv[0]) - np.round(np.arange(n) * 1e9 / hz)
    e = np.abs(err - np.median(err)) / 1e6
    m = re.search(r'p99 ([\d.]+) ms, max ([\d.]+) ms', (tmp / 'player.log').read_text())
    drift, order = (err[-1] - err[0]) / 1e6, [d for d, _ in got] == list(range(n))
    return [n, order, *(f'{v:.3f} ms' for v in np.percentile(e, [50, 99, 100])),
            f'{drift:+.3f} ms', ' / '.join(m.groups() if m else '--')]  # fmt: skip


def info(tmp: Path, n: int) -> list[Any]:
    from rclpy.serialization import serialize_message
    from std_msgs.msg import Int64

    path, data = tmp / 'info', serialize_message(Int64())
    write = timed(write_bag, path, '/bench/info', 'std_msgs/msg/Int64', data, n, 1e3)
    inproc = timed(bags.open_bag, path)
    assert bags.open_bag(path).count == n
    walls = [timed(subprocess.run, ['apf-swarm', *args], capture_output=True, check=True)
             for args in (['bag', 'info', str(path)], ['--help'])]  # fmt: skip
    size = sum(f.stat().st_size for f in path.glob('*.mcap')) / 1e6
    return [f'{n:,}', f'{size:.1f} MB', f'{write:.1f} s', f'{walls[0]:.2f} s',
            f'{walls[1]:.2f} s', f'{1e3 * inproc:.0f} ms']  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--quick', action='store_true', help='fewer rates, shorter windows')
    ap.add_argument('--smoke', action='store_true', help='one short case of each (seconds)')
    args = ap.parse_args(argv)
    exit_on_signals()
    quick, smoke = args.quick or args.smoke, args.smoke
    rates = (1000,) if smoke else (1000, 4000) if quick else (1000, 4000, 8000, 16000)
    seconds = 1.0 if smoke else 2.0 if quick else 4.0
    domain = pick_domain_id(lo=202, hi=232)
    print(f'{os.cpu_count()} cores, load {os.getloadavg()[0]:.2f}; domain {domain}\n')
    with tempfile.TemporaryDirectory(prefix='bench_bags_') as tmpd:
        tmp = Path(tmpd)
        ros = Ros(domain)
        try:
            recs = [ceiling(tmp, 2000 if smoke else 20000 if quick else 100000)]
            for r in rates:
                log(f'recorder at {r} msg/s')
                recs.append(recorder(tmp, ros, float(r), seconds, float(recs[0][6])))
            log('play at 100 Hz')
            pl = play(tmp, ros, 100 if smoke else 300 if quick else 1000, 100.0)
        finally:
            ros.close()
        swarms = []
        for pr in (100.0,) if quick else (100.0, 500.0):
            log(f'realtime swarm recorded, publish_rate {pr:g} Hz')
            other = pick_domain_id(exclude=[domain], lo=202, hi=232)
            swarms.append(swarm(tmp, pr, 3.0 if smoke else 5.0 if quick else 10.0, other))
        log('bag info on a big bag')
        big = info(tmp, 10_000 if smoke else 100_000 if quick else 1_000_000)
    print('### Recorder against its ceiling (nav_msgs/Odometry)\n')
    head = 'case | offered msg/s: | achieved msg/s: | received: | written: | lost: | '
    print(table(head + 'CPU µs/msg: | CPU %: | recorder / ceiling:', recs) + '\n')
    print('### Recording the realtime swarm\n')
    head = 'plant rate: | messages: | msg/s: | written: | lost: | dropped: | state live / bag:'
    print(table(head, swarms) + '\n')
    print('### Playback at 100 Hz\n')
    head = 'messages: | in order | error p50: | p99: | max: | drift: | player late p99 / max [ms]:'
    print(table(head, [pl]) + '\n')
    print('### `apf-swarm bag info` on a big bag\n')
    head = 'messages: | size: | write: | `bag info`: | `apf-swarm --help`: | `open_bag`:'
    print(table(head, [big]))
    return 1 if any('failed' in r for r in swarms) or not pl[1] else 0


if __name__ == '__main__':
    sys.exit(main())
