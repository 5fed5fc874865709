"""The DDS side of a run's isolation without a ROS graph (apf_swarm_nodes.dds.profiles): the
Fast DDS profile's content, the environment a run gets, the refusal's message, the port mapping."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path
from types import SimpleNamespace

import pytest
from apf_swarm_nodes.dds import profiles as dds
from apf_swarm_nodes.dds import swarm_domain
from apf_swarm_nodes.dds.errors import DdsError

NS = {'f': 'http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles'}


def parse(text: str) -> ET.Element:
    return ET.fromstring(text.encode())


def test_the_localhost_profile_binds_loopback_only_without_multicast() -> None:
    root = parse(dds.profile_xml(localhost=True, participants=20))
    udp, shm = root.findall('.//f:transport_descriptor', NS)
    assert udp.findtext('f:type', namespaces=NS) == 'UDPv4'
    allowed = [i.get('name') for i in udp.findall('f:interfaces/f:allowlist/f:interface', NS)]
    assert allowed == ['127.0.0.1']
    assert int(udp.findtext('f:maxInitialPeersRange', namespaces=NS)) == 36  # 20 + 16 spare
    assert shm.findtext('f:type', namespaces=NS) == 'SHM'
    participant = root.find('.//f:participant', NS)
    assert participant.get('is_default_profile') == 'true'
    rtps = participant.find('f:rtps', NS)
    # no builtin transport (it would bind 0.0.0.0), only the two above
    assert rtps.findtext('f:useBuiltinTransports', namespaces=NS) == 'false'
    assert [t.text for t in rtps.findall('f:userTransports/f:transport_id', NS)] == [
        'apf_swarm_udp_loopback',
        'apf_swarm_shm',
    ]
    builtin = rtps.find('f:builtin', NS)
    # a unicast metatraffic locator on 127.0.0.1, hence no multicast one; peers on 127.0.0.1
    for where in ('f:metatrafficUnicastLocatorList', 'f:initialPeersList'):
        addrs = [a.text for a in builtin.findall(f'{where}/f:locator/f:udpv4/f:address', NS)]
        assert addrs == ['127.0.0.1'], where
    assert builtin.find('f:metatrafficMulticastLocatorList', NS) is None
    assert '0.0.0.0' not in dds.profile_xml(localhost=True)


@pytest.mark.parametrize('participants', [4, 12, 36, 50])
def test_the_announcements_repeat_through_a_start_up_at_a_bounded_rate(participants: int) -> None:
    period, window, lease = dds.discovery_timing(participants)
    assert dds.PERIOD_MIN <= period <= dds.PERIOD_MAX
    assert window >= 5.0 and window >= min(dds.WINDOW_MAX, 0.5 * participants)
    assert lease == 3.0  # Fast DDS's default: the steady state costs what it did
    # every participant receives participants / period announcements a second while starting
    assert participants / period <= 100
    config = parse(dds.profile_xml(participants=participants)).find('.//f:discovery_config', NS)
    count = int(config.findtext('f:initialAnnouncements/f:count', namespaces=NS))
    nanosec = int(config.findtext('f:initialAnnouncements/f:period/f:nanosec', namespaces=NS))
    assert nanosec == round(period * 1e9) and count == round(window / period)
    assert config.findtext('f:leaseAnnouncement/f:sec', namespaces=NS) == '3'
    assert config.findtext('f:leaseDuration/f:sec', namespaces=NS) == '20'
    assert 32 <= dds.max_participants(participants) <= 120


def test_the_network_profile_keeps_the_middleware_transports() -> None:
    root = parse(dds.profile_xml(localhost=False, participants=10))
    assert root.find('.//f:transport_descriptors', NS) is None
    rtps = root.find('.//f:participant/f:rtps', NS)
    assert [c.tag.split('}')[1] for c in rtps] == ['builtin']
    assert [c.tag.split('}')[1] for c in rtps.find('f:builtin', NS)] == ['discovery_config']
    with pytest.raises(ValueError, match='discovery timing'):
        dds.profile_xml(lease_announcement=30.0)


@pytest.fixture
def no_swarm(monkeypatch: pytest.MonkeyPatch) -> list[tuple[int, bool]]:
    """The domain check, recorded instead of run (it needs a ROS graph)."""
    calls: list[tuple[int, bool]] = []

    def record(domain: int, *, network: bool = False) -> None:
        calls.append((domain, network))

    monkeypatch.setattr(dds, 'refuse_other_swarm', record)
    return calls


def test_a_localhost_run_gets_the_profile_and_drops_what_names_other_hosts(
    tmp_path: Path, no_swarm: list[tuple[int, bool]]
) -> None:
    env = {
        'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST',
        'FASTRTPS_DEFAULT_PROFILES_FILE': '/mine.xml',
        'ROS_STATIC_PEERS': '192.0.2.7',
        'FASTDDS_BUILTIN_TRANSPORTS': 'UDPv4',
    }
    said: list[str] = []
    path = dds.isolate_dds(tmp_path, 7, 'LOCALHOST', processes=6, environ=env, say=said.append)
    assert path == tmp_path / 'fastdds_localhost.xml' and path.is_file()
    assert (
        env['FASTRTPS_DEFAULT_PROFILES_FILE'] == env['FASTDDS_DEFAULT_PROFILES_FILE'] == str(path)
    )
    assert env['ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'SUBNET'  # LOCALHOST adds rmw's socket
    assert 'ROS_STATIC_PEERS' not in env
    assert any('/mine.xml is replaced' in s for s in said)
    assert any('ROS_STATIC_PEERS ignored' in s for s in said)
    assert no_swarm == [(7, False)]
    assert path.read_text() == dds.profile_xml(localhost=True, participants=6)
    # the bring-up's own participant: the same profile without shared memory
    own = dds.own_participant_environment(env)
    udp = Path(own['FASTRTPS_DEFAULT_PROFILES_FILE'])
    assert udp == tmp_path / dds.OWN_PROFILE and own['FASTDDS_DEFAULT_PROFILES_FILE'] == str(udp)
    kinds = [t.text for t in ET.parse(udp).getroot().findall('.//{*}type')]
    assert kinds == ['UDPv4']
    assert [t.text for t in ET.parse(path).getroot().findall('.//{*}type')] == ['UDPv4', 'SHM']
    assert udp.read_text() == dds.profile_xml(localhost=True, participants=6, shm=False)
    # a network run: the builtin transports, UDP alone
    assert dds.own_participant_environment({}) == {'FASTDDS_BUILTIN_TRANSPORTS': 'UDPv4'}


def test_a_network_run_keeps_a_users_profile_and_off_does_nothing(
    tmp_path: Path, no_swarm: list[tuple[int, bool]]
) -> None:
    env = {'FASTRTPS_DEFAULT_PROFILES_FILE': '/mine.xml', 'ROS_STATIC_PEERS': '192.0.2.7'}
    assert dds.isolate_dds(tmp_path, 3, 'SUBNET', processes=5, environ=env) is None
    assert env == {'FASTRTPS_DEFAULT_PROFILES_FILE': '/mine.xml', 'ROS_STATIC_PEERS': '192.0.2.7'}
    env = {}
    path = dds.isolate_dds(tmp_path, 3, 'SYSTEM_DEFAULT', processes=5, environ=env)
    assert path is not None and env['FASTRTPS_DEFAULT_PROFILES_FILE'] == str(path)
    assert 'ROS_AUTOMATIC_DISCOVERY_RANGE' not in env  # the bring-up's own setting stays
    assert no_swarm == [(3, True), (3, True)]
    env = {}
    assert dds.isolate_dds(tmp_path / 'off', 3, 'OFF', processes=5, environ=env) is None
    assert env == {} and not (tmp_path / 'off').exists() and len(no_swarm) == 2


def test_another_middleware_is_refused_for_a_localhost_run(
    tmp_path: Path, no_swarm: list[tuple[int, bool]]
) -> None:
    env = {'RMW_IMPLEMENTATION': 'rmw_cyclonedds_cpp'}
    with pytest.raises(DdsError, match='RMW_IMPLEMENTATION=rmw_cyclonedds_cpp'):
        dds.isolate_dds(tmp_path, 3, 'LOCALHOST', processes=5, environ=env)
    dds.check_rmw({'RMW_IMPLEMENTATION': 'rmw_fastrtps_cpp'})
    dds.check_rmw({})


def test_the_refusal_names_the_domain_the_topics_and_what_to_do(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    found = [f'/uav_{i}/force_cmd (1 publishers: /uav_{i}/tracker)' for i in range(1, 5)]
    monkeypatch.setattr(swarm_domain, 'swarm_publishers', lambda domain, network=False: found)
    with pytest.raises(DdsError) as err:
        swarm_domain.refuse_other_swarm(42)
    text = str(err.value)
    assert text.startswith('ROS_DOMAIN_ID=42 already carries a swarm: /uav_1/force_cmd')
    assert 'and 1 more' in text and '--domain-id' in text and '\n' not in text
    monkeypatch.setattr(swarm_domain, 'swarm_publishers', lambda domain, network=False: [])
    swarm_domain.refuse_other_swarm(42)


def test_the_domain_ports_are_one_per_participant() -> None:
    base = 7400 + 250 * 5 + 10
    # domain 5's participants 0 and 2 (discovery and data ports), domain 6's 0, domain 4's 0
    ports = {base, base + 1, base + 4, base + 5, base + 250, base - 250, 7000}
    assert swarm_domain.domain_participant_ports(5, ports) == {base, base + 4}
    assert swarm_domain.domain_participant_ports(6, ports) == {base + 250}
    assert swarm_domain.domain_participant_ports(7, ports) == set()


def test_the_command_writes_the_profile_and_prints_the_environment(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / 'p.xml'
    assert dds.main(['--out', str(out), '--processes', '40']) == 0
    printed = capsys.readouterr().out.splitlines()
    assert f'export FASTRTPS_DEFAULT_PROFILES_FILE={out}' in printed
    assert 'export ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET' in printed
    assert printed[-1].startswith('unset ROS_LOCALHOST_ONLY ROS_STATIC_PEERS')
    assert out.read_text() == dds.profile_xml(localhost=True, participants=40)


class FakeGraph:
    """What the domain probe reads of a graph: topics, and each topic's publishers."""

    def __init__(self, publishers: dict[str, list[tuple[str, str]]]) -> None:
        self.publishers = publishers

    def get_topic_names_and_types(self) -> list[tuple[str, list[str]]]:
        return [(t, ['x/msg/Y']) for t in self.publishers]

    def get_publishers_info_by_topic(self, topic: str) -> list[SimpleNamespace]:
        return [
            SimpleNamespace(node_namespace=ns, node_name=n) for ns, n in self.publishers[topic]
        ]


def test_a_swarm_is_told_from_a_viewer_by_its_publishers() -> None:
    viewer = FakeGraph({'/swarm/state': [], '/rosout': [('/', 'viewer')], '/uav_1/odom': []})
    assert swarm_domain._swarm_topics(viewer) == []  # subscribers only, and topics of every node
    swarm = FakeGraph(
        {
            '/uav_12/velocity_cmd': [('/uav_12', 'tracker')],
            '/swarm/state': [('/', 'plant')],
            '/swarm/start': [('/', '_NODE_NAME_UNKNOWN_')],
            '/uav_x/force_cmd': [('/', 'someone')],
            '/clock': [('/', 'sim')],
        }
    )
    assert swarm_domain._swarm_topics(swarm) == [
        '/swarm/state (1 publishers: /plant)',
        '/swarm/start (1 publishers: a node not yet named)',
        '/uav_12/velocity_cmd (1 publishers: /uav_12/tracker)',
    ]


def test_own_participant_sets_the_udp_only_environment_then_restores_it(monkeypatch) -> None:
    """The bring-up's node and its domain probe are made inside own_participant(): UDP only
    while Fast DDS reads its transports, the run's environment as before afterwards."""
    import os

    from apf_swarm_nodes.dds.profiles import own_participant

    monkeypatch.delenv('FASTDDS_BUILTIN_TRANSPORTS', raising=False)
    monkeypatch.delenv('FASTRTPS_DEFAULT_PROFILES_FILE', raising=False)
    monkeypatch.delenv('FASTDDS_DEFAULT_PROFILES_FILE', raising=False)
    with own_participant():
        assert os.environ['FASTDDS_BUILTIN_TRANSPORTS'] == 'UDPv4'
    assert 'FASTDDS_BUILTIN_TRANSPORTS' not in os.environ
    monkeypatch.setenv('FASTDDS_BUILTIN_TRANSPORTS', 'DEFAULT')
    with own_participant():
        assert os.environ['FASTDDS_BUILTIN_TRANSPORTS'] == 'UDPv4'
    assert os.environ['FASTDDS_BUILTIN_TRANSPORTS'] == 'DEFAULT'
