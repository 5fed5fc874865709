"""The DDS side of a run's isolation: a Fast DDS profile that keeps a run on this machine,
the discovery timing that makes its graph ready as soon as its nodes are up, and the
refusal of a domain that already carries a swarm. The bring-up calls :func:`isolate_dds`.

**Localhost only.** ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` alone does not keep a run on
the machine: rmw_fastrtps (Jazzy) then sends its own discovery only to 127.0.0.1, but it adds
a UDP transport of its own whose sockets bind ``0.0.0.0``, so a node on another host that
names this one as a static peer (``ROS_STATIC_PEERS``) is discovered, sees every topic and
exchanges data. A localhost run therefore gets :func:`profile_xml`'s profile: one UDPv4
transport whose interface allowlist is 127.0.0.1 (every socket, discovery, data and
sending, binds 127.0.0.1), shared memory, discovery by unicast to 127.0.0.1 only (no
multicast), and ``ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET``: the one range in which rmw adds
nothing to the profile's transports (LOCALHOST adds its socket, SUBNET only the static
peers, which the loopback transport cannot reach). Fast DDS 2.14 reads the profile from
``FASTRTPS_DEFAULT_PROFILES_FILE`` (3.x from ``FASTDDS_DEFAULT_PROFILES_FILE``; both are
set). A network run (``--discovery-range SUBNET`` or ``SYSTEM_DEFAULT``: several hosts,
``scripts/multihost.py``) gets the discovery timing only, with the middleware's transports.

**A graph ready at once.** Fast DDS enables a new participant's discovery, and sends its
first announcement, *before* it registers its receivers (``RTPSParticipantImpl::enable``);
a datagram that arrives in between is dropped. A participant that already runs answers a
newcomer's first announcement at once, with its own, sent to the newcomer alone, and never
again until its next periodic announcement. When the newcomer's process is starved of CPU
in that window (a bring-up starting its nodes on two cores), the answer is lost, and the
pair does not see each other until the older one announces again, ``leaseAnnouncement``
later (3 s by default); the newcomer's own later announcements do not help, the older
participant already knows it. The bring-up's own participant is always the oldest, so its
graph waited about 4 s whenever any answer was lost, which the more processes start at
once the likelier. The profile lets every participant repeat its announcement every
``period`` for the first ``window`` seconds of its life (:func:`discovery_timing`: the
start-up of the whole run), so that a lost answer costs one period. docs/PERFORMANCE.md,
"Discovery", has the measurements.

``python -m apf_swarm_nodes.dds.profiles`` writes the localhost profile for nodes started by
hand and prints the environment they need (docs/RELIABILITY.md, "Isolation").
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Callable, MutableMapping, Sequence
from pathlib import Path
from typing import Any

from .errors import DdsError
from .participant import (
    LOCALHOST_PROFILE,
    OWN_PROFILE,
    PROFILE_VARIABLES,
    own_participant,
    own_participant_environment,
)
from .swarm_domain import MAX_PARTICIPANTS, refuse_other_swarm

__all__ = [
    'LEASE_ANNOUNCEMENT',
    'OWN_PROFILE',
    'PROFILE_VARIABLES',
    'check_rmw',
    'discovery_timing',
    'isolate_dds',
    'localhost_environment',
    'max_participants',
    'own_participant',
    'own_participant_environment',
    'profile_xml',
    'write_profile',
]

#: the variables Fast DDS reads its XML profile from: 2.14 (these wheels) the first, 3.x
#: the second
#: the discovery ranges that reach other hosts
NETWORK_RANGES = ('SUBNET', 'SYSTEM_DEFAULT')
#: what a localhost run does not take from the environment: it would name other hosts
#: (peers the loopback transport cannot reach, a discovery server elsewhere)
NOT_LOCAL = ('ROS_STATIC_PEERS', 'ROS_DISCOVERY_SERVER', 'ROS_SUPER_CLIENT')
#: a participant repeats its announcement every ``participants`` x this [s], within
#: [PERIOD_MIN, PERIOD_MAX], ...
PERIOD_PER_PARTICIPANT, PERIOD_MIN, PERIOD_MAX = 0.02, 0.1, 0.5
#: ... for ``participants`` x this [s] after its creation, within [WINDOW_MIN, WINDOW_MAX]
#: (Fast DDS ``initialAnnouncements``: period and count) ...
WINDOW_PER_PARTICIPANT, WINDOW_MIN, WINDOW_MAX = 0.5, 5.0, 30.0
#: ... and then this often [s] (Fast DDS ``leaseAnnouncement``; its default: every
#: announcement reaches every participant, so a shorter one costs CPU all the run long)
LEASE_ANNOUNCEMENT = 3.0
#: a remote participant silent this long is removed [s] (Fast DDS ``leaseDuration``; its
#: default)
LEASE_DURATION = 20.0
#: participants on this machine beyond a run's own, for the 127.0.0.1 ports a localhost
#: participant announces to: viewers, ``ros2 topic``, tests' observers, the domain probe
SPARE_PARTICIPANTS = 16
#: what a run open to the network says before it starts
OPEN_WARNING = (
    'WARNING: this run is OPEN TO THE NETWORK: any host on it can see every topic, read '
    'every state and steer the swarm (a run id in clear does not stop it). Use --secure to '
    'admit only the hosts of this run (docs/RELIABILITY.md, "Multi-host runs: threat model")'
)


# --------------------------------------------------------------------------------------------
# the profile
# --------------------------------------------------------------------------------------------


def max_participants(participants: int) -> int:
    """How many participants of this machine a localhost participant announces itself to
    (Fast DDS ``maxInitialPeersRange``: the ports of participants 0..N-1 on 127.0.0.1): a
    run's ``participants`` and :data:`SPARE_PARTICIPANTS`, at least rmw's 32, at most what
    one domain's ports hold. Two participants whose indices both lie past it never
    discover each other."""
    return max(32, min(MAX_PARTICIPANTS, participants + SPARE_PARTICIPANTS))


def discovery_timing(participants: int) -> tuple[float, float, float]:
    """(period, window, lease announcement) [s] of a participant's announcements in a run
    of ``participants``: every ``period`` for its first ``window`` seconds, then every
    ``lease announcement``. The window covers the run's start-up (about half a second of
    CPU per node process, on two cores), the period grows with the run so that the
    announcements each participant receives while it starts (participants / period a
    second, from each of them) stay a small share of the start-up's CPU: with 35
    participants a period of 0.1 s made the start-up slower, not the graph faster."""
    period = min(PERIOD_MAX, max(PERIOD_MIN, participants * PERIOD_PER_PARTICIPANT))
    window = min(WINDOW_MAX, max(WINDOW_MIN, participants * WINDOW_PER_PARTICIPANT))
    return period, window, LEASE_ANNOUNCEMENT


def _duration(seconds: float) -> str:
    sec = int(seconds)
    return f'<sec>{sec}</sec><nanosec>{round((seconds - sec) * 1e9)}</nanosec>'


def profile_xml(
    *,
    localhost: bool = True,
    participants: int = 32,
    peers: int | None = None,
    period: float | None = None,
    window: float | None = None,
    lease_announcement: float | None = None,
    shm: bool = True,
) -> str:
    """The Fast DDS XML profile of a run of ``participants`` (the default participant
    profile: every participant of a process that reads it gets it).

    ``localhost``: UDPv4 on 127.0.0.1 only (``interfaces/allowlist``) and shared memory, no
    builtin transport, discovery traffic on 127.0.0.1 only (a unicast metatraffic locator,
    hence no multicast one), sent to the ports of ``peers`` participants there
    (``initialPeersList`` 127.0.0.1, ``maxInitialPeersRange``; default
    :func:`max_participants`); use it with ``ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET``.
    Otherwise the middleware's transports and discovery (multicast, ``ROS_STATIC_PEERS``,
    ``ROS_DISCOVERY_SERVER``, ``FASTDDS_BUILTIN_TRANSPORTS``). Both: the announcements of
    :func:`discovery_timing`, unless given."""
    p, w, lease = discovery_timing(participants)
    period = p if period is None else period
    window = w if window is None else window
    lease = lease if lease_announcement is None else lease_announcement
    peers = max_participants(participants) if peers is None else peers
    if not (period > 0 and window >= period and LEASE_DURATION > lease > 0):
        raise ValueError(f'bad discovery timing: period {period}, window {window}, lease {lease}')
    discovery = [
        '<discovery_config>',
        f'  <leaseDuration>{_duration(LEASE_DURATION)}</leaseDuration>',
        f'  <leaseAnnouncement>{_duration(lease)}</leaseAnnouncement>',
        '  <initialAnnouncements>',
        f'    <count>{round(window / period)}</count>',
        f'    <period>{_duration(period)}</period>',
        '  </initialAnnouncements>',
        '</discovery_config>',
    ]
    loopback = '<locator><udpv4><address>127.0.0.1</address></udpv4></locator>'
    if localhost:
        what = 'localhost only: UDPv4 on 127.0.0.1' + (' and shared memory' if shm else '')
        shm_descriptor = [
            '  <transport_descriptor>',
            '    <transport_id>apf_swarm_shm</transport_id>',
            '    <type>SHM</type>',
            '  </transport_descriptor>',
        ]
        transports = [
            '<transport_descriptors>',
            '  <transport_descriptor>',
            '    <transport_id>apf_swarm_udp_loopback</transport_id>',
            '    <type>UDPv4</type>',
            f'    <maxInitialPeersRange>{peers}</maxInitialPeersRange>',
            '    <interfaces><allowlist><interface name="127.0.0.1"/></allowlist></interfaces>',
            '  </transport_descriptor>',
            *(shm_descriptor if shm else []),
            '</transport_descriptors>',
        ]
        rtps = [
            '<userTransports>',
            '  <transport_id>apf_swarm_udp_loopback</transport_id>',
            *(['  <transport_id>apf_swarm_shm</transport_id>'] if shm else []),
            '</userTransports>',
            '<useBuiltinTransports>false</useBuiltinTransports>',
            '<builtin>',
            *(f'  {line}' for line in discovery),
            f'  <metatrafficUnicastLocatorList>{loopback}</metatrafficUnicastLocatorList>',
            f'  <initialPeersList>{loopback}</initialPeersList>',
            '</builtin>',
        ]
    else:
        what = "the network: the middleware's transports and discovery"
        transports = []
        rtps = ['<builtin>', *(f'  {line}' for line in discovery), '</builtin>']
    return profiles_file(
        f'apf_swarm, {what}; written by apf_swarm_nodes.dds.profiles',
        'apf_swarm',
        transports,
        rtps,
    )


def profiles_file(comment: str, name: str, transports: list[str], rtps: list[str]) -> str:
    """A Fast DDS XML profiles file: the ``transports`` lines (transport descriptors) and
    one default participant profile ``name`` with the ``rtps`` lines, under ``comment``."""
    lines = [
        '<?xml version="1.0" encoding="UTF-8"?>',
        f'<!-- {comment} -->',
        '<dds xmlns="http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles">',
        '  <profiles>',
        *(f'    {line}' for line in transports),
        f'    <participant profile_name="{name}" is_default_profile="true">',
        '      <rtps>',
        *(f'        {line}' for line in rtps),
        '      </rtps>',
        '    </participant>',
        '  </profiles>',
        '</dds>',
    ]
    return '\n'.join(lines) + '\n'


def write_profile(path: Path, **kwargs: Any) -> Path:
    """Write :func:`profile_xml` (``kwargs``) to ``path``; returns its absolute path."""
    path = Path(path).resolve()
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(profile_xml(**kwargs))
    return path


def localhost_environment(profile: Path) -> dict[str, str]:
    """The variables a process needs to run localhost only with the ``profile`` written by
    :func:`write_profile` (and :data:`NOT_LOCAL` unset)."""
    env = dict.fromkeys(PROFILE_VARIABLES, str(profile))
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'SUBNET'  # LOCALHOST adds rmw's own 0.0.0.0 socket
    return env


def check_rmw(environ: MutableMapping[str, str]) -> None:
    """The profile is Fast DDS's: refuse another middleware (DdsError)."""
    rmw = environ.get('RMW_IMPLEMENTATION', '')
    if rmw and not rmw.startswith('rmw_fastrtps'):
        raise DdsError(
            f'RMW_IMPLEMENTATION={rmw}: a localhost run is kept on this machine by a Fast DDS '
            'profile, which another middleware ignores; unset RMW_IMPLEMENTATION (the '
            'wheels ship rmw_fastrtps_cpp), or run with --discovery-range SUBNET knowing '
            'that the run is then open to the network'
        )


# --------------------------------------------------------------------------------------------
# the bring-up's hook
# --------------------------------------------------------------------------------------------


def isolate_dds(
    directory: Path,
    domain: int,
    discovery_range: str,
    *,
    processes: int,
    environ: MutableMapping[str, str] | None = None,
    say: Callable[[str], None] | None = None,
) -> Path | None:
    """Set a run's DDS up in ``environ`` (default ``os.environ``, which the bring-up's own
    node and every child inherit): write its profile into ``directory``, point Fast DDS at
    it, then refuse ``domain`` if it already carries a swarm (DdsError). Call it once
    ``ROS_DOMAIN_ID`` and ``ROS_AUTOMATIC_DISCOVERY_RANGE`` are set, before ``rclpy.init``.

    ``LOCALHOST``: the localhost profile (nothing from outside this machine); a profile file
    of the user's is replaced and :data:`NOT_LOCAL` variables are dropped, each warned.
    ``SUBNET`` / ``SYSTEM_DEFAULT``: the discovery timing only, unless the user set a profile
    file, which is kept. ``OFF``: nothing. ``processes``: the run's participants (node
    processes, the bring-up, the recorder). Returns the profile written, or None."""
    env = os.environ if environ is None else environ
    if discovery_range == 'OFF':
        return None
    own = next((env[v] for v in PROFILE_VARIABLES if env.get(v)), None)
    path: Path | None = None
    if discovery_range == 'LOCALHOST':
        check_rmw(env)
        if own is not None and say is not None:
            say(
                f'warning: the Fast DDS profile {own} is replaced for this run by the '
                'localhost one (--discovery-range SUBNET keeps yours)'
            )
        for var in NOT_LOCAL:
            if env.pop(var, None) is not None and say is not None:
                say(f'warning: {var} ignored: a localhost run reaches no other host')
        path = write_profile(
            Path(directory) / LOCALHOST_PROFILE, localhost=True, participants=processes
        )
        # the same without shared memory, for the bring-up's own participant
        # (:func:`own_participant_environment`)
        write_profile(
            Path(directory) / OWN_PROFILE, localhost=True, participants=processes, shm=False
        )
        env.update(localhost_environment(path))
    elif discovery_range in NETWORK_RANGES:
        if say is not None:
            say(OPEN_WARNING)
        if own is None:
            path = write_profile(
                Path(directory) / 'fastdds_network.xml', localhost=False, participants=processes
            )
            env.update(dict.fromkeys(PROFILE_VARIABLES, str(path)))
    else:
        raise DdsError(f'unknown discovery range {discovery_range!r}')
    refuse_other_swarm(domain, network=discovery_range != 'LOCALHOST')
    return path


# --------------------------------------------------------------------------------------------
# python -m apf_swarm_nodes.dds.profiles
# --------------------------------------------------------------------------------------------


def main(argv: Sequence[str] | None = None) -> int:
    """Write the localhost profile and print the shell lines that put it in effect."""
    cache = Path(os.environ.get('XDG_CACHE_HOME') or Path.home() / '.cache') / 'apf_swarm'
    p = argparse.ArgumentParser(
        prog='python -m apf_swarm_nodes.dds.profiles',
        description='Write the Fast DDS profile of a localhost run (the one the bring-up '
        'writes into DIR/dds/) for nodes started by hand, and print the environment they '
        'need: eval "$(python -m apf_swarm_nodes.dds.profiles)"',
    )
    p.add_argument(
        '--out',
        type=Path,
        default=cache / LOCALHOST_PROFILE,
        help=f'the profile to write (default {cache / LOCALHOST_PROFILE})',
    )
    p.add_argument(
        '--processes',
        type=int,
        default=32,
        metavar='N',
        help='ROS processes this machine runs on the domain (default 32)',
    )
    args = p.parse_args(argv)
    if args.processes < 1:
        p.error('--processes: at least 1')
    path = write_profile(args.out, localhost=True, participants=args.processes)
    for key, value in localhost_environment(path).items():
        print(f'export {key}={value}')
    print(f'unset ROS_LOCALHOST_ONLY {" ".join(NOT_LOCAL)}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
