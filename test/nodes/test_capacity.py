"""The bring-up's tracker process limit (bringup.check_capacity) from a probe, without ROS."""

from __future__ import annotations

import pytest
from apf_swarm_nodes.bringup.errors import BringupError
from apf_swarm_nodes.capacity import probe

from apf_swarm_nodes import bringup

PROBE = {
    'machine': {'cpu': 'x', 'cores': 2, 'host': 'h'},
    'cpu_per_message': 50e-6,
    'rtt': {'p50': 0.001, 'p90': 0.002, 'p99': 0.004},
    'state_cost': {'3': 50e-6, '16': 200e-6, '32': 800e-6},
    'process_rss': 60 * 2**20,
}


@pytest.fixture
def limit(monkeypatch) -> int:
    monkeypatch.setattr(probe, 'ensure', lambda refresh=False, say=None: PROBE)
    return probe.process_limit(PROBE)['processes']


def test_processes_past_the_probe_limit_are_refused_naming_it(limit) -> None:
    bringup.check_capacity(limit)
    with pytest.raises(BringupError, match=rf'{limit + 1} processes .* allows {limit} tracker'):
        bringup.check_capacity(limit + 1)
    bringup.check_capacity(4 * limit, per_process=4)  # 4 to a process: the limit
    with pytest.raises(BringupError, match='--trackers-per-process K'):
        bringup.check_capacity(4 * limit + 1, per_process=4)
    bringup.check_capacity(10 * limit, allow_overload=True)


def test_without_a_probe_nothing_is_refused_with_a_warning(monkeypatch) -> None:
    def fail(refresh=False, say=None):
        raise RuntimeError('the capacity probe failed (exit 1)')

    monkeypatch.setattr(probe, 'ensure', fail)
    said: list[str] = []
    bringup.check_capacity(10_000, say=said.append)
    assert len(said) == 1 and 'no' in said[0] and 'probe failed' in said[0]


def test_the_trackers_per_process_default_follows_the_cores_and_the_period() -> None:
    # about PROCESSES_PER_CORE processes per core: 2 cores, 8 processes
    assert probe.trackers_per_process(PROBE, 3) == 1
    assert probe.trackers_per_process(PROBE, 8) == 1
    assert probe.trackers_per_process(PROBE, 64) == 8
    # no more commands in one process than half a period at their p99 (this probe has no
    # p99: its mean): at 128 trackers 3.2 ms a command (linear past 32) and 2 x 50 us of
    # messages, so 7 in the 25 ms of half a period at 20 Hz, 1 at 100 Hz
    assert probe.trackers_per_process(PROBE, 128) == 7
    assert probe.trackers_per_process(PROBE, 128, rate=100.0) == 1
    # without a probe, the cores alone
    assert probe.trackers_per_process(None, 3) == 1


def test_derive_counts_the_shared_state_once_per_process_and_the_tail() -> None:
    tails = {**PROBE, 'state_cost_p99': {'3': 100e-6, '16': 400e-6, '32': 1600e-6}}
    one = probe.derive(tails, 32, 50.0, per_process=1)
    eight = probe.derive(tails, 32, 50.0, per_process=8)
    assert one['per_tracker_cpu'] == pytest.approx(3 * 50e-6 + 800e-6, rel=1e-4)
    assert eight['per_tracker_cpu'] == pytest.approx(50e-6 / 8 + 2 * 50e-6 + 800e-6, rel=1e-4)
    assert eight['capacity']['50'] >= one['capacity']['50']
    # the latency a process of 8 adds: its 8 commands at the p99, or the swarm's burst of
    # work on the 2 cores when that is longer
    each = 50e-6 / 8 + 2 * 50e-6 + 800e-6
    use = 32 * 50.0 * each / 2
    longer = max(8 * 1600e-6, 32 * each / 2)
    assert eight['latency'] == pytest.approx((0.002 + longer) / (1 - use), rel=1e-4)
    slow = probe.derive(tails, 8, 50.0, per_process=8)
    tail8 = 8 * probe._state_cost_at(tails, 8, 'state_cost_p99')
    assert tail8 > 8 * slow['per_tracker_cpu'] / 2  # here the process's commands are longer
    assert slow['latency'] == pytest.approx((0.002 + tail8) / (1 - slow['utilization']), rel=1e-3)
    cheap = {**tails, 'state_cost_p99': {'3': 10e-6, '16': 10e-6, '32': 10e-6}}
    burst = probe.derive(cheap, 32, 50.0, per_process=8)['latency']
    assert burst == pytest.approx((0.002 + 32 * each / 2) / (1 - use), rel=1e-4)
    # beyond the measured sizes the cost grows linearly (the block direction)
    assert probe.derive(tails, 64, 50.0)['per_tracker_cpu'] == pytest.approx(3 * 50e-6 + 1600e-6)


def test_the_largest_swarm_is_the_last_size_that_fits() -> None:
    most = probe.largest_swarm(PROBE)
    assert most >= 1

    def fits(n: int) -> bool:
        k = probe.trackers_per_process(PROBE, n, 20.0)
        return probe.derive(PROBE, n, 20.0, k)['capacity']['20'] >= n

    assert fits(most) and not fits(most + 1)
    # a faster rate carries fewer; a rate below the probe's lowest (a run's --rate 10), more
    assert probe.largest_swarm(PROBE, 100.0) < most < probe.largest_swarm(PROBE, 10.0)
    assert set(probe.derive(PROBE, 8, 10.0)['capacity']) == {'100', '50', '20', '10'}
    slow = {**PROBE, 'cpu_per_message': 1.0}
    assert probe.largest_swarm(slow) == 0
