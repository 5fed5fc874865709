"""The transport of a secure multi-host run (apf_swarm_nodes.dds.secure), without the bring-up:
a member of the run on simulated host 1 (the discovery server's profile, publishing and
subscribing), outsiders on host 2, each a real rclpy process in its own network namespace
(no shared memory can carry data between them: the profiles have none).

The outsiders have (a) no certificate, (b) a self-signed one, (c) one from another run's
authority, and the friendliest settings for themselves (they verify nothing and take no
OpenSSL configuration); the positive control is the same process with host 2's files of
the run. And the reason the run needs its OpenSSL configuration: without it, Fast DDS 2.14
admits a TLS client with no certificate at all.

Own ROS_DOMAIN_ID, bounded waits, processes stopped by PID, namespaces removed also on
failure. Needs root and iproute2 (skipped, with the reason, without them).
"""

from __future__ import annotations

import datetime as dt
import importlib.util
import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from apf_swarm_nodes.bringup import pick_domain_id, stop_process
from apf_swarm_nodes.dds import profiles as dds
from apf_swarm_nodes.dds import secure

ROOT = Path(__file__).resolve().parents[2]
_spec = importlib.util.spec_from_file_location('multihost', ROOT / 'scripts' / 'multihost.py')
multihost = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(multihost)
NO_HOSTS = multihost.unavailable()
pytestmark = pytest.mark.skipif(NO_HOSTS is not None, reason=f'simulated hosts: {NO_HOSTS}')

#: a node that publishes /apf_secret (the member) or /apf_steer (the others) and subscribes
#: the other, then prints what it saw: the topics and nodes of the graph, the messages it
#: received, how many subscribers its publisher matched, how long it looked. It looks for
#: SECONDS at most, until the file STOP exists, or (the control) until it has seen it all
PEER = r"""
import json, os, sys, time
import rclpy
from std_msgs.msg import String
seconds, name, stop = float(sys.argv[1]), sys.argv[2], sys.argv[3]
rclpy.init()
node = rclpy.create_node(name)
got = []
node.create_subscription(String, '/apf_steer' if name == 'member' else '/apf_secret',
                         lambda m: got.append(1), 10)
pub = node.create_publisher(String, '/apf_secret' if name == 'member' else '/apf_steer', 10)
topics, nodes, matched = set(), set(), 0
t0 = time.monotonic()
while time.monotonic() < t0 + seconds and not os.path.exists(stop):
    pub.publish(String(data=name))
    rclpy.spin_once(node, timeout_sec=0.02)
    topics |= {t for t, _ in node.get_topic_names_and_types()}
    nodes |= {n for n, _ in node.get_node_names_and_namespaces()}
    matched = max(matched, pub.get_subscription_count())
    if name == 'control' and len(got) >= 5 and 'member' in nodes and matched:
        break
print(json.dumps({'topics': sorted(topics), 'nodes': sorted(nodes), 'received': len(got),
                  'matched': matched, 'seconds': time.monotonic() - t0}), flush=True)
"""
#: outsiders look at least this much longer than the positive control needed to see it all
MARGIN = 8.0

ADMITS = r"""
import json, sys
from pathlib import Path
from apf_swarm_nodes.dds.secure import tls_admits
# outsiders knocking at the same ports slow every handshake there (RELIABILITY.md)
print(json.dumps([tls_admits(a, p, cert=c and Path(c), key=k and Path(k), timeout=30.0)
                  for a, p, c, k in json.loads(sys.argv[1])]))
"""


@pytest.fixture
def lab() -> Iterator[multihost.Lab]:
    with multihost.Lab(2) as made:
        yield made
    listed = subprocess.run(['ip', 'netns', 'list'], capture_output=True, text=True).stdout
    assert not any(ns in listed for ns in made.hosts)


def self_signed(directory: Path) -> tuple[Path, Path]:
    """A certificate signed by its own key (an outsider's)."""
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import NameOID

    key = ec.generate_private_key(ec.SECP256R1())
    name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, 'outsider')])
    now = dt.datetime.now(dt.UTC)
    cert = (
        x509.CertificateBuilder()
        .subject_name(name)
        .issuer_name(name)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - dt.timedelta(minutes=5))
        .not_valid_after(now + dt.timedelta(days=1))
        .sign(key, hashes.SHA256())
    )
    directory.mkdir(parents=True, exist_ok=True)
    (directory / 'cert.pem').write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    (directory / 'key.pem').write_bytes(
        key.private_bytes(
            serialization.Encoding.PEM,
            serialization.PrivateFormat.PKCS8,
            serialization.NoEncryption(),
        )
    )
    (directory / 'key.pem').chmod(0o600)
    return directory / 'cert.pem', directory / 'key.pem'


def outsider_profile(path: Path, text: str, *, with_cert: bool) -> Path:
    """An outsider's version of a host profile: it verifies nothing; without a
    certificate and key if so said."""
    text = text.replace(
        '<verify>VERIFY_PEER</verify><verify>VERIFY_FAIL_IF_NO_PEER_CERT</verify>',
        '<verify>VERIFY_NONE</verify>',
    )
    if not with_cert:
        text = '\n'.join(
            line
            for line in text.splitlines()
            if '<private_key_file>' not in line and '<cert_chain_file>' not in line
        )
    path.write_text(text)
    return path


def start(ns: str, env: dict[str, str], *argv: str) -> subprocess.Popen[str]:
    return subprocess.Popen(
        ['ip', 'netns', 'exec', ns, sys.executable, *argv],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
        start_new_session=True,
    )


def result(proc: subprocess.Popen[str], timeout: float) -> dict:
    try:
        out, _ = proc.communicate(timeout=timeout)
    finally:
        stop_process(proc, ((signal.SIGINT, 5.0), (signal.SIGKILL, 5.0)))
    assert proc.returncode == 0, out
    return json.loads(out.strip().splitlines()[-1])


def control_then_outsiders(
    control: subprocess.Popen[str],
    outsiders: list[tuple[str, subprocess.Popen[str]]],
    stop: Path,
    t0: float,
    again: Callable[[], subprocess.Popen[str]],
    saw_all: Callable[[dict], bool],
) -> dict[str, dict]:
    """The control's view (it stops once it has seen the swarm, 45 s at most), then the
    outsiders', stopped :data:`MARGIN` s after the control was done (counted from ``t0``,
    when they all started). A control that did not see it all (``saw_all`` of its view
    false) is started ``again`` once: Fast DDS 2.14's TCP discovery now and then never
    discovers a participant that did connect (docs/RELIABILITY.md), the member's own
    looker as much as a node; once its data flowed but its node never showed."""
    seen = {'control': result(control, 60.0)}
    if not saw_all(seen['control']):
        seen['control'] = result(again(), 60.0)
    time.sleep(max(0.0, t0 + seen['control']['seconds'] + MARGIN - time.monotonic()))
    stop.touch()
    for name, proc in outsiders:
        seen[name] = result(proc, 30.0)
        # (each counts from its own start, a second or two after t0 on a loaded machine)
        assert seen[name]['seconds'] >= seen['control']['seconds'] + MARGIN - 4.0, seen
    return seen


def base_env(domain: int) -> dict[str, str]:
    env = {
        k: v
        for k, v in os.environ.items()
        if k not in (*secure.NOT_SECURE, 'OPENSSL_CONF', *dds.PROFILE_VARIABLES)
    }
    env.update(ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE='SUBNET')
    env.update(RCUTILS_LOGGING_SEVERITY_THRESHOLD='FATAL')  # the refused handshakes' errors
    return env


def admits_all(ns: str, env: dict[str, str], tries: list[tuple]) -> list[bool]:
    """Whether each (address, port, cert or None, key or None) admits a TLS client,
    probed from ``ns`` (one process for all)."""
    p = subprocess.run(
        ['ip', 'netns', 'exec', ns, sys.executable, '-c', ADMITS,
         json.dumps([[a, port, c and str(c), k and str(k)] for a, port, c, k in tries])],
        env=env, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert p.returncode == 0, p.stderr
    return json.loads(p.stdout)


def admits(ns: str, env: dict[str, str], address: str, port: int, *files: Path) -> bool:
    cert, key = files if files else (None, None)
    return admits_all(ns, env, [(address, port, cert, key)])[0]


def test_outsiders_without_the_runs_certificate_see_nothing(
    lab: multihost.Lab, tmp_path: Path
) -> None:
    """Host 1: a member of the run (the discovery server's profile) publishes /apf_secret
    and subscribes /apf_steer. Host 2, at the same time: outsiders with no certificate, a
    self-signed one, one of another run's authority see no topic but their own, no node
    but their own, receive nothing, and no subscriber matches their /apf_steer; the member
    of the run on host 2 sees and receives it all (the positive control). Every TLS port of
    host 1 refuses a client without the run's certificate; host 1 has no UDP socket."""
    h1, h2 = lab.hosts
    d = pick_domain_id(lo=102, hi=201)
    port = secure.server_port(d)
    pki = secure.write_run_files(
        tmp_path / 'dds', ['h1', 'h2'], 'h1', (lab.addr[h1], port), run=f'test{d}', participants=6
    )
    other = secure.make_pki(tmp_path / 'other', ['x'], run='another run')['x']
    mine = pki.hosts['h2']
    text = mine.profile.read_text()
    outsiders = {
        'no_cert': outsider_profile(tmp_path / 'no_cert.xml', text, with_cert=False),
        'self_signed': outsider_profile(tmp_path / 'self.xml', text, with_cert=True),
        'other_ca': outsider_profile(tmp_path / 'other.xml', text, with_cert=True),
    }
    cert, key = self_signed(tmp_path / 'self')
    swaps = {
        'self_signed': {mine.cert: cert, mine.key: key},
        'other_ca': {mine.cert: other[0], mine.key: other[1], pki.ca: tmp_path / 'other/ca.pem'},
    }
    for name, swap in swaps.items():
        text = outsiders[name].read_text()
        for old, new in swap.items():
            text = text.replace(str(old), str(new))
        outsiders[name].write_text(text)
    env = base_env(d)
    run_env = {**env, **secure.secure_environment(pki.server_profile, pki.openssl)}
    stop = tmp_path / 'stop'
    member = start(h1, run_env, '-c', PEER, '120', 'member', str(tmp_path / 'never'))
    procs: list[tuple[str, subprocess.Popen[str]]] = []
    controls: list[tuple[str, subprocess.Popen[str]]] = []
    try:
        t0 = time.monotonic()
        for name, profile in outsiders.items():
            out_env = {**env, **dict.fromkeys(dds.PROFILE_VARIABLES, str(profile))}
            procs.append((name, start(h2, out_env, '-c', PEER, '120', name, str(stop))))
        h2_env = {**env, **secure.secure_environment(mine.profile, pki.openssl)}
        control = start(h2, h2_env, '-c', PEER, '45', 'control', str(stop))
        controls.append(('control', control))
        # meanwhile: every TCP port host 1 listens on refuses a client without the run's
        # certificate, with a self-signed one, with another authority's; admits the run's
        listening = set()
        for _ in range(50):
            ss = subprocess.run(
                ['ip', 'netns', 'exec', h1, 'ss', '-Htln'], capture_output=True, text=True
            ).stdout
            listening = {int(line.split()[3].rsplit(':', 1)[1]) for line in ss.splitlines()}
            if port in listening:  # the member is the server: its one port
                break
            subprocess.run(['sleep', '0.1'])
        assert port in listening, listening
        files = [(None, None), (cert, key), other, (mine.cert, mine.key)]
        tries = [(lab.addr[h1], p, c, k) for p in sorted(listening) for c, k in files]
        admitted = admits_all(h2, env, tries)
        assert admitted == [False, False, False, True] * len(listening), (tries, admitted)
        udp = subprocess.run(
            ['ip', 'netns', 'exec', h1, 'ss', '-Hulpn'], capture_output=True, text=True
        ).stdout
        assert udp.strip() == '', udp

        def again() -> subprocess.Popen[str]:
            proc = start(h2, h2_env, '-c', PEER, '45', 'control', str(stop))
            controls.append(('control, again', proc))
            return proc

        def saw_all(view: dict) -> bool:
            return 'member' in view['nodes'] and view['received'] >= 5 and view['matched'] >= 1

        seen = control_then_outsiders(control, procs, stop, t0, again, saw_all)
    finally:
        for _, proc in [*procs, *controls]:
            stop_process(proc, ((signal.SIGKILL, 5.0),))
        stop_process(member, ((signal.SIGINT, 5.0), (signal.SIGKILL, 5.0)))
    for name in outsiders:
        s = seen[name]
        assert s['nodes'] == [name], (name, s)
        assert set(s['topics']) <= {'/apf_secret', '/apf_steer', '/rosout', '/parameter_events'}
        assert s['received'] == 0 and s['matched'] == 0, (name, s)
    control = seen['control']
    assert 'member' in control['nodes'] and control['received'] >= 5, control
    assert control['matched'] >= 1, control


def test_without_the_openssl_configuration_fast_dds_admits_anyone(
    lab: multihost.Lab, tmp_path: Path
) -> None:
    """Why a run's processes need ``OPENSSL_CONF``: the same member with the same profile
    (``VERIFY_PEER`` and ``VERIFY_FAIL_IF_NO_PEER_CERT``) but without it completes a TLS
    handshake with a client that has no certificate: Fast DDS 2.14 does not ask for one.
    With it, the same client is refused. Should a later Fast DDS fail the first half, its
    profile verifies by itself, and docs/RELIABILITY.md should say so."""
    h1, h2 = lab.hosts
    d = pick_domain_id(lo=102, hi=201)
    port = secure.server_port(d)
    pki = secure.write_run_files(
        tmp_path / 'dds', ['h1'], 'h1', (lab.addr[h1], port), run=f'test{d}', participants=2
    )
    env = base_env(d)
    found = {}
    for with_conf in (False, True):
        run_env = {**env, **secure.secure_environment(pki.server_profile, pki.openssl)}
        if not with_conf:
            del run_env['OPENSSL_CONF']
        member = start(h1, run_env, '-c', PEER, '20', 'member', str(tmp_path / 'never'))
        try:
            for _ in range(100):
                try:
                    found[with_conf] = admits(h2, env, lab.addr[h1], port)
                    break
                except AssertionError:  # not listening yet
                    subprocess.run(['sleep', '0.1'])
        finally:
            stop_process(member, ((signal.SIGINT, 5.0), (signal.SIGKILL, 5.0)))
    assert found == {False: True, True: False}, found


def test_a_node_needs_only_the_profile(lab: multihost.Lab, tmp_path: Path) -> None:
    """A host joins a secure run by pointing ``FASTRTPS_DEFAULT_PROFILES_FILE`` at its
    profile, nothing else: a node of ours started so (no ``OPENSSL_CONF``) refuses a TLS
    client without a certificate and admits the run's. The control, a plain rclpy process
    with the same environment, admits anyone (so the test can fail)."""
    h1, h2 = lab.hosts
    d = pick_domain_id(lo=102, hi=201)
    pki = secure.write_run_files(
        tmp_path / 'dds', ['h1', 'h2'], 'h2', (lab.addr[h2], secure.server_port(d)),
        run=f'test{d}', participants=2,
    )  # fmt: skip
    env = {**base_env(d), **dict.fromkeys(dds.PROFILE_VARIABLES, str(pki.hosts['h1'].profile))}
    env.pop('ROS_AUTOMATIC_DISCOVERY_RANGE')
    run_cert = (pki.hosts['h2'].cert, pki.hosts['h2'].key)
    found = {}
    for who, argv in (
        ('plain rclpy', ['-c', PEER, '30', 'member', str(tmp_path / 'never')]),
        ('our node', ['-m', 'apf_swarm_nodes.target_node']),
    ):
        proc = start(h1, env, *argv)
        try:
            ports: set[int] = set()
            for _ in range(150):
                ports = listening_tcp(h1)
                if ports or proc.poll() is not None:
                    break
                subprocess.run(['sleep', '0.1'])
            assert ports, f'{who}: no TCP port (exit {proc.poll()})'
            tries = [(lab.addr[h1], p, *files) for p in sorted(ports)
                     for files in ((None, None), run_cert)]  # fmt: skip
            found[who] = admits_all(h2, env, tries)
        finally:
            stop_process(proc, ((signal.SIGINT, 5.0), (signal.SIGKILL, 5.0)))
    n = len(found['our node']) // 2
    assert found['our node'] == [False, True] * n, found
    assert found['plain rclpy'][0] is True, found


# --------------------------------------------------------------------------------------------
# the bring-up
# --------------------------------------------------------------------------------------------

#: someone who wants to read or steer the swarm: subscribes /swarm/state, publishes
#: /uav_1/force_cmd (as test_isolation's looker) for SECONDS at most, until the file STOP
#: exists, or (with 'until', the control) until it has seen the plant, some states and a
#: subscriber of its commands
LOOKER = r"""
import json, os, sys, time
import rclpy
from apf_swarm_msgs.msg import ForceCommand, SwarmState
from rclpy.qos import QoSProfile, ReliabilityPolicy
rclpy.init()
node = rclpy.create_node('looker')
got = []
qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT)
node.create_subscription(SwarmState, '/swarm/state', lambda m: got.append(1), qos)
pub = node.create_publisher(ForceCommand, '/uav_1/force_cmd', 10)
topics, nodes, matched = set(), set(), 0
t0 = time.monotonic()
end = t0 + float(sys.argv[1])
until, stop = sys.argv[2] == 'until', sys.argv[3]
while time.monotonic() < end and not os.path.exists(stop):
    rclpy.spin_once(node, timeout_sec=0.05)
    topics |= {t for t, _ in node.get_topic_names_and_types()}
    nodes |= {ns.rstrip('/') + '/' + n for n, ns in node.get_node_names_and_namespaces()}
    matched = max(matched, pub.get_subscription_count())
    if until and '/plant' in nodes and len(got) >= 5 and matched:
        break
print(json.dumps({'topics': sorted(topics), 'nodes': sorted(nodes), 'states': len(got),
                  'force_cmd_matched': matched, 'seconds': time.monotonic() - t0}), flush=True)
"""
OWN_TOPICS = {'/swarm/state', '/uav_1/force_cmd', '/rosout', '/parameter_events'}


@pytest.fixture
def lab3() -> Iterator[multihost.Lab]:
    with multihost.Lab(3) as made:
        yield made
    listed = subprocess.run(['ip', 'netns', 'list'], capture_output=True, text=True).stdout
    assert not any(ns in listed for ns in made.hosts)


def listening_tcp(ns: str) -> set[int]:
    ss = subprocess.run(['ip', 'netns', 'exec', ns, 'ss', '-Htln'], capture_output=True, text=True)
    return {int(line.split()[3].rsplit(':', 1)[1]) for line in ss.stdout.splitlines()}


def test_a_secure_bringup_admits_only_its_hosts(lab3: multihost.Lab, tmp_path: Path) -> None:
    """``swarm_up.py --discovery-range SUBNET --secure``: plant, target and bring-up on host
    1, the trackers on host 2; on host 3 outsiders with no certificate, a self-signed one,
    another run's see no node and no topic of the swarm, receive no /swarm/state and no
    subscriber matches their /uav_1/force_cmd; the same looker with host 2's files does
    (the positive control). Every TCP port of hosts 1 and 2 refuses them, no UDP socket is
    open there, and the run's keys are gone at its end."""
    h1, h2, h3 = lab3.hosts
    d = pick_domain_id(lo=102, hi=201)
    out = (tmp_path / 'run').resolve()
    err = tmp_path / 'bringup.stderr'
    procs: list[tuple[str, subprocess.Popen[str]]] = []
    controls: list[tuple[str, subprocess.Popen[str]]] = []
    stop = tmp_path / 'stop'
    bring = None
    try:
        # a secure bring-up whose graph never completes (a node connected to the discovery
        # server but never discovered: Fast DDS 2.14's TCP, RELIABILITY.md) is started again,
        # once: that is a known upstream fault, not what this test is about
        for attempt in range(2):
            argv = [
                'ip', 'netns', 'exec', h1, sys.executable, str(ROOT / 'scripts' / 'swarm_up.py'),
                '--preset', 'triangle', '--n-trackers', '3', '--duration', '120',
                '--domain-id', str(d), '--out', str(out), '--no-plots', '--allow-overload',
                '--discovery-range', 'SUBNET', '--secure', '--secure-address', lab3.addr[h1],
                '--node-netns', f'tracker*={h2}', '--ready-timeout', '20',
            ]  # fmt: skip
            with open(err, 'wb') as f:
                bring = subprocess.Popen(
                    argv, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=f,
                    cwd=ROOT, start_new_session=True,
                )  # fmt: skip
            end = time.monotonic() + 90
            while 'graph ready after' not in err.read_text(errors='replace'):
                if bring.poll() is not None:
                    text = err.read_text(errors='replace')
                    assert attempt == 0 and 'graph was not complete' in text, text
                    out = out.with_name(f'{out.name}_again')
                    break
                assert time.monotonic() < end, err.read_text(errors='replace')
                time.sleep(0.1)
            else:
                break
        text = err.read_text(errors='replace')
        assert 'OPEN TO THE NETWORK' not in text and 'secure: TCP with TLS only' in text
        dds_dir = out / 'dds'
        mine = dds_dir / h2
        profile = (mine / secure.PROFILE_FILE).read_text()
        other = secure.make_pki(tmp_path / 'other', ['x'], run='another run')['x']
        cert, key = self_signed(tmp_path / 'self')
        variants = {
            'no_cert': (False, {}),
            'self_signed': (True, {mine / 'cert.pem': cert, mine / 'key.pem': key}),
            'other_ca': (
                True,
                {
                    mine / 'cert.pem': other[0],
                    mine / 'key.pem': other[1],
                    dds_dir / 'ca.pem': tmp_path / 'other' / 'ca.pem',
                },
            ),
        }
        env = base_env(d)
        # every TCP port of the run's hosts refuses the outsiders' certificates (probed
        # before the outsiders knock: they slow every handshake, see RELIABILITY.md)
        ports = {h1: listening_tcp(h1), h2: listening_tcp(h2)}
        assert secure.server_port(d) in ports[h1] and len(ports[h1]) >= 3, ports  # + plant, target
        assert len(ports[h2]) >= 1, ports
        files = [(None, None), (cert, key), other]
        tries = [
            (lab3.addr[ns], p, c, k) for ns, listening in ports.items()
            for p in sorted(listening) for c, k in files
        ]  # fmt: skip
        admitted = admits_all(h3, env, tries)
        assert not any(admitted), [t for t, a in zip(tries, admitted, strict=True) if a]
        for ns in ports:
            udp = subprocess.run(
                ['ip', 'netns', 'exec', ns, 'ss', '-Hulpn'], capture_output=True, text=True
            ).stdout
            assert udp.strip() == '', (ns, udp)
        t0 = time.monotonic()
        for name, (with_cert, swap) in variants.items():
            text = profile
            for old, new in swap.items():
                text = text.replace(str(old), str(new))
            path = outsider_profile(tmp_path / f'{name}.xml', text, with_cert=with_cert)
            out_env = {**env, **dict.fromkeys(dds.PROFILE_VARIABLES, str(path))}
            procs.append((name, start(h3, out_env, '-c', LOOKER, '90', '-', str(stop))))
        control_env = {
            **env,
            **secure.secure_environment(mine / secure.PROFILE_FILE, dds_dir / 'openssl.cnf'),
        }
        control = start(h3, control_env, '-c', LOOKER, '45', 'until', str(stop))
        controls.append(('control', control))

        def again() -> subprocess.Popen[str]:
            proc = start(h3, control_env, '-c', LOOKER, '45', 'until', str(stop))
            controls.append(('control, again', proc))
            return proc

        seen = control_then_outsiders(
            control, procs, stop, t0, again, lambda v: '/plant' in v['nodes'] and v['states']
        )
    finally:
        for _, proc in [*procs, *controls]:
            stop_process(proc, ((signal.SIGKILL, 5.0),))
        if bring is not None:
            rc = stop_process(bring, ((signal.SIGINT, 30.0), (signal.SIGKILL, 5.0)))
    for name in variants:
        s = seen[name]
        assert s['nodes'] == ['/looker'], (name, s)
        assert set(s['topics']) <= OWN_TOPICS, (name, s)
        assert s['states'] == 0 and s['force_cmd_matched'] == 0, (name, s)
    control = seen['control']
    assert '/plant' in control['nodes'] and control['states'] > 0, control
    assert control['force_cmd_matched'] == 1, control
    assert rc == 130, err.read_text(errors='replace')
    assert not list(dds_dir.glob('*/key.pem'))  # removed at the end
    assert (dds_dir / 'ca.pem').is_file() and (mine / 'cert.pem').is_file()
