"""``apf-swarm clean``: what an older version, a killed bring-up or a power cut left behind --
Fast DDS shared-memory files of participants that no longer exist (:mod:`.shm`), node
processes of ours whose bring-up is gone, and expired domain leases (the bring-up's only
files outside its output directory).

A bring-up puts ``APF_SWARM_BRINGUP=<pid>:<start time>`` in its environment before it
starts anything, so every node process it starts (executed, or forked from its zygote,
whose environment it is) names it: such a node is an orphan once that process is gone,
wherever the node was reparented. A node without the mark (an older version, started by
hand) is an orphan when it was reparented to init."""

from __future__ import annotations

import argparse
import contextlib
import os
import signal
import time
from collections.abc import Callable
from pathlib import Path

import psutil

from .shm import stale_fastdds_files

__all__ = [
    'BRINGUP_ENV',
    'add_arguments',
    'bringup_alive',
    'bringup_mark',
    'expired_leases',
    'orphan_nodes',
    'run',
]

#: a process runs one of our node executables when its command line names this directory
NODE_DIR = f'{os.sep}apf_swarm_nodes{os.sep}lib{os.sep}apf_swarm_nodes{os.sep}'
#: the variable that names a node's bring-up: ``<pid>:<start time>``
BRINGUP_ENV = 'APF_SWARM_BRINGUP'


def bringup_mark(pid: int | None = None) -> str:
    """The value of :data:`BRINGUP_ENV` for process ``pid`` (this one by default)."""
    pid = os.getpid() if pid is None else pid
    return f'{pid}:{psutil.Process(pid).create_time():.2f}'


def bringup_alive(mark: str) -> bool:
    """Whether the process a :data:`BRINGUP_ENV` value names still runs (the same process:
    its start time too; a malformed mark counts as alive, nothing is stopped for it)."""
    pid_s, _, start_s = mark.partition(':')
    try:
        pid, start = int(pid_s), float(start_s)
    except ValueError:
        return True
    try:
        proc = psutil.Process(pid)
        return proc.status() != psutil.STATUS_ZOMBIE and abs(proc.create_time() - start) < 0.02
    except psutil.NoSuchProcess:
        return False
    except psutil.Error:
        return True


def orphan_nodes() -> list[psutil.Process]:
    """Our node processes (executed, or forked from the zygote: their command line is the
    executable's) whose bring-up is gone: the one their :data:`BRINGUP_ENV` names, or
    without it, their parent (reparented to init, pid 1). A node under a live bring-up,
    test or benchmark is left alone."""
    out = []
    for proc in psutil.process_iter(['pid', 'ppid', 'cmdline']):
        try:
            line = ' '.join(proc.info['cmdline'] or [])
            if NODE_DIR not in line or proc.pid == os.getpid():
                continue
            try:
                mark = proc.environ().get(BRINGUP_ENV)
            except psutil.AccessDenied:
                mark = None
            if (mark is None and proc.info['ppid'] == 1) or (
                mark is not None and not bringup_alive(mark)
            ):
                out.append(proc)
        except (psutil.Error, OSError):
            continue
    return out


def expired_leases() -> list[Path]:
    """Domain leases (``bringup.isolation.pick_domain_id``) older than their term."""
    from .domains import DOMAIN_LEASE, lease_dir

    now, out = time.time(), []
    with contextlib.suppress(OSError):
        for p in lease_dir().iterdir():
            if p.name.isdigit():
                with contextlib.suppress(OSError):
                    if now - p.stat().st_mtime >= DOMAIN_LEASE:
                        out.append(p)
    return sorted(out)


def _stop(procs: list[psutil.Process], say: Callable[[str], None]) -> int:
    """SIGTERM, 3 s, then SIGKILL; how many were stopped."""
    for p in procs:
        with contextlib.suppress(psutil.Error):
            p.send_signal(signal.SIGTERM)
    _, alive = psutil.wait_procs(procs, timeout=3.0)
    for p in alive:
        with contextlib.suppress(psutil.Error):
            p.kill()
    _, still = psutil.wait_procs(alive, timeout=2.0)
    for p in still:
        say(f'could not stop pid {p.pid}')
    return len(procs) - len(still)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        '--dry-run',
        action='store_true',
        help='list what would be removed or stopped, change nothing',
    )


def run(args: argparse.Namespace, say: Callable[[str], None] = print) -> int:
    """Remove stale shared memory, stop orphaned nodes; print what was done. Exit 0."""
    t0 = time.monotonic()
    orphans = orphan_nodes()
    verb = 'would remove' if args.dry_run else 'removed'
    for p in orphans:
        try:
            say(f'orphaned node pid {p.pid}: {" ".join(p.cmdline())[:160]}')
        except psutil.Error:
            continue
    leases = expired_leases()
    for path in leases:
        say(f'expired lease: {path}')
    # the orphans first: what they hold is stale once they are gone
    stopped = 0 if args.dry_run else _stop(orphans, say)
    found = stale_fastdds_files()
    for path in found.stale:
        say(f'stale: {path}')
    removed = len(found.stale) if args.dry_run else found.remove()
    if not args.dry_run:
        for path in leases:
            with contextlib.suppress(OSError):
                path.unlink()
    say(
        f'{verb} {removed} stale Fast DDS shared-memory files ({found.segments_in_use} segments '
        f'and {found.ports_in_use} ports in use kept); '
        + (
            f'{len(orphans)} orphaned node processes found'
            if args.dry_run
            else f'stopped {stopped} orphaned node processes'
        )
        + f'; {verb} {len(leases)} expired domain leases'
        + f' ({time.monotonic() - t0:.2f} s)'
    )
    return 0
