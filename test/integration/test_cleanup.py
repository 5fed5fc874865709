"""Nothing left behind: a run ends within its bound however it is stopped, leaves no process
and no Fast DDS shared memory, also when nodes were killed mid-run; ``apf-swarm clean``
removes what a killed participant left.

Every run gets its own domain (102..201) and ``--out`` under ``tmp_path``; waits are bounded
polls; every process a run started (found by its ``config.yaml`` on their command lines) is
stopped by PID at the end, also on failure. ``/dev/shm`` is shared with every other job of
the machine: a run's leftovers are the entries that appeared while it ran and that no live
process holds once it has ended (``shm.unheld``; other jobs' live participants hold theirs).
"""

from __future__ import annotations

import contextlib
import json
import os
import random
import re
import signal
import subprocess
import sys
import textwrap
import time
from collections.abc import Callable
from pathlib import Path

import psutil
import pytest
from apf_swarm_nodes.bringup import pick_domain_id
from apf_swarm_nodes.dds.shm import fastdds_entries, unheld

ROOT = Path(__file__).resolve().parents[2]
SWARM_UP = ROOT / 'scripts' / 'swarm_up.py'


def wait_for(cond: Callable[[], bool], timeout: float, what: str) -> None:
    end = time.monotonic() + timeout
    while not cond():
        if time.monotonic() > end:
            raise AssertionError(f'timed out after {timeout:g} s waiting for {what}')
        time.sleep(0.05)


def alive(p: psutil.Process) -> bool:
    """Whether ``p`` still runs (a zombie or a process gone meanwhile does not)."""
    try:
        return p.is_running() and p.status() != psutil.STATUS_ZOMBIE
    except psutil.Error:
        return False


def _procs_naming(needle: str) -> list[psutil.Process]:
    out = []
    for p in psutil.process_iter(['cmdline', 'status']):
        try:
            if p.info['status'] != psutil.STATUS_ZOMBIE and needle in ' '.join(
                p.info['cmdline'] or []
            ):
                out.append(p)
        except psutil.Error:
            continue
    return out


class Run:
    """``swarm_up.py ARGS --domain-id D --out DIR --no-plots`` in its own session."""

    def __init__(self, tmp: Path, name: str, *args: str) -> None:
        self.out = (tmp / name).resolve()
        self.config = str(self.out / 'config.yaml')
        self.err_path = tmp / f'{name}.stderr'
        argv = [sys.executable, str(SWARM_UP), *args]
        argv += ['--domain-id', str(pick_domain_id(lo=102, hi=201))]
        argv += ['--out', str(self.out), '--no-plots']
        with open(self.err_path, 'wb') as err:
            self.popen = subprocess.Popen(
                argv,
                stdin=subprocess.DEVNULL,
                stdout=subprocess.DEVNULL,
                stderr=err,
                cwd=ROOT,
                start_new_session=True,
            )
        self.seen: dict[int, psutil.Process] = {}

    def stderr(self) -> str:
        return self.err_path.read_text(errors='replace')

    def nodes(self) -> list[psutil.Process]:
        now = _procs_naming(self.config)
        self.seen.update({p.pid: p for p in now})
        return now

    def sim_time(self) -> float:
        found = re.findall(r': t +([0-9.]+)/', self.stderr())
        return float(found[-1]) if found else -1.0

    def left(self) -> list[int]:
        """Live processes of the run: every node seen, anything naming its config."""
        self.nodes()
        return [pid for pid, p in self.seen.items() if alive(p)]

    def cleanup(self) -> None:
        if self.popen.poll() is None:
            self.popen.kill()
            self.popen.wait(10)
        for pid in self.left():
            with contextlib.suppress(OSError):
                os.kill(pid, signal.SIGKILL)


@pytest.fixture
def start(tmp_path: Path):
    runs: list[Run] = []

    def make(name: str, *args: str) -> Run:
        runs.append(Run(tmp_path, name, *args))
        return runs[-1]

    yield make
    for run in runs:
        run.cleanup()


def left_shm(before: set[str]) -> set[str]:
    """The entries that appeared since ``before`` and that no live process holds."""
    return unheld(fastdds_entries() - before)


def test_a_run_that_ends_leaves_no_process_and_no_shared_memory(start) -> None:
    before = fastdds_entries()
    run = start('ends', '--preset', 'triangle', '--duration', '3')
    assert run.popen.wait(120) == 0, run.stderr()
    assert run.left() == [], run.left()
    assert left_shm(before) == set()
    summary = json.loads((run.out / 'summary.json').read_text())
    assert set(summary['stop_signals']) <= {'SIGINT', 'exited'}, summary['stop_signals']


def test_repeated_kills_of_publishing_nodes_then_a_stop_end_in_time_and_leave_nothing(
    start,
) -> None:
    """Trackers and the (lockstep) target SIGKILLed five times while they publish, each
    respawned; then SIGINT: the run ends within its stop bound, no process of it is left,
    and no shared memory either -- the killed participants' files existed (they never left
    DDS) and the bring-up removed them."""
    from apf_swarm_nodes.bringup.supervision import Signals

    before = fastdds_entries()
    run = start(
        'kills', '--preset', 'triangle', '--duration', '120', '--respawn', '--max-respawns', '9'
    )
    wait_for(lambda: run.sim_time() >= 0.5, 90, 'the run to fly')
    rng = random.Random(7)
    for k in range(5):
        victims = [
            p for p in run.nodes() if re.search(r'/(tracker|target) ', ' '.join(p.cmdline()))
        ]
        assert victims, run.stderr()
        victim = rng.choice(victims)
        victim.kill()
        wait_for(
            lambda k=k: run.stderr().count('respawned ') >= k + 1,
            30,
            f'respawn {k + 1}: {run.stderr()}',
        )
        t = run.sim_time()
        wait_for(lambda t=t: run.sim_time() > t + 0.2, 60, 'the run to go on')  # publishing
    assert run.popen.poll() is None, run.stderr()
    t0 = time.monotonic()
    run.popen.send_signal(signal.SIGINT)
    bound = float(Signals.BOUND)  # at most; the bring-up's own is its stop's grace + 10 s
    rc = run.popen.wait(bound + 30)
    took = time.monotonic() - t0
    err = run.stderr()
    assert rc == 130, err
    assert took < bound, (took, err)
    assert 'Traceback' not in err, err
    wait_for(lambda: run.left() == [], 5, f'no process of the run: {run.left()}')
    # what the five killed participants left is gone: removed by this bring-up at its end
    # ("removed N stale Fast DDS shared-memory files"), or already by another run's end on
    # this machine (every run removes what no live process holds, its own or not)
    assert left_shm(before) == set(), err
    summary = json.loads((run.out / 'summary.json').read_text())
    assert summary['respawns'] == 5 and summary['status'] == 'interrupted'
    assert summary['stop_signals'].get('SIGKILL', 0) == 0, summary['stop_signals']


PARTICIPANT = textwrap.dedent(
    """
    import time, rclpy
    from std_msgs.msg import String
    rclpy.init()
    node = rclpy.create_node('stale_participant')
    pub = node.create_publisher(String, '/stale_topic', 10)
    sub = node.create_subscription(String, '/stale_topic', lambda m: None, 10)
    print('ready', flush=True)
    while True:
        pub.publish(String(data='x'))
        rclpy.spin_once(node, timeout_sec=0.05)
    """
)


def test_apf_swarm_clean_removes_what_a_killed_participant_left(tmp_path: Path) -> None:
    """A participant (default transports: shared memory) SIGKILLed while it publishes
    leaves its files; `apf-swarm clean --dry-run` names them and keeps them, `apf-swarm
    clean` removes them; files live participants hold stay."""
    env = {**os.environ, 'ROS_DOMAIN_ID': str(pick_domain_id(lo=102, hi=201))}
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    for var in ('FASTRTPS_DEFAULT_PROFILES_FILE', 'FASTDDS_DEFAULT_PROFILES_FILE'):
        env.pop(var, None)
    env.pop('FASTDDS_BUILTIN_TRANSPORTS', None)
    before = fastdds_entries()
    p = subprocess.Popen(
        [sys.executable, '-c', PARTICIPANT],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
        start_new_session=True,
    )
    try:
        assert p.stdout is not None and p.stdout.readline().strip() == 'ready'
        wait_for(lambda: fastdds_entries() - before, 10, 'its shared-memory files')
        time.sleep(0.5)
        mine = fastdds_entries() - before
        # held while it lives (those of other jobs that appeared meanwhile are held too)
        assert unheld(mine) == set()
        p.kill()
        p.wait(10)
    finally:
        if p.poll() is None:
            p.kill()
    dead = unheld(mine)
    assert dead, 'the killed participant left nothing: the test proves nothing'
    dry = subprocess.run(
        [sys.executable, '-m', 'apf_swarm_nodes.cli', 'clean', '--dry-run'],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert dry.returncode == 0, dry.stderr
    # another job's run removes stale files at its end too: judge those still there
    still = {n for n in dead & fastdds_entries() if n.startswith('fastrtps_')}
    if not still:
        pytest.skip("another job's cleanup removed the killed participant's files first")
    assert all(f'stale: /dev/shm/{n}' in dry.stdout for n in still), (still, dry.stdout)
    assert 'would remove' in dry.stdout, dry.stdout
    done = subprocess.run(
        [sys.executable, '-m', 'apf_swarm_nodes.cli', 'clean'],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 0, done.stderr
    assert re.search(r'removed \d+ stale Fast DDS shared-memory files', done.stdout), done.stdout
    # gone, or taken over by a live participant since (ports are shared between
    # participants: another job's may open one again, its lock file held anew)
    assert unheld(dead) == set(), sorted(unheld(dead))


@pytest.mark.parametrize('spawn', ['fork', 'exec'])
def test_a_sigkilled_bring_up_leaves_no_process_and_no_shared_memory(start, spawn) -> None:
    """SIGKILL of the bring-up mid-run (nothing of it can clean up): its nodes end on their
    parent-death signal, and its helper (the zygote that forked them, or the janitor told
    the pids of those it executed) ends too, once it has killed any node still there and
    removed the shared memory; no process of the run a few seconds later, and nothing of
    its shared memory that no live process holds."""
    from apf_swarm_nodes.bringup import zygote

    before = fastdds_entries()
    run = start(f'killed_{spawn}', '--preset', 'triangle', '--duration', '60', '--spawn', spawn)
    wait_for(lambda: run.sim_time() >= 0.5, 90, 'the run to fly')
    helper = 'bringup.zygote' if spawn == 'fork' else 'bringup.janitor'
    helpers = [
        p for p in psutil.Process(run.popen.pid).children() if helper in ' '.join(p.cmdline())
    ]
    assert len(run.nodes()) == 5 and len(helpers) == 1
    run.popen.kill()
    run.popen.wait(10)
    end = time.monotonic() + zygote.ORPHAN_GRACE + 15.0
    while time.monotonic() < end and (run.left() or any(alive(p) for p in helpers)):
        time.sleep(0.1)
    assert run.left() == [], run.left()
    assert not any(alive(p) for p in helpers)
    assert left_shm(before) == set()


ORPHAN_MAKER = textwrap.dedent(
    """
    import os, subprocess, sys
    from apf_swarm_nodes.dds.cleanup import BRINGUP_ENV, bringup_mark
    env = dict(os.environ, **{BRINGUP_ENV: bringup_mark()})  # as a bring-up marks its nodes
    node = subprocess.Popen(
        [sys.executable, '-c', 'import time; time.sleep(120)', sys.argv[1]],
        env=env, start_new_session=True, stdin=subprocess.DEVNULL,
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )
    print(node.pid, flush=True)  # then this 'bring-up' ends: the node is orphaned
    """
)


def test_apf_swarm_clean_stops_a_node_whose_bring_up_is_gone() -> None:
    """A process of ours (its command line names a node executable) whose bring-up, named
    in its environment, has ended: `clean --dry-run` names it and leaves it, `clean`
    stops it."""
    from apf_swarm_nodes.bringup.commands import executable_path, package_prefix

    exe = str(executable_path(package_prefix(), 'tracker'))
    out = subprocess.run(
        [sys.executable, '-c', ORPHAN_MAKER, exe], capture_output=True, text=True, timeout=30
    )
    pid = int(out.stdout.strip())
    node = psutil.Process(pid)
    try:
        wait_for(lambda: node.ppid() != 0, 5, 'the orphan')
        dry = subprocess.run(
            [sys.executable, '-m', 'apf_swarm_nodes.cli', 'clean', '--dry-run'],
            capture_output=True,
            text=True,
            timeout=60,
        )
        assert f'orphaned node pid {pid}:' in dry.stdout, dry.stdout
        assert node.is_running()
        done = subprocess.run(
            [sys.executable, '-m', 'apf_swarm_nodes.cli', 'clean'],
            capture_output=True,
            text=True,
            timeout=60,
        )
        assert f'orphaned node pid {pid}:' in done.stdout, done.stdout
        assert re.search(r'stopped [1-9]\d* orphaned node processes', done.stdout), done.stdout
        wait_for(lambda: not alive(node), 5, 'it')
    finally:
        with contextlib.suppress(psutil.Error):
            node.kill()


def test_a_killed_probe_leaves_no_echo_process() -> None:
    """The capacity probe's echo process (a node in its own session, which never ends by
    itself) ends with the probe, however the probe ends: here SIGKILL mid-measure."""
    env = {**os.environ, 'ROS_DOMAIN_ID': str(pick_domain_id(lo=102, hi=201))}
    probe = subprocess.Popen(
        [sys.executable, '-m', 'apf_swarm_nodes.capacity.probe', '--measure'],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        env=env,
        start_new_session=True,
    )
    mine = 'probe --echo'

    def echoes() -> list[psutil.Process]:
        out = []
        for p in _procs_naming(mine):
            with contextlib.suppress(psutil.Error):
                if p.environ().get('ROS_DOMAIN_ID') == env['ROS_DOMAIN_ID']:
                    out.append(p)
        return out

    try:
        wait_for(lambda: bool(echoes()), 30, 'the echo process')
        found = echoes()
        probe.kill()
        probe.wait(10)
        wait_for(lambda: not any(alive(p) for p in found), 10, 'the echo to end')
    finally:
        probe.kill()
        for p in echoes():
            with contextlib.suppress(psutil.Error):
                p.kill()
