"""The realtime plant without ROS (apf_swarm_core.realtime_plant): the clock's start, the
target's refusals, the physics step and the end of the run."""

from __future__ import annotations

import numpy as np
from apf_swarm_core.config import SwarmConfig
from apf_swarm_core.plant_model import PlantModel
from apf_swarm_core.realtime_plant import RealtimePlant


def make(duration: float = 0.05) -> RealtimePlant:
    cfg = SwarmConfig().replace(n_trackers=3, dt=0.01, duration=duration)
    return RealtimePlant(PlantModel(cfg), timeout=1.0, stale_after=0.1, arm_timeout=10.0)


def command(rt: RealtimePlant, uav_id: int, now: float) -> None:
    assert rt.model.offer_command(uav_id, -1, np.zeros(3), np.zeros(3), now=now, instance=1)


def test_the_clock_starts_once_every_tracker_commands() -> None:
    rt = make()
    assert rt.start(100.0) == [] and not rt.clock_started
    for i in (1, 2, 3):
        command(rt, i, 100.5)
    (said,) = rt.arm(101.0)
    assert said.kind == 'info' and rt.clock_started and rt.wall0 == 101.0
    assert rt.arm(102.0) == []  # once


def test_the_clock_starts_at_arm_timeout_without_the_silent_ones() -> None:
    rt = make()
    rt.start(100.0)
    command(rt, 2, 100.5)
    assert rt.arm(109.9) == [] and not rt.clock_started
    (said,) = rt.arm(110.0)
    assert said.kind == 'warn' and "['uav_1', 'uav_3']" in said.text and rt.clock_started


def test_stale_and_out_of_order_inputs_are_refused() -> None:
    rt = make()
    x, v = np.ones(3), np.zeros(3)
    assert rt.stale_command(1, 1.5) == (
        'command of uav_1 is stale: stamped 1.500 s ago (command_timeout 1 s)'
    )
    assert rt.stale_command(1, 0.5) is None
    assert rt.offer_target(x, v, seq=10, age=1.5, now=0.0) is not None and rt.target is None
    assert rt.offer_target(x, v, seq=10, age=0.0, now=5.0) is None
    assert rt.offer_target(x, v, seq=9, age=0.0, now=5.1) == (
        'target state out of order (stamp 9 ns after 10)'
    )
    assert rt.target is not None and rt.target.received == 5.0
    assert rt.target_age(5.25) == 0.25


def test_the_physics_runs_the_configurations_steps_then_is_done() -> None:
    rt = make(duration=0.05)
    rt.start(0.0)
    for i in (1, 2, 3):
        command(rt, i, 0.0)
    rt.arm(0.0)
    rt.offer_target(np.zeros(3), np.zeros(3), seq=0, age=0.0, now=0.0)
    assert rt.physics(0.02) == [] and rt.model.k == 2 and not rt.done
    assert rt.command_arrives(0.035) and rt.model.k == 3
    said = rt.physics(0.2)
    assert rt.done and [a.kind for a in said] == ['info'] and said[0].text.startswith('done: 5')
    assert not rt.command_arrives(0.3)
    sample = rt.state_sample(0.3)
    assert sample['step'] == rt.model.k and rt.final_published


def test_the_shared_events_refuse_stale_commands_and_bad_targets() -> None:
    from apf_swarm_core.plant_model import Command

    rt = make()
    assert not rt.needs_match and rt.reports_latency
    rt.start(100.0)
    ok, out = rt.take_command(Command(1, -1, np.zeros(3), np.zeros(3), False), 2.0, 100.1)
    assert not ok and [a.kind for a in out] == ['refuse'] and 'stale' in out[0].text
    ok, out = rt.take_command(Command(1, -1, np.zeros(3), np.zeros(3), False), 0.01, 100.1)
    assert ok and out == []
    assert [a.kind for a in rt.take_target(np.full(3, np.nan), np.zeros(3), 5, 0.0, 100.2)] == [
        'refuse'
    ]
    assert rt.take_target(np.zeros(3), np.zeros(3), 5, 0.0, 100.2) == []
    (late,) = rt.take_target(np.zeros(3), np.zeros(3), 4, 0.0, 100.3)
    assert late.kind == 'refuse' and 'out of order' in late.text
    assert rt.model.rejected == 3


def test_the_plant_loads_its_compiled_step_before_the_first_one() -> None:
    """A plant started as an executable (not forked from the zygote, which loads every
    kernel) loads the compiled integration when it is built, not inside the first step's
    deadline (0.2-0.7 s under load). In a fresh interpreter: the kernel has its
    signatures once PlantModel exists, though no step ran."""
    import subprocess
    import sys

    code = (
        'from apf_swarm_core.config import SwarmConfig\n'
        'from apf_swarm_core.kernels import plant_rows\n'
        'from apf_swarm_core.plant_model import PlantModel\n'
        'before = len(plant_rows.signatures)\n'
        'PlantModel(SwarmConfig(n_trackers=3))\n'
        'print(before, len(plant_rows.signatures))\n'
    )
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    before, after = map(int, out.stdout.split())
    assert before == 0 and after >= 1
