"""The bring-up's own DDS participant: on UDP only, never on shared memory (a participant
whose call blocks on a shared-memory mutex that a killed node held cannot stop the run), and
the variables that name a Fast DDS profile file."""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator, Mapping
from pathlib import Path

__all__ = [
    'LOCALHOST_PROFILE',
    'OWN_PROFILE',
    'PROFILE_VARIABLES',
    'SECURE_PROFILE',
    'SECURE_SERVER_PROFILE',
    'named_profile',
    'own_participant',
    'own_participant_environment',
]

#: the variables that name a Fast DDS profile file (both names Fast DDS 2.x reads)
PROFILE_VARIABLES = ('FASTRTPS_DEFAULT_PROFILES_FILE', 'FASTDDS_DEFAULT_PROFILES_FILE')
#: a run's profile on one machine (:mod:`.profiles` writes it in DIR/dds/)
LOCALHOST_PROFILE = 'fastdds_localhost.xml'
#: the profile of the bring-up's own participant, beside the run's (UDP on 127.0.0.1 only)
OWN_PROFILE = 'fastdds_localhost_udp.xml'
#: a secure run's profiles (:mod:`.secure` writes them, as its ``PROFILE_FILE`` and
#: ``SERVER_PROFILE``): a host's (DIR/dds/HOST/), and the discovery server's (DIR/dds/), the
#: bring-up's own participant
SECURE_PROFILE, SECURE_SERVER_PROFILE = 'fastdds_secure.xml', 'fastdds_secure_server.xml'


def named_profile(environ: Mapping[str, str]) -> str | None:
    """The Fast DDS profile file ``environ`` names, or None."""
    return next((environ[v] for v in PROFILE_VARIABLES if environ.get(v)), None)


def own_participant_environment(environ: Mapping[str, str] | None = None) -> dict[str, str]:
    """The variables that put the bring-up's own participant on UDP only, never on shared
    memory: a participant whose call blocks on a shared-memory mutex that a killed node
    held cannot stop the run then. Localhost runs: the run's profile without its SHM
    transport (written beside it by :func:`~.profiles.isolate_dds`); secure runs: the
    discovery server's profile (TCP with TLS, :mod:`.secure`); otherwise
    ``FASTDDS_BUILTIN_TRANSPORTS=UDPv4``. Set them for ``rclpy.init`` only: the nodes keep
    shared memory."""
    own = named_profile(os.environ if environ is None else environ)
    if own is not None:
        path = Path(own)
        beside = {
            LOCALHOST_PROFILE: path.with_name(OWN_PROFILE),
            SECURE_PROFILE: path.parent.parent / SECURE_SERVER_PROFILE,
        }.get(path.name)
        if beside is not None and beside.is_file():
            return dict.fromkeys(PROFILE_VARIABLES, str(beside))
    return {'FASTDDS_BUILTIN_TRANSPORTS': 'UDPv4'}


@contextlib.contextmanager
def own_participant() -> Iterator[None]:
    """``os.environ`` with :func:`own_participant_environment` while a participant of the
    bring-up's own is made (``rclpy.init`` and the node: Fast DDS reads its transports
    then), as before afterwards: the bring-up's node and its domain probe."""
    own = own_participant_environment()
    saved = {k: os.environ.get(k) for k in own}
    os.environ.update(own)
    try:
        yield
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
