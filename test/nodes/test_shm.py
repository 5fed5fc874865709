"""Stale Fast DDS shared-memory files (apf_swarm_nodes.shm) on fake files: what a live process
holds stays, what no one holds goes."""

from __future__ import annotations

import fcntl
import os
import time
from pathlib import Path

from apf_swarm_nodes.shm import count_fastdds_files, stale_fastdds_files


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
        before = count_fastdds_files(tmp_path)
        assert found.remove() == 7
        assert count_fastdds_files(tmp_path) == before - 7
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
    assert count_fastdds_files(tmp_path / 'none') == 0


def test_orphans_are_our_nodes_whose_parent_is_gone(monkeypatch) -> None:
    """Only a node executable's process reparented to init is an orphan (a node under a live
    bring-up, test or benchmark has that process as its parent)."""
    import psutil

    from apf_swarm_nodes import cleanup

    class P:
        def __init__(self, pid: int, ppid: int, cmd: str) -> None:
            self.pid, self.info = pid, {'pid': pid, 'ppid': ppid, 'cmdline': cmd.split()}

    node = '/ws/install/apf_swarm_nodes/lib/apf_swarm_nodes/tracker --ros-args'
    procs = [
        P(101, 1, f'python {node}'),  # orphaned
        P(102, 77, f'python {node}'),  # under its bring-up
        P(103, 1, 'python /usr/bin/something_else'),
    ]
    monkeypatch.setattr(psutil, 'process_iter', lambda attrs=None: iter(procs))
    assert [p.pid for p in cleanup.orphan_nodes()] == [101]


def test_clean_dry_run_changes_nothing(tmp_path: Path, monkeypatch, capsys) -> None:
    import argparse

    from apf_swarm_nodes import cleanup, shm

    _touch(tmp_path, 'fastrtps_0123456789abcdef')
    _touch(tmp_path, 'fastrtps_0123456789abcdef_el')
    monkeypatch.setattr(shm, 'SHM_DIR', tmp_path)
    monkeypatch.setattr(cleanup, 'stale_fastdds_files', lambda: stale_fastdds_files(tmp_path))
    monkeypatch.setattr(cleanup, 'orphan_nodes', list)
    assert cleanup.run(argparse.Namespace(dry_run=True)) == 0
    assert 'would remove 2 stale' in capsys.readouterr().out
    assert count_fastdds_files(tmp_path) == 2
    assert cleanup.run(argparse.Namespace(dry_run=False)) == 0
    assert 'removed 2 stale' in capsys.readouterr().out
    assert count_fastdds_files(tmp_path) == 0
