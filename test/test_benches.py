"""Every benchmark script answers ``--help`` at once: exit 0, usage on stdout, nothing else,
nothing started (their ``--smoke`` runs are CI's, `.ci/run`: ``bench/run_all.py --smoke``)."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCRIPTS = sorted(p for p in (ROOT / 'bench').glob('*.py') if not p.name.startswith('_'))


def test_every_script_is_found() -> None:
    names = {p.name for p in SCRIPTS}
    assert {'run_all.py', 'bench_control.py', 'bench_bags.py', 'bench_graph.py'} <= names


@pytest.mark.parametrize('script', SCRIPTS, ids=[p.stem for p in SCRIPTS])
def test_help_exits_0_and_prints_usage_only(script: Path) -> None:
    t0 = time.monotonic()
    p = subprocess.run(
        [sys.executable, str(script), '--help'],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=ROOT,
    )
    assert p.returncode == 0, p.stderr
    assert p.stdout.startswith('usage: '), p.stdout[:200]
    assert p.stderr == ''
    assert '--smoke' in p.stdout  # every benchmark has a smoke mode (run_all passes it on)
    assert time.monotonic() - t0 < 30  # a --help that starts a run would take longer
