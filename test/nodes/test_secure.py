"""A secure run's files (apf_swarm_nodes.dds.secure): the authority and host certificates, the
profile, and bad input (missing, expired, mismatched, another run's, a key others can read)
named with its file and what to do."""

from __future__ import annotations

import datetime as dt
import os
import stat
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest
from apf_swarm_nodes.dds import secure
from apf_swarm_nodes.dds.errors import DdsError

NS = '{http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles}'


@pytest.fixture
def pki(tmp_path: Path) -> secure.Pki:
    return secure.write_run_files(
        tmp_path / 'dds', ['h1', 'h2'], 'h1', ('10.0.0.1', 20007), run='r', participants=6
    )


def test_files_keys_private_and_authority_key_never_written(pki: secure.Pki) -> None:
    d = pki.ca.parent
    assert sorted(p.name for p in d.iterdir()) == sorted(
        ['ca.pem', 'openssl.cnf', 'fastdds_secure_server.xml', 'h1', 'h2']
    )
    for host in pki.hosts.values():
        assert stat.S_IMODE(host.key.stat().st_mode) == 0o600
        assert sorted(p.name for p in host.key.parent.iterdir()) == [
            'cert.pem',
            'fastdds_secure.xml',
            'fastdds_secure_client.xml',
            'key.pem',
        ]
    # the only private keys on disk are the hosts'
    keys = [p for p in d.rglob('*') if p.is_file() and b'PRIVATE KEY' in p.read_bytes()]
    assert sorted(keys) == sorted(h.key for h in pki.hosts.values())
    assert secure.remove_keys(d) == sorted(h.key for h in pki.hosts.values())
    assert not any(h.key.exists() for h in pki.hosts.values())


def test_profile_is_tls_over_tcp_only(pki: secure.Pki) -> None:
    h2 = pki.hosts['h2']
    kinds = {h2.profile: 'SUPER_CLIENT', h2.client_profile: 'CLIENT', pki.server_profile: 'SERVER'}
    for path, kind in kinds.items():
        server = kind == 'SERVER'
        root = ET.parse(path).getroot()
        descriptors = root.findall(f'.//{NS}transport_descriptor')
        assert len(descriptors) == 1
        assert descriptors[0].findtext(f'{NS}type') == 'TCPv4'
        tls = descriptors[0].find(f'{NS}tls')
        assert tls is not None
        assert tls.findtext(f'{NS}verify_file') == str(pki.ca)
        assert 'VERIFY_PEER' in [v.text for v in tls.iter(f'{NS}verify')]
        assert tls.find(f'{NS}password') is None  # an empty one breaks the parsing
        assert root.findtext(f'.//{NS}useBuiltinTransports') == 'false'
        protocol = root.findtext(f'.//{NS}discoveryProtocol')
        assert protocol == kind
        port = root.findtext(f'.//{NS}listening_ports/{NS}port')
        assert port == ('20007' if server else '0')
    assert 'VerifyMode = Peer,Require' in pki.openssl.read_text()
    env = secure.secure_environment(pki.hosts['h2'].profile, pki.openssl)
    assert env['OPENSSL_CONF'] == str(pki.openssl)
    assert env['FASTRTPS_DEFAULT_PROFILES_FILE'] == str(pki.hosts['h2'].profile)


def check(pki: secure.Pki, host: str = 'h2', **kw: object) -> str:
    h = pki.hosts[host]
    with pytest.raises(DdsError) as err:
        secure.check_files(pki.ca, h.cert, h.key, **kw)  # type: ignore[arg-type]
    return str(err.value)


def test_bad_input_names_the_file_and_the_fix(pki: secure.Pki, tmp_path: Path) -> None:
    h2 = pki.hosts['h2']
    secure.check_files(pki.ca, h2.cert, h2.key)  # fine as written
    later = dt.datetime.now(dt.UTC) + secure.VALIDITY + dt.timedelta(hours=1)
    msg = check(pki, now=later)
    assert str(pki.ca) in msg and 'expired' in msg and 'start the run again' in msg
    earlier = dt.datetime.now(dt.UTC) - dt.timedelta(days=1)
    assert 'not valid before' in check(pki, now=earlier)
    # another run's certificate
    other = secure.make_pki(tmp_path / 'other', ['h2'], run='other')['h2']
    with pytest.raises(DdsError, match="not issued by the run's authority") as err:
        secure.check_files(pki.ca, other[0], other[1])
    assert str(other[0]) in str(err.value)
    # a key that is not the certificate's
    with pytest.raises(DdsError, match='mismatched') as err:
        secure.check_files(pki.ca, h2.cert, pki.hosts['h1'].key)
    assert str(pki.hosts['h1'].key) in str(err.value)
    # a key others can read
    h2.key.chmod(0o644)
    msg = check(pki)
    assert f'chmod 600 {h2.key}' in msg and '0644' in msg
    h2.key.chmod(0o600)
    # missing files
    os.unlink(h2.key)
    assert f'{h2.key}: private key missing' in check(pki)
    os.unlink(h2.cert)
    assert f"{h2.cert}: the host's certificate missing" in check(pki)


def test_check_command(pki: secure.Pki, capsys: pytest.CaptureFixture[str]) -> None:
    d = pki.hosts['h2'].cert.parent
    assert secure.main(['check', str(d)]) == 0
    assert secure.main(['env', str(d)]) == 0
    out = capsys.readouterr().out
    assert f'export OPENSSL_CONF={pki.openssl}' in out
    pki.hosts['h2'].key.chmod(0o640)
    assert secure.main(['check', str(d)]) == 2
    assert 'chmod 600' in capsys.readouterr().err


def test_a_reused_authority_names_the_new_runs_openssl_configuration(
    pki: secure.Pki, tmp_path: Path
) -> None:
    """``--secure-pki DIR``: the new run's profiles name its own OpenSSL configuration, the
    one the bring-up gives its processes, so a node takes the same and starts."""
    again = secure.write_run_files(
        tmp_path / 'run again',
        ['h1', 'h2'],
        'h1',
        ('10.0.0.1', 20007),
        run='r2',
        participants=6,
        reuse=pki.ca.parent,
    )  # fmt: skip (a space in the run's path, too)
    assert again.openssl.parent == tmp_path / 'run again' != pki.ca.parent
    for profile in (again.hosts['h2'].profile, again.hosts['h2'].client_profile):
        env = secure.secure_environment(profile, again.openssl)
        secure.complete_environment(env)  # no DdsError: the same file
        assert env['OPENSSL_CONF'] == str(again.openssl.resolve())


def test_bringup_stops_on_bad_reused_files(tmp_path: Path) -> None:
    """``swarm_up.py --secure --secure-pki DIR`` with a kept run's files: a key readable by
    others, a key missing, another run's certificate, an expired authority each stop the
    bring-up before any node starts, with one error line naming the file and the fix."""
    import subprocess
    import sys

    from apf_swarm_nodes.bringup import pick_domain_id

    root = Path(__file__).resolve().parents[2]

    def bringup(pki_dir: Path, name: str) -> tuple[int, str, Path]:
        out = tmp_path / name
        p = subprocess.run(
            [sys.executable, str(root / 'scripts' / 'swarm_up.py'), '--preset', 'triangle',
             '--n-trackers', '3', '--duration', '1', '--out', str(out), '--no-plots',
             '--domain-id', str(pick_domain_id(lo=102, hi=201)), '--discovery-range', 'SUBNET',
             '--secure', '--secure-pki', str(pki_dir), '--secure-address', '127.0.0.1'],
            capture_output=True, text=True, timeout=120, cwd=root,
        )  # fmt: skip
        return p.returncode, p.stderr, out

    def kept(name: str, **kw: object) -> Path:
        d = tmp_path / name / 'dds'
        secure.make_pki(d, [secure.THIS_HOST], run=name, **kw)  # type: ignore[arg-type]
        return d

    d = kept('perm')
    key = d / secure.THIS_HOST / 'key.pem'
    key.chmod(0o644)
    d2 = kept('missing')
    (d2 / secure.THIS_HOST / 'key.pem').unlink()
    d3 = kept('foreign')
    other = kept('other')
    for f in ('cert.pem', 'key.pem'):
        (d3 / secure.THIS_HOST / f).write_bytes((other / secure.THIS_HOST / f).read_bytes())
    (d3 / secure.THIS_HOST / 'key.pem').chmod(0o600)
    long_ago = dt.datetime.now(dt.UTC) - dt.timedelta(days=30)
    d4 = kept('expired', now=long_ago)
    cases = {
        'perm': (d, f'chmod 600 {key}'),
        'missing': (d2, f'{d2 / secure.THIS_HOST / "key.pem"}: private key missing'),
        'foreign': (d3, f"{d3 / secure.THIS_HOST / 'cert.pem'}: not issued by the run's"),
        'expired': (d4, f'{d4 / "ca.pem"}: certificate expired'),
    }
    for name, (pki_dir, expected) in cases.items():
        rc, err, out = bringup(pki_dir, name)
        errors = [line for line in err.splitlines() if 'error' in line]
        assert rc == 2, (name, err)
        assert len(errors) == 1 and expected in errors[0], (name, err)
        assert not list((out / 'logs').glob('*.log')), name  # no node was started


def test_check_refuses_stops_a_port_that_admits_anyone(pki: secure.Pki) -> None:
    """The bring-up's self-check against a TLS server of Python's own: one that does not
    ask for a certificate (as Fast DDS 2.14 without the run's OpenSSL configuration) stops
    the run; one that requires a certificate of the run's authority passes."""
    import socket
    import ssl
    import threading

    h1 = pki.hosts['h1']

    def serve(require: bool) -> tuple[socket.socket, threading.Thread]:
        ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
        ctx.load_cert_chain(str(h1.cert), str(h1.key))
        if require:
            ctx.verify_mode = ssl.CERT_REQUIRED
            ctx.load_verify_locations(str(pki.ca))
        listener = socket.create_server(('127.0.0.1', 0))

        def accept_once() -> None:
            conn, _ = listener.accept()
            try:
                with ctx.wrap_socket(conn, server_side=True) as tls:
                    tls.recv(1)
            except (ssl.SSLError, OSError):
                pass

        t = threading.Thread(target=accept_once, daemon=True)
        t.start()
        return listener, t

    for require in (False, True):
        listener, t = serve(require)
        port = listener.getsockname()[1]
        try:
            if require:
                secure.check_refuses('127.0.0.1', port, timeout=5.0)
            else:
                with pytest.raises(DdsError, match='admitted a client without a certificate'):
                    secure.check_refuses('127.0.0.1', port, timeout=5.0)
        finally:
            listener.close()
            t.join(5.0)


def test_a_node_takes_its_openssl_configuration_from_the_profile(
    pki: secure.Pki, tmp_path: Path
) -> None:
    """The profile is all a joining host needs: a node fills in ``OPENSSL_CONF``; an
    environment that contradicts the profile stops it, naming the variable; another
    profile, or none, is left alone."""
    for profile in (pki.hosts['h2'].profile, pki.hosts['h2'].client_profile, pki.server_profile):
        env = {'FASTRTPS_DEFAULT_PROFILES_FILE': str(profile)}
        secure.complete_environment(env)
        assert env['OPENSSL_CONF'] == str(pki.openssl), profile
        secure.complete_environment(env)  # the same one given: fine
    base = {'FASTDDS_DEFAULT_PROFILES_FILE': str(pki.hosts['h2'].profile)}
    bad = {
        'OPENSSL_CONF': str(tmp_path / 'other.cnf'),
        'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST',
        'ROS_STATIC_PEERS': '10.0.0.9',
        'ROS_DISCOVERY_SERVER': '10.0.0.1:11811',
    }
    for key, value in bad.items():
        with pytest.raises(DdsError, match=key):
            secure.complete_environment({**base, key: value})
    secure.complete_environment({**base, 'ROS_LOCALHOST_ONLY': '0'})
    other = tmp_path / 'plain.xml'
    other.write_text('<dds/>')
    for env in ({}, {'FASTRTPS_DEFAULT_PROFILES_FILE': str(other)}):
        before = dict(env)
        secure.complete_environment(env)
        assert env == before
    pki.openssl.unlink()
    with pytest.raises(DdsError, match=r'openssl\.cnf.*missing'):
        secure.complete_environment(dict(base))
