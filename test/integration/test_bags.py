"""Bags with real processes: a recorded bring-up run read back, replayed and repaired.

One lockstep bring-up with ``--record`` (3 trackers, 2 s simulated) is shared by the module;
the other tests start the recorder, the player and a tracker as their own processes in an
isolated domain (the ``graph`` fixture). Waits are bounded polls of a condition.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from apf_swarm_core.metrics import SUMMARY_KEYS
from apf_swarm_nodes.bags.recover import _scan_mcap
from apf_swarm_nodes.bringup import pick_domain_id, stop_process
from apf_swarm_nodes.dds.qos import qos_from_dict
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message, serialize_message

from apf_swarm_msgs.msg import ForceCommand
from apf_swarm_nodes import bags

ROOT = Path(__file__).resolve().parents[2]
SWARM_UP = ROOT / 'scripts' / 'swarm_up.py'
DURATION = 2.0
STEPS = 2000


def apf(*args: str, timeout: float = 120) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        ['apf-swarm', *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        env={**os.environ, 'PYTHONWARNINGS': 'ignore'},
    )


@pytest.fixture(scope='module')
def recorded(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``swarm_up.py --record``: the run directory (``bag/``, ``summary.json``...)."""
    out = tmp_path_factory.mktemp('bags') / 'run'
    domain = pick_domain_id(lo=102, hi=201)
    err = out.parent / 'bringup.stderr'
    with open(err, 'wb') as fh:
        p = subprocess.Popen(
            [
                sys.executable,
                str(SWARM_UP),
                '--preset',
                'triangle',
                '--duration',
                str(DURATION),
                '--record',
                '--domain-id',
                str(domain),
                '--out',
                str(out),
                '--no-plots',
            ],
            stdin=subprocess.DEVNULL,
            stdout=fh,
            stderr=subprocess.STDOUT,
            cwd=ROOT,
            start_new_session=True,
        )
    try:
        rc = p.wait(240)
    finally:
        stop_process(p)
    assert rc == 0, err.read_text()
    return out


# --------------------------------------------------------------------------------------------
# the recorded run
# --------------------------------------------------------------------------------------------


def test_info_counts_equal_what_the_nodes_published(recorded: Path) -> None:
    summary = json.loads((recorded / 'summary.json').read_text())
    rec = summary['recording']
    p = apf('bag', 'info', str(recorded / 'bag'), '--json')
    assert p.returncode == 0, p.stderr
    info = json.loads(p.stdout)
    topics = info['topics']
    # the plant published one /swarm/state per step (the bring-up received all of them)
    assert summary['messages']['received'] == STEPS and summary['messages']['dropped'] == 0
    assert topics['/swarm/state']['count'] == STEPS
    for i in (1, 2, 3):
        # one command per step per tracker (a re-sent step may add an answer)
        assert STEPS <= topics[f'/uav_{i}/force_cmd']['count'] <= STEPS + 5
        assert topics[f'/uav_{i}/force_cmd']['type'] == 'apf_swarm_msgs/msg/ForceCommand'
    assert STEPS <= topics['/clock']['count'] <= STEPS + 5
    # steps 0..STEPS: the plant asks ahead, and its last request is capped at the final step
    assert topics['/target/odom']['count'] == STEPS + 1
    assert topics['/rosout']['count'] >= 5  # every node's start-up lines
    # the recorder counted every message it received and wrote, and they are what info reads
    assert rec['received'] == rec['written'] == info['messages'] == rec['messages']
    assert rec['dropped'] == 0
    assert sum(t['count'] for t in topics.values()) == info['messages']
    # offered QoS of the publishers: /swarm/state reliable, /swarm/start transient local
    assert topics['/swarm/state']['offered_qos_profiles'][0]['reliability'] == 'reliable'
    assert topics['/swarm/start']['offered_qos_profiles'][0]['durability'] == 'transient_local'
    assert topics['/swarm/state']['frequency'] == pytest.approx(STEPS / info['duration'])
    text = apf('bag', 'info', str(recorded / 'bag'))
    assert text.returncode == 0 and '/swarm/state' in text.stdout and 'mcap' in text.stdout


def test_bag_reads_back_with_rosbags_and_mcap(recorded: Path) -> None:
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
    from rosbags.highlevel import AnyReader

    bag = recorded / 'bag'
    meta = (bag / 'metadata.yaml').read_text()
    assert 'version: 9' in meta and 'storage_identifier: mcap' in meta
    with np.load(recorded / 'trajectory.npz') as z:
        x, t = z['x'], z['t']
    # rosbags: every message deserializes, the custom types from the bag's definitions
    counts: dict[str, int] = {}
    states = []
    with AnyReader([bag]) as reader:  # no typestore given: the bag's own definitions
        for conn, _ts, raw in reader.messages():
            msg = reader.deserialize(raw, conn.msgtype)
            counts[conn.topic] = counts.get(conn.topic, 0) + 1
            if conn.topic == '/swarm/state':
                states.append(msg)
        hashes = {c.topic: c.digest for c in reader.connections}
    assert len(states) == STEPS
    assert [int(s.step) for s in states] == list(range(STEPS))
    for k in (0, STEPS // 2, STEPS - 1):
        pos = np.array([(p.x, p.y, p.z) for p in states[k].positions])
        np.testing.assert_array_equal(pos, x[k])
        assert states[k].sim_time == pytest.approx(t[k], abs=1e-12)
    # the stored type hash is the one rosidl generated for the custom type
    from ament_index_python.packages import get_package_share_directory

    generated = json.loads(
        (
            Path(get_package_share_directory('apf_swarm_msgs')) / 'msg' / 'SwarmState.json'
        ).read_text()
    )
    assert hashes['/swarm/state'] == generated['type_hashes'][0]['hash_string']
    # mcap + mcap_ros2: the same messages, decoded from the embedded ros2msg schemas
    mcounts: dict[str, int] = {}
    forces = []
    for file in bags.bag_files(bag):
        with open(file, 'rb') as f:
            for _schema, channel, _m, dec in make_reader(
                f, decoder_factories=[DecoderFactory()]
            ).iter_decoded_messages():
                mcounts[channel.topic] = mcounts.get(channel.topic, 0) + 1
                if channel.topic == '/uav_2/force_cmd':
                    forces.append((dec.step, dec.force.x, dec.force.y, dec.force.z))
    assert mcounts == counts
    assert len(forces) >= STEPS and forces[0][0] == 0


def test_metrics_equal_the_live_summary(recorded: Path) -> None:
    live = json.loads((recorded / 'summary.json').read_text())
    p = apf('bag', 'metrics', str(recorded / 'bag'), '--json')
    assert p.returncode == 0, p.stderr
    got = json.loads(p.stdout)
    assert got['mode'] == 'lockstep'
    for key, value in got.items():
        if key in ('mode',):
            continue
        assert value == live[key], key  # the same samples through the same function
    assert all(k in got for k in SUMMARY_KEYS)


def test_export_and_plot(recorded: Path, tmp_path: Path) -> None:
    csv_path = tmp_path / 'state.csv'
    p = apf(
        'bag', 'export', str(recorded / 'bag'), '--topic', '/swarm/state', '--csv', str(csv_path)
    )
    assert p.returncode == 0, p.stderr
    import csv

    with open(csv_path) as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == STEPS
    with np.load(recorded / 'trajectory.npz') as z:
        x = z['x']
    assert float(rows[10]['positions.1.y']) == x[10, 1, 1]
    assert int(rows[-1]['step']) == STEPS - 1
    p = apf('bag', 'plot', str(recorded / 'bag'), '--out', str(tmp_path / 'fig'))
    assert p.returncode == 0, p.stderr
    pngs = sorted(q.name for q in (tmp_path / 'fig').glob('*.png'))
    assert pngs == [
        'fig2_trajectories_proposed.png',
        'fig4_xy_proposed.png',
        'fig6_centroid_proposed.png',
        'fig7_centroid_error.png',
    ]


# --------------------------------------------------------------------------------------------
# replay
# --------------------------------------------------------------------------------------------


def test_replay_drives_a_fresh_tracker_as_in_the_live_run(
    recorded: Path, graph, tmp_path: Path
) -> None:
    """/swarm/odom of the bag into a new tracker 1: its commands equal the recorded ones.

    At the recorded pace. A second recorder takes the fresh tracker's commands (its take
    loop keeps up where a Python listener in this process, sharing the CPU with pytest, lost
    some). The player does not wait for the commands as the live plant does; that the
    tracker keeps up relies on the lockstep inputs' depth (node_common.LOCKSTEP_DEPTH: with
    the former depth 10, a tracker starved for 10 input periods on this loaded machine missed
    1-5 % of the steps).
    """
    from std_msgs.msg import String

    status: list[dict] = []
    graph.node.create_subscription(
        String,
        '/recorder/status',
        lambda m: status.append(json.loads(m.data)),
        QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL),
    )
    graph.start(
        'tracker',
        'tracker',
        '--params-file',
        str(recorded / 'config.yaml'),
        '-r',
        '__ns:=/uav_1',
        '-r',
        '__node:=tracker',
        '-p',
        'uav_id:=1',
        '-p',
        'mode:=lockstep',
    )
    replayed = tmp_path / 'replayed'
    graph.start(
        'recorder', 'recorder', '-p', f'output:={replayed}', '-p', 'topics:=[/uav_1/force_cmd]'
    )

    def recording() -> bool:
        t = status[-1]['topics'].get('/uav_1/force_cmd') if status else None
        return bool(t) and t['matched'] >= 1

    graph.spin_until(recording, 30, 'the second recorder to record /uav_1/force_cmd')
    graph.start(
        'player',
        'player',
        '-p',
        f'bag:={recorded / "bag"}',
        '-p',
        'topics:=[/swarm/odom]',
        '-p',
        'wait_for:=[/swarm/odom]',
    )
    graph.spin_until(
        lambda: status[-1]['received'] >= STEPS,
        60,
        f'{STEPS} commands of the fresh tracker (recorder status)',
    )
    assert graph.stop('recorder') == 0

    def commands(bag: Path) -> np.ndarray:
        out = []
        for _t, _type, _ts, raw in bags.iter_raw(bag, ['/uav_1/force_cmd']):
            m = deserialize_message(raw, ForceCommand)
            out.append(
                (
                    m.step,
                    m.force.x,
                    m.force.y,
                    m.force.z,
                    m.sliding_surface.x,
                    m.filter_state.y,
                    m.gradient.z,
                )
            )
        return np.array(out)

    live, fresh = commands(recorded / 'bag'), commands(replayed)
    assert live.shape == fresh.shape == (STEPS, 7)
    np.testing.assert_array_equal(fresh, live)  # bit for bit, every step


def _timing_bag(path: Path, n: int, hz: float) -> list[int]:
    from std_msgs.msg import Int64

    stamps = []
    with bags.BagWriter(path) as w:
        q = qos_from_dict(
            {
                'history': 'keep_last',
                'depth': 10,
                'reliability': 'reliable',
                'durability': 'volatile',
            }
        )
        conn = w.add_topic('/timing', 'std_msgs/msg/Int64', offered_qos=[q])
        t0 = 1_700_000_000_000_000_000
        for i in range(n):
            ts = t0 + int(round(i * 1e9 / hz))
            w.write(conn, ts, serialize_message(Int64(data=i)))
            stamps.append(ts)
    return stamps


#: asserted bound on the p99 schedule error at 100 Hz. The goal is 2 ms, met on a quiet
#: machine (docs/PERFORMANCE.md, "Bags": the benchmark's measured p99); this 2-core machine
#: shared with other jobs starves the player for tens of ms at times (measured p99 37-54 ms
#: at load average 7), so the test allows 10 ms and one retry: a systematic lateness or a
#: drift still fails it.
P99_BOUND_MS = 10.0


def _play_once(graph, bag: Path, stamps: list[int], attempt: int) -> tuple[float, float]:
    """Play ``bag`` into a listener; (p99 |error|, drift) in ms, every message in order."""
    from std_msgs.msg import Int64

    n = len(stamps)
    got: list[tuple[int, int]] = []
    sub = graph.node.create_subscription(
        Int64,
        '/timing',
        lambda m, info: got.append((m.data, info['received_timestamp'])),
        QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE),
    )
    name = f'player{attempt}'
    graph.start(name, 'player', '-p', f'bag:={bag}', '-p', 'wait_for:=[/timing]')
    graph.spin_until(lambda: len(got) >= n, 30, f'{n} played messages')
    player = graph.procs.pop(name)
    assert player.wait(20) == 0, graph.log(name)  # it exits by itself when done
    graph.node.destroy_subscription(sub)
    assert [d for d, _ in got] == list(range(n))  # every message, in order
    recv = np.array([r for _, r in got], dtype=np.int64)
    err = (recv - recv[0]) - (np.array(stamps) - stamps[0])
    err_ms = (err - np.median(err)) / 1e6
    return float(np.percentile(np.abs(err_ms), 99)), float(err_ms[-1] - err_ms[0])


def test_play_delivers_every_message_in_order_on_time(graph, tmp_path: Path) -> None:
    stamps = _timing_bag(tmp_path / 'timing', 300, 100.0)
    results = []
    for attempt in range(2):
        p99, drift = _play_once(graph, tmp_path / 'timing', stamps, attempt)
        results.append((p99, drift))
        # absolute schedule: the last message is not later than the first by more than jitter
        if p99 < P99_BOUND_MS and abs(drift) < P99_BOUND_MS:
            return
    raise AssertionError(f'p99 schedule error / drift over 2 attempts: {results} ms')


def test_play_offset_loop_clock_and_remap(graph, tmp_path: Path) -> None:
    """start_offset skips, loop repeats, /clock follows the bag time, -r renames."""
    from rosgraph_msgs.msg import Clock
    from std_msgs.msg import Int64

    stamps = _timing_bag(tmp_path / 'small', 50, 100.0)  # 0.49 s of bag time
    got: list[int] = []
    clocks: list[int] = []
    graph.node.create_subscription(
        Int64, '/renamed', lambda m: got.append(m.data), QoSProfile(depth=1000)
    )
    graph.node.create_subscription(
        Clock,
        '/clock',
        lambda m: clocks.append(m.clock.sec * 1_000_000_000 + m.clock.nanosec),
        QoSProfile(depth=1000),
    )
    graph.start(
        'player',
        'player',
        '-p',
        f'bag:={tmp_path / "small"}',
        '-p',
        'loop:=true',
        '-p',
        'start_offset:=0.2',
        '-p',
        'clock:=50.0',
        '-r',
        '/timing:=/renamed',
        '-p',
        'wait_for:=[/renamed]',
    )
    graph.spin_until(lambda: len(got) >= 75, 30, 'two and a half passes')
    assert graph.stop('player') == 0
    first = got[:60]
    assert first == list(range(20, 50)) * 2  # 0.2 s skipped, then again
    assert clocks and all(
        stamps[0] + 200_000_000 - 1 <= c <= stamps[-1] + 20_000_000 for c in clocks
    )
    assert len(clocks) >= 20  # about 50 Hz over >= 0.6 s


# --------------------------------------------------------------------------------------------
# a recorder killed by SIGKILL
# --------------------------------------------------------------------------------------------


def test_sigkilled_recorder_leaves_a_bag_that_reindex_recovers(graph, tmp_path: Path) -> None:
    from std_msgs.msg import Int64

    bag = tmp_path / 'killed'
    pub = graph.node.create_publisher(Int64, '/kill_test', QoSProfile(depth=100))
    graph.start(
        'recorder',
        'recorder',
        '-p',
        f'output:={bag}',
        '-p',
        'flush_period:=0.1',
        '-p',
        'topics:=[/kill_test]',
    )
    graph.spin_until(lambda: pub.get_subscription_count() >= 1, 30, 'the recorder to subscribe')
    sent = 0

    def publish_and_count(target: int) -> bool:
        nonlocal sent
        if sent < target:
            pub.publish(Int64(data=sent))
            sent += 1
        return sent >= target

    graph.spin_until(lambda: publish_and_count(300), 30, '300 messages published')
    file = bag / 'killed_0.mcap'
    # a flush every 0.1 s: the complete chunks hold >= 300 messages soon
    graph.spin_until(
        lambda: publish_and_count(sent + 1) and len(_scan_mcap(file).messages) >= 300,
        20,
        'a flushed chunk',
    )
    proc = graph.procs.pop('recorder')
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait(10)
    before = file.read_bytes()
    assert not (bag / 'metadata.yaml').exists()
    p = apf('bag', 'info', str(bag))
    assert p.returncode == 2 and 'reindex' in p.stderr and 'Traceback' not in p.stderr
    p = apf('bag', 'reindex', str(bag))
    assert p.returncode == 0, p.stderr
    info = json.loads(apf('bag', 'info', str(bag), '--json').stdout)
    m = info['topics']['/kill_test']['count']
    assert 300 <= m <= sent
    values = [
        deserialize_message(raw, Int64).data
        for _t, _y, _ts, raw in bags.iter_raw(bag, ['/kill_test'])
    ]
    assert values == list(range(m))  # every message up to the last flushed chunk
    backups = list(bag.glob('reindex-backup-*/killed_0.mcap'))
    assert len(backups) == 1 and backups[0].read_bytes() == before


def test_recorder_selects_compresses_and_splits(graph, tmp_path: Path) -> None:
    """regex and exclude select the topics; zstd chunks; a new file every 0.2 s of messages;
    SIGINT closes the bag with every message."""
    import time

    from std_msgs.msg import Int64

    bag = tmp_path / 'sel'
    pubs = {
        t: graph.node.create_publisher(Int64, t, QoSProfile(depth=100))
        for t in ('/sel/a', '/sel/b', '/other')
    }
    graph.start(
        'recorder',
        'recorder',
        '-p',
        f'output:={bag}',
        '-p',
        'regex:=^/sel/',
        '-p',
        'exclude:=b$',
        '-p',
        'compress:=true',
        '-p',
        'split_duration:=0.2',
    )
    graph.spin_until(
        lambda: pubs['/sel/a'].get_subscription_count() >= 1, 30, 'the recorder on /sel/a'
    )
    sent = [0]
    next_at = [time.monotonic()]

    def publish_paced() -> bool:  # 100 Hz, driven by the spin loop
        if time.monotonic() >= next_at[0] and sent[0] < 80:
            for pub in pubs.values():
                pub.publish(Int64(data=sent[0]))
            sent[0] += 1
            next_at[0] += 0.01
        return sent[0] >= 80

    graph.spin_until(publish_paced, 30, '80 messages on each topic')
    assert pubs['/sel/b'].get_subscription_count() == 0  # excluded: no subscription
    assert pubs['/other'].get_subscription_count() == 0  # not matching the regex
    assert graph.stop('recorder') == 0
    info = bags.open_bag(bag)
    assert [t.name for t in info.topics] == ['/sel/a']
    assert info.topic('/sel/a').count == 80
    assert len(info.files) >= 3 and {f.compression for f in info.files} == {'zstd'}
    values = [deserialize_message(raw, Int64).data for *_x, raw in bags.iter_raw(bag)]
    assert values == list(range(80))
    rec = json.loads(info.custom_data[bags.CUSTOM_RECORDER])
    assert rec['received'] == rec['written'] == 80 and rec['dropped'] == 0


def test_recorder_refuses_an_existing_output(graph, tmp_path: Path) -> None:
    (tmp_path / 'exists').mkdir()
    graph.start('recorder', 'recorder', '-p', f'output:={tmp_path / "exists"}')
    proc = graph.procs.pop('recorder')
    assert proc.wait(30) == 2
    log = graph.log('recorder')
    assert 'exists already' in log and 'Traceback' not in log
