"""The workspace's checked habits: ruff (lint and format) and mypy, configured in
pyproject.toml, as ROS 2 packages run their linters from the test suite."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _tool(name: str) -> str:
    found = shutil.which(name, path=str(Path(sys.executable).parent)) or shutil.which(name)
    if found is None:
        pytest.fail(f'{name} is not installed: `make setup` installs it (requirements.txt)')
    return found


@pytest.mark.parametrize(
    'argv',
    [['ruff', 'check', '.'], ['ruff', 'format', '--check', '.'], ['mypy']],
    ids=['ruff-check', 'ruff-format', 'mypy'],
)
def test_the_tree_passes(argv: list[str]) -> None:
    done = subprocess.run(
        [_tool(argv[0]), *argv[1:]], cwd=ROOT, capture_output=True, text=True, timeout=600
    )
    assert done.returncode == 0, f'`{" ".join(argv)}` found problems:\n{done.stdout}{done.stderr}'


def test_the_checks_find_a_planted_problem(tmp_path: Path) -> None:
    # the configuration really selects rules: an unused import and an untyped function fail
    bad = tmp_path / 'bad.py'
    bad.write_text('import os\n\n\ndef f(x):\n    return x\n')
    lint = subprocess.run(
        [_tool('ruff'), 'check', '--config', str(ROOT / 'pyproject.toml'), str(bad)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert lint.returncode == 1 and 'F401' in lint.stdout, lint.stdout
    types = subprocess.run(
        [_tool('mypy'), '--config-file', str(ROOT / 'pyproject.toml'), str(bad)],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert types.returncode == 1 and 'no-untyped-def' in types.stdout, types.stdout
