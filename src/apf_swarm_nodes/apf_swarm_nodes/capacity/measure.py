"""How the capacity probe measures this machine (:func:`measure`, JSON for :mod:`.probe`):
the round trip of a ``SwarmOdometry`` of 16 trackers between this process and an echo
process that publishes the CDR bytes back (p50 / p90 / p99 [s]); the echo's CPU per message
[s] and resident set [bytes] (what every node process costs at least); and the cost of one
tracker's state, offer and command, for :data:`COMMAND_SIZES` trackers [s]."""

from __future__ import annotations

import subprocess
import sys
import time
from typing import Any

import numpy as np

from .machine import identity, process_cpu_seconds, process_rss

__all__ = ['COMMAND_SIZES', 'echo', 'measure', 'ping_pong', 'state_cost']

#: tracker counts whose command cost is measured (others are interpolated, and extrapolated
#: linearly beyond: the block direction's cost grows with the tracker's own gradient)
COMMAND_SIZES = (3, 16, 32, 64, 128)
PING, PONG = '/apf_probe/ping', '/apf_probe/pong'


def state_cost(n: int, repeats: int = 200) -> tuple[float, float]:
    """Mean and p99 seconds of what one tracker does with one state: its
    :meth:`TrackerAgent.offer_swarm` of n trackers' states and its
    :meth:`TrackerAgent.command`, realtime preset (the median alone would hide the tail a
    deadline meets)."""
    from apf_swarm_core.agents import TrackerAgent
    from apf_swarm_core.config_files import load_preset

    cfg = load_preset('realtime').replace(n_trackers=n)
    agent = TrackerAgent(cfg, 1)
    rng = np.random.default_rng(0)
    x = rng.normal(scale=2.0, size=(n, 3))
    ids = list(range(1, n + 1))
    times = []
    for k in range(repeats + 10):
        t0 = time.perf_counter()
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
        agent.command(-1)
        times.append(time.perf_counter() - t0)
    arr = np.asarray(times[10:])  # the first calls warm the caches
    return float(arr.mean()), float(np.quantile(arr, 0.99))


def echo() -> int:
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


def ping_pong(seconds: float, rate: float, n: int) -> dict[str, Any]:
    """Round trips and the echo's CPU per message; rclpy initialized by the caller."""
    import rclpy
    from rclpy.qos import qos_profile_sensor_data

    from apf_swarm_msgs.msg import SwarmOdometry

    from ..conversions import swarm_odom_msg
    from ..lifetime import dying_with_parent, stop_process

    # it ends with this process, however this one ends (rclpy's SIGINT handler stops it)
    echo = subprocess.Popen(
        dying_with_parent(
            [sys.executable, '-m', 'apf_swarm_nodes.capacity.probe', '--echo'], 'INT'
        ),
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
    """Run the probe in this process (``python -m apf_swarm_nodes.capacity.probe --measure``
    does it in a process of its own, on a free domain, localhost only: :func:`.probe.ensure`)."""
    import rclpy

    measured = {str(k): state_cost(k) for k in COMMAND_SIZES}
    costs = {k: round(mean, 7) for k, (mean, _) in measured.items()}
    tails = {k: round(p99, 7) for k, (_, p99) in measured.items()}
    rclpy.init()
    try:
        pp = ping_pong(seconds, rate, n)
    finally:
        rclpy.try_shutdown()
    return {
        'machine': identity(),
        'measured_at': time.strftime('%Y-%m-%dT%H:%M:%SZ', time.gmtime()),
        **pp,
        'state_cost': costs,
        'state_cost_p99': tails,
    }
