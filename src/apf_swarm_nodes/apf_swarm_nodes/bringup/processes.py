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

if TYPE_CHECKING:
    from .janitor import Janitor
    from .zygote import Spawn, Zygote

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
    """One supervised OS process: its own process group, output appended to ``log_path``.

    With a ``zygote``, a node executable of the package is forked from it (the same
    ``main()``, argv, environment and log; see :mod:`.zygote`), else executed. ``netns``: the
    network namespace it runs in (a simulated host; root): the forked process enters it, an
    executed one runs under ``ip netns exec``."""

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
        """Start (or restart) the process; the log is appended to, with a header on restarts.
        ``forked``: the process, already forked by the zygote in a batch."""
        self.log_path.parent.mkdir(parents=True, exist_ok=True)
        with open(self.log_path, 'ab') as log:
            if self.starts:
                log.write(
                    f'\n===== {self.name}: restart {self.starts} at '
                    f'{time.strftime("%H:%M:%S")} =====\n'.encode()
                )
                log.flush()
        if forked is None and self.zygote is not None:
            forked = self.zygote.spawn_all([self.spawn()])[0]
        if forked is not None:
            self.popen = forked
        else:
            with open(self.log_path, 'ab') as log:
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

    def spawn(self) -> Spawn:
        """What the zygote forks for this process."""
        from .zygote import Spawn

        return Spawn(self.argv, self.log_path, self.env, self.cwd, self.netns)

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
            batch = zygote.spawn_all([self.children[i].spawn() for i in mine])
            for i, f in zip(mine, batch, strict=True):
                forked[i] = f
        for c, f in zip(self.children, forked, strict=True):
            c.start(f)

    def stop_grace(self, select: Callable[[Child], bool] | None = None) -> float:
        """The longest :meth:`stop_all` of the children ``select`` accepts (all by
        default) can take: every stage's wait, and the first stage's
        :data:`STOP_CPU_PER_PROCESS` per process, shared over the cores; 0 without any."""
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
        poll_interval: float = 0.02,
        select: Callable[[Child], bool] | None = None,
    ) -> dict[str, str]:
        """Stop every running child: SIGINT to each group, wait, SIGTERM, wait, SIGKILL.

        A child counts as stopped when its process has exited (and is reaped) and its process
        group has no member left. Each stage waits at most its time in :attr:`stop_sequence`
        and ends early once every child is stopped, or when ``hurry()`` (a counter, e.g. of
        signals received) grows: each further Ctrl-C moves on to the next stage at once.
        Returns ``{name: how}`` in the group's order, ``how`` one of
        ``exited`` (had already ended), ``SIGINT``, ``SIGTERM``, ``SIGKILL`` (the signal after
        which it stopped) or ``not stopped`` (should never happen; see :meth:`leftovers`).
        ``select``: only the children it accepts (the bring-up stops the trackers first).
        The first stage waits :data:`STOP_CPU_PER_PROCESS` more per process still running,
        shared over the cores.
        """

        def stopped(c: Child) -> bool:
            return c.popen is not None and c.poll() is not None and not _group_alive(c.popen.pid)

        how: dict[str, str] = {}
        pending = []
        for c in self.children:
            if c.popen is None or (select is not None and not select(c)):
                continue
            c.stopping = True
            if stopped(c):
                how[c.name] = 'exited'
            else:
                pending.append(c)
        for stage, (sig, wait_s) in enumerate(self.stop_sequence):
            if not pending:
                break
            for c in pending:
                c.signal_group(sig)
            extra = STOP_CPU_PER_PROCESS * len(pending) / (os.cpu_count() or 1) if not stage else 0
            deadline = time.monotonic() + wait_s + extra
            hurried = hurry() if hurry else 0
            while pending:
                still = []
                for c in pending:
                    if stopped(c):
                        how[c.name] = signal.Signals(sig).name
                    else:
                        still.append(c)
                pending = still
                if not pending or time.monotonic() >= deadline:
                    break
                if hurry is not None and hurry() > hurried:
                    break
                time.sleep(poll_interval)
        for c in pending:
            how[c.name] = 'not stopped'
        return {c.name: how[c.name] for c in self.children if c.name in how}  # in their order

    def leftovers(self) -> list[tuple[str, int]]:
        """(name, pid) of every live process in a process group this group ever started
        (each start is a new session: process group id = the child's pid); empty when clean."""
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
