"""The soak benchmark (bench/soak.py) in its short form: a 15 s realtime run, sampled."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from apf_swarm_nodes.bringup import pick_domain_id

ROOT = Path(__file__).resolve().parents[2]


def test_short_soak_reports_every_node_and_no_memory_growth(tmp_path: Path) -> None:
    out = tmp_path / 'soak'
    p = subprocess.run(
        [
            sys.executable,
            str(ROOT / 'bench' / 'soak.py'),
            '--duration',
            '15',
            '--every',
            '0.5',
            '--out',
            str(out),
            '--domain-id',
            str(pick_domain_id(lo=102, hi=201)),
        ],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=ROOT,
    )
    assert p.returncode == 0, p.stdout + p.stderr
    result = json.loads((out / 'soak.json').read_text())
    nodes = {r['node']: r for r in result['nodes']}
    assert set(nodes) == {'plant', 'target', 'tracker_1', 'tracker_2', 'tracker_3'}
    for r in nodes.values():
        assert r['samples'] >= 20
        assert 40 < r['rss_after_warmup_mb'] < 400  # an rclpy process, not a stray
        # a leak grows; a resident set that shrinks (pages reclaimed under load) is none
        assert r['growth_pct'] < 5.0, r
        assert 0 < r['cpu_pct'] < 100
    run = result['run']
    assert run['bringup_exit'] == 0 and run['status'] == 'completed'
    assert run['missed_deadlines'] == 0 and run['dropped'] == 0
    assert '| tracker_2 |' in p.stdout and 'pass' in p.stdout
    assert (out / 'soak_rss.png').stat().st_size > 10_000
    assert (out / 'soak.csv').read_text().count('\n') > 100
