"""A multi-host run that admits only its own hosts (``apf-swarm up --discovery-range SUBNET
--secure``): a certificate authority per run and a certificate and key per host
(:func:`make_pki`), Fast DDS profiles of TCPv4 with TLS only and discovery through the
bring-up's own participant (:func:`profile_xml`), and an OpenSSL configuration that makes
every TLS context require the peer's certificate (:data:`OPENSSL_CONFIG`: Fast DDS 2.14 never
asks a connecting peer for one). docs/RELIABILITY.md, "Multi-host runs: threat model", says
what it protects, what not, and why each part is there.

``python -m apf_swarm_nodes.dds.secure check DIR/dds/HOST`` checks a host's files before it
joins; ``python -m apf_swarm_nodes.dds.secure env DIR/dds/HOST`` prints its environment.
"""

from __future__ import annotations

import argparse
import contextlib
import datetime as dt
import os
import socket
import ssl
import stat
import sys
from collections.abc import Callable, Mapping, MutableMapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from .errors import DdsError
from .participant import SECURE_PROFILE as PROFILE_FILE
from .participant import SECURE_SERVER_PROFILE as SERVER_PROFILE
from .participant import named_profile
from .profiles import (
    LEASE_ANNOUNCEMENT,
    LEASE_DURATION,
    NETWORK_RANGES,
    check_rmw,
    discovery_timing,
    duration,
    localhost_environment,
    profiles_file,
)

if TYPE_CHECKING:
    from cryptography import x509

__all__ = [
    'CA_FILE',
    'CERT_FILE',
    'CLIENT_PROFILE_FILE',
    'KEY_FILE',
    'OPENSSL_FILE',
    'PROFILE_FILE',
    'SERVER_PROFILE',
    'THIS_HOST',
    'HostFiles',
    'Pki',
    'check_files',
    'check_refuses',
    'complete_environment',
    'first_address',
    'make_pki',
    'profile_xml',
    'remove_keys',
    'secure_dds',
    'secure_environment',
    'server_port',
    'write_run_files',
]

#: the files of a run's security, under DIR/dds/: the authority's certificate and the
#: OpenSSL configuration, shared; per host (DIR/dds/HOST/): its certificate, key, profile
#: (:data:`PROFILE_FILE`; it and :data:`SERVER_PROFILE` are named in :mod:`.participant`,
#: which gives the bring-up's own participant the server's)
CA_FILE, OPENSSL_FILE = 'ca.pem', 'openssl.cnf'
CERT_FILE, KEY_FILE = 'cert.pem', 'key.pem'
#: a host's profile for processes that need no view of the whole graph (the trackers): a
#: discovery client, told only of the endpoints matching its own (what it saves:
#: docs/PERFORMANCE.md, "Real-time flight")
CLIENT_PROFILE_FILE = 'fastdds_secure_client.xml'
#: the bring-up's host among the run's hosts (DIR/dds/bringup/)
THIS_HOST = 'bringup'
#: the discovery server's TCP port is this plus the domain id
SERVER_PORT_BASE = 20000
#: how long a run's certificates are valid, and how far back (hosts' clocks differ)
VALIDITY = dt.timedelta(days=7)
BACKDATE = dt.timedelta(minutes=10)
#: the TCP sockets' send and receive buffers [bytes]
SOCKET_BUFFER = 4 * 2**20
#: the Fast DDS transport id in the profile
TRANSPORT_ID = 'apf_swarm_tls'
#: the protocols a TLS connection of the run refuses (Fast DDS TLS options)
TLS_REFUSED = ('NO_SSLV2', 'NO_SSLV3', 'NO_TLSV1', 'NO_TLSV1_1')


def server_port(domain: int) -> int:
    """The discovery server's TCP port on the bring-up's host for ``domain``."""
    return SERVER_PORT_BASE + domain


# --------------------------------------------------------------------------------------------
# the run's authority
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class HostFiles:
    """A host's files: certificate, key, profile and the trackers' profile (under
    DIR/dds/HOST/)."""

    name: str
    cert: Path
    key: Path
    profile: Path
    client_profile: Path


@dataclass(frozen=True)
class Pki:
    """A run's authority certificate, OpenSSL configuration and hosts (by name)."""

    ca: Path
    openssl: Path
    hosts: dict[str, HostFiles]
    server_profile: Path


def _write_private(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` readable by its owner only (created 0600, never wider)."""
    with contextlib.suppress(FileNotFoundError):
        path.unlink()
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, 'wb') as f:
        f.write(data)


def make_pki(
    directory: Path,
    hosts: Sequence[str],
    *,
    run: str = 'apf_swarm',
    now: dt.datetime | None = None,
    validity: dt.timedelta = VALIDITY,
) -> dict[str, tuple[Path, Path]]:
    """A certificate authority for a run (``directory``/ca.pem; its key is never written)
    and a certificate and key per host (``directory``/HOST/cert.pem, key.pem, mode 0600),
    EC P-256 and ECDSA-SHA256, valid from ``now`` - :data:`BACKDATE` for ``validity``.
    Returns {host: (cert, key)}."""
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

    if len(set(hosts)) != len(hosts) or not hosts:
        raise ValueError(f'hosts must be distinct and at least one: {hosts}')
    now = now or dt.datetime.now(dt.UTC)
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    ca_key = ec.generate_private_key(ec.SECP256R1())
    ca_name = f'{run} run authority'

    def issue(subject: str, key: ec.EllipticCurvePrivateKey, *extensions: Any) -> bytes:
        """The PEM certificate of ``key`` for ``subject``, signed by the authority, with
        ``extensions`` ((extension, critical), in order)."""
        builder = (
            x509.CertificateBuilder()
            .subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, subject)]))
            .issuer_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, ca_name)]))
            .public_key(key.public_key())
            .serial_number(x509.random_serial_number())
            .not_valid_before(now - BACKDATE)
            .not_valid_after(now + validity)
        )
        for extension, critical in extensions:
            builder = builder.add_extension(extension, critical)
        return builder.sign(ca_key, hashes.SHA256()).public_bytes(serialization.Encoding.PEM)

    ca_usage = x509.KeyUsage(
        digital_signature=False,
        content_commitment=False,
        key_encipherment=False,
        data_encipherment=False,
        key_agreement=False,
        key_cert_sign=True,
        crl_sign=True,
        encipher_only=False,
        decipher_only=False,
    )
    (directory / CA_FILE).write_bytes(
        issue(
            ca_name,
            ca_key,
            (x509.BasicConstraints(ca=True, path_length=0), True),
            (ca_usage, True),
            (x509.SubjectKeyIdentifier.from_public_key(ca_key.public_key()), False),
        )
    )
    usage = [ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH]
    out = {}
    for host in hosts:
        key = ec.generate_private_key(ec.SECP256R1())
        where = directory / host
        where.mkdir(parents=True, exist_ok=True)
        (where / CERT_FILE).write_bytes(
            issue(
                f'{run} {host}',
                key,
                (x509.BasicConstraints(ca=False, path_length=None), True),
                (x509.ExtendedKeyUsage(usage), False),
                (x509.SubjectAlternativeName([x509.DNSName(host)]), False),
                (x509.AuthorityKeyIdentifier.from_issuer_public_key(ca_key.public_key()), False),
            )
        )
        pem = key.private_bytes(
            serialization.Encoding.PEM,
            serialization.PrivateFormat.PKCS8,
            serialization.NoEncryption(),
        )
        _write_private(where / KEY_FILE, pem)
        out[host] = (where / CERT_FILE, where / KEY_FILE)
    return out  # the authority's key goes with this call: it signs nothing more


def remove_keys(directory: Path) -> list[Path]:
    """Remove every host key under ``directory`` (DIR/dds/); returns those removed."""
    removed = []
    for key in sorted(Path(directory).glob(f'*/{KEY_FILE}')):
        with contextlib.suppress(FileNotFoundError):
            key.unlink()
            removed.append(key)
    return removed


# --------------------------------------------------------------------------------------------
# bad input
# --------------------------------------------------------------------------------------------

_AGAIN = 'start the run again (it issues new ones), or copy them again from its DIR/dds/'


def _current_cert(path: Path, what: str, now: dt.datetime) -> x509.Certificate:
    """The PEM certificate ``path`` (``what`` it is), valid at ``now``, else DdsError."""
    from cryptography import x509

    if not path.is_file():
        raise DdsError(f'{path}: {what} missing; {_AGAIN}')
    try:
        cert = x509.load_pem_x509_certificate(path.read_bytes())
    except (ValueError, OSError) as exc:
        raise DdsError(f'{path}: not a PEM certificate ({exc}); {_AGAIN}') from exc
    start, end = cert.not_valid_before_utc, cert.not_valid_after_utc
    if now >= end:
        raise DdsError(f'{path}: certificate expired at {end:%Y-%m-%d %H:%M} UTC; {_AGAIN}')
    if now < start:
        raise DdsError(
            f'{path}: certificate not valid before {start:%Y-%m-%d %H:%M} UTC (is this '
            "host's clock right?); set the clock, or " + _AGAIN
        )
    return cert


def check_files(ca: Path, cert: Path, key: Path, *, now: dt.datetime | None = None) -> None:
    """DdsError, naming the file and what to do, unless ``cert`` is a current certificate
    signed by the current authority ``ca``, ``key`` its private key, readable by its owner
    only."""
    from cryptography.exceptions import InvalidSignature
    from cryptography.hazmat.primitives import serialization

    now = now or dt.datetime.now(dt.UTC)
    ca, cert, key = Path(ca), Path(cert), Path(key)
    ca_cert = _current_cert(ca, "the run's authority certificate", now)
    host_cert = _current_cert(cert, "the host's certificate", now)
    try:
        host_cert.verify_directly_issued_by(ca_cert)
    except (ValueError, TypeError, InvalidSignature) as exc:
        raise DdsError(
            f"{cert}: not issued by the run's authority {ca} (a certificate of another "
            f'run?); {_AGAIN}'
        ) from exc
    if not key.is_file():
        raise DdsError(f'{key}: private key missing (removed at the run end?); {_AGAIN}')
    mode = stat.S_IMODE(key.stat().st_mode)
    if mode & 0o077:
        raise DdsError(
            f'{key}: private key readable by others (mode {mode:04o}); '
            f'`chmod 600 {key}`, and start a new run if others may have read it'
        )
    try:
        private = serialization.load_pem_private_key(key.read_bytes(), password=None)
    except (ValueError, TypeError, OSError) as exc:
        raise DdsError(f'{key}: not an unencrypted PEM private key ({exc}); {_AGAIN}') from exc
    if private.public_key() != host_cert.public_key():
        raise DdsError(f'{key}: not the key of the certificate {cert} (mismatched); {_AGAIN}')


# --------------------------------------------------------------------------------------------
# the profile and the OpenSSL configuration
# --------------------------------------------------------------------------------------------


#: the OpenSSL configuration of a run's processes (DIR/dds/openssl.cnf): every TLS context
#: verifies its peer and, when it accepts, requires a certificate
OPENSSL_CONFIG = """\
# apf_swarm, written by apf_swarm_nodes.dds.secure: every TLS context of the
# process verifies its peer and requires the peer's certificate (Fast DDS 2.14
# does not apply the profile's verify mode to the connections it accepts)
openssl_conf = apf_swarm_init

[apf_swarm_init]
ssl_conf = apf_swarm_ssl

[apf_swarm_ssl]
system_default = apf_swarm_tls

[apf_swarm_tls]
VerifyMode = Peer,Require
MinProtocol = TLSv1.2
"""


def server_prefix(run: str) -> str:
    """The discovery server's GUID prefix (12 bytes, dotted hex) of the run ``run``."""
    import hashlib

    return '.'.join(f'{b:02x}' for b in hashlib.sha256(run.encode()).digest()[:12])


def profile_xml(
    *,
    ca: Path,
    cert: Path,
    key: Path,
    server: tuple[str, int],
    prefix: str,
    is_server: bool = False,
    participants: int = 32,
    super_client: bool = True,
    openssl: Path | None = None,
) -> str:
    """The Fast DDS profile of a host of a secure run (``is_server``: the bring-up's own
    participant, the discovery server, listening on ``server``'s port): TCPv4 with TLS
    only, discovery through the server at ``server`` (address, port) whose GUID prefix is
    ``prefix``; a super client that learns the whole graph, or (``super_client`` false) a
    client that learns only what matches its own endpoints. Its comment names the run's
    OpenSSL configuration ``openssl`` (default: beside ``ca``) for
    :func:`complete_environment`."""
    address, port = server
    locator = {'locator': {'tcpv4': {'address': address, 'physical_port': port, 'port': port}}}
    tls = {
        'private_key_file': Path(key).resolve(),
        'cert_chain_file': Path(cert).resolve(),
        'verify_file': Path(ca).resolve(),
        # Fast DDS applies the first of these only, to the connections it makes; the ones
        # it accepts are verified by OpenSSL's configuration (OPENSSL_CONFIG)
        'verify_mode': {'verify': ['VERIFY_PEER', 'VERIFY_FAIL_IF_NO_PEER_CERT']},
        'options': {'option': ['DEFAULT_WORKAROUNDS', 'NO_COMPRESSION', *TLS_REFUSED]},
        'handshake_role': 'DEFAULT',
    }
    transport = {
        'transport_id': TRANSPORT_ID,
        'type': 'TCPv4',
        # the server on its known port; a node on one the system picks (announced)
        'listening_ports': {'port': port if is_server else 0},
        'enable_tcp_nodelay': 'true',
        # a blocking send on a full socket deadlocks the discovery of a large swarm
        # (eProsima/Fast-DDS#5235): a send that would block drops its message, which
        # reliability sends again; and buffers that a discovery burst does not fill
        'non_blocking_send': 'true',
        'sendBufferSize': SOCKET_BUFFER,
        'receiveBufferSize': SOCKET_BUFFER,
        'tls': tls,
    }
    # a super client learns the whole graph (the plant's and the viewers' checks); a client
    # only the endpoints that match its own (the trackers)
    kind = 'SERVER' if is_server else 'SUPER_CLIENT' if super_client else 'CLIENT'
    discovery: dict[str, Any] = {
        'discoveryProtocol': kind,
        'leaseDuration': duration(LEASE_DURATION),
        'leaseAnnouncement': duration(LEASE_ANNOUNCEMENT),
        'clientAnnouncementPeriod': duration(discovery_timing(participants)[0]),
    }
    builtin: dict[str, Any] = {'discovery_config': discovery}
    if is_server:
        builtin['metatrafficUnicastLocatorList'] = locator
    else:
        discovery['discoveryServersList'] = {
            'RemoteServer': {'@prefix': prefix, 'metatrafficUnicastLocatorList': locator}
        }
    rtps = {
        **({'prefix': prefix} if is_server else {}),
        'userTransports': {'transport_id': TRANSPORT_ID},
        'useBuiltinTransports': 'false',
        'builtin': builtin,
    }
    what = 'discovery server' if is_server else 'node'
    comment = (
        f'apf_swarm, secure multi-host run ({what}): TCPv4 with TLS only, peers '
        "verified against the run's authority; written by apf_swarm_nodes.dds.secure. The "
        "run's nodes take their OpenSSL configuration from here, any other process needs "
        f'OPENSSL_CONF={Path(openssl or Path(ca).parent / OPENSSL_FILE).resolve()}'
    )
    return profiles_file(comment, 'apf_swarm_secure', [transport], rtps)


def secure_environment(profile: Path, openssl: Path) -> dict[str, str]:
    """The variables a process of a secure run needs (with ``ROS_DOMAIN_ID``; no
    ``ROS_STATIC_PEERS`` / ``ROS_DISCOVERY_SERVER``, which would add UDP)."""
    env = localhost_environment(Path(profile).resolve())  # the profile, and SUBNET
    return {**env, 'OPENSSL_CONF': str(Path(openssl).resolve())}


#: what a secure run does not take from the environment: each would add UDP
NOT_SECURE = ('ROS_STATIC_PEERS', 'ROS_DISCOVERY_SERVER', 'ROS_SUPER_CLIENT',
              'FASTDDS_BUILTIN_TRANSPORTS', 'ROS_LOCALHOST_ONLY')  # fmt: skip

#: how a secure profile names its OpenSSL configuration (in its comment: :func:`profile_xml`)
_CONF_MARK = 'OPENSSL_CONF='


def complete_environment(environ: MutableMapping[str, str]) -> None:
    """Complete ``environ`` (a node's, before ``rclpy.init``) for the secure profile it
    names, so that the profile is all a joining host needs: ``OPENSSL_CONF`` from the
    profile (without it this Fast DDS admits any TLS client). Nothing for another profile
    or none. DdsError naming the variable and the fix when the environment contradicts the
    profile: another ``OPENSSL_CONF``, a discovery range other than SUBNET, or a variable
    that adds UDP (:data:`NOT_SECURE`)."""
    profile = named_profile(environ)
    if profile is None or not Path(profile).is_file():
        return
    head = Path(profile).read_text(errors='replace')[:2000]
    if 'apf_swarm, secure multi-host run' not in head or _CONF_MARK not in head:
        return
    conf = head.split(_CONF_MARK, 1)[1].split(' -->', 1)[0].strip()
    fix = f'unset it: the profile {profile} names its own'
    given = environ.get('OPENSSL_CONF')
    if given and Path(given).resolve() != Path(conf).resolve():
        raise DdsError(f'OPENSSL_CONF={given}, but the secure profile needs {conf}: {fix}')
    if not Path(conf).is_file():
        raise DdsError(
            f"{conf} (named by the secure profile {profile}) is missing: copy the run's "
            "DIR/dds/ with the host's files, or start the host from the bring-up"
        )
    span = environ.get('ROS_AUTOMATIC_DISCOVERY_RANGE', 'SUBNET') or 'SUBNET'
    if span != 'SUBNET':
        raise DdsError(f'ROS_AUTOMATIC_DISCOVERY_RANGE={span} adds UDP to a secure run: {fix}')
    for key in NOT_SECURE:
        if environ.get(key) and not (key == 'ROS_LOCALHOST_ONLY' and environ[key] == '0'):
            raise DdsError(f'{key}={environ[key]} adds UDP to a secure run: {fix}')
    environ['OPENSSL_CONF'] = conf


def write_run_files(
    directory: Path,
    hosts: Sequence[str],
    server_host: str,
    server: tuple[str, int],
    *,
    run: str,
    participants: int,
    reuse: Path | None = None,
) -> Pki:
    """Everything a secure run needs under ``directory`` (DIR/dds/): the authority, each
    host's certificate, key and profile, the server's profile (``server_host``'s files),
    the OpenSSL configuration. ``reuse``: the DIR/dds/ of an earlier run whose keys were
    kept (``--keep-keys``): its authority and host files instead of new ones (the new
    profiles name them; nothing is copied), each checked (:func:`check_files`: DdsError
    naming the file and what to do)."""
    directory = Path(directory).resolve()
    directory.mkdir(parents=True, exist_ok=True)
    if reuse is None:
        issued = make_pki(directory, list(hosts), run=run)
        ca = directory / CA_FILE
    else:
        reuse = Path(reuse).resolve()
        ca = reuse / CA_FILE
        issued = {}
        for host in hosts:
            if not (reuse / host).is_dir():
                raise DdsError(
                    f'--secure-pki {reuse}: no files for host {host!r} ({reuse / host} '
                    'missing); a kept authority cannot admit a new host: run without '
                    '--secure-pki to issue new files for every host'
                )
            issued[host] = (reuse / host / CERT_FILE, reuse / host / KEY_FILE)
            check_files(ca, *issued[host])
            (directory / host).mkdir(exist_ok=True)
    openssl = directory / OPENSSL_FILE
    openssl.write_text(OPENSSL_CONFIG)
    prefix = server_prefix(run)

    def write(
        path: Path, cert: Path, key: Path, *, is_server: bool = False, super_client: bool = True
    ) -> Path:
        path.write_text(
            profile_xml(
                ca=ca, cert=cert, key=key, server=server, prefix=prefix, is_server=is_server,
                participants=participants, super_client=super_client, openssl=openssl,
            )
        )  # fmt: skip
        return path

    files = {}
    for host, (cert, key) in issued.items():
        profile = write(directory / host / PROFILE_FILE, cert, key)
        client = write(directory / host / CLIENT_PROFILE_FILE, cert, key, super_client=False)
        files[host] = HostFiles(host, cert, key, profile, client)
    server_profile = write(directory / SERVER_PROFILE, *issued[server_host], is_server=True)
    return Pki(ca, openssl, files, server_profile)


def first_address() -> str:
    """This host's first non-loopback IPv4 address (DdsError if it has none)."""
    import psutil

    for addrs in psutil.net_if_addrs().values():
        for a in addrs:
            if a.family == socket.AF_INET and not a.address.startswith('127.'):
                return str(a.address)
    raise DdsError(
        '--secure: this host has no IPv4 address but loopback; give the one the other hosts '
        'reach it at with --secure-address ADDR'
    )


def secure_dds(
    directory: Path,
    domain: int,
    discovery_range: str,
    *,
    hosts: Sequence[str],
    address: str | None,
    processes: int,
    run: str,
    reuse: Path | None = None,
    environ: MutableMapping[str, str] | None = None,
    say: Callable[[str], None] | None = None,
) -> Pki:
    """The bring-up's hook of a secure run (instead of :func:`~.profiles.isolate_dds`): write
    the run's files into ``directory`` (DIR/dds/) for this host (:data:`THIS_HOST`) and
    ``hosts`` (or name those of ``reuse``, see :func:`write_run_files`), and put this
    host's environment into ``environ`` (default ``os.environ``), dropping what would add
    UDP. The discovery server is this process's own participant
    (:func:`~.participant.own_participant`), at ``address`` (default :func:`first_address`),
    port :func:`server_port`. A secure run skips the domain check: no participant of
    another run can reach it."""
    env = os.environ if environ is None else environ
    if discovery_range not in NETWORK_RANGES:
        raise DdsError(
            f'--secure with --discovery-range {discovery_range}: --secure is for a run '
            'across hosts (--discovery-range SUBNET); a LOCALHOST run admits nothing from '
            'outside this machine already'
        )
    check_rmw(env)
    address = address or first_address()
    names = [THIS_HOST, *dict.fromkeys(h for h in hosts if h != THIS_HOST)]
    for name in names:
        if not name or '/' in name or name.startswith('.'):
            raise DdsError(f'--secure: {name!r} is not a usable host name')
    pki = write_run_files(
        directory, names, THIS_HOST, (address, server_port(domain)), run=run,
        participants=processes, reuse=reuse,
    )  # fmt: skip
    for var in NOT_SECURE:
        if env.pop(var, None) is not None and say is not None:
            say(f'warning: {var} ignored: a secure run talks TCP with TLS only')
    env.pop('OPENSSL_CONF', None)
    env.update(secure_environment(pki.hosts[THIS_HOST].profile, pki.openssl))
    if say is not None:
        say(
            f'secure: TCP with TLS only, discovery server {address}:{server_port(domain)}; '
            f'files for {", ".join(names)} in {Path(directory)}'
        )
    return pki


# --------------------------------------------------------------------------------------------
# the self-check
# --------------------------------------------------------------------------------------------


def tls_admits(address: str, port: int, *, cert: Path | None = None, key: Path | None = None,
               timeout: float = 5.0) -> bool:  # fmt: skip
    """Whether the TLS server at ``address``:``port`` completes a TLS 1.2 handshake with a
    client that presents ``cert``/``key`` (None: no certificate) and does not verify the
    server. TLS 1.2, so that the server's verdict on the client's certificate arrives
    within the handshake."""
    ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_CLIENT)
    ctx.check_hostname = False
    ctx.verify_mode = ssl.CERT_NONE
    ctx.maximum_version = ssl.TLSVersion.TLSv1_2
    if cert is not None:
        ctx.load_cert_chain(str(cert), str(key) if key is not None else None)
    with socket.create_connection((address, port), timeout=timeout) as raw:
        try:
            with ctx.wrap_socket(raw) as tls:
                tls.do_handshake()
        except (ssl.SSLError, ConnectionError):
            return False
    return True


def check_refuses(address: str, port: int, *, timeout: float = 10.0) -> None:
    """DdsError unless the TLS server at ``address``:``port`` (the bring-up's own) refuses
    a client without a certificate; waits up to ``timeout`` s for it to listen."""
    import time

    end = time.monotonic() + timeout
    while True:
        try:
            admitted = tls_admits(address, port)
            break
        except OSError as exc:
            if time.monotonic() > end:
                raise DdsError(
                    f'--secure: the discovery server {address}:{port} does not answer ({exc}); '
                    'another process holds the port? choose another --domain-id'
                ) from exc
            time.sleep(0.1)
    if admitted:
        raise DdsError(
            f'--secure: the TLS port {address}:{port} admitted a client without a '
            "certificate: this OpenSSL ignores the run's configuration (OPENSSL_CONF); "
            'nothing was started. Run without --secure only on a network you trust'
        )


# --------------------------------------------------------------------------------------------
# python -m apf_swarm_nodes.dds.secure
# --------------------------------------------------------------------------------------------


def main(argv: Sequence[str] | None = None, environ: Mapping[str, str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog='python -m apf_swarm_nodes.dds.secure',
        description="A secure run's host files (DIR/dds/HOST/): check them, or print the "
        'environment a process on that host needs: eval "$(python -m apf_swarm_nodes.dds.secure '
        'env DIR/dds/HOST)"',
    )
    p.add_argument('action', choices=('check', 'env'))
    p.add_argument('host_dir', type=Path, help='DIR/dds/HOST of a secure run')
    args = p.parse_args(argv)
    d = args.host_dir.resolve()
    try:
        check_files(d.parent / CA_FILE, d / CERT_FILE, d / KEY_FILE)
        for needed in (d / PROFILE_FILE, d.parent / OPENSSL_FILE):
            if not needed.is_file():
                raise DdsError(f'{needed}: missing; {_AGAIN}')
    except DdsError as exc:
        print(f'apf-swarm: error: {exc}', file=sys.stderr)
        return 2
    if args.action == 'check':
        print(f'{d}: ok')
        return 0
    for k, v in secure_environment(d / PROFILE_FILE, d.parent / OPENSSL_FILE).items():
        print(f'export {k}={v}')
    print(f'unset {" ".join(NOT_SECURE)}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
