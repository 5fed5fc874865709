"""QoS profiles between rclpy, rosbag2's metadata (the v9 mapping: policy names, ``{sec,
nsec}`` times) and rosbags' ``Qos``: the one mapping of the recorder, the player and the bag
tools.

A bag stores what each publisher offered. The recorder subscribes with what every offered
profile accepts (:func:`recording_profile`); the player publishes what the recorded
publishers offered (:func:`replay_profile`). rclpy is imported only by the functions that
make or read an rclpy profile, so that the bag tools run without it.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

__all__ = [
    'INFINITE',
    'make_profile',
    'profile_to_dict',
    'qos_from_dict',
    'recording_profile',
    'replay_profile',
]

#: an infinite duration as rosbag2 writes it
INFINITE = {'sec': 0x7FFFFFFF, 'nsec': 0xFFFFFFFF}


def qos_from_dict(d: Mapping[str, Any]) -> Any:
    """A metadata.yaml v9 QoS mapping (names, ``{sec, nsec}`` times) as a rosbags ``Qos``;
    an unknown policy name becomes ``UNKNOWN``."""
    from rosbags.interfaces import (
        Qos,
        QosDurability,
        QosHistory,
        QosLiveliness,
        QosReliability,
        QosTime,
    )

    def enum(cls: Any, value: Any) -> Any:
        if isinstance(value, int):
            return cls(value)
        try:
            return cls[str(value).upper()]
        except KeyError:
            return cls.UNKNOWN

    def tm(value: Any) -> Any:
        value = value or {}
        return QosTime(int(value.get('sec', 0)), int(value.get('nsec', 0)))

    return Qos(
        enum(QosHistory, d.get('history', 'unknown')),
        int(d.get('depth', 0)),
        enum(QosReliability, d.get('reliability', 'unknown')),
        enum(QosDurability, d.get('durability', 'unknown')),
        tm(d.get('deadline')),
        tm(d.get('lifespan')),
        enum(QosLiveliness, d.get('liveliness', 'unknown')),
        tm(d.get('liveliness_lease_duration')),
        bool(d.get('avoid_ros_namespace_conventions', False)),
    )


def _name(value: Any) -> str:
    return str(getattr(value, 'name', value)).lower()


def _duration(d: Any) -> dict[str, int]:
    ns = int(d.nanoseconds) if d is not None else 0
    if ns >= 0x7FFFFFFFFFFFFFFF or ns < 0:
        return dict(INFINITE)
    return {'sec': ns // 1_000_000_000, 'nsec': ns % 1_000_000_000}


def profile_to_dict(q: Any) -> dict[str, Any]:
    """An rclpy ``QoSProfile`` (as a publisher offers it) as the metadata.yaml v9 mapping."""
    return {
        'history': _name(q.history),
        'depth': int(q.depth),
        'reliability': _name(q.reliability),
        'durability': _name(q.durability),
        'deadline': _duration(q.deadline),
        'lifespan': _duration(q.lifespan),
        'liveliness': _name(q.liveliness),
        'liveliness_lease_duration': _duration(q.liveliness_lease_duration),
        'avoid_ros_namespace_conventions': bool(q.avoid_ros_namespace_conventions),
    }


def make_profile(*, reliable: bool, transient_local: bool, depth: int) -> Any:
    """An rclpy keep-last profile: the one place the project builds one (the nodes' profiles
    per topic, :mod:`.node_common`, and the recorder's and the player's)."""
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=depth,
        reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.TRANSIENT_LOCAL
        if transient_local
        else DurabilityPolicy.VOLATILE,
    )


def recording_profile(offered: Sequence[Mapping[str, Any]], depth: int) -> Any:
    """The rclpy profile a recorder subscribes with: reliable and transient-local only when
    every offered profile is (a reliable reader matches no best-effort writer), keep last
    ``depth``."""
    return make_profile(
        reliable=all(q.get('reliability') == 'reliable' for q in offered),
        transient_local=all(q.get('durability') == 'transient_local' for q in offered),
        depth=int(depth),
    )


def replay_profile(offered: Sequence[Mapping[str, Any]], depth: int) -> Any:
    """The rclpy profile a player publishes a recorded topic with: the first recorded
    publisher's reliability and durability (reliable and volatile when the bag recorded
    none), keep last the larger of ``depth`` and its depth."""
    q = offered[0] if offered else {}
    return make_profile(
        reliable=q.get('reliability') != 'best_effort',
        transient_local=q.get('durability') == 'transient_local',
        depth=max(int(depth), int(q.get('depth', 0) or 0)),
    )
