"""What every benchmark that starts processes does so that none outlives it: each child dies
with the benchmark (``setpriv --pdeathsig KILL``: the kernel's parent-death signal, even when
the benchmark is killed with SIGKILL; no ``preexec_fn``, which is unsafe in a process with
threads, as rclpy's), and SIGTERM / SIGHUP end the benchmark through its ``finally`` blocks,
which stop the children they started (a timeout's SIGTERM used to leave a recorder
running)."""

from __future__ import annotations

import argparse
import shutil
import signal
import sys
from collections.abc import Sequence
from typing import Any

__all__ = ['dying_with_parent', 'exit_on_signals']


def dying_with_parent(argv: Sequence[str], sig: str = 'KILL') -> list[str]:
    """``argv`` run so that it gets ``sig`` (default SIGKILL; ``'TERM'`` lets a benchmark
    unwind through its ``finally`` blocks) when the process that started it ends (Linux,
    util-linux ``setpriv``; unchanged where there is none)."""
    setpriv = shutil.which('setpriv')
    return [setpriv, '--pdeathsig', sig, '--', *argv] if setpriv else list(argv)


def exit_on_signals() -> None:
    """SIGTERM and SIGHUP raise SystemExit in the main thread (exit status 128 + signal),
    so that ``finally`` blocks stop what the benchmark started."""

    def handler(signum: int, _frame: Any) -> None:
        raise SystemExit(128 + signum)

    for sig in (signal.SIGTERM, signal.SIGHUP):
        signal.signal(sig, handler)


if __name__ == '__main__':
    argparse.ArgumentParser(
        description='A module of the benchmarks (imported by them), not a benchmark: '
        'it has nothing to run.'
    ).parse_args()
    sys.exit('bench/_children.py is a module of the benchmarks, not a benchmark')
