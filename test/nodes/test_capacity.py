"""The bring-up's tracker process limit (bringup.check_capacity) from a probe, without ROS."""

from __future__ import annotations

import pytest
from apf_swarm_nodes.errors import CliError

from apf_swarm_nodes import bringup, probe

PROBE = {
    'machine': {'cpu': 'x', 'cores': 2, 'host': 'h'},
    'cpu_per_message': 50e-6,
    'rtt': {'p50': 0.001, 'p90': 0.002, 'p99': 0.004},
    'command_cost': {'3': 50e-6, '16': 200e-6, '32': 800e-6},
    'process_rss': 60 * 2**20,
}


@pytest.fixture
def limit(monkeypatch) -> int:
    monkeypatch.setattr(probe, 'ensure', lambda refresh=False, say=None: PROBE)
    return probe.process_limit(PROBE)['processes']


def test_processes_past_the_probe_limit_are_refused_naming_it(limit) -> None:
    bringup.check_capacity(limit)
    with pytest.raises(CliError, match=rf'{limit + 1} processes .* allows {limit} tracker'):
        bringup.check_capacity(limit + 1)
    bringup.check_capacity(4 * limit, per_process=4)  # 4 to a process: the limit
    with pytest.raises(CliError, match='--trackers-per-process K'):
        bringup.check_capacity(4 * limit + 1, per_process=4)
    bringup.check_capacity(10 * limit, allow_overload=True)


def test_without_a_probe_nothing_is_refused_with_a_warning(monkeypatch) -> None:
    def fail(refresh=False, say=None):
        raise RuntimeError('the capacity probe failed (exit 1)')

    monkeypatch.setattr(probe, 'ensure', fail)
    said: list[str] = []
    bringup.check_capacity(10_000, say=said.append)
    assert len(said) == 1 and 'no' in said[0] and 'probe failed' in said[0]
