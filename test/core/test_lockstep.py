"""The lockstep barrier without ROS: events in, actions out, and the simulator's trajectory
at the end."""

import numpy as np
import pytest
from apf_swarm_core.agents import TrackerAgent
from apf_swarm_core.config_files import load_preset
from apf_swarm_core.lockstep import LOOKAHEAD, LockstepBarrier
from apf_swarm_core.plant_model import PlantModel
from apf_swarm_core.simulator import simulate


def kinds(actions):
    return [a.kind for a in actions]


def make(steps=20, timeout=1.0):
    cfg = load_preset('triangle').replace(duration=steps * 0.001)
    model = PlantModel(cfg)
    return cfg, model, LockstepBarrier(model, timeout)


def target_state(cfg, k):
    x, v = cfg.target_trajectory_obj.state(k * cfg.dt)
    return np.asarray(x), np.asarray(v)


def test_step_0_waits_for_the_target_and_asks_for_it_ahead():
    cfg, _, bar = make()
    out = bar.start(0.0)
    # no /swarm/odom before the target's state of step 0; the request covers the run
    assert kinds(out) == ['request', 'step']
    assert out[0].step == min(LOOKAHEAD - 1, cfg.steps)
    assert bar.late() == ['uav_1', 'uav_2', 'uav_3', 'target']
    out = bar.on_target(0, *target_state(cfg, 0), 0.001)
    assert kinds(out) == ['swarm_odom'] and out[0].step == 0
    # a state never asked for, or of a step already integrated, is not kept
    assert bar.on_target(cfg.steps + 5, *target_state(cfg, 0), 0.002) == []


def test_the_barrier_flies_the_simulators_trajectory():
    cfg, model, bar = make(steps=30)
    agents = {i: TrackerAgent(cfg, i) for i in model.ids}
    pending = bar.start(0.0)
    for k in range(cfg.steps + 1):
        pending += bar.on_target(k, *target_state(cfg, k), 0.0) if k < cfg.steps else []
    states = []
    # play the trackers: answer every swarm_odom with each tracker's command of that step
    while pending:
        a = pending.pop(0)
        if a.kind == 'state':
            states.append(a)
        if a.kind != 'swarm_odom':
            continue
        tx, tv = bar.target.x, bar.target.v
        for i, agent in agents.items():
            agent.offer_swarm(a.step, model.ids, model.x, model.v, model.active, tx, tv, 0.0, 0.0)
            cmd = agent.command(a.step)
            assert model.offer_command(i, a.step, cmd.force[0], cmd.sliding_surface[0])
            pending += bar.on_command(0.0)
    assert bar.done and [s.step for s in states] == list(range(cfg.steps))
    sim = simulate(cfg).trajectory
    x = np.array([s.data['x'] for s in states])
    np.testing.assert_array_equal(x, sim['x'][: cfg.steps])


def test_a_late_tracker_gets_the_step_again_then_is_missed_and_deactivated():
    cfg, model, bar = make()
    bar.start(0.0)
    bar.on_target(0, *target_state(cfg, 0), 0.0)
    for i in (1, 2):
        model.offer_command(i, 0, np.zeros(3), np.zeros(3))
        bar.on_command(0.0)
    assert bar.tick(0.5) == []  # within the deadline
    again = bar.tick(1.01)
    assert kinds(again)[0] == 'warn' and 'uav_3' in again[0].text and 'again' in again[0].text
    assert 'step' in kinds(again) and 'swarm_odom' in kinds(again)
    missed = bar.tick(2.02)
    assert 'state' in kinds(missed) and model.missed == 1
    assert not model.active[2] and model.k == 1
    assert any('uav_3' in a.text and 'zero force' in a.text for a in missed)


def test_a_silent_target_is_held_and_its_age_grows():
    cfg, model, bar = make()
    bar.start(0.0)
    bar.on_target(0, *target_state(cfg, 0), 0.0)
    for i in model.ids:
        model.offer_command(i, 0, np.zeros(3), np.zeros(3))
    out = bar.on_command(0.0)
    assert model.k == 1 and kinds(out)[-1] == 'state'
    # step 1's target state never comes (only step 0's was sent)
    bar.tick(1.01)
    held = bar.tick(2.02)
    assert bar.target_absent and model.missed == 1
    assert kinds(held) == ['warn', 'swarm_odom'] and 'holding the last one' in held[0].text
    assert bar.target_age() == pytest.approx(cfg.dt)
    # the target publishes again: its state is taken and the log says so
    back = bar.on_target(1, *target_state(cfg, 1), 2.1)
    assert any(a.kind == 'info' and 'publishes again' in a.text for a in back)
    assert not bar.target_absent and bar.target_age() == 0.0


def test_target_window_sends_new_states_and_repeats_a_late_window():
    from apf_swarm_core.lockstep import target_window

    assert list(target_window(63, 0)) == list(range(64))  # the first request
    assert list(target_window(95, 64)) == list(range(64, 96))  # only what is new
    assert list(target_window(200, 64, lookahead=64)) == list(range(137, 201))  # at most 64
    # the plant repeats a request for states already out: that window again
    assert list(target_window(95, 96)) == list(range(32, 96))
    assert list(target_window(10, 11)) == list(range(11))


def test_the_shared_events_refuse_bad_inputs_and_finish_the_step():
    from apf_swarm_core.plant_model import Command

    cfg, model, bar = make()
    assert bar.needs_match and not bar.reports_latency
    bar.start(0.0)
    bad = bar.take_target(np.full(3, np.nan), np.zeros(3), 0, 0.0, 0.0)
    assert kinds(bad) == ['refuse'] and 'target state' in bad[0].text and model.rejected == 1
    x, v = target_state(cfg, 0)
    assert 'swarm_odom' in kinds(bar.take_target(x, v, 0, 0.0, 0.0))  # stamp 0 ns: step 0
    ok, out = bar.take_command(Command(1, 0, np.full(3, np.inf), np.zeros(3), False), 0.0, 0.0)
    assert not ok and kinds(out) == ['refuse'] and model.rejected == 2
    for i in (1, 2, 3):
        ok, out = bar.take_command(Command(i, 0, np.zeros(3), np.zeros(3), False), 0.0, 0.0)
        assert ok
    # the last command finishes step 0: step 1 goes out, then the state of step 0
    assert model.k == 1 and kinds(out)[-1] == 'state'
