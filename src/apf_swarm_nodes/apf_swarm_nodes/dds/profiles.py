"""The DDS side of a run's isolation (:func:`isolate_dds`, called by the bring-up): a Fast
DDS profile that keeps a localhost run on this machine, discovery announcements repeated
through the run's start-up, and the refusal of a domain that already carries a swarm.
docs/RELIABILITY.md, "Isolation", says why each part of the profile is there;
``python -m apf_swarm_nodes.dds.profiles`` writes it for nodes started by hand.
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Callable, Mapping, MutableMapping, Sequence
from pathlib import Path
from typing import Any
from xml.sax.saxutils import escape, quoteattr

from .errors import DdsError
from .participant import (
    LOCALHOST_PROFILE,
    OWN_PROFILE,
    PROFILE_VARIABLES,
    named_profile,
    own_participant,
    own_participant_environment,
)
from .swarm_domain import MAX_PARTICIPANTS, refuse_other_swarm

__all__ = [
    'LEASE_ANNOUNCEMENT',
    'LEASE_DURATION',
    'NETWORK_RANGES',
    'OWN_PROFILE',
    'PROFILE_VARIABLES',
    'check_rmw',
    'discovery_timing',
    'duration',
    'isolate_dds',
    'localhost_environment',
    'max_participants',
    'own_participant',
    'own_participant_environment',
    'profile_xml',
    'profiles_file',
    'write_profile',
]

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
#: ... and then this often [s] (Fast DDS ``leaseAnnouncement``, its default)
LEASE_ANNOUNCEMENT = 3.0
#: a remote participant silent this long is removed [s] (Fast DDS ``leaseDuration``, its
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
    (Fast DDS ``maxInitialPeersRange``): a run's ``participants`` and
    :data:`SPARE_PARTICIPANTS`, at least rmw's 32, at most what one domain's ports hold."""
    return max(32, min(MAX_PARTICIPANTS, participants + SPARE_PARTICIPANTS))


def discovery_timing(participants: int) -> tuple[float, float, float]:
    """(period, window, lease announcement) [s] of a participant's announcements in a run
    of ``participants``: every ``period`` for its first ``window`` seconds (the run's
    start-up), then every ``lease announcement``; the period grows with the run, so that
    the announcements a starting participant receives stay a small share of its CPU."""
    period = min(PERIOD_MAX, max(PERIOD_MIN, participants * PERIOD_PER_PARTICIPANT))
    window = min(WINDOW_MAX, max(WINDOW_MIN, participants * WINDOW_PER_PARTICIPANT))
    return period, window, LEASE_ANNOUNCEMENT


def duration(seconds: float) -> dict[str, int]:
    """A Fast DDS duration element's content."""
    sec = int(seconds)
    return {'sec': sec, 'nanosec': round((seconds - sec) * 1e9)}


def xml_lines(tag: str, value: Any) -> list[str]:
    """The lines of the XML element ``tag`` holding ``value``: a mapping is its children in
    order (a key ``'@name'`` an attribute, a list a repeated child), anything else its
    text. An element without grandchildren is one line."""
    if not isinstance(value, Mapping):
        return [f'<{tag}>{escape(str(value))}</{tag}>']
    attrs = ''.join(f' {k[1:]}={quoteattr(str(v))}' for k, v in value.items() if k[0] == '@')
    children = [
        (k, v)
        for k, vs in value.items()
        if k[0] != '@'
        for v in (vs if isinstance(vs, list) else [vs])
    ]
    inner = [line for k, v in children for line in xml_lines(k, v)]
    if not inner:
        return [f'<{tag}{attrs}/>']
    if not any(isinstance(v, Mapping) and any(c[0] != '@' for c in v) for _, v in children):
        return [f'<{tag}{attrs}>{"".join(inner)}</{tag}>']
    return [f'<{tag}{attrs}>', *(f'  {line}' for line in inner), f'</{tag}>']


def profiles_file(comment: str, name: str, descriptors: list[dict[str, Any]], rtps: Any) -> str:
    """A Fast DDS XML profiles file under ``comment``: the transport ``descriptors`` and
    one default participant profile ``name`` whose ``rtps`` element holds ``rtps``."""
    profiles: dict[str, Any] = {}
    if descriptors:
        profiles['transport_descriptors'] = {'transport_descriptor': descriptors}
    profiles['participant'] = {'@profile_name': name, '@is_default_profile': 'true', 'rtps': rtps}
    root = {'@xmlns': 'http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles', 'profiles': profiles}
    head = ['<?xml version="1.0" encoding="UTF-8"?>', f'<!-- {comment} -->']
    return '\n'.join([*head, *xml_lines('dds', root)]) + '\n'


def profile_xml(
    *,
    localhost: bool = True,
    participants: int = 32,
    lease_announcement: float | None = None,
    shm: bool = True,
) -> str:
    """The Fast DDS XML profile of a run of ``participants`` (the default participant
    profile: every participant of a process that reads it gets it).

    ``localhost``: UDPv4 on 127.0.0.1 only (``interfaces/allowlist``) and, with ``shm``,
    shared memory, no builtin transport, discovery by unicast to the 127.0.0.1 ports of
    :func:`max_participants`; use it with ``ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET``.
    Otherwise the middleware's transports and discovery. Both: the announcements of
    :func:`discovery_timing` (``lease_announcement``: another period after the start-up)."""
    period, window, lease = discovery_timing(participants)
    lease = lease if lease_announcement is None else lease_announcement
    if not LEASE_DURATION > lease > 0:
        raise ValueError(f'bad discovery timing: lease announcement {lease} s')
    discovery = {
        'leaseDuration': duration(LEASE_DURATION),
        'leaseAnnouncement': duration(lease),
        'initialAnnouncements': {'count': round(window / period), 'period': duration(period)},
    }
    if not localhost:
        what = "the network: the middleware's transports and discovery"
        descriptors, rtps = [], {'builtin': {'discovery_config': discovery}}
    else:
        what = 'localhost only: UDPv4 on 127.0.0.1' + (' and shared memory' if shm else '')
        udp = 'apf_swarm_udp_loopback'
        descriptors = [
            {
                'transport_id': udp,
                'type': 'UDPv4',
                'maxInitialPeersRange': max_participants(participants),
                'interfaces': {'allowlist': {'interface': {'@name': '127.0.0.1'}}},
            }
        ]
        if shm:
            descriptors.append({'transport_id': 'apf_swarm_shm', 'type': 'SHM'})
        loopback = {'locator': {'udpv4': {'address': '127.0.0.1'}}}
        rtps = {
            'userTransports': {'transport_id': [d['transport_id'] for d in descriptors]},
            'useBuiltinTransports': 'false',
            'builtin': {
                'discovery_config': discovery,
                'metatrafficUnicastLocatorList': loopback,
                'initialPeersList': loopback,
            },
        }
    comment = f'apf_swarm, {what}; written by apf_swarm_nodes.dds.profiles'
    return profiles_file(comment, 'apf_swarm', descriptors, rtps)


def write_profile(path: Path, **kwargs: Any) -> Path:
    """Write :func:`profile_xml` (``kwargs``) to ``path``; returns its absolute path."""
    path = Path(path).resolve()
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(profile_xml(**kwargs))
    return path


def localhost_environment(profile: Path) -> dict[str, str]:
    """The variables a process needs to run localhost only with the ``profile`` written by
    :func:`write_profile` (and :data:`NOT_LOCAL` unset); a secure run's too, with its
    own profile: SUBNET is the one range in which rmw adds no transport of its own to the
    profile's (LOCALHOST adds a socket on 0.0.0.0)."""
    env = dict.fromkeys(PROFILE_VARIABLES, str(profile))
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'SUBNET'
    return env


def check_rmw(environ: Mapping[str, str]) -> None:
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
    own = named_profile(env)
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


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m apf_swarm_nodes.dds.profiles``: write the localhost profile and print the
    shell lines that put it in effect."""
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
