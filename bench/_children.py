"""What every benchmark that starts processes does so that none outlives it: each child dies
with the benchmark (:func:`apf_swarm_nodes.lifetime.dying_with_parent`: the kernel's
parent-death signal, even when the benchmark is killed with SIGKILL), and SIGTERM / SIGHUP
end the benchmark through its ``finally`` blocks, which stop the children it started."""

from __future__ import annotations

import argparse
import signal
import sys
from typing import Any

from apf_swarm_nodes.lifetime import dying_with_parent

__all__ = ['dying_with_parent', 'exit_on_signals']


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
