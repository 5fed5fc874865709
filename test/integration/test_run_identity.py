"""A run's identity at topic level: a tracker process of run 5 answers the /swarm/odom of
its run and refuses, counts and logs that of another run; the bring-up gives every node of
a run one identity and reports it."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from apf_swarm_nodes.bringup import pick_domain_id
from apf_swarm_nodes.conversions import dt_to_ns, step_stamp, swarm_odom_msg
from apf_swarm_nodes.node_common import control_qos

from apf_swarm_core import load_preset
from apf_swarm_msgs.msg import SwarmOdometry

CONFIG = Path(__file__).resolve().parents[2] / 'config'
APF = shutil.which('apf-swarm')


def test_a_tracker_refuses_the_states_of_another_run(graph: Any) -> None:
    cfg = load_preset('triangle')
    forces, sub = graph.lone_tracker('run:=5')
    qos = control_qos('lockstep')
    pub = graph.node.create_publisher(SwarmOdometry, '/swarm/odom', qos)
    graph.spin_until(
        lambda: pub.get_subscription_count() == 1 and sub.get_publisher_count() == 1,
        30,
        'the tracker matched',
    )
    rng = np.random.default_rng(4)
    x, v = rng.normal(scale=2.0, size=(2, 3, 3))
    dt_ns = dt_to_ns(cfg.dt)

    def send(step: int, run: int) -> None:
        pub.publish(
            swarm_odom_msg(
                step=step,
                stamp=step_stamp(step, dt_ns),
                uav_ids=[1, 2, 3],
                x=x,
                v=v,
                target_x=np.zeros(3),
                target_v=np.zeros(3),
                run=run,
            )
        )

    send(0, 6)  # another run: refused, no command for step 0
    graph.spin_until(lambda: 'another run' in graph.log('tracker'), 10, 'the refusal log')
    send(1, 5)
    graph.spin_until(lambda: len(forces) == 1, 10, 'the command of step 1')
    f = forces[0]
    assert (f.step, f.run, f.rejected_inputs) == (1, 5, 1)
    assert '/swarm/odom of another run (6; this run: 5)' in graph.log('tracker')


@pytest.mark.skipif(APF is None, reason='apf-swarm is not on PATH')
def test_the_bring_up_gives_its_nodes_one_identity(tmp_path: Path) -> None:
    out = tmp_path / 'run'
    p = subprocess.run(
        [APF, 'up', '--preset', 'triangle', '--duration', '0.5', '--no-plots', '--out',
         str(out), '--domain-id', str(pick_domain_id(lo=102, hi=201))],
        capture_output=True,
        text=True,
        timeout=180,
        env={**os.environ, 'PYTHONWARNINGS': 'ignore'},
    )  # fmt: skip
    assert p.returncode == 0, p.stderr
    summary = json.loads((out / 'summary.json').read_text())
    assert int(summary['run_id'], 16) > 0
    # every node has the run's identity: a plant of another identity than its trackers
    # would refuse every command, and the lockstep run would miss every deadline
    assert summary['status'] == 'completed', summary['status']
    assert (summary['rejected_inputs'], summary['missed_deadlines']) == (0, 0)
