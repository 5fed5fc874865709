"""The capacity check before a run starts, and its ``ROS_DOMAIN_ID`` (:mod:`..dds.domains`)."""

from __future__ import annotations

from collections.abc import Callable

from ..dds.domains import pick_domain_id
from .errors import BringupError

__all__ = ['check_capacity', 'pick_domain_id']


def check_capacity(
    n_trackers: int,
    *,
    allow_overload: bool = False,
    per_process: int = 1,
    say: Callable[[str], None] | None = None,
) -> None:
    """Refuse (BringupError) more tracker processes (``ceil(n_trackers / per_process)``) than
    the machine's probe allows (:func:`~..capacity.probe.process_limit`); without a probe,
    nothing is refused, with a warning."""
    from ..capacity import probe

    if allow_overload:
        return
    procs = -(-n_trackers // per_process)
    machine = probe.ensure_or_warn(say, 'the tracker process limit is not known, none applied')
    if machine is None:
        return
    limit = probe.process_limit(machine)
    if procs > limit['processes']:
        raise BringupError(
            f'n_trackers = {n_trackers} in {procs} processes is more than this '
            f'machine runs: its probe (`apf-swarm probe`) allows '
            f'{limit["processes"]} tracker processes ({limit["cpu"]} by CPU at '
            f'{probe.RATES[-1]:g} Hz, {limit["memory"]} by memory); use fewer '
            f'trackers, --trackers-per-process K to host several in one process, '
            f'or --allow-overload to start them anyway'
        )
