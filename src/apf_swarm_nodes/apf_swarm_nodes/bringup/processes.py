"""Process supervision without ROS: each node an OS process in its own process group,
started, watched, restarted and stopped by its own PID (:class:`Child`, :class:`ProcessGroup`),
and the bring-up's exit codes."""

from __future__ import annotations

import os
import signal
import subprocess
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from ..capacity.machine import group_members
from ..lifetime import STOP_CPU_PER_PROCESS, Process, describe_rc, dying_with_parent

__all__ = [
    'EXIT_BAD_INPUT',
    'EXIT_CHILD_DIED',
    'EXIT_INTERRUPTED',
    'EXIT_LOST_SAMPLES',
    'EXIT_OK',
    'EXIT_STALLED',
    'STOP_SEQUENCE',
    'Child',
    'ProcessGroup',
    'StopRun',
]

if TYPE_CHECKING:
    from .janitor import Janitor
    from .zygote import Zygote

EXIT_OK = 0
EXIT_BAD_INPUT = 2
EXIT_CHILD_DIED = 3
EXIT_STALLED = 4
EXIT_LOST_SAMPLES = 5
EXIT_INTERRUPTED = 130

#: escalation of :meth:`ProcessGroup.stop_all`: (signal, seconds to wait after it)
STOP_SEQUENCE = ((signal.SIGINT, 5.0), (signal.SIGTERM, 3.0), (signal.SIGKILL, 2.0))


def _group_alive(pgid: int) -> bool:
    """True while process group ``pgid`` has a member that is not a zombie."""
    try:
        os.killpg(pgid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    # zombies answer kill(0) too (and PID 1 of a container may never reap them)
    return bool(group_members(pgid))


@dataclass
class Child:
    """One supervised OS process in its own process group, output appended to ``log_path``:
    forked from the ``zygote`` if it has one and can (:mod:`.zygote`), else executed (under
    ``ip netns exec`` with a ``netns``, a simulated host)."""

    name: str
    argv: list[str]
    log_path: Path
    env: Mapping[str, str] | None = None
    cwd: Path | None = None
    zygote: Zygote | None = None
    netns: str | None = None
    #: told the pid of an executed process (it cleans up if the bring-up is killed)
    janitor: Janitor | None = None
    popen: Process | None = None
    starts: int = 0
    #: of those, restarts while the graph came up (before the run; not respawns)
    unseen_restarts: int = 0
    stopping: bool = False
    pids: list[int] = field(default_factory=list)

    def start(self, forked: Process | None = None) -> None:
        """Start (or restart, with a header in the log) the process; ``forked``: already
        forked by the zygote in a batch."""
        self.log_path.parent.mkdir(parents=True, exist_ok=True)
        with open(self.log_path, 'ab') as log:
            if self.starts:
                log.write(
                    f'\n===== {self.name}: restart {self.starts} at '
                    f'{time.strftime("%H:%M:%S")} =====\n'.encode()
                )
                log.flush()
            if forked is None and self.zygote is not None:
                forked = self.zygote.spawn_all([self])[0]
            if forked is not None:
                self.popen = forked
            else:
                self.popen = subprocess.Popen(
                    dying_with_parent(
                        self.argv
                        if self.netns is None
                        else ['ip', 'netns', 'exec', self.netns, *self.argv]
                    ),
                    stdin=subprocess.DEVNULL,
                    stdout=log,
                    stderr=subprocess.STDOUT,
                    env=dict(self.env) if self.env is not None else None,
                    cwd=self.cwd,
                    start_new_session=True,
                    close_fds=True,
                )
                if self.janitor is not None:
                    self.janitor.watch(self.popen.pid)
        self.starts += 1
        self.stopping = False
        self.pids.append(self.popen.pid)

    @property
    def pid(self) -> int | None:
        return self.popen.pid if self.popen is not None else None

    @property
    def respawns(self) -> int:
        return max(0, self.starts - 1 - self.unseen_restarts)

    def poll(self) -> int | None:
        """The exit code once the process ended (reaped), else None (also when never started)."""
        return self.popen.poll() if self.popen is not None else None

    def signal_group(self, sig: int) -> None:
        """Send ``sig`` to the child's process group (no error if it is gone); a stopped
        (SIGSTOP, Ctrl-Z) process is continued so that it can handle SIGINT / SIGTERM."""
        if self.popen is None:
            return
        try:
            os.killpg(self.popen.pid, sig)
            if sig not in (signal.SIGKILL, signal.SIGCONT):
                os.killpg(self.popen.pid, signal.SIGCONT)
        except ProcessLookupError:
            pass

    def death_report(self, rc: int, n: int = 10) -> str:
        """Multi-line report of an unexpected exit: name, pid, exit code, last log lines."""
        try:
            with open(self.log_path, 'rb') as f:
                f.seek(max(0, f.seek(0, os.SEEK_END) - 16384))
                lines = f.read().decode('utf-8', errors='replace').splitlines()[-n:]
        except OSError:
            lines = []
        head = (
            f'{self.name} (pid {self.pid}) died unexpectedly: {describe_rc(rc)}; '
            f'last {len(lines)} lines of {self.log_path}:'
        )
        return '\n'.join([head] + [f'    | {ln}' for ln in lines])


class ProcessGroup:
    """A set of :class:`Child` processes started, polled and stopped together."""

    def __init__(self, stop_sequence: Sequence[tuple[int, float]] = STOP_SEQUENCE) -> None:
        self.children: list[Child] = []
        self.stop_sequence = tuple(stop_sequence)

    def add(self, child: Child) -> Child:
        if any(c.name == child.name for c in self.children):
            raise ValueError(f'duplicate child name {child.name!r}')
        self.children.append(child)
        return child

    def __iter__(self) -> Iterator[Child]:
        return iter(self.children)

    def start_all(self) -> None:
        """Start every child; those with a zygote forked from it in one batch."""
        forked: list[Process | None] = [None] * len(self.children)
        zygote = next((c.zygote for c in self.children if c.zygote is not None), None)
        if zygote is not None:
            mine = [i for i, c in enumerate(self.children) if c.zygote is zygote]
            batch = zygote.spawn_all([self.children[i] for i in mine])
            for i, f in zip(mine, batch, strict=True):
                forked[i] = f
        for c, f in zip(self.children, forked, strict=True):
            c.start(f)

    def stop_grace(self, select: Callable[[Child], bool] | None = None) -> float:
        """The longest :meth:`stop_all` of the children ``select`` accepts can take [s]: every
        stage's wait plus :data:`STOP_CPU_PER_PROCESS` per process over the cores."""
        n = sum(1 for c in self.children if select is None or select(c))
        if not n:
            return 0.0
        waits = sum(wait_s for _, wait_s in self.stop_sequence)
        return waits + STOP_CPU_PER_PROCESS * n / (os.cpu_count() or 1)

    def poll(self) -> list[tuple[Child, int]]:
        """Children that exited since they were (re)started and were not asked to stop."""
        return [(c, rc) for c in self.children if not c.stopping and (rc := c.poll()) is not None]

    def stop_all(
        self,
        *,
        hurry: Callable[[], int] | None = None,
        select: Callable[[Child], bool] | None = None,
    ) -> dict[str, str]:
        """Stop the running children ``select`` accepts (default all) by the stages of
        :attr:`stop_sequence` (the first :data:`STOP_CPU_PER_PROCESS` per process longer,
        over the cores); a stage ends once each is reaped and its group empty, or when
        ``hurry()`` (a count of signals) grows. ``{name: how}`` in the group's order, ``how``
        ``exited`` (already), the signal name after which it stopped, or ``not stopped``."""

        def stopped(c: Child) -> bool:
            return c.popen is not None and c.poll() is not None and not _group_alive(c.popen.pid)

        chosen = [c for c in self.children if c.popen and (select is None or select(c))]
        for c in chosen:
            c.stopping = True
        how = {c.name: 'exited' for c in chosen if stopped(c)}
        pending = [c for c in chosen if c.name not in how]
        for stage, (sig, wait_s) in enumerate(self.stop_sequence):
            if not pending:
                break
            for c in pending:
                c.signal_group(sig)
            extra = STOP_CPU_PER_PROCESS * len(pending) / (os.cpu_count() or 1) if not stage else 0
            deadline = time.monotonic() + wait_s + extra
            hurried = hurry() if hurry else 0
            while True:
                how.update((c.name, signal.Signals(sig).name) for c in pending if stopped(c))
                pending = [c for c in pending if c.name not in how]
                if not pending or time.monotonic() >= deadline or (hurry and hurry() > hurried):
                    break
                time.sleep(0.02)
        for c in pending:
            how[c.name] = 'not stopped'
        return {c.name: how[c.name] for c in self.children if c.name in how}  # in their order

    def leftovers(self) -> list[tuple[str, int]]:
        """(name, pid) of every live process in a process group this group ever started."""
        return [
            (c.name, member)
            for c in self.children
            for pid in c.pids
            for member in group_members(pid)
        ]


class StopRun(Exception):  # noqa: N818 (a control-flow signal, not an error)
    """Ends the run early with an exit code and a status word."""

    def __init__(self, code: int, status: str, message: str = '') -> None:
        super().__init__(message)
        self.code, self.status, self.message = code, status, message
