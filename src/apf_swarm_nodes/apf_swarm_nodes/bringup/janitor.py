"""The janitor: what a killed bring-up cannot do for the nodes it executed (or a secure
run's keys). The bring-up tells it, a line each, every node's pid, ``keys DIR`` and, when it
closes normally, ``"bye"``; an input that ends without it: the janitor removes the keys and
cleans up as the zygote would (:func:`~.zygote.orphaned_cleanup`)."""

from __future__ import annotations

import contextlib
import signal
import subprocess
import sys
from pathlib import Path

import psutil

from .zygote import BYE, close_helper, orphaned_cleanup

__all__ = ['Janitor', 'main']

#: the start of a line that names a directory of host keys (DIR/dds/)
KEYS = 'keys '


class Janitor:
    """The bring-up's handle on its janitor process (see the module docstring)."""

    def __init__(self) -> None:
        self.proc: subprocess.Popen[bytes] | None = subprocess.Popen(
            [sys.executable, '-m', __name__],
            stdin=subprocess.PIPE,
            start_new_session=True,
            close_fds=True,
        )

    def watch(self, pid: int) -> None:
        """A node process this bring-up started: the janitor's if the bring-up dies."""
        self._tell(str(pid))

    def keys(self, directory: Path) -> None:
        """A secure run's host keys (DIR/dds/): removed if the bring-up dies."""
        self._tell(KEYS + str(Path(directory).resolve()))

    def _tell(self, line: str) -> None:
        proc = self.proc
        if proc is None or proc.stdin is None:
            return
        with contextlib.suppress(OSError, ValueError):
            proc.stdin.write(line.encode() + b'\n')
            proc.stdin.flush()

    def close(self) -> None:
        """The bring-up ends normally (it stopped its nodes itself): goodbye."""
        proc, self.proc = self.proc, None
        if proc is not None:
            close_helper(proc, BYE.encode())


def main() -> None:
    """Read the bring-up's lines; without a goodbye, clean up after it."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    watched: list[psutil.Process] = []
    keys: list[Path] = []
    for raw in sys.stdin:
        line = raw.strip()
        if line == BYE:
            return
        if line.startswith(KEYS):
            keys.append(Path(line[len(KEYS) :]))
            continue
        with contextlib.suppress(ValueError, psutil.Error):
            watched.append(psutil.Process(int(line)))
    from ..dds.secure import remove_keys

    for directory in keys:
        remove_keys(directory)
    orphaned_cleanup(watched)


if __name__ == '__main__':
    main()
