"""The bring-up's zygote (apf_swarm_nodes.bringup.zygote) with real processes: a forked node
is the executable it stands for (argv, command line, log, environment, session, exit code),
it is the caller's child, and it is stopped by its own PID.

The zygote makes its caller a child subreaper; so that pytest does not become one, each case
runs its caller in a subprocess of its own (``DRIVER``), which reports what it saw as JSON.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
from apf_swarm_nodes.bringup import pick_domain_id
from apf_swarm_nodes.bringup.commands import executable_path, package_prefix
from apf_swarm_nodes.bringup.zygote import ForkedProcess, node_entry_points, serve

DRIVER = r"""
import json, os, signal, sys, time
from pathlib import Path
from apf_swarm_nodes.bringup.processes import Child, ProcessGroup
from apf_swarm_nodes.bringup.zygote import Zygote
from apf_swarm_nodes.capacity.machine import process_args

tmp, exe = Path(sys.argv[1]), sys.argv[2]
zygote = Zygote()
env = dict(os.environ, ROS_LOG_DIR=str(tmp / 'node_logs'))
group = ProcessGroup()
bad = group.add(Child('bad', [exe, '--ros-args', '-p', 'qos_depth:=0'], tmp / 'bad.log', env,
                      zygote=zygote))
live = group.add(Child('live', [exe, '--ros-args', '-r', '__node:=zygote_target'],
                       tmp / 'live.log', env, cwd=tmp, zygote=zygote))
other = group.add(Child('other', [sys.executable, '-c', 'import time; time.sleep(60)'],
                        tmp / 'other.log', env, zygote=zygote))
t0 = time.monotonic()
group.start_all()
out = {'kinds': [type(c.popen).__name__ for c in group], 'ppid': {}, 'error': zygote.error}
deadline = time.monotonic() + 60
while bad.poll() is None and time.monotonic() < deadline:
    time.sleep(0.02)
out['bad_rc'] = bad.poll()
pid = live.pid
out['live_pid'] = pid
with open(f'/proc/{pid}/stat') as f:
    out['ppid'] = int(f.read().rsplit(')', 1)[1].split()[1])
out['me'] = os.getpid()
out['sid'] = os.getsid(pid)
out['args'] = process_args(pid)
out['comm'] = Path(f'/proc/{pid}/comm').read_text().strip()
out['cwd'] = os.readlink(f'/proc/{pid}/cwd')
while 'target:' not in (tmp / 'live.log').read_text() and time.monotonic() < deadline:
    time.sleep(0.05)
out['ros_logs'] = sorted(p.name for p in (tmp / 'node_logs').glob('*'))
out['how'] = group.stop_all()
out['live_rc'] = live.poll()
out['left'] = group.leftovers()
# a respawn after the batch is forked too
live.start()
out['respawn_kind'] = type(live.popen).__name__
while (tmp / 'live.log').read_text().count('target:') < 2 and time.monotonic() < deadline:
    time.sleep(0.05)
out['how2'] = group.stop_all()
zygote.close()
print(json.dumps(out))
"""


@pytest.fixture
def ros_env(tmp_path: Path) -> dict[str, str]:
    env = dict(os.environ)
    env['ROS_DOMAIN_ID'] = str(pick_domain_id(lo=102, hi=201))  # away from make test's
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    env['ROS_LOG_DIR'] = str(tmp_path / 'ros')
    return env


def drive(tmp_path: Path, env: dict[str, str], script: str = DRIVER) -> dict[str, Any]:
    """Run ``script`` (its caller of the zygote) in a subprocess; what it printed last."""
    exe = str(executable_path(package_prefix(), 'target'))
    done = subprocess.run(
        [sys.executable, '-c', script, str(tmp_path), exe],
        env=env,
        capture_output=True,
        text=True,
        timeout=180,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    return dict(json.loads(done.stdout.strip().splitlines()[-1]))


def test_a_forked_node_is_its_executable_and_the_callers_child(
    tmp_path: Path, ros_env: dict[str, str]
) -> None:
    out = drive(tmp_path, ros_env)
    assert out['error'] is None
    # the node executables were forked, the other command executed
    assert out['kinds'] == ['ForkedProcess', 'ForkedProcess', 'Popen']
    # a bad parameter: the node's own error line in its log, and its exit code through waitpid
    assert out['bad_rc'] == 2
    bad_log = (tmp_path / 'bad.log').read_text()
    assert 'qos_depth' in bad_log and 'Traceback' not in bad_log
    # re-parented to the caller (the subreaper), in a session of its own
    assert out['ppid'] == out['me']
    assert out['sid'] == out['live_pid']
    # the command line and name of the executable, its environment and working directory
    assert out['args'][1:] == [out['args'][1], '--ros-args', '-r', '__node:=zygote_target']
    assert out['args'][1].endswith('/lib/apf_swarm_nodes/target')
    assert out['comm'] == 'target'
    # its environment: rcl wrote the node's ROS log where the child's ROS_LOG_DIR says
    assert out['ros_logs'], 'no ROS log file in the ROS_LOG_DIR of the child'
    assert out['cwd'] == str(tmp_path)
    # stopped by its own PID on the first signal, cleanly; nothing left
    assert out['how']['live'] == 'SIGINT' and out['live_rc'] == 0
    assert out['left'] == []
    assert out['respawn_kind'] == 'ForkedProcess'
    assert out['how2']['live'] == 'SIGINT'
    assert 'Traceback' not in (tmp_path / 'live.log').read_text()


def test_the_zygote_answers_bad_requests_and_ends_with_its_input(tmp_path: Path) -> None:
    """The protocol without forking a node: a line that is not a list of requests gets an
    error reply, the end of input ends the loop."""
    requests = tmp_path / 'in'
    requests.write_bytes(b'{"not": "a list"}\nnot json\n')
    replies = tmp_path / 'out'
    with open(requests, 'rb') as rin, open(replies, 'wb') as rout:
        assert serve(rin, rout) is None
    lines = [json.loads(x) for x in replies.read_text().splitlines()]
    assert lines[0] == [{'error': 'expected a JSON list of requests'}]
    assert lines[1][0]['error'].startswith('ValueError')


def test_the_node_executables_are_the_packages_console_scripts() -> None:
    entries = node_entry_points()
    assert {'tracker', 'trackers', 'plant', 'target', 'recorder', 'player'} <= set(entries)
    assert 'apf-swarm' not in entries
    assert entries['tracker'] == 'apf_swarm_nodes.tracker_node:main'


def test_a_forked_process_that_is_not_a_child_is_judged_by_liveness() -> None:
    """poll() on a PID this process cannot wait for: alive -> None, gone -> killed."""
    p = subprocess.Popen([sys.executable, '-c', 'import time; time.sleep(30)'])
    try:
        other = ForkedProcess(os.getppid(), ['parent'])  # alive, not our child
        assert other.poll() is None
    finally:
        p.kill()
        p.wait()
    gone = ForkedProcess(p.pid, ['gone'])  # reaped already: not a child, not alive
    assert gone.poll() is not None
    with pytest.raises(subprocess.TimeoutExpired):
        ForkedProcess(os.getppid(), ['parent']).wait(0.05)


FALLBACK = r"""
import json, os, sys
from pathlib import Path
from apf_swarm_nodes.bringup.processes import Child, ProcessGroup
from apf_swarm_nodes.bringup.zygote import Zygote

tmp, exe = Path(sys.argv[1]), sys.argv[2]
zygote = Zygote()
zygote.proc.kill()
zygote.proc.wait()
group = ProcessGroup()
c = group.add(Child('live', [exe, '--ros-args', '-r', '__node:=fallback_target'],
                    tmp / 'live.log', zygote=zygote))
group.start_all()
out = {'kind': type(c.popen).__name__, 'error': zygote.error, 'closed': zygote.proc is None}
out['how'] = group.stop_all()
out['left'] = group.leftovers()
print(json.dumps(out))
"""


def test_a_dead_zygote_leaves_the_nodes_to_be_executed(
    tmp_path: Path, ros_env: dict[str, str]
) -> None:
    out = drive(tmp_path, ros_env, FALLBACK)
    assert out['kind'] == 'Popen'
    assert 'zygote' in out['error'] and out['closed'] is True
    assert out['how']['live'] in ('SIGINT', 'exited') and out['left'] == []


def test_an_orphaned_zygote_kills_the_nodes_that_do_not_stop_then_cleans(
    tmp_path: Path, monkeypatch
) -> None:
    """The zygote of a killed bring-up: a node that stops on its parent-death SIGINT is
    waited for, one that does not is SIGKILLed (its whole session) once the grace is over,
    and the shared memory is cleaned only once both are gone."""
    import signal
    import time

    import psutil
    from apf_swarm_nodes.bringup import zygote
    from apf_swarm_nodes.dds import shm

    stubborn = subprocess.Popen(
        [sys.executable, '-c', 'import signal, time; signal.signal(2, 1); time.sleep(60)'],
        start_new_session=True,
    )
    polite = subprocess.Popen(
        [sys.executable, '-c', 'import time; time.sleep(60)'], start_new_session=True
    )
    procs = [psutil.Process(stubborn.pid), psutil.Process(polite.pid)]
    cleaned: list[list[bool]] = []

    def remove_stale() -> int:
        cleaned.append([p.poll() is not None for p in (stubborn, polite)])
        return 0

    monkeypatch.setattr(shm, 'remove_stale', remove_stale)
    monkeypatch.setattr(zygote, 'ORPHAN_GRACE', 1.0)
    monkeypatch.setattr(zygote, 'ORPHAN_SECOND_LOOK', 0.1)
    try:
        time.sleep(0.3)
        for p in (stubborn, polite):  # the parent-death signal
            p.send_signal(signal.SIGINT)
        t0 = time.monotonic()
        zygote.orphaned_cleanup(procs)
        took = time.monotonic() - t0
        assert polite.wait(5) != 0 and stubborn.wait(5) == -signal.SIGKILL
        # both gone before the cleanup (its first look, and its second a moment later)
        assert cleaned == [[True, True]] * 2
        assert 1.0 <= took < 10.0
    finally:
        for p in (stubborn, polite):
            p.kill()


HOSTED = r"""
import json, os, sys, time
from pathlib import Path
from apf_swarm_nodes.bringup.processes import Child, ProcessGroup
from apf_swarm_nodes.bringup.zygote import Zygote

tmp, exe, ns = Path(sys.argv[1]), sys.argv[2], os.environ['TEST_NETNS']
zygote = Zygote()
group = ProcessGroup()
argv = [exe, '--ros-args', '-r', '__node:=zygote_target']
forked = group.add(Child('forked', argv, tmp / 'forked.log', zygote=zygote, netns=ns))
executed = group.add(Child('executed', argv, tmp / 'executed.log', netns=ns))
lost = group.add(Child('lost', argv, tmp / 'lost.log', zygote=zygote, netns='apf-no-such-ns'))
group.start_all()
deadline = time.monotonic() + 60
while lost.poll() is None and time.monotonic() < deadline:
    time.sleep(0.02)
out = {'kinds': [type(c.popen).__name__ for c in group], 'lost_rc': lost.poll()}
while not all('target:' in (tmp / f'{c}.log').read_text() for c in ('forked', 'executed')):
    assert time.monotonic() < deadline, 'the hosted nodes did not start'
    time.sleep(0.05)
# a process run by `ip netns exec` is the child of `ip`'s exec: the same pid
out['net'] = {c.name: os.stat(f'/proc/{c.pid}/ns/net').st_ino for c in (forked, executed)}
out['how'] = group.stop_all()
zygote.close()
print(json.dumps(out))
"""


def test_a_node_for_a_simulated_host_runs_in_its_network_namespace(
    tmp_path: Path, ros_env: dict[str, str]
) -> None:
    """Forked by the zygote (which enters the namespace) or executed (``ip netns exec``), a
    node process of a simulated host has that host's network, and a namespace that does not
    exist ends the forked node with exit code 2 and the reason in its log."""
    if os.geteuid() != 0 or shutil.which('ip') is None:
        pytest.skip('network namespaces need root and iproute2')
    ns = f'apfz{os.getpid()}'
    subprocess.run(['ip', 'netns', 'add', ns], check=True)
    try:
        out = drive(tmp_path, {**ros_env, 'TEST_NETNS': ns}, HOSTED)
        host = os.stat(f'/run/netns/{ns}').st_ino
    finally:
        subprocess.run(['ip', 'netns', 'del', ns], check=False)
    assert out['kinds'] == ['ForkedProcess', 'Popen', 'ForkedProcess']
    assert out['net'] == {'forked': host, 'executed': host}
    assert host != os.stat('/proc/self/ns/net').st_ino
    assert out['lost_rc'] == 2
    assert "cannot enter network namespace 'apf-no-such-ns'" in (tmp_path / 'lost.log').read_text()
    assert out['how'] == {'forked': 'SIGINT', 'executed': 'SIGINT', 'lost': 'exited'}
