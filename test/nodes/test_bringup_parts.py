"""The bring-up's ROS-free parts: graph expectations, process supervision (real
subprocesses, no ROS) and the accumulation of /swarm/state samples."""

from __future__ import annotations

import signal
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from apf_swarm_core.config import SwarmConfig
from apf_swarm_nodes.analysis.errors import AnalysisError
from apf_swarm_nodes.bringup import (
    Child,
    ProcessGroup,
    StateAccumulator,
    expected_graph,
    graph_missing,
)
from apf_swarm_nodes.bringup.commands import Plan
from apf_swarm_nodes.bringup.graph import input_readers


def complete_counts(n: int, mode: str) -> tuple[list[str], dict[str, tuple[int, int]]]:
    nodes, topics = expected_graph(n, mode)
    return nodes, {t.topic: (t.publishers, t.subscribers) for t in topics}


@pytest.mark.parametrize('mode', ['lockstep', 'realtime'])
def test_a_complete_graph_misses_nothing_and_each_gap_is_named(mode: str) -> None:
    nodes, counts = complete_counts(3, mode)
    _, topics = expected_graph(3, mode)
    assert graph_missing(nodes, counts, nodes, topics) == []
    assert len(nodes) == 5 and ('/clock' in counts) == (mode == 'lockstep')
    # a tracker missing, and a force topic without its publisher
    gone = [n for n in nodes if n != '/uav_2/tracker']
    short = dict(counts, **{'/uav_3/force_cmd': (0, 1)})
    missing = graph_missing(gone, short, nodes, topics)
    assert missing[0] == 'node /uav_2/tracker'
    assert missing[1].startswith('topic /uav_3/force_cmd: publishers 0 (need 1)')


def test_the_aggregate_inputs_count_for_the_per_uav_readers() -> None:
    nodes, topics = expected_graph(3, 'realtime')
    counts = {t.topic: (t.publishers, 0 if 'odom' in t.topic else t.subscribers) for t in topics}
    assert any(
        'subscribers 0 + 0 on /swarm/odom' in m
        for m in graph_missing(nodes, counts, nodes, topics)
    )
    counts['/swarm/odom'] = (1, 3)  # every tracker reads the aggregate instead
    counts['/target/odom'] = (1, 1)  # and the plant reads the target
    assert graph_missing(nodes, counts, nodes, topics) == []
    # a realtime process of 4 trackers reads the aggregate once
    assert input_readers(16, 'realtime', 4) == 4
    assert input_readers(16, 'lockstep', 4) == 16
    assert input_readers(16, 'realtime', 4, 'odom') == 16


def test_hosted_nodes_invert_the_process_names_of_node_commands() -> None:
    from apf_swarm_nodes.bringup.commands import hosted_nodes

    assert hosted_nodes('trackers_3-5') == ['/uav_3/tracker', '/uav_4/tracker', '/uav_5/tracker']
    assert hosted_nodes('tracker_7') == ['/uav_7/tracker']
    assert hosted_nodes('plant') == ['/plant'] and hosted_nodes('target') == ['/target/target']
    assert hosted_nodes('recorder') == [] and hosted_nodes('trackers_x') == []


def test_a_process_never_seen_while_the_graph_stalls_is_restarted_at_most_twice() -> None:
    from apf_swarm_nodes.bringup.graph import UnseenRestart

    hosted = {'trackers_1-2': ['/uav_1/tracker', '/uav_2/tracker']}
    watch = UnseenRestart(hosted, stall=5.0, limit=2, peer_wait=2.5)
    unseen = ['node /uav_1/tracker', 'node /uav_2/tracker', 'topic /uav_1/force_cmd: ...']
    # progress (fewer missing) resets the clock; no restart before the stall
    assert watch.due(0.0, [*unseen, 'topic /plant: ...']) == []
    assert watch.due(4.0, unseen) == []
    assert watch.due(8.9, unseen) == []
    assert watch.due(9.0, unseen) == ['trackers_1-2']
    # the restarted process gets its own stall
    assert watch.due(13.0, unseen) == []
    assert watch.due(17.9, unseen) == []
    assert watch.due(18.0, unseen) == ['trackers_1-2']
    assert watch.due(40.0, unseen) == []  # the limit
    assert watch.restarts == {'trackers_1-2': 2}


def test_a_process_unseen_after_all_its_peers_showed_up_is_restarted() -> None:
    from apf_swarm_nodes.bringup.graph import UnseenRestart

    hosted = {
        'plant': ['/plant'],
        'trackers_1-2': ['/uav_1/tracker', '/uav_2/tracker'],
        'trackers_3-4': ['/uav_3/tracker', '/uav_4/tracker'],
    }
    watch = UnseenRestart(hosted, stall=9.0, limit=2, peer_wait=2.5)
    late = ['node /uav_3/tracker', 'node /uav_4/tracker']
    edges = [f'topic /uav_{i}/force_cmd: ...' for i in range(9)]
    # the graph is still progressing; nobody restarts while a peer is still unseen too
    start = ['node /plant', 'node /uav_1/tracker', 'node /uav_2/tracker']
    assert watch.due(0.0, [*start, *late, *edges]) == []
    assert watch.due(1.0, [*start[1:], *late, *edges[:8]]) == []  # plant up
    assert watch.due(2.0, ['node /uav_2/tracker', *late, *edges[:7]]) == []  # 1-2 up
    # a partly seen process counts as up; the last peer showed up at 2.0
    assert watch.due(4.4, [*late, *edges[:6]]) == []
    assert watch.due(4.5, [*late, *edges[:5]]) == ['trackers_3-4']
    # its restart gets peer_wait again; a process showing a node is never restarted
    assert watch.due(6.0, [*late, *edges[:4]]) == []
    assert watch.due(6.5, ['node /uav_4/tracker', *edges[:3]]) == []
    assert watch.due(30.0, ['node /uav_4/tracker', *edges[:3]]) == []
    assert watch.restarts == {'trackers_3-4': 1}


def wait_until(cond, timeout: float) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if cond():
            return True
        time.sleep(0.02)
    return cond()


#: a child that ends on SIGINT, whatever disposition it inherited (a background job of a
#: non-interactive shell starts with SIGINT ignored, and Python then keeps it ignored)
POLITE = (
    'import signal, time; signal.signal(signal.SIGINT, signal.default_int_handler); '
    'print("ready", flush=True); time.sleep(60)'
)


def test_a_group_stops_each_child_with_the_first_signal_that_works(tmp_path: Path) -> None:
    # one child exits on SIGINT, one ignores SIGINT and exits on SIGTERM, one has exited already
    ignores_int = (
        'import signal, time; signal.signal(signal.SIGINT, signal.SIG_IGN); '
        'print("ready", flush=True); time.sleep(60)'
    )
    group = ProcessGroup(
        stop_sequence=((signal.SIGINT, 5.0), (signal.SIGTERM, 5.0), (signal.SIGKILL, 5.0))
    )
    group.add(
        Child(
            'polite',
            [sys.executable, '-c', POLITE],
            tmp_path / 'a.log',
        )
    )
    group.add(Child('stubborn', [sys.executable, '-c', ignores_int], tmp_path / 'b.log'))
    group.add(Child('done', [sys.executable, '-c', 'print("bye")'], tmp_path / 'c.log'))
    with pytest.raises(ValueError, match='duplicate child name'):
        group.add(Child('done', ['true'], tmp_path / 'd.log'))
    group.start_all()
    done = group.children[2]
    assert wait_until(lambda: done.poll() is not None, 10)
    assert group.poll() == [(done, 0)]  # an unexpected exit is reported
    # both run their code (the stubborn one ignores SIGINT) once they say so; the stages
    # are long enough for a loaded machine to finish an interpreter after its SIGINT
    for log in ('a.log', 'b.log'):
        assert wait_until(lambda log=log: 'ready' in (tmp_path / log).read_text(), 30)
    how = group.stop_all()
    assert how == {'done': 'exited', 'polite': 'SIGINT', 'stubborn': 'SIGTERM'}, how
    assert group.leftovers() == []
    assert (tmp_path / 'c.log').read_text().strip() == 'bye'


def test_a_restarted_child_appends_to_its_log_with_a_header(tmp_path: Path) -> None:
    c = Child('echo', [sys.executable, '-c', 'print("run")'], tmp_path / 'e.log')
    c.start()
    assert wait_until(lambda: c.poll() is not None, 10)
    c.start()
    assert wait_until(lambda: c.poll() is not None, 10)
    text = (tmp_path / 'e.log').read_text()
    assert text.count('run') == 2 and 'echo: restart 1' in text
    assert c.respawns == 1 and len(c.pids) == 2


def sample(step: int, n: int = 3) -> SimpleNamespace:
    z = np.zeros((n, 3))
    return SimpleNamespace(
        step=step,
        t=step * 0.001,
        x=z + step,
        v=z,
        u=z,
        s=z,
        target_x=np.zeros(3),
        target_v=np.zeros(3),
        active=(True,) * n,
        target_age=0.0,
        stale_inputs=0,
        command_latency=(0.0,) * n,
    )


def test_lockstep_samples_count_gaps_and_out_of_order_steps() -> None:
    acc = StateAccumulator('lockstep', 10, record_every=2)
    for k in (0, 1, 2, 5, 4, 6, 7, 8, 9):
        acc.add(sample(k))
    m = acc.messages()
    assert m['received'] == 9 and m['dropped'] == 2 and m['gaps'] == [[3, 4]]
    assert m['out_of_order'] == 1 and m['expected'] == 10 and acc.complete
    traj = acc.trajectory()
    assert traj is not None
    # every second step is kept; the dropped step 4 is not there
    np.testing.assert_array_equal(traj['t'] * 1000, [0, 2, 6, 8])
    assert traj['x'].shape == (4, 3, 3) and traj['active'].dtype == bool


def test_a_trajectory_refuses_samples_of_another_size() -> None:
    acc = StateAccumulator('realtime', 10)
    acc.add(sample(0))
    acc.add(sample(0))  # the publish timer repeated a step
    acc.add(sample(3, n=4))
    assert acc.messages()['repeated'] == 1
    with pytest.raises(AnalysisError, match='changed its number of trackers from 3'):
        acc.trajectory()
    assert StateAccumulator('lockstep', 5).trajectory() is None


def test_the_stop_bound_is_the_grace_of_each_stage_and_grows_with_the_load(
    tmp_path: Path, monkeypatch
) -> None:
    """The bring-up's watchdog bound (Supervisor.stop_bound): the trackers' stop, then the
    plant's and target's, then the recorder's, each at its longest, and a margin; the first
    stage waits STOP_CPU_PER_PROCESS more per process, shared over the cores."""
    import os

    from apf_swarm_nodes.bringup import processes
    from apf_swarm_nodes.bringup.graph import RECORDER_STOP_SEQUENCE
    from apf_swarm_nodes.bringup.supervision import STOP_MARGIN, Signals, Supervisor

    monkeypatch.setattr(os, 'cpu_count', lambda: 2)
    per = processes.STOP_CPU_PER_PROCESS / 2
    waits = sum(w for _, w in processes.STOP_SEQUENCE)

    def run(n_trackers: int, record: bool) -> Supervisor:
        sup = Supervisor(Plan(SwarmConfig(), tmp_path), Signals(), print)
        for name in ['target', 'plant', *[f'tracker_{i}' for i in range(n_trackers)]]:
            sup.group.add(Child(name, ['true'], tmp_path / f'{name}.log'))
        if record:
            sup.rec_group.add(Child('recorder', ['true'], tmp_path / 'recorder.log'))
        return sup

    small, large = run(3, False).stop_bound(), run(64, True).stop_bound()
    assert small == pytest.approx(2 * waits + 5 * per + STOP_MARGIN)
    rec = sum(w for _, w in RECORDER_STOP_SEQUENCE) + per
    assert large == pytest.approx(2 * waits + 66 * per + rec + STOP_MARGIN)
    assert ProcessGroup().stop_grace() == 0.0
    # a small run's bound is half the old fixed 60 s; the 66 processes, recorded,
    # get a few seconds more than it
    assert small < 35.0 and large < 70.0


def test_the_stop_reports_each_process_with_the_signal_that_stopped_it(
    tmp_path: Path, monkeypatch
) -> None:
    """Trackers first, then the others: each keeps the signal that stopped it in stopped_by
    (a second pass over the whole group once reported every tracker as 'exited', hiding a
    SIGKILL), and the stop is said in one line."""
    from apf_swarm_nodes.bringup.supervision import Signals, Supervisor
    from apf_swarm_nodes.dds import shm

    monkeypatch.setattr(shm, 'remove_stale', lambda: 0)
    said: list[str] = []
    sup = Supervisor(Plan(SwarmConfig(), tmp_path), Signals(), said.append)
    for name in ('target', 'plant', 'tracker_1', 'tracker_2'):
        sup.group.add(Child(name, [sys.executable, '-c', POLITE], tmp_path / f'{name}.log'))
    sup.group.start_all()
    for name in ('target', 'plant', 'tracker_1', 'tracker_2'):
        assert wait_until(lambda n=name: 'ready' in (tmp_path / f'{n}.log').read_text(), 30)
    sup.stop_children()
    assert sup.stop_how == dict.fromkeys(('tracker_1', 'tracker_2', 'target', 'plant'), 'SIGINT')
    assert list(sup.stop_how)[:2] == ['tracker_1', 'tracker_2']  # the trackers first
    assert any('stopped 4 processes' in s and '4 SIGINT' in s for s in said), said
    assert sup.leftovers == []


def test_a_node_param_must_read_name_value() -> None:
    import argparse

    from apf_swarm_nodes.argtypes import node_param

    assert node_param('stale_after:=0.2') == 'stale_after:=0.2'
    for bad in ('stale_after=0.2', 'stale_after:=', ':=3', 'a b:=1'):
        with pytest.raises(argparse.ArgumentTypeError, match='expected NAME:=VALUE'):
            node_param(bad)


def test_the_janitor_of_a_killed_bringup_removes_the_keys_and_a_goodbye_keeps_them(
    tmp_path: Path,
) -> None:
    from apf_swarm_nodes.bringup.janitor import Janitor

    def host_key(run: str) -> Path:
        key = tmp_path / run / 'dds' / 'h1' / 'key.pem'
        key.parent.mkdir(parents=True)
        key.write_bytes(b'secret')
        (key.parent / 'cert.pem').write_bytes(b'public')
        return key

    killed, closed = host_key('killed'), host_key('closed')
    janitor = Janitor()
    janitor.keys(killed.parents[1])
    assert janitor.proc is not None and janitor.proc.stdin is not None
    janitor.proc.stdin.close()  # its input ends without the goodbye: the bring-up died
    janitor.proc.wait(30)
    assert not killed.exists() and (killed.parent / 'cert.pem').exists()
    polite = Janitor()
    polite.keys(closed.parents[1])
    polite.close()
    assert closed.exists()
