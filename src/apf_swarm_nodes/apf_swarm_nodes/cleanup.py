"""``apf-swarm clean``: what an older version, a killed bring-up or a power cut left behind --
Fast DDS shared-memory files of participants that no longer exist (:mod:`.shm`) and node
processes of ours whose bring-up is gone (reparented to init)."""

from __future__ import annotations

import argparse
import contextlib
import os
import signal
import time
from collections.abc import Callable

import psutil

from .shm import stale_fastdds_files

__all__ = ['add_arguments', 'orphan_nodes', 'run']

#: a process runs one of our node executables when its command line names this directory
NODE_DIR = f'{os.sep}apf_swarm_nodes{os.sep}lib{os.sep}apf_swarm_nodes{os.sep}'


def orphan_nodes() -> list[psutil.Process]:
    """Our node processes (executed, or forked from the zygote: their command line is the
    executable's) whose parent is gone: reparented to init (pid 1). A node under a live
    bring-up, test or benchmark has that process as its parent and is left alone."""
    out = []
    for proc in psutil.process_iter(['pid', 'ppid', 'cmdline']):
        try:
            line = ' '.join(proc.info['cmdline'] or [])
            if NODE_DIR in line and proc.info['ppid'] == 1 and proc.pid != os.getpid():
                out.append(proc)
        except (psutil.Error, OSError):
            continue
    return out


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
    found = stale_fastdds_files()
    orphans = orphan_nodes()
    verb = 'would remove' if args.dry_run else 'removed'
    for p in orphans:
        try:
            say(f'orphaned node pid {p.pid}: {" ".join(p.cmdline())[:160]}')
        except psutil.Error:
            continue
    if args.dry_run:
        for path in found.stale:
            say(f'stale: {path}')
        removed, stopped = len(found.stale), 0
    else:
        removed, stopped = found.remove(), _stop(orphans, say)
    say(
        f'{verb} {removed} stale Fast DDS shared-memory files ({found.segments_in_use} segments '
        f'and {found.ports_in_use} ports in use kept); '
        + (
            f'{len(orphans)} orphaned node processes found'
            if args.dry_run
            else f'stopped {stopped} orphaned node processes'
        )
        + f' ({time.monotonic() - t0:.2f} s)'
    )
    return 0
