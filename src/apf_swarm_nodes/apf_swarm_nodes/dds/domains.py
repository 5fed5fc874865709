"""Which ``ROS_DOMAIN_ID`` a run takes: a random domain nobody on this machine uses (no bound
UDP or shared-memory port of its range), leased under a lock so that two runs picking at the
same instant get different domains."""

from __future__ import annotations

import fcntl
import os
import random
import re
import tempfile
import time
from collections.abc import Iterable
from pathlib import Path

from .swarm_domain import bound_udp_ports, domain_port_range

__all__ = ['DOMAIN_LEASE', 'domain_looks_busy', 'env_domain', 'lease_dir', 'pick_domain_id']


def _bound_udp_ports() -> set[int]:
    """Bound UDP ports, and the ports of Fast DDS's shared-memory segments."""
    ports = bound_udp_ports()
    try:
        for entry in os.listdir('/dev/shm'):
            m = re.match(r'fastrtps_port(\d+)$', entry)
            if m:
                ports.add(int(m.group(1)))
    except OSError:
        pass
    return ports


def domain_looks_busy(domain: int, ports: set[int] | None = None) -> bool:
    """True when a UDP port (or Fast DDS shared-memory port) of the domain's range is in use."""
    ports = _bound_udp_ports() if ports is None else ports
    return any(p in domain_port_range(domain) for p in ports)


#: how long a picked domain stays reserved for its picker [s]: long enough for the run it
#: was picked for to start its nodes, whose bound ports then mark it busy
DOMAIN_LEASE = 60.0


def lease_dir() -> Path:
    """Where the domain leases of this machine's runs are kept."""
    base = os.environ.get('XDG_RUNTIME_DIR') or tempfile.gettempdir()
    return Path(base) / 'apf_swarm-domains'


def pick_domain_id(
    exclude: Iterable[int] = (), lo: int = 1, hi: int = 101, rng: random.Random | None = None
) -> int:
    """A random domain in ``[lo, hi]``, not in ``exclude``, preferring one nobody uses: no
    bound port of its range, and not picked in the last :data:`DOMAIN_LEASE` seconds by any
    process of this machine (a lease file, written under a lock, so two runs that pick at
    the same instant, before either has bound a port, get different domains)."""
    rng = rng or random.SystemRandom()
    excl = set(exclude)
    candidates = [d for d in range(lo, hi + 1) if d not in excl]
    rng.shuffle(candidates)
    leases = lease_dir()
    try:
        leases.mkdir(parents=True, exist_ok=True)
        lock = open(leases / '.lock', 'w')  # noqa: SIM115 (held across the lease, closed below)
    except OSError:
        lock = None  # no lease files here: the ports decide alone
    try:
        if lock is not None:
            fcntl.flock(lock, fcntl.LOCK_EX)
        ports, now = _bound_udp_ports(), time.time()

        def leased(d: int) -> bool:
            try:
                return now - (leases / str(d)).stat().st_mtime < DOMAIN_LEASE
            except OSError:
                return False

        free = [d for d in candidates if not domain_looks_busy(d, ports)]
        d = next(
            (d for d in free if lock is None or not leased(d)), free[0] if free else candidates[0]
        )
        if lock is not None:
            (leases / str(d)).write_text(f'{os.getpid()}\n')
        return d
    finally:
        if lock is not None:
            lock.close()


def env_domain() -> int | None:
    try:
        return int(os.environ.get('ROS_DOMAIN_ID', ''))
    except ValueError:
        return None
