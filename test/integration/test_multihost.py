"""The swarm across simulated hosts (scripts/multihost.py): network namespaces joined by veth
pairs; secure (TCP with TLS, the default) or open (--open: UDP only, multicast discovery or
the Fast DDS discovery server). Skipped, with the
reason, on a machine without root or iproute2."""

from __future__ import annotations

import importlib.util
import json
import math
import subprocess
import sys
from itertools import combinations
from pathlib import Path

import numpy as np
import pytest
from apf_swarm_core.config_files import load_config
from apf_swarm_core.simulator import simulate
from apf_swarm_nodes.bringup import pick_domain_id

ROOT = Path(__file__).resolve().parents[2]
SCRIPT = ROOT / 'scripts' / 'multihost.py'
_spec = importlib.util.spec_from_file_location('multihost', SCRIPT)
multihost = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(multihost)

REASON = multihost.unavailable()
pytestmark = pytest.mark.skipif(REASON is not None, reason=f'simulated hosts: {REASON}')


def run_lab(out: Path, *args: str) -> tuple[subprocess.CompletedProcess, dict]:
    for _ in range(2):
        p = _run_lab(out, *args)
        # a secure run whose graph never completed (Fast DDS 2.14's TCP: a node connected
        # to the discovery server but never discovered; docs/RELIABILITY.md) runs again,
        # once: a known upstream fault, not what these tests are about
        if '--open' in args or p.returncode != 2 or 'graph was not complete' not in p.stderr:
            break
    assert p.returncode == 0, p.stdout[-3000:] + p.stderr[-3000:]
    return p, json.loads((out / 'multihost.json').read_text())


def _run_lab(out: Path, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [
            sys.executable,
            str(SCRIPT),
            '--hosts',
            '3',
            '--out',
            str(out),
            '--domain-id',
            str(pick_domain_id(lo=102, hi=201)),
            *args,
        ],
        capture_output=True,
        text=True,
        timeout=240,
        cwd=ROOT,
    )


def no_namespaces_left(tag_text: str) -> bool:
    listed = subprocess.run(['ip', 'netns', 'list'], capture_output=True, text=True).stdout
    return tag_text not in listed


@pytest.mark.parametrize('transport', ['open', 'secure'])
def test_three_hosts_lockstep_equals_the_simulator(tmp_path: Path, transport: str) -> None:
    """Plant and target on host 1, trackers on hosts 2 and 3; open: UDP, multicast discovery
    on the lab's subnet; secure (the default): TCP with TLS, the bring-up's discovery
    server. Either lockstep run equals the headless simulator exactly."""
    out = tmp_path / 'mc'
    p, result = run_lab(
        out, '--n-trackers', '3', '--duration', '1.5', *(['--open'] if transport == 'open' else [])
    )
    assert result['secure'] == (transport == 'secure')
    assert result['discovery'] == ('multicast' if transport == 'open' else 'server')
    hosts = {h['host']: h for h in result['hosts']}
    assert hosts[1]['runs'] == 'plant, target, bring-up' and hosts[1]['processes'] == 2
    assert hosts[2]['runs'] == 'tracker_1, tracker_3' and hosts[2]['processes'] == 2
    assert hosts[3]['runs'] == 'tracker_2' and hosts[3]['processes'] == 1
    assert all(h['cpu_pct'] > 0 for h in hosts.values())
    assert len({h['address'] for h in hosts.values()}) == 3
    cfg = load_config(out / 'config.yaml')
    sim = simulate(cfg).trajectory
    with np.load(out / 'trajectory.npz') as data:
        assert data['x'].shape == (1500, 3, 3)
        assert np.max(np.abs(data['x'] - sim['x'])) <= 1e-9
    summary = json.loads((out / 'summary.json').read_text())
    assert summary['missed_deadlines'] == 0 and summary['rejected_inputs'] == 0
    assert '| 3 |' in p.stdout and 'CPU' in p.stdout
    assert no_namespaces_left(hosts[1]['netns'])


def test_three_hosts_discovery_server_realtime_forms_the_triangle(tmp_path: Path) -> None:
    """The Fast DDS discovery server on host 1, realtime: the triangle forms across hosts."""
    out = tmp_path / 'ds'
    _, result = run_lab(
        out,
        '--n-trackers',
        '3',
        '--mode',
        'realtime',
        '--duration',
        '16',
        '--discovery',
        'server',
        '--open',
    )
    assert result['discovery'] == 'server'
    cfg = load_config(out / 'config.yaml')
    d = math.sqrt(cfg.c * math.log(cfg.b / (cfg.a + cfg.k_n / (3 * cfg.k_f))))
    with np.load(out / 'trajectory.npz') as data:
        t, x = data['t'], data['x']
    # measured on an idle machine: the triangle is within 0.3 % from t = 6 s on; the last
    # 4 s leave room for a slow start on a loaded one
    x = x[t >= 12.0]
    assert len(x) > 100
    pairs = np.stack(
        [np.linalg.norm(x[:, i] - x[:, j], axis=-1) for i, j in combinations(range(3), 2)]
    )
    # realtime on a loaded 2-core machine: 90 % of the samples (see test_bringup.within)
    summary = json.loads((out / 'summary.json').read_text())
    assert np.quantile(np.abs(pairs - d).max(axis=0), 0.9) <= 0.05 * d, (
        pairs.min(),
        pairs.max(),
        d,
        {
            k: summary.get(k)
            for k in ('missed_deadlines', 'stale_inputs', 'rejected_inputs', 'faults', 'timing')
        },
    )
    # judged by flight over the last 40 %, next to the headless emulation with the latencies
    # measured across the hosts
    assert summary['flight_check']['run']['flies'], summary['flight_check']['run']
    assert summary['flight_check']['emulation']['flies']
    assert no_namespaces_left(result['hosts'][0]['netns'])
