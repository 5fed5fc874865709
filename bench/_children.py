"""What every benchmark that starts processes uses so that none outlives it: children die
with the benchmark (:func:`apf_swarm_nodes.lifetime.dying_with_parent`) and are stopped by
process group (:func:`apf_swarm_nodes.lifetime.stop_process`); SIGTERM / SIGHUP end the
benchmark through its ``finally`` blocks. A module, not a benchmark."""

from __future__ import annotations

import signal
import subprocess
from typing import Any

from apf_swarm_nodes.lifetime import dying_with_parent, stop_process

__all__ = ['dying_with_parent', 'exit_on_signals', 'start', 'stop', 'table']


def exit_on_signals() -> None:
    """SIGTERM and SIGHUP raise SystemExit (128 + signal), so ``finally`` blocks run."""

    def handler(signum: int, _frame: Any) -> None:
        raise SystemExit(128 + signum)

    for sig in (signal.SIGTERM, signal.SIGHUP):
        signal.signal(sig, handler)


def start(argv: list[str], sig: str = 'TERM', **kw: Any) -> subprocess.Popen[bytes]:
    """``argv`` in its own session, dying with this process."""
    return subprocess.Popen(dying_with_parent(argv, sig), start_new_session=True, **kw)


def stop(p: subprocess.Popen[bytes], grace: float = 30.0) -> int | None:
    """SIGINT to its group, SIGTERM, then SIGKILL; its exit code (None if it outlived all)."""
    seq = ((signal.SIGINT, grace), (signal.SIGTERM, 5.0), (signal.SIGKILL, 5.0))
    return stop_process(p, seq)


def table(header: str, rows: list[list[Any]]) -> str:
    """A Markdown table: ``header`` is 'a | b | c' (a trailing ':' right-aligns)."""
    cols = [c.strip() for c in header.split('|')]
    head = '| ' + ' | '.join(c.rstrip(':') for c in cols) + ' |'
    rule = '|' + '|'.join('---:' if c.endswith(':') else '---' for c in cols) + '|'
    body = ['| ' + ' | '.join(str(v) for v in r) + ' |' for r in rows]
    return '\n'.join([head, rule, *body])
