"""Fast DDS's shared-memory files of participants that no longer exist, found and removed
(what ``fastdds shm clean`` does; the wheels ship no ``fastdds`` tool).

Per participant a segment ``fastrtps_<16 hex>`` and its lock file ``..._el``; per port a
segment ``fastrtps_port<N>``, its mutex ``sem.fastrtps_port<N>_mutex`` and, while someone
listens, a lock file ``..._el`` or ``_sl``. A live owner holds an ``flock`` on its lock
files, so a lock file that can be locked exclusively is stale with its segment and mutex
(Fast DDS's own rule). A port segment without a lock file is stale when no process maps it
and it is older than :data:`MIN_AGE`. Nothing a live process holds is removed
(docs/RELIABILITY.md, "Shared memory and orphans").
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import re
import time
from dataclasses import dataclass, field
from pathlib import Path

__all__ = [
    'MIN_AGE',
    'SHM_DIR',
    'ShmCleanup',
    'fastdds_entries',
    'mapped_shm_names',
    'remove_stale',
    'stale_fastdds_files',
    'unheld',
]

SHM_DIR = Path('/dev/shm')
#: a port segment without a lock file is left alone until it is this old [s]
MIN_AGE = 1.0

_SEGMENT_LOCK = re.compile(r'^fastrtps_[0-9a-z]{16}_(el|sl)$')
_PORT_LOCK = re.compile(r'^fastrtps_port\d{1,5}_(el|sl)$')
_PORT = re.compile(r'^fastrtps_port\d{1,5}$')


@dataclass
class ShmCleanup:
    """What :func:`stale_fastdds_files` found: the files to remove and what is in use."""

    stale: list[Path] = field(default_factory=list)
    segments_in_use: int = 0
    ports_in_use: int = 0
    #: port segments without a lock file, mapped by no one, but younger than the minimum age
    young: int = 0

    def remove(self) -> int:
        """Remove the stale files (those already gone are skipped); how many were removed."""
        removed = 0
        for path in self.stale:
            with contextlib.suppress(OSError):
                path.unlink()
                removed += 1
        return removed


def _locked(path: Path) -> bool:
    """Whether a live process holds an flock on ``path`` (Fast DDS's lock files)."""
    try:
        fd = os.open(path, os.O_RDONLY)
    except FileNotFoundError:
        return False
    except OSError:
        return True  # unreadable: leave it alone
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)  # (released when fd is closed)
        return False
    except OSError:
        return True
    finally:
        os.close(fd)


def mapped_shm_names(shm_dir: Path = SHM_DIR) -> set[str]:
    """Names of the files in ``shm_dir`` that some process has mapped now."""
    prefix = str(shm_dir).rstrip('/') + '/'
    names: set[str] = set()
    for pid in os.listdir('/proc'):
        if not pid.isdigit():
            continue
        try:
            with open(f'/proc/{pid}/maps', encoding='utf-8', errors='replace') as f:
                for line in f:
                    i = line.find(prefix)
                    if i >= 0:
                        names.add(line[i + len(prefix) :].split(' (deleted)')[0].strip())
        except OSError:
            continue
    return names


def stale_fastdds_files(shm_dir: Path = SHM_DIR, min_age: float = MIN_AGE) -> ShmCleanup:
    """The Fast DDS files in ``shm_dir`` of participants that no longer exist."""
    out = ShmCleanup()
    try:
        names = set(os.listdir(shm_dir))
    except OSError:
        return out
    ports_locked: set[str] = set()
    for name in sorted(names):
        seg_lock, port_lock = _SEGMENT_LOCK.match(name), _PORT_LOCK.match(name)
        if not (seg_lock or port_lock):
            continue
        base = name[:-3]
        if _locked(shm_dir / name):
            if seg_lock:
                out.segments_in_use += 1
            else:
                out.ports_in_use += 1
                ports_locked.add(base)
            continue
        out.stale += [shm_dir / name, shm_dir / base]
        if port_lock:
            out.stale.append(shm_dir / f'sem.{base}_mutex')
            ports_locked.add(base)  # handled with its lock file
    now = time.time()
    mapped: set[str] | None = None
    for name in sorted(names):
        if not _PORT.match(name) or name in ports_locked:
            continue
        if any(f'{name}_{k}' in names for k in ('el', 'sl')):
            continue
        if mapped is None:
            mapped = mapped_shm_names(shm_dir)
        if name in mapped:
            out.ports_in_use += 1
            continue
        try:
            age = now - (shm_dir / name).stat().st_mtime
        except OSError:
            continue
        if age >= min_age:
            out.stale += [shm_dir / name, shm_dir / f'sem.{name}_mutex']
        else:
            out.young += 1
    out.stale = [p for p in dict.fromkeys(out.stale) if p.name in names]
    return out


def remove_stale(shm_dir: Path = SHM_DIR, min_age: float = MIN_AGE) -> int:
    """Remove the stale files (:func:`stale_fastdds_files`); when port segments were too
    young to judge (the run's last processes wrote them just before they ended), look again
    once they are old enough. How many files were removed."""
    found = stale_fastdds_files(shm_dir, min_age)
    removed = found.remove()
    if found.young:
        time.sleep(min_age)
        removed += stale_fastdds_files(shm_dir, min_age).remove()
    return removed


def fastdds_entries(shm_dir: Path = SHM_DIR) -> set[str]:
    """The names of Fast DDS's entries in ``shm_dir`` now."""
    try:
        return {n for n in os.listdir(shm_dir) if n.startswith(('fastrtps_', 'sem.fastrtps_'))}
    except OSError:
        return set()


def _owner_base(name: str) -> str:
    """The segment or port an entry belongs to: ``fastrtps_port7411`` for its lock files and
    its mutex ``sem.fastrtps_port7411_mutex``, the name itself for a segment."""
    if name.startswith('sem.') and name.endswith('_mutex'):
        return name[len('sem.') : -len('_mutex')]
    if name.endswith(('_el', '_sl')):
        return name[:-3]
    return name


def unheld(names: set[str] | list[str], shm_dir: Path = SHM_DIR) -> set[str]:
    """Of ``names`` (entries of ``shm_dir``), those that still exist and that no live process
    holds: neither a lock on its segment's or port's lock file, nor a mapping of the segment,
    the port or the mutex. What a run that has ended left behind is the entries it created
    that are unheld; entries that other jobs' live participants created in the meantime are
    held, and not counted."""
    present = fastdds_entries(shm_dir)
    todo = [n for n in names if n in present]
    if not todo:
        return set()
    mapped = mapped_shm_names(shm_dir)
    held_bases: dict[str, bool] = {}

    def base_held(base: str) -> bool:
        if base not in held_bases:
            held_bases[base] = (
                base in mapped
                or f'sem.{base}_mutex' in mapped
                or any(
                    f'{base}_{k}' in present and _locked(shm_dir / f'{base}_{k}')
                    for k in ('el', 'sl')
                )
            )
        return held_bases[base]

    return {n for n in todo if n not in mapped and not base_held(_owner_base(n))}
