"""The live view of a real run: ``apf-swarm up --view 0`` (target, plant and trackers over DDS)
served to a Foxglove WebSocket client in the test, which decodes the scene with the schema the
server advertises and finds in it the positions the run wrote to ``trajectory.npz``."""

from __future__ import annotations

import os
import re
import shutil
import signal
import subprocess
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from apf_swarm_core.config_files import load_preset
from apf_swarm_nodes.bringup import pick_domain_id, stop_process

APF = shutil.which('apf-swarm')
pytestmark = pytest.mark.skipif(APF is None, reason='apf-swarm is not on PATH')


def test_a_client_sees_the_run_it_watches(tmp_path: Path, foxglove_client: Any) -> None:
    out = tmp_path / 'run'
    err_path = tmp_path / 'up.stderr'
    with open(err_path, 'w') as err:
        proc = subprocess.Popen(
            [APF, 'up', '--preset', 'triangle', '--mode', 'lockstep', '--duration', '8',
             '--view', '0', '--no-plots', '--out', str(out),
             '--domain-id', str(pick_domain_id(lo=102, hi=201))],
            stdout=subprocess.DEVNULL,
            stderr=err,
            env={**os.environ, 'PYTHONWARNINGS': 'ignore'},
            start_new_session=True,
        )  # fmt: skip
    try:
        deadline = time.monotonic() + 60
        url = None
        while url is None:
            found = re.search(r'view: (ws://127\.0\.0\.1:\d+)', err_path.read_text())
            url = found.group(1) if found else None
            assert proc.poll() is None or url, err_path.read_text()
            assert time.monotonic() < deadline, 'no view address:\n' + err_path.read_text()
            time.sleep(0.05)
        c = foxglove_client(url)
        assert {'/swarm/scene', '/swarm/frames', '/swarm/metrics'} <= set(c.channels)
        assert c.channels['/swarm/scene']['schemaName'] == 'foxglove.SceneUpdate'
        c.subscribe('/swarm/scene', '/swarm/metrics')
        decode = c.decoder('/swarm/scene')
        scenes: dict[int, np.ndarray] = {}
        metrics = 0
        for topic, _ts, payload in c.messages(timeout=120):
            if topic == '/swarm/metrics':
                metrics += 1
                continue
            ents = {e.id: e for e in decode.FromString(payload).entities}
            step = int({m.key: m.value for m in ents['uav_1'].metadata}['step'])
            scenes[step] = np.array(
                [
                    [p.x, p.y, p.z]
                    for p in (ents[f'uav_{i}'].spheres[0].pose.position for i in (1, 2, 3))
                ]
            )
            if proc.poll() is not None:
                break
        c.close()
        assert proc.wait(timeout=120) == 0, err_path.read_text()
    finally:
        if proc.poll() is None:
            stop_process(proc, ((signal.SIGINT, 20.0), (signal.SIGKILL, 5.0)))
    with np.load(out / 'trajectory.npz') as npz:
        x, t = npz['x'], npz['t']
    dt = load_preset('triangle').dt
    # at most 20 frames a second of wall time, and a lockstep run is faster than real time:
    # a few frames at least, each the state of its step exactly
    assert len(scenes) >= 5 and metrics >= 5, (len(scenes), metrics)
    by_step = {round(tk / dt): k for k, tk in enumerate(t)}
    # every step shown is a sample of the trajectory (record_every 1), shown exactly
    assert set(scenes) <= set(by_step), sorted(set(scenes) - set(by_step))[:10]
    for s, shown in scenes.items():
        np.testing.assert_array_equal(shown, x[by_step[s]])
