"""The bring-up's stop watchdog (bringup.supervision.Signals) in a real process whose main
thread never returns to Python: a SIGTERM still ends it within the bound."""

from __future__ import annotations

import signal
import subprocess
import sys
import textwrap
import time

import pytest

SCRIPT = textwrap.dedent(
    """
    import sys, threading
    from apf_swarm_nodes.bringup.supervision import Signals
    s = Signals(bound=float(sys.argv[1]))
    s.install()
    if len(sys.argv) > 2:
        s.arm()  # stopping begins: the bound runs without a signal
    print('ready', flush=True)
    lock = threading.Lock()
    lock.acquire()
    lock.acquire()  # blocks for ever: the handler only sets a flag, as in a DDS call
    """
)


def _blocked(bound: float, *extra: str) -> subprocess.Popen[str]:
    p = subprocess.Popen(
        [sys.executable, '-c', SCRIPT, str(bound), *extra],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    assert p.stdout is not None and p.stdout.readline().strip() == 'ready'
    return p


def test_sigterm_ends_a_run_whose_main_thread_is_blocked_within_the_bound() -> None:
    p = _blocked(1.0)
    try:
        t0 = time.monotonic()
        p.send_signal(signal.SIGTERM)
        rc = p.wait(10)
        took = time.monotonic() - t0
    finally:
        p.kill()
    assert rc == 130
    assert 1.0 <= took < 10.0
    assert 'exiting now' in p.stderr.read()


@pytest.mark.parametrize('second', [signal.SIGINT, signal.SIGTERM])
def test_a_second_signal_shortens_the_bound(second) -> None:
    p = _blocked(60.0)
    try:
        p.send_signal(signal.SIGTERM)
        time.sleep(0.3)
        # the positive control: the bound holds, the process is still there
        assert p.poll() is None
        t0 = time.monotonic()
        p.send_signal(second)
        rc = p.wait(15)
        assert rc == 130 and time.monotonic() - t0 < 15.0
    finally:
        p.kill()


def test_a_stop_that_hangs_without_any_signal_ends_within_the_bound() -> None:
    """The run's own stop (its end, a failed start) arms the bound: a shutdown blocked in
    DDS after the nodes were killed (the 85-minute hang) ends too."""
    t0 = time.monotonic()
    p = _blocked(1.0, 'arm')
    try:
        rc = p.wait(10)
    finally:
        p.kill()
    assert rc == 130 and time.monotonic() - t0 < 10.0


NODE_SCRIPT = textwrap.dedent(
    """
    import sys, threading
    from rclpy.node import Node
    from apf_swarm_nodes import node_common
    node_common.NODE_STOP_BOUND = float(sys.argv[1])

    def blocked(node):
        print('ready', flush=True)
        if sys.argv[2] == 'blocked':
            lock = threading.Lock()
            lock.acquire()
            lock.acquire()  # never returns to Python, as a call blocked in DDS
        while node_common.running():
            threading.Event().wait(0.05)

    sys.exit(node_common.run_node('blocked_node', lambda: Node('blocked_node'), [], run=blocked))
    """
)


def _node(bound: float, how: str) -> subprocess.Popen[str]:
    import os

    from apf_swarm_nodes.bringup import pick_domain_id

    env = {**os.environ, 'ROS_DOMAIN_ID': str(pick_domain_id(lo=102, hi=201))}
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    p = subprocess.Popen(
        [sys.executable, '-c', NODE_SCRIPT, str(bound), how],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )
    assert p.stdout is not None and p.stdout.readline().strip() == 'ready', p.stderr
    return p


@pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGTERM])
def test_a_node_blocked_in_a_call_ends_within_its_bound_after_a_stop_signal(sig) -> None:
    """A node process (node_common.run_node, as every node, the player and `bag play`) whose
    main thread never returns to Python: the stop signal's handler cannot run, its watchdog
    ends it (a node started by hand, or whose bring-up died, nobody escalates for)."""
    p = _node(1.0, 'blocked')
    try:
        time.sleep(0.5)
        assert p.poll() is None  # the positive control: blocked, it has not ended by itself
        t0 = time.monotonic()
        p.send_signal(sig)
        rc = p.wait(15)
        took = time.monotonic() - t0
    finally:
        p.kill()
    err = p.stderr.read() if p.stderr else ''
    assert rc == 130, err
    assert 1.0 <= took < 15.0
    assert f'blocked_node: still not ended 1 s after {sig.name}' in err, err


def test_a_node_that_is_not_blocked_stops_cleanly_on_sigint() -> None:
    """The watchdog changes nothing for a node that stops in time: exit 0, no line."""
    p = _node(1.0, 'free')
    try:
        p.send_signal(signal.SIGINT)
        rc = p.wait(15)
    finally:
        p.kill()
    err = p.stderr.read() if p.stderr else ''
    assert rc == 0, err
    assert 'still not ended' not in err
