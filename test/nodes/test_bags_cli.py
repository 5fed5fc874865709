"""``apf-swarm bag ...`` without a ROS graph: small bags written here, every bad input.

Each bad input must give one line ``apf-swarm: error: ...`` that names the problem and what to
do, exit code 2, no traceback; nothing in an existing bag may change except by ``reindex``
(which keeps a backup).
"""

from __future__ import annotations

import csv
import hashlib
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from apf_swarm_nodes.dds.qos import qos_from_dict

from apf_swarm_nodes import bags

APF = shutil.which('apf-swarm')
pytestmark = pytest.mark.skipif(
    APF is None, reason='apf-swarm is not on PATH: source scripts/activate.sh (make test does)'
)
T0 = 1_700_000_000_000_000_000
QOS = {'history': 'keep_last', 'depth': 10, 'reliability': 'reliable', 'durability': 'volatile'}


def run(*args: str, timeout: float = 120) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [APF, *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        env={**os.environ, 'PYTHONWARNINGS': 'ignore'},
    )


def assert_bad(p: subprocess.CompletedProcess[str], *words: str) -> None:
    """Exit 2, one line on stderr naming the problem, no traceback."""
    assert p.returncode == 2, (p.returncode, p.stdout, p.stderr)
    lines = p.stderr.strip().splitlines()
    assert len(lines) == 1, p.stderr
    assert lines[0].startswith('apf-swarm: error: '), lines[0]
    assert 'Traceback' not in p.stderr
    for w in words:
        assert w in lines[0], (w, lines[0])


def write_bag(
    path: Path, n: int = 200, *, compress: bool = False, chunk_size: int = 2048, **kw
) -> Path:
    """A bag with /counter (std_msgs/Int64 at 100 Hz) and /uav (ForceCommand, custom)."""
    from rclpy.serialization import serialize_message
    from std_msgs.msg import Int64

    from apf_swarm_msgs.msg import ForceCommand

    with bags.BagWriter(path, compress=compress, chunk_size=chunk_size, **kw) as w:
        q = qos_from_dict(QOS)
        c1 = w.add_topic('/counter', 'std_msgs/msg/Int64', offered_qos=[q])
        c2 = w.add_topic('/uav', 'apf_swarm_msgs/msg/ForceCommand', offered_qos=[q])
        for i in range(n):
            w.write(c1, T0 + i * 10_000_000, serialize_message(Int64(data=i)))
            m = ForceCommand(uav_id=2, step=i)
            m.force.x = 0.5 * i
            w.write(c2, T0 + i * 10_000_000 + 1, serialize_message(m))
    return path


def digest(path: Path) -> dict[str, str]:
    return {
        str(p.relative_to(path)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(path.rglob('*'))
        if p.is_file()
    }


# --------------------------------------------------------------------------------------------
# good bags
# --------------------------------------------------------------------------------------------


def test_info_export_and_nothing_modified(tmp_path: Path) -> None:
    bag = write_bag(tmp_path / 'b')
    before = digest(bag)
    p = run('bag', 'info', str(bag), '--json')
    assert p.returncode == 0, p.stderr
    info = json.loads(p.stdout)
    assert info['messages'] == 400 and info['storage'] == 'mcap' and info['version'] == 9
    assert info['topics']['/counter']['count'] == 200
    assert info['topics']['/uav']['type'] == 'apf_swarm_msgs/msg/ForceCommand'
    assert info['duration'] == pytest.approx(1.99, abs=1e-6)
    assert info['topics']['/counter']['frequency'] == pytest.approx(200 / 1.99, rel=1e-6)
    assert info['topics']['/counter']['offered_qos_profiles'][0]['depth'] == 10
    assert info['files'][0]['chunks'] > 1
    out = tmp_path / 'uav.csv'
    p = run('bag', 'export', str(bag), '--topic', '/uav', '--csv', str(out))
    assert p.returncode == 0, p.stderr
    rows = list(csv.DictReader(out.open()))
    assert len(rows) == 200
    assert float(rows[7]['force.x']) == 3.5 and rows[7]['uav_id'] == '2'
    assert int(rows[7]['timestamp_ns']) == T0 + 7 * 10_000_000 + 1
    assert 'header.stamp.sec' in rows[0]
    p = run('bag', 'export', str(bag), '--topic', '/counter')  # to stdout
    assert p.returncode == 0 and p.stdout.splitlines()[1].endswith(',0')
    assert digest(bag) == before  # info and export never modify a bag


def test_compressed_and_split_bag_reads_back(tmp_path: Path) -> None:
    from rosbags.highlevel import AnyReader

    bag = write_bag(tmp_path / 's', 500, compress=True, split_duration=1.0)
    files = bags.bag_files(bag)
    assert [f.name for f in files] == ['s_0.mcap', 's_1.mcap', 's_2.mcap', 's_3.mcap', 's_4.mcap']
    info = bags.open_bag(bag)
    assert info.count == 1000 and {f.compression for f in info.files} == {'zstd'}
    with AnyReader([bag]) as r:
        vals = [
            r.deserialize(raw, c.msgtype).data
            for c, _t, raw in r.messages()
            if c.topic == '/counter'
        ]
    assert vals == list(range(500))
    bag2 = write_bag(tmp_path / 'z', 300, split_size=4096)
    assert len(bags.bag_files(bag2)) > 2 and bags.open_bag(bag2).count == 600


def test_reindex_of_a_complete_bag_keeps_the_data_and_backs_up_metadata(tmp_path: Path) -> None:
    bag = write_bag(tmp_path / 'r')
    old = (bag / 'metadata.yaml').read_text()
    mcap_before = (bag / 'r_0.mcap').read_bytes()
    p = run('bag', 'reindex', str(bag))
    assert p.returncode == 0, p.stderr
    backups = list(bag.glob('reindex-backup-*/metadata.yaml'))
    assert len(backups) == 1 and backups[0].read_text() == old
    assert (bag / 'r_0.mcap').read_bytes() == mcap_before  # a complete file is kept as is
    new = bags.open_bag(bag)
    assert new.count == 400
    assert (
        new.topic('/uav').type_hash == bags.type_definition('apf_swarm_msgs/msg/ForceCommand')[1]
    )


def test_reindex_recovers_the_complete_chunks_of_a_truncated_file(tmp_path: Path) -> None:
    bag = write_bag(tmp_path / 't', 400)
    src = bag / 't_0.mcap'
    data = src.read_bytes()
    (bag / 'metadata.yaml').unlink()
    src.write_bytes(data[: len(data) // 2])  # killed half way through
    assert_bad(run('bag', 'info', str(bag)), 'metadata.yaml is missing', 'reindex')
    p = run('bag', 'reindex', str(bag))
    assert p.returncode == 0, p.stderr
    info = bags.open_bag(bag)
    counter = info.topic('/counter').count
    assert 50 < counter < 400
    from rclpy.serialization import deserialize_message
    from std_msgs.msg import Int64

    vals = [deserialize_message(raw, Int64).data for *_x, raw in bags.iter_raw(bag, ['/counter'])]
    assert vals == list(range(counter))


# --------------------------------------------------------------------------------------------
# bad input: one line, exit 2
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    'cmd',
    [
        ('info',),
        ('metrics',),
        ('export', '--topic', '/x'),
        ('reindex',),
        ('plot', '--out', 'OUT'),
        ('play',),
    ],
)
def test_path_that_does_not_exist(tmp_path: Path, cmd: tuple[str, ...]) -> None:
    args = [a.replace('OUT', str(tmp_path / 'o')) for a in cmd]
    assert_bad(
        run('bag', args[0], str(tmp_path / 'nope'), *args[1:]), 'nope', 'no such file or directory'
    )


def test_directory_that_is_not_a_bag(tmp_path: Path) -> None:
    (tmp_path / 'd').mkdir()
    (tmp_path / 'd' / 'notes.txt').write_text('hi')
    assert_bad(run('bag', 'info', str(tmp_path / 'd')), 'is not a bag')
    assert_bad(run('bag', 'reindex', str(tmp_path / 'd')), 'is not a bag')
    assert_bad(run('bag', 'info', str(tmp_path / 'd' / 'notes.txt')), 'is a file')


def test_missing_metadata_yaml(tmp_path: Path) -> None:
    bag = write_bag(tmp_path / 'm')
    (bag / 'metadata.yaml').unlink()
    for cmd in (('info',), ('metrics',), ('export', '--topic', '/counter')):
        assert_bad(
            run('bag', cmd[0], str(bag), *cmd[1:]),
            'metadata.yaml is missing',
            'apf-swarm bag reindex',
        )


def test_truncated_and_corrupt_mcap(tmp_path: Path) -> None:
    bag = write_bag(tmp_path / 'c')
    before = digest(bag)
    f = bag / 'c_0.mcap'
    data = f.read_bytes()
    f.write_bytes(data[:-100])  # the footer is gone
    assert_bad(run('bag', 'info', str(bag)), 'c_0.mcap', 'truncated or corrupt', 'reindex')
    f.write_bytes(b'\x00' * 64 + data[64:])  # garbage where the magic should be
    assert_bad(run('bag', 'info', str(bag)), 'truncated or corrupt')
    assert_bad(run('bag', 'export', str(bag), '--topic', '/counter'), 'truncated or corrupt')
    f.write_bytes(os.urandom(5000))
    assert_bad(run('bag', 'reindex', str(bag)), 'nothing to recover')
    # a garbled metadata.yaml
    f.write_bytes(data)
    assert digest(bag) == before
    (bag / 'metadata.yaml').write_text('rosbag2_bagfile_information: [1, 2')
    assert_bad(run('bag', 'info', str(bag)), 'metadata.yaml is not rosbag2 metadata')


def test_topic_that_is_not_in_the_bag(tmp_path: Path) -> None:
    bag = write_bag(tmp_path / 'tp')
    assert_bad(
        run('bag', 'export', str(bag), '--topic', '/nothere'),
        'topic /nothere is not in',
        '/counter',
    )
    assert_bad(run('bag', 'play', str(bag), '--topics', '/nothere'), 'topic /nothere is not in')
    assert_bad(
        run('bag', 'metrics', str(bag), '--config', 'config/triangle.yaml'),
        'topic /swarm/state is not in',
    )
    assert_bad(run('bag', 'metrics', str(bag)), 'no apf_swarm configuration', '--config')


def test_a_type_nobody_knows(tmp_path: Path) -> None:
    bag = tmp_path / 'u'
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    msgdef = 'int32 a\n'
    store = get_typestore(Stores.EMPTY)
    store.register(get_types_from_msg(msgdef, 'nobody_msgs/msg/Thing'))
    with bags.BagWriter(bag) as w:
        c = w.add_topic(
            '/mystery',
            'nobody_msgs/msg/Thing',
            msgdef=msgdef,
            rihs01=store.hash_rihs01('nobody_msgs/msg/Thing'),
            offered_qos=[qos_from_dict(QOS)],
        )
        w.write(c, T0, b'\x00\x01\x00\x00\x07\x00\x00\x00')
    # the bag carries the definition: inspection works
    p = run('bag', 'export', str(bag), '--topic', '/mystery')
    assert p.returncode == 0 and p.stdout.splitlines()[1] == f'{T0},7', p.stderr
    # but nothing here can publish it
    assert_bad(run('bag', 'play', str(bag)), 'nobody_msgs/msg/Thing', 'not installed')
    # and a recorder cannot describe a type nobody defines
    with pytest.raises(Exception, match='nobody_msgs/msg/Other is unknown'):
        bags.type_definition('nobody_msgs/msg/Other')
    # a bag whose stored definition is broken
    bag2 = tmp_path / 'u2'
    with bags.BagWriter(bag2) as w:
        c = w.add_topic(
            '/broken',
            'nobody_msgs/msg/Thing',
            msgdef='this is not a msg',
            rihs01='RIHS01_' + '0' * 64,
        )
        w.write(c, T0, b'\x00\x01\x00\x00')
    assert_bad(run('bag', 'export', str(bag2), '--topic', '/broken'), 'type definitions stored')


def test_bag_arguments_are_checked(tmp_path: Path) -> None:
    bag = write_bag(tmp_path / 'a')
    p = run('bag', 'play', str(bag), '--rate', '0')
    assert p.returncode == 2 and 'must be a positive number' in p.stderr
    assert_bad(run('bag', 'play', str(bag), '--remap', 'nocolon'), 'FROM:=TO')
    out = tmp_path / 'x.csv'
    out.write_text('keep')
    assert_bad(
        run('bag', 'export', str(bag), '--topic', '/counter', '--csv', str(out)),
        'exists',
        '--force',
    )
    assert out.read_text() == 'keep'


def test_flatten_nested_and_arrays() -> None:
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    Point = store.types['geometry_msgs/msg/Point']
    Poly = store.types['geometry_msgs/msg/Polygon']
    P32 = store.types['geometry_msgs/msg/Point32']
    poly = Poly(points=[P32(x=1.0, y=2.0, z=3.0), P32(x=4.0, y=5.0, z=6.0)])
    assert bags.flatten(poly) == {
        'points.0.x': 1.0,
        'points.0.y': 2.0,
        'points.0.z': 3.0,
        'points.1.x': 4.0,
        'points.1.y': 5.0,
        'points.1.z': 6.0,
    }
    assert bags.flatten(Point(x=1.0, y=2.0, z=3.0)) == {'x': 1.0, 'y': 2.0, 'z': 3.0}
    Cov = store.types['geometry_msgs/msg/PoseWithCovariance']
    pose = Cov(
        pose=store.types['geometry_msgs/msg/Pose'](
            position=Point(x=0.0, y=0.0, z=0.0),
            orientation=store.types['geometry_msgs/msg/Quaternion'](x=0.0, y=0.0, z=0.0, w=1.0),
        ),
        covariance=np.arange(36, dtype=float),
    )
    flat = bags.flatten(pose)
    assert flat['covariance.35'] == 35.0 and flat['pose.orientation.w'] == 1.0
    assert len(flat) == 7 + 36


def test_the_bag_tools_import_no_rclpy() -> None:
    # the bag package and the whole metrics path (samples, runio) run without rclpy
    code = (
        'import sys\n'
        'from apf_swarm_nodes import bags\nfrom apf_swarm_nodes.analysis import runio, samples\n'
        'import apf_swarm_nodes.bags.read, apf_swarm_nodes.bags.recover\n'
        'import apf_swarm_nodes.bags.export, apf_swarm_nodes.bags.write\n'
        'print(sorted(m for m in sys.modules if m.split(".")[0] == "rclpy"))\n'
    )
    done = subprocess.run(
        [sys.executable, '-c', code], capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == '[]', done.stdout
