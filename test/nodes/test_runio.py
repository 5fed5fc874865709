"""Run outputs without ROS: the fault report of summary.json (runio.fault_report) and when
the accumulated /swarm/state is complete (bringup.StateAccumulator)."""

from __future__ import annotations

import numpy as np
from apf_swarm_nodes.analysis.runio import TARGET_SILENT_AGE, fault_report


def test_inactive_trackers_and_a_silent_target_become_spans_with_warnings() -> None:
    t = np.arange(10) * 0.1
    active = np.ones((10, 3), dtype=bool)
    active[3:6, 1] = False  # uav_2 inactive from 0.3 to 0.5 s
    age = np.zeros(10)
    age[7:] = TARGET_SILENT_AGE * 2  # target silent from 0.7 s to the end
    faults, warnings = fault_report(t, active, age)
    assert faults['inactive'] == {'uav_2': [[0.3, 0.5]]}
    assert faults['target_silent'] == [[0.7, 0.9]]
    assert faults['target_age_max'] == TARGET_SILENT_AGE * 2
    assert faults['stale'] == []
    assert len(warnings) == 2 and 'uav_2' in warnings[0] and 'silent' in warnings[1]


def test_stale_brakes_during_the_flight_are_a_warning() -> None:
    t = np.arange(10) * 0.1
    count = np.array([0, 0, 0, 0, 3, 6, 6, 6, 7, 7])
    faults, warnings = fault_report(t, None, None, count)
    assert faults['stale'] == [[0.4, 0.5], [0.8, 0.8]]
    assert len(warnings) == 1
    assert '2 time(s)' in warnings[0] and 't = 0.4' in warnings[0] and '7 stale' in warnings[0]


def test_a_realtime_run_is_complete_with_the_plants_final_state() -> None:
    """Lockstep ends with step ``steps - 1``; realtime with the state at physics step
    ``steps`` (the plant's clock starts once every tracker commands, so wall time alone
    does not say when its run ends)."""
    from types import SimpleNamespace

    from apf_swarm_nodes.bringup import StateAccumulator

    lock, real = StateAccumulator('lockstep', 100), StateAccumulator('realtime', 100)
    for step in range(100):
        lock.add(SimpleNamespace(step=step))
    assert lock.complete
    for step in (0, 10, 55, 99):
        real.add(SimpleNamespace(step=step))
    assert not real.complete
    real.add(SimpleNamespace(step=100))
    assert real.complete and real.repeated == 0
