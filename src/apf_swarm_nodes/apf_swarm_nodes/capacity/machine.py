"""What this machine is and what its processes cost: the one place the project reads them
(psutil; the CPU model from ``/proc/cpuinfo``, which psutil does not give).

Used by the capacity probe (its cache key), the bring-up (process groups, bound ports) and
the benchmarks (the CPU model, each process's CPU and memory).
"""

from __future__ import annotations

import os
import platform
import socket
from functools import lru_cache
from pathlib import Path
from typing import Any

import psutil

__all__ = [
    'cpu_model',
    'group_members',
    'identity',
    'process_args',
    'process_cpu_seconds',
    'process_rss',
]


@lru_cache(maxsize=1)
def cpu_model() -> str:
    """The CPU's model name (``/proc/cpuinfo``), else what :mod:`platform` knows."""
    try:
        for line in Path('/proc/cpuinfo').read_text(errors='replace').splitlines():
            if line.startswith('model name'):
                return line.split(':', 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine() or 'unknown CPU'


def identity() -> dict[str, Any]:
    """What tells one machine from another for a cached measurement: CPU model, cores,
    host name."""
    return {'cpu': cpu_model(), 'cores': os.cpu_count() or 1, 'host': socket.gethostname()}


def process_cpu_seconds(pid: int) -> float | None:
    """User plus system CPU time of a process [s]; None when it is gone."""
    try:
        t = psutil.Process(pid).cpu_times()
    except (psutil.NoSuchProcess, psutil.AccessDenied):
        return None
    return float(t.user + t.system)


def process_args(pid: int) -> list[str] | None:
    """A process's command line as a list of arguments; None when it is gone.

    A node process forked by the bring-up's zygote shows its executable's command line as
    one title (``setproctitle``: the arguments joined by spaces, padded with NULs); it is
    split on whitespace here, so both kinds read alike."""
    try:
        with open(f'/proc/{pid}/cmdline', 'rb') as f:
            raw = f.read()
    except OSError:
        return None
    args = [a.decode(errors='replace') for a in raw.split(b'\0') if a]
    return args[0].split() if len(args) == 1 else args


def process_rss(pid: int) -> int | None:
    """Resident set of a process [bytes]; None when it is gone."""
    try:
        return int(psutil.Process(pid).memory_info().rss)
    except (psutil.NoSuchProcess, psutil.AccessDenied):
        return None


def group_members(pgid: int) -> list[int]:
    """Live (not zombie) processes of process group ``pgid``."""
    out = []
    for p in psutil.process_iter(['status']):
        try:
            if p.info['status'] != psutil.STATUS_ZOMBIE and os.getpgid(p.pid) == pgid:
                out.append(p.pid)
        except (ProcessLookupError, psutil.Error):
            continue
    return out
