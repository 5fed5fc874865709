"""Helpers for topic-level tests: real node processes, an isolated domain, bounded waits."""

from __future__ import annotations

import os
import signal
import subprocess
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
import rclpy
from ament_index_python.packages import get_package_prefix
from apf_swarm_nodes.bringup import pick_domain_id, stop_process
from apf_swarm_nodes.dds.profiles import localhost_environment, write_profile
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node

LIB = Path(get_package_prefix('apf_swarm_nodes')) / 'lib' / 'apf_swarm_nodes'
ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / 'config'


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Every test of this directory runs real node processes: marked ``integration``."""
    here = Path(__file__).parent
    for item in items:
        if here in Path(str(item.path)).parents:
            item.add_marker(pytest.mark.integration)


@pytest.fixture(autouse=True, scope='session')
def _no_shared_memory_left_behind():
    """Tests that SIGKILL a participant outside a bring-up (a recorder, a node started by
    hand) leave its Fast DDS files: removed once the tests are done, as a run removes its
    own (only what no live process holds)."""
    yield
    from apf_swarm_nodes.dds.shm import remove_stale

    remove_stale()


def free_domain_id() -> int:
    """A domain id for this test in 102..201, away from make test's 1..100: one with no bound
    port and not leased by another picker (``pick_domain_id``)."""
    return pick_domain_id(lo=102, hi=201)


class Graph:
    """Node processes in one isolated domain, and an in-process rclpy node to observe them."""

    def __init__(self, tmp: Path, domain_id: int | None = None) -> None:
        self.domain_id = domain_id if domain_id is not None else free_domain_id()
        self.env = {
            **os.environ,
            'ROS_DOMAIN_ID': str(self.domain_id),
            'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST',
        }
        self.tmp = tmp
        self.procs: dict[str, subprocess.Popen] = {}
        self.context = Context()
        rclpy.init(context=self.context, domain_id=self.domain_id)
        self.node = Node('test_observer', context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)

    def start(
        self, name: str, exe: str, *ros_args: str, env: dict[str, str] | None = None
    ) -> subprocess.Popen:
        """Start node ``exe`` as ``name`` (its output in ``name.log``); ``env``: variables
        for this process only, over the graph's (e.g. :meth:`no_shared_memory`)."""
        with open(self.tmp / f'{name}.log', 'w') as log:  # the child keeps its own copy
            p = subprocess.Popen(
                [str(LIB / exe), '--ros-args', *ros_args],
                env={**self.env, **(env or {})},
                stdout=log,
                stderr=subprocess.STDOUT,
                start_new_session=True,
            )
        self.procs[name] = p
        return p

    def no_shared_memory(self) -> dict[str, str]:
        """The variables (for :meth:`start`) that put one node process on UDP on 127.0.0.1
        only, off Fast DDS shared memory: for a process the test freezes (SIGSTOP).

        A shared-memory port is guarded by a mutex in memory mapped by every participant
        that writes into it: a push into the port and Fast DDS's port watchdog (each
        participant checks every port it writes to about once a second) lock it. A process
        stopped while one of its threads holds the mutex of the plant's port stalls every
        tracker's publish into that port for the lock's timeout (1 s in Fast DDS 2.14), and
        the plant counts all of them missed at one step: a second fault, not the one the test
        injects. Over UDP a stopped process only stops receiving (the kernel drops what its
        socket cannot hold); no peer waits for it."""
        profile = write_profile(self.tmp / 'udp_only.xml', localhost=True, shm=False)
        # LOCALHOST would make rmw add its own shared-memory transport to the profile's
        return localhost_environment(profile)

    def log(self, name: str) -> str:
        return (self.tmp / f'{name}.log').read_text()

    def spin_until(
        self, cond: Callable[[], bool], timeout: float, what: str, fail: bool = True
    ) -> bool:
        """Spin the observer until ``cond()`` holds (True); after ``timeout`` s fail naming
        ``what``, or with ``fail=False`` return False. A node process that died fails."""
        end = time.monotonic() + timeout
        while not cond():
            if time.monotonic() > end:
                if not fail:
                    return False
                raise AssertionError(f'timed out after {timeout:g} s waiting for {what}')
            for name, p in self.procs.items():
                if p.poll() is not None and p.returncode != 0:
                    raise AssertionError(f'{name} exited with {p.returncode}:\n{self.log(name)}')
            self.executor.spin_once(timeout_sec=0.02)
        return True

    def call(self, send: Callable[[], Any], timeout: float, what: str, resend: float = 2.0) -> Any:
        """The result of the service future ``send()`` returns, re-sent every ``resend`` s
        until answered or ``timeout`` s: a server that has not yet matched the client's
        response reader drops the response (rmw_fastrtps waits 100 ms for the match), so
        one request can go unanswered on a loaded machine."""
        end = time.monotonic() + timeout
        while True:
            future = send()
            left = end - time.monotonic()
            if self.spin_until(future.done, max(0.0, min(resend, left)), what, fail=False):
                return future.result()
            future.cancel()
            if time.monotonic() >= end:
                raise AssertionError(
                    f'timed out after {timeout:g} s waiting for {what} '
                    f'(re-sent every {resend:g} s)'
                )

    def stop(self, name: str, timeout: float = 5.0) -> int:
        """SIGINT the process group, then SIGKILL; returns the exit code."""
        return stop_process(
            self.procs.pop(name), ((signal.SIGINT, timeout), (signal.SIGKILL, timeout))
        )

    def lone_tracker(self, *params: str) -> tuple[list[Any], Any]:
        """A tracker process ``/uav_2/tracker`` of the triangle preset (lockstep) with the
        extra ``params`` (``NAME:=VALUE``), and a reader of its commands: the list the
        commands arrive in and the subscription (wait on its publisher count)."""
        from apf_swarm_nodes.node_common import control_qos

        from apf_swarm_msgs.msg import ForceCommand

        args = [a for p in ('uav_id:=2', *params) for a in ('-p', p)]
        self.start(
            'tracker',
            'tracker',
            '--params-file',
            str(CONFIG / 'triangle.yaml'),
            *args,
            '-r',
            '__ns:=/uav_2',
        )
        forces: list[ForceCommand] = []
        sub = self.node.create_subscription(
            ForceCommand, '/uav_2/force_cmd', forces.append, control_qos('lockstep')
        )
        return forces, sub

    def close(self) -> None:
        for name in list(self.procs):
            self.stop(name)
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


@pytest.fixture
def graph(tmp_path: Path):
    """An isolated domain with an observer node; every process it started is stopped after."""
    g = Graph(tmp_path)
    yield g
    g.close()
