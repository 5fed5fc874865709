"""What the benchmarks share (a module, not a benchmark): children that die with the benchmark,
stopped by process group (:mod:`apf_swarm_nodes.lifetime`), SIGTERM / SIGHUP that end it through
its ``finally`` blocks, the ``swarm_up.py`` command, the log line, timing, tables."""

import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from apf_swarm_nodes.lifetime import dying_with_parent, stop_process

ROOT = Path(__file__).resolve().parents[1]


def exit_on_signals() -> None:
    """SIGTERM and SIGHUP raise SystemExit (128 + signal), so ``finally`` blocks run."""
    for sig in (signal.SIGTERM, signal.SIGHUP):
        signal.signal(sig, lambda signum, _frame: sys.exit(128 + signum))


def start(argv: list[str], sig: str = 'TERM', **kw: Any) -> subprocess.Popen[bytes]:
    """``argv`` in its own session, dying with this process."""
    return subprocess.Popen(dying_with_parent(argv, sig), start_new_session=True, **kw)


def stop(p: subprocess.Popen[bytes], grace: float = 30.0) -> int | None:
    """SIGINT to its group, SIGTERM, then SIGKILL; its exit code (None if it outlived all)."""
    return stop_process(p, ((signal.SIGINT, grace), (signal.SIGTERM, 5.0), (signal.SIGKILL, 5.0)))


def swarm_up(*args: Any) -> list[str]:
    """The bring-up, ``scripts/swarm_up.py``, without plots: ``args`` as strings."""
    return [sys.executable, str(ROOT / 'scripts' / 'swarm_up.py'), '--no-plots', *map(str, args)]


def log(msg: str) -> None:
    """A progress line on stderr, after the benchmark's name."""
    print(f'{Path(sys.argv[0]).stem}: {msg}', file=sys.stderr, flush=True)


def timed(f: Callable[..., Any], *args: Any, **kw: Any) -> float:
    """Wall seconds of ``f(*args, **kw)``."""
    t0 = time.perf_counter()
    f(*args, **kw)
    return time.perf_counter() - t0


def table(header: str, rows: list[list[Any]]) -> str:
    """A Markdown table: ``header`` is 'a | b | c' (a trailing ':' right-aligns)."""
    cols = [c.strip() for c in header.split('|')]
    head = '| ' + ' | '.join(c.rstrip(':') for c in cols) + ' |'
    rule = '|' + '|'.join('---:' if c.endswith(':') else '---' for c in cols) + '|'
    body = ['| ' + ' | '.join(str(v) for v in r) + ' |' for r in rows]
    return '\n'.join([head, rule, *body])
