"""The capacity probe (apf_swarm_nodes.capacity: probe and measure): a real ping-pong between
two rclpy processes, cached; and what follows from a probe (ROS-free)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
from pathlib import Path

import pytest
from apf_swarm_nodes.bringup import pick_domain_id
from apf_swarm_nodes.capacity import measure as probe_measure
from apf_swarm_nodes.capacity import probe
from apf_swarm_nodes.capacity.machine import identity

APF = shutil.which('apf-swarm')


def test_probe_measures_caches_and_rereads(tmp_path: Path) -> None:
    assert APF is not None, 'apf-swarm is not on PATH: source scripts/activate.sh'
    env = {
        **os.environ,
        'APF_SWARM_CACHE': str(tmp_path),
        'ROS_DOMAIN_ID': str(pick_domain_id(lo=102, hi=201)),
        'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST',
    }
    first = subprocess.run(
        [APF, 'probe', '--json', '--n-trackers', '16'],
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert first.returncode == 0, first.stderr
    assert 'measuring this machine' in first.stderr
    doc = json.loads(first.stdout)
    p, d = doc['probe'], doc['derived']
    # a round trip over DDS on one machine: more than the wire, less than a control period
    assert 0.0 < p['rtt']['p50'] <= p['rtt']['p90'] <= p['rtt']['p99'] < 0.1
    assert p['round_trips'] >= 0.8 * p['messages'] > 0  # best effort, on loopback
    assert 0.0 < p['cpu_per_message'] < 0.01
    # one command cost per size, each well under a control period (no ordering by size:
    # that would be a timed assertion between close figures)
    assert sorted(p['state_cost'], key=int) == [str(k) for k in probe_measure.COMMAND_SIZES]
    assert all(0.0 < c < 0.01 for c in p['state_cost'].values()), p['state_cost']
    assert d['latency'] > p['rtt']['p90'] and d['rate'] in probe.RATES
    # an rclpy node process holds tens of MiB: more than the interpreter, less than a GiB
    assert 20 * 2**20 < p['process_rss'] < 2**30, p['process_rss']
    lim = doc['process_limit']
    assert lim['processes'] == max(1, min(lim['cpu'], lim['memory'])) >= 1
    cached = json.loads((tmp_path / 'probe.json').read_text())
    assert cached['machine'] == identity() and cached['rtt'] == p['rtt']
    again = subprocess.run(
        [APF, 'probe', '--json'], env=env, capture_output=True, text=True, timeout=60
    )
    assert again.returncode == 0 and 'measuring' not in again.stderr
    assert json.loads(again.stdout)['probe'] == p


def _probe(cpu_per_message: float, cost16: float, cores: int = 2) -> dict:
    return {
        'machine': {'cpu': 'x', 'cores': cores, 'host': 'h'},
        'cpu_per_message': cpu_per_message,
        'rtt': {'p50': 0.001, 'p90': 0.002, 'p99': 0.004},
        'state_cost': {'3': cost16 / 4, '16': cost16, '32': 4 * cost16},
        'state_cost_p99': {'3': cost16 / 2, '16': 2 * cost16, '32': 8 * cost16},
        'process_rss': 60 * 2**20,
    }


def test_the_process_limit_is_the_smaller_of_cpu_at_the_lowest_rate_and_memory() -> None:
    p = _probe(50e-6, 200e-6)
    # one tracker per process at 20 Hz: 3 messages and a 3-tracker command (cost16 / 4)
    cpu = int(0.5 * 2 / (20 * (3 * 50e-6 + 50e-6)))
    lim = probe.process_limit(p, available=64 * 2**30)
    assert lim == {'processes': cpu, 'cpu': cpu, 'memory': int(0.5 * 64 * 1024 / 60)}
    small = probe.process_limit(p, available=3 * 2**30)  # 1.5 GiB for 60 MiB each
    assert small['processes'] == small['memory'] == 25
    assert probe.process_limit(p, available=0)['processes'] == 1


def test_derive_scales_capacity_with_the_cost_and_picks_the_highest_rate_that_fits() -> None:
    fast, slow = probe.derive(_probe(50e-6, 200e-6), 16), probe.derive(_probe(100e-6, 400e-6), 16)
    # per tracker and period: 3 messages and a command; 50 % of 2 cores
    assert fast['capacity']['100'] == int(0.5 * 2 / (100 * (3 * 50e-6 + 200e-6)))
    assert slow['capacity']['100'] == fast['capacity']['100'] // 2
    assert fast['rate'] == 100.0 and slow['rate'] == 50.0
    use = 16 * 100 * (3 * 50e-6 + 200e-6) / 2
    assert fast['utilization'] == pytest.approx(use, abs=1e-3)
    # the round trip's p90 and the longer of the command's p99 (2 x its mean in this probe)
    # and the swarm's burst: the 16 trackers' work shared by the 2 cores
    burst = 16 * (3 * 50e-6 + 200e-6) / 2
    assert burst > 400e-6
    assert fast['latency'] == pytest.approx((0.002 + burst) / (1 - use), rel=1e-3)
    assert probe.derive(_probe(50e-6, 200e-6), 16, 20.0)['rate'] == 20.0


def test_a_probe_of_another_machine_is_not_used(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setenv('APF_SWARM_CACHE', str(tmp_path))
    (tmp_path / 'probe.json').write_text(json.dumps(_probe(50e-6, 200e-6)))
    assert probe.load() is None
    (tmp_path / 'probe.json').write_text('{not json')
    assert probe.load() is None
    # a probe of this machine without a field of this version is measured again
    mine = {**_probe(50e-6, 200e-6), 'machine': identity()}
    (tmp_path / 'probe.json').write_text(json.dumps(mine))
    assert probe.load() == mine
    del mine['process_rss']
    (tmp_path / 'probe.json').write_text(json.dumps(mine))
    assert probe.load() is None
