"""The tracker's timing modes without ROS: one call per input decides accept or refuse,
wait, command or brake (apf_swarm_core.tracker_modes)."""

from __future__ import annotations

import numpy as np
import pytest
from apf_swarm_core.agents import TrackerAgent
from apf_swarm_core.simulator import BatchSimulator
from apf_swarm_core.tracker_modes import (
    LockstepTracker,
    RealtimeTracker,
    SwarmOdom,
    tracker_mode,
)

from apf_swarm_core import load_preset

DT_NS = 1_000_000  # the triangle preset's step, 1 ms


@pytest.fixture
def cfg():
    return load_preset('triangle')


def swarm(step: int, x, v, tx, tv, *, target_age: float = 0.0, stamp_ns: int | None = None):
    return SwarmOdom(
        step=step,
        stamp_ns=step * DT_NS if stamp_ns is None else stamp_ns,
        uav_ids=[1, 2, 3],
        x=np.asarray(x, dtype=float),
        v=np.asarray(v, dtype=float),
        target_x=np.asarray(tx, dtype=float),
        target_v=np.asarray(tv, dtype=float),
        active=[True, True, True],
        target_age=target_age,
        command_latency=np.zeros(0),
    )


def test_lockstep_commands_each_step_as_the_simulator_does(cfg) -> None:
    sim = BatchSimulator([cfg])
    trackers = [LockstepTracker(TrackerAgent(cfg, i), 0.5, DT_NS) for i in (1, 2, 3)]
    for k in range(50):
        tx, tv = sim.target.state(k)
        m = swarm(k, sim.x[0], sim.v[0], tx[0], tv[0])
        replies = [t.on_swarm(m) for t in trackers]
        assert all(r is not None and r.output is not None and r.step == k for r in replies)
        # the same step again: already answered, nothing to send, nothing refused
        assert trackers[0].on_swarm(m) is None
        ref, _, _ = sim.step()
        assert np.array_equal(np.stack([r.force for r in replies]), ref.force[0])


def test_lockstep_waits_for_every_input_of_a_step(cfg) -> None:
    t = LockstepTracker(TrackerAgent(cfg, 2), 0.5, DT_NS)
    x, v = np.eye(3), np.zeros((3, 3))
    for j in (1, 2, 3):
        assert t.on_odom(j, 0, x[j - 1], v[j - 1]) is None
    r = t.on_odom(0, 0, np.zeros(3), np.zeros(3))  # the target completes step 0
    assert r is not None and r.output is not None and r.step == 0


def test_a_stale_target_brakes_and_reports_once_then_commands_again(cfg) -> None:
    agent = TrackerAgent(cfg, 1)
    t = LockstepTracker(agent, 0.5, DT_NS)
    x, v = np.eye(3) * 2.0, np.ones((3, 3))
    # the plant holds a silent target: its age grows in simulated time
    old = t.on_swarm(swarm(0, x, v, np.zeros(3), np.zeros(3), target_age=0.6))
    assert old is not None and old.output is None and old.stale == [0] and old.report_stale
    np.testing.assert_array_equal(old.force, agent.safe_command())
    again = t.on_swarm(swarm(1, x, v, np.zeros(3), np.zeros(3), target_age=0.7))
    assert again is not None and again.brake is not None and not again.report_stale
    back = t.on_swarm(swarm(2, x, v, np.zeros(3), np.zeros(3)))
    assert back is not None and back.output is not None
    assert agent.stale == 2


def test_a_refused_input_says_why(cfg) -> None:
    t = LockstepTracker(TrackerAgent(cfg, 1), 0.5, DT_NS)
    bad = np.full((3, 3), np.nan)
    assert t.on_swarm(swarm(0, bad, bad, np.zeros(3), np.zeros(3))) is None
    assert t.refused and 'finite' in t.refused


def test_realtime_odom_trigger_answers_the_own_state_only(cfg) -> None:
    t = RealtimeTracker(TrackerAgent(cfg, 2), 0.5, 50.0, on_odom=True)
    x, v = np.eye(3), np.zeros((3, 3))
    now_ns, mono = 10_000_000_000, 100.0
    assert t.on_odom(0, now_ns, np.zeros(3), np.zeros(3), now_ns, mono) is None
    assert t.on_odom(1, now_ns, x[0], v[0], now_ns, mono) is None
    assert t.on_odom(3, now_ns, x[2], v[2], now_ns, mono) is None
    r = t.on_odom(2, now_ns, x[1], v[1], now_ns, mono)
    assert r is not None and r.output is not None and r.step == 1
    # the watchdog is quiet while the inputs are fresh, brakes once they are stale
    assert t.on_timer(now_ns, mono + 0.1) is None
    late = t.on_timer(now_ns, mono + 0.6)
    assert late is not None and late.brake is not None and late.stale == [0, 1, 2, 3]


def test_realtime_age_is_the_ros_clock_minus_the_stamp(cfg) -> None:
    t = RealtimeTracker(TrackerAgent(cfg, 1), 0.5, 50.0, on_odom=False)
    x, v = np.eye(3), np.zeros((3, 3))
    # stamped 0.6 s before now: stale on arrival
    m = swarm(-1, x, v, np.zeros(3), np.zeros(3), stamp_ns=0)
    assert t.on_swarm(m, 600_000_000, 50.0) is None  # the timer trigger waits for the timer
    r = t.on_timer(600_000_000, 50.0)
    assert r is not None and r.brake is not None and r.report_stale


def test_tracker_mode_picks_the_mode(cfg) -> None:
    agent = TrackerAgent(cfg, 1)
    args = {'dt_ns': DT_NS, 'control_rate': 50.0, 'on_odom': True}
    assert isinstance(tracker_mode('lockstep', agent, 0.5, **args), LockstepTracker)
    assert isinstance(tracker_mode('realtime', agent, 0.5, **args), RealtimeTracker)
    assert LockstepTracker.TIME_UNIT != RealtimeTracker.TIME_UNIT
