"""Processes that end: a child that dies with the process that started it (even a SIGKILLed
one), one stopped by a sequence of signals to its process group, and how an exit code
reads. Used by the bring-up, the capacity probe and the benchmarks."""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import subprocess
from collections.abc import Sequence
from typing import Protocol

__all__ = ['STOP_CPU_PER_PROCESS', 'Process', 'describe_rc', 'dying_with_parent', 'stop_process']

#: CPU seconds a node takes to leave DDS after SIGINT: the first stage of a stop waits this
#: much longer per process still running, shared over the cores, so that a loaded machine
#: does not turn a stop into SIGKILLs
STOP_CPU_PER_PROCESS = 0.3


class Process(Protocol):
    """What supervision needs of a started process: a :class:`subprocess.Popen`, or a
    :class:`~.bringup.zygote.ForkedProcess`."""

    pid: int

    def poll(self) -> int | None: ...

    def wait(self, timeout: float | None = None) -> int: ...


def describe_rc(rc: int) -> str:
    if rc < 0:
        try:
            return f'killed by {signal.Signals(-rc).name}'
        except ValueError:
            return f'killed by signal {-rc}'
    return f'exit code {rc}'


def dying_with_parent(argv: Sequence[str], sig: str = 'KILL') -> list[str]:
    """``argv`` run so that it gets SIGKILL (or ``sig``) when the process that started it
    dies, even by SIGKILL: util-linux ``setpriv --pdeathsig`` (no ``preexec_fn``, unsafe in a
    process with DDS threads); unchanged where there is no setpriv. SIGKILL, as with the
    bring-up gone nothing would escalate a SIGINT a busy node missed (the shared memory it
    leaves is removed later); ``INT`` for a process whose own stop is bounded (the probe's)."""
    setpriv = shutil.which('setpriv')
    return [setpriv, '--pdeathsig', sig, '--', *argv] if setpriv else list(argv)


def stop_process(
    popen: Process,
    sequence: Sequence[tuple[int, float]] = ((signal.SIGINT, 30.0), (signal.SIGKILL, 5.0)),
) -> int | None:
    """Stop one process started with ``start_new_session=True``: each signal of ``sequence``
    to its process group, then wait at most that many seconds, until it has exited. Returns
    its exit code (None if it outlived every signal). :meth:`ProcessGroup.stop_all` does the
    same for a whole graph, and also waits for every member of each group."""
    for sig, wait_s in sequence:
        if popen.poll() is not None:
            break
        with contextlib.suppress(ProcessLookupError):
            os.killpg(popen.pid, sig)
        try:
            popen.wait(wait_s)
        except subprocess.TimeoutExpired:
            continue
    return popen.poll()
