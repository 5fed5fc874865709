"""One swarm per domain: before a run starts, whether its domain already carries a swarm
(:func:`refuse_other_swarm`: a publisher of a topic only a swarm publishes; subscribers such
as a viewer or a recorder do not count), and Fast DDS's port mapping, which tells whether
any participant runs on the domain here (:func:`domain_participant_ports`)."""

from __future__ import annotations

import contextlib
import os
import time
from collections.abc import Iterable
from typing import Any

from ..topics import DISCOVERY_INFO, SWARM_PUBLISHED, UAV_TOPIC
from .errors import DdsError

__all__ = [
    'MAX_PARTICIPANTS',
    'SWARM_PUBLISHED',
    'bound_udp_ports',
    'domain_participant_ports',
    'domain_port_range',
    'refuse_other_swarm',
    'swarm_publishers',
]

#: Fast DDS's port mapping (RTPS 9.6.1.1): on domain d, participant i listens for
#: discovery on PB + DG d + 10 + 2 i and for data on the next port
_PORT_BASE, _DOMAIN_GAIN, _META_OFFSET = 7400, 250, 10
#: the most participants whose ports stay inside one domain's range
MAX_PARTICIPANTS = (_DOMAIN_GAIN - _META_OFFSET) // 2
#: how long a network run's domain is watched for a swarm [s] (no local port tells
#: whether a remote participant is there)
NETWORK_WATCH = 2.0
#: how long the domain probe waits at most [s]: longer than a lease announcement period,
#: after which every participant there has announced itself again
PROBE_TIMEOUT = 4.0

_UNKNOWN_NAME = '_NODE_NAME_UNKNOWN_'


def domain_port_range(domain: int) -> range:
    """The UDP ports of ``domain`` (Fast DDS's mapping: PB + DG d and the DG after)."""
    lo = _PORT_BASE + _DOMAIN_GAIN * domain
    return range(lo, lo + _DOMAIN_GAIN)


def domain_participant_ports(domain: int, ports: Iterable[int] | None = None) -> set[int]:
    """The discovery ports of ``domain``'s participants bound in this network namespace
    (UDP, Fast DDS's port mapping): one per participant running here on that domain."""
    if ports is None:
        ports = bound_udp_ports()
    lo = _PORT_BASE + _DOMAIN_GAIN * domain + _META_OFFSET
    return {p for p in ports if lo <= p < lo + 2 * MAX_PARTICIPANTS and (p - lo) % 2 == 0}


def bound_udp_ports(pid: int | None = None) -> set[int]:
    """The UDP ports bound in this network namespace (of process ``pid`` only, if given)."""
    import psutil

    with contextlib.suppress(psutil.Error, OSError):
        if pid is not None:
            conns = psutil.Process(pid).net_connections('udp')
        else:
            conns = psutil.net_connections('udp')
        return {c.laddr.port for c in conns if c.laddr}
    return set()


def swarm_publishers(
    domain: int,
    *,
    network: bool = False,
    timeout: float = PROBE_TIMEOUT,
    settle: float = 0.3,
    poll: float = 0.05,
) -> list[str]:
    """The swarm topics (:data:`SWARM_PUBLISHED`, ``/uav_<i>/force_cmd``, ``.../odom``, the
    setpoints ``.../accel_cmd`` and ``.../velocity_cmd``) with a publisher on ``domain``,
    each as ``'topic (N publishers: /node, ...)'``.

    An rclpy participant of its own, made with this process's environment (call it once the
    run's profile is set) but on UDP only (:func:`~.participant.own_participant`), watches the
    graph until a swarm publisher shows (then ``settle`` s more, for the names), or
    ``timeout`` s. Localhost (``network`` False): nothing bound on the domain's ports here
    means nothing to see, [] at once; otherwise the watch also ends ``settle`` s after every
    participant on those ports has shown its ``ros_discovery_info`` writer. Network:
    :data:`NETWORK_WATCH` s at least."""
    others = domain_participant_ports(domain)
    if not others and not network:
        return []
    import rclpy
    from rclpy.context import Context

    from .participant import own_participant

    ctx = Context()
    # on UDP only, as the bring-up's own node: a shared-memory port whose mutex a killed
    # process of another run held cannot block the check
    with own_participant():
        rclpy.init(context=ctx, domain_id=domain)
    node = None
    try:
        with own_participant():
            node = rclpy.create_node(
                'apf_swarm_domain_probe',
                context=ctx,
                enable_rosout=False,
                start_parameter_services=False,
            )
        others -= bound_udp_ports(os.getpid())
        t0 = time.monotonic()
        found: list[str] = []
        found_at: float | None = None  # the first swarm publisher seen
        all_seen_at: float | None = None  # every local participant seen, none a swarm's
        while True:
            now = time.monotonic()
            found = _swarm_topics(node) or found
            if found:
                found_at = now if found_at is None else found_at
                if now >= found_at + settle:
                    break
            elif network:
                if now >= t0 + NETWORK_WATCH:
                    break
            else:
                seen = node.get_publishers_info_by_topic(DISCOVERY_INFO, no_mangle=True)
                if len(seen) - 1 >= len(others):  # every participant, minus this probe
                    all_seen_at = now if all_seen_at is None else all_seen_at
                    if now >= all_seen_at + settle:
                        break
            if now >= t0 + timeout:
                break
            time.sleep(poll)
        return found
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown(context=ctx)


def _swarm_topics(node: Any) -> list[str]:
    order = {t: k for k, t in enumerate(SWARM_PUBLISHED)}
    found = []
    for topic, _types in node.get_topic_names_and_types():
        if topic not in order and not UAV_TOPIC.match(topic):
            continue
        pubs = node.get_publishers_info_by_topic(topic)
        if pubs:
            names = sorted(
                'a node not yet named'
                if p.node_name == _UNKNOWN_NAME
                else f'{p.node_namespace.rstrip("/")}/{p.node_name}'
                for p in pubs
            )
            who = f'{len(pubs)} publishers: {", ".join(names)}'
            found.append((order.get(topic, len(order)), topic, who))
    return [f'{topic} ({who})' for _, topic, who in sorted(found)]


def refuse_other_swarm(domain: int, *, network: bool = False) -> None:
    """DdsError when ``domain`` already carries a swarm (:func:`swarm_publishers`)."""
    found = swarm_publishers(domain, network=network)
    if found:
        shown = '; '.join(found[:3]) + (f'; and {len(found) - 3} more' if len(found) > 3 else '')
        raise DdsError(
            f'ROS_DOMAIN_ID={domain} already carries a swarm: {shown}. Two swarms on one '
            "domain take each other's states and commands: choose another --domain-id (or "
            'none: the bring-up picks a free one), or stop that swarm first'
        )
