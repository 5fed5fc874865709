"""Stale Fast DDS shared-memory files (apf_swarm_nodes.dds.shm) on fake files: what a live process
holds stays, what no one holds goes."""

from __future__ import annotations

import fcntl
import os
import subprocess
import sys
import time
from pathlib import Path

from apf_swarm_nodes.dds.shm import fastdds_entries, stale_fastdds_files


def _touch(d: Path, name: str, age: float = 0.0) -> Path:
    p = d / name
    p.write_bytes(b'x')
    if age:
        t = time.time() - age
        os.utime(p, (t, t))
    return p


def test_only_files_no_live_process_holds_are_stale(tmp_path: Path) -> None:
    live_seg, dead_seg = 'fastrtps_0123456789abcdef', 'fastrtps_fedcba9876543210'
    for base in (live_seg, dead_seg):
        _touch(tmp_path, base)
        _touch(tmp_path, f'{base}_el')
    for port in ('fastrtps_port7411', 'fastrtps_port7413'):
        _touch(tmp_path, port)
        _touch(tmp_path, f'sem.{port}_mutex')
        _touch(tmp_path, f'{port}_el')
    _touch(tmp_path, 'fastrtps_port7415', age=60.0)  # no listener left, old
    _touch(tmp_path, 'sem.fastrtps_port7415_mutex', age=60.0)
    _touch(tmp_path, 'fastrtps_port7417')  # no lock file yet, but just created
    _touch(tmp_path, 'fastrtps_port7419', age=60.0)  # no lock file, but a process maps it
    mapped = (tmp_path / 'fastrtps_port7419').open('r+b')
    import mmap

    view = mmap.mmap(mapped.fileno(), 1)
    _touch(tmp_path, 'lttng-ust-wait-6')  # not Fast DDS's
    held = [
        os.open(tmp_path / f'{live_seg}_el', os.O_RDONLY),
        os.open(tmp_path / 'fastrtps_port7411_el', os.O_RDONLY),
    ]
    try:
        for fd in held:  # as a live participant holds them
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        found = stale_fastdds_files(tmp_path)
        assert found.segments_in_use == 1 and found.ports_in_use == 2
        assert sorted(p.name for p in found.stale) == sorted(
            [
                dead_seg,
                f'{dead_seg}_el',
                'fastrtps_port7413',
                'fastrtps_port7413_el',
                'sem.fastrtps_port7413_mutex',
                'fastrtps_port7415',
                'sem.fastrtps_port7415_mutex',
            ]
        )
        before = len(fastdds_entries(tmp_path))
        assert found.remove() == 7
        assert len(fastdds_entries(tmp_path)) == before - 7
        assert (tmp_path / live_seg).exists() and (tmp_path / 'fastrtps_port7411').exists()
        assert (tmp_path / 'fastrtps_port7417').exists()
        assert (tmp_path / 'fastrtps_port7419').exists()
        assert (tmp_path / 'lttng-ust-wait-6').exists()
        # the live ones are still locked by their owner: our probe took nothing from it
        for fd in held:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        assert stale_fastdds_files(tmp_path).stale == []
    finally:
        for fd in held:
            os.close(fd)
        view.close()
        mapped.close()
    # the owner gone (its descriptors closed, as the kernel does when it dies): stale
    assert {p.name for p in stale_fastdds_files(tmp_path).stale} >= {live_seg, 'fastrtps_port7411'}


def test_a_missing_directory_finds_nothing(tmp_path: Path) -> None:
    found = stale_fastdds_files(tmp_path / 'none')
    assert found.stale == [] and found.remove() == 0
    assert len(fastdds_entries(tmp_path / 'none')) == 0


def test_orphans_are_our_nodes_whose_parent_is_gone(monkeypatch) -> None:
    """Only a node executable's process reparented to init is an orphan (a node under a live
    bring-up, test or benchmark has that process as its parent)."""
    import psutil
    from apf_swarm_nodes.dds import cleanup

    class P:
        def __init__(self, pid: int, ppid: int, cmd: str, mark: str | None = None) -> None:
            self.pid, self.info = pid, {'pid': pid, 'ppid': ppid, 'cmdline': cmd.split()}
            self.mark = mark

        def environ(self) -> dict[str, str]:
            return {} if self.mark is None else {cleanup.BRINGUP_ENV: self.mark}

    node = '/ws/install/apf_swarm_nodes/lib/apf_swarm_nodes/tracker --ros-args'
    live = cleanup.bringup_mark()  # this process stands for a live bring-up
    dead = subprocess.Popen([sys.executable, '-c', 'pass'])
    gone = cleanup.bringup_mark(dead.pid)
    dead.wait()
    procs = [
        P(101, 1, f'python {node}'),  # orphaned (no mark: an older version)
        P(102, 77, f'python {node}'),  # under its bring-up
        P(103, 1, 'python /usr/bin/something_else'),
        P(104, 55, f'python {node}', mark=gone),  # its bring-up died, reparented elsewhere
        P(105, 1, f'python {node}', mark=live),  # reparented, but its bring-up lives
        P(106, 55, f'python {node}', mark=f'{os.getpid()}:12.00'),  # a reused pid
    ]
    monkeypatch.setattr(psutil, 'process_iter', lambda attrs=None: iter(procs))
    assert [p.pid for p in cleanup.orphan_nodes()] == [101, 104, 106]
    assert cleanup.bringup_alive(live) and not cleanup.bringup_alive(gone)
    assert cleanup.bringup_alive('garbage')  # never a reason to stop anything


def test_clean_dry_run_changes_nothing(tmp_path: Path, monkeypatch, capsys) -> None:
    import argparse

    from apf_swarm_nodes.dds import cleanup, shm

    _touch(tmp_path, 'fastrtps_0123456789abcdef')
    _touch(tmp_path, 'fastrtps_0123456789abcdef_el')
    monkeypatch.setattr(shm, 'SHM_DIR', tmp_path)
    monkeypatch.setattr(cleanup, 'stale_fastdds_files', lambda: stale_fastdds_files(tmp_path))
    monkeypatch.setattr(cleanup, 'orphan_nodes', list)
    monkeypatch.setattr(cleanup, 'expired_leases', list)
    assert cleanup.run(argparse.Namespace(dry_run=True)) == 0
    assert 'would remove 2 stale' in capsys.readouterr().out
    assert len(fastdds_entries(tmp_path)) == 2
    assert cleanup.run(argparse.Namespace(dry_run=False)) == 0
    assert 'removed 2 stale' in capsys.readouterr().out
    assert len(fastdds_entries(tmp_path)) == 0


def test_expired_domain_leases_are_found(tmp_path: Path, monkeypatch) -> None:
    from apf_swarm_nodes.dds import cleanup, domains

    monkeypatch.setattr(domains, 'lease_dir', lambda: tmp_path)
    _touch(tmp_path, '17', age=domains.DOMAIN_LEASE + 5)  # expired
    _touch(tmp_path, '18')  # a run picked it just now
    _touch(tmp_path, '.lock', age=3600.0)  # the pickers' lock, never removed
    assert [p.name for p in cleanup.expired_leases()] == ['17']


def test_ports_too_young_to_judge_are_judged_again_once_old_enough(tmp_path: Path) -> None:
    """A port segment without a lock file that the run's last process wrote just before it
    ended is too young at the run's end: remove_stale looks again once it is old enough."""
    from apf_swarm_nodes.dds.shm import remove_stale

    _touch(tmp_path, 'fastrtps_port7421')
    _touch(tmp_path, 'sem.fastrtps_port7421_mutex')
    found = stale_fastdds_files(tmp_path, min_age=0.3)
    assert found.stale == [] and found.young == 1
    t0 = time.monotonic()
    assert remove_stale(tmp_path, min_age=0.3) == 2
    assert 0.3 <= time.monotonic() - t0 < 5.0
    assert len(fastdds_entries(tmp_path)) == 0
