"""The sizes a newcomer can read, as floors: the tracker and plant nodes a page each, the
README and the performance reference short, the benches thin, and Python under src/ no
larger than the ratchet in ``SRC_LINES`` (lower it when the code shrinks; raising it needs
the reason in the commit). Lines are counted as ``wc -l`` counts them."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

# the most lines each may have
FLOORS = {
    'src/apf_swarm_nodes/apf_swarm_nodes/tracker_node.py': 200,
    'src/apf_swarm_nodes/apf_swarm_nodes/plant_node.py': 200,
    'README.md': 250,
    'docs/PERFORMANCE.md': 400,
}
BENCH_LINES = 1500
SRC_LINES = 18718


def _lines(path: Path) -> int:
    return len(path.read_bytes().splitlines())


def _python(under: Path) -> list[Path]:
    return sorted(p for p in under.rglob('*.py') if '__pycache__' not in p.parts)


@pytest.mark.parametrize(('name', 'most'), sorted(FLOORS.items()))
def test_a_file_stays_within_its_floor(name: str, most: int) -> None:
    assert _lines(ROOT / name) <= most, f'{name} has more than {most} lines'


def test_the_benches_stay_thin() -> None:
    total = sum(_lines(p) for p in _python(ROOT / 'bench'))
    assert total <= BENCH_LINES, f'bench/ has {total} lines of Python, more than {BENCH_LINES}'


def test_python_under_src_does_not_grow_past_its_ratchet() -> None:
    total = sum(_lines(p) for p in _python(ROOT / 'src'))
    assert total <= SRC_LINES, (
        f'src/ has {total} lines of Python, more than the ratchet {SRC_LINES}: '
        'make room in the same change, or raise SRC_LINES in test/test_house.py with the reason'
    )


def test_no_not_implemented_stub_under_src() -> None:
    stubs = []
    for path in _python(ROOT / 'src'):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Raise) and 'NotImplementedError' in ast.unparse(node):
                stubs.append(f'{path.relative_to(ROOT)}:{node.lineno}')
    assert not stubs, f'NotImplementedError stubs (use abc.abstractmethod): {stubs}'
