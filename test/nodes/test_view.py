"""The live view's messages and server, ``apf-swarm bag view`` and ``bag animate``, and the
progress bars: a Foxglove WebSocket client (``websockets``) decodes what the server sends
with the protobuf schema the server advertises, independently of the SDK that encoded it."""

from __future__ import annotations

import io
import json
import math
import os
import re
import shutil
import subprocess
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from apf_swarm_core.config_files import load_preset
from apf_swarm_core.formation import design_pair_sets
from apf_swarm_core.metrics import formation_edges
from apf_swarm_core.simulator import simulate
from apf_swarm_nodes.analysis.animate import animate, frame_indices
from apf_swarm_nodes.analysis.style import EDGE_BAD, EDGE_GOOD, edge_colour
from apf_swarm_nodes.conversions import SwarmSample
from apf_swarm_nodes.progress import Progress, progress_iter
from apf_swarm_nodes.view.scene import RESPAWN_SHOWN, UavStates
from apf_swarm_nodes.view.server import LiveView

from apf_swarm_nodes import bags

APF = shutil.which('apf-swarm')
D = 1.6  # side of the test triangle [m]
TRI = np.array([[0.0, 0.0, 0.0], [D, 0.0, 0.0], [D / 2, D * math.sqrt(3) / 2, 0.0]])


def sample(x: np.ndarray, step: int = 0, **kw: Any) -> SwarmSample:
    n = len(x)
    fields: dict[str, Any] = {
        'step': step,
        't': 0.01 * step,
        'uav_ids': tuple(range(1, n + 1)),
        'x': x,
        'v': np.zeros_like(x),
        'u': np.zeros_like(x),
        's': np.zeros_like(x),
        'target_x': x.mean(axis=0),
        'target_v': np.zeros(3),
        'potential': 1.0,
        'centroid_error': 0.0,
        'formation_error': 0.0,
        'missed_deadlines': 0,
        'stale_inputs': 0,
        'rejected_inputs': 0,
        'active': (True,) * n,
        'command_latency': (0.0,) * n,
    }
    fields.update(kw)
    return SwarmSample(**fields)


def wait_watched(view: LiveView, timeout: float = 10.0) -> None:
    deadline = time.monotonic() + timeout
    while not view.watched():
        assert time.monotonic() < deadline, 'the subscription never reached the server'
        time.sleep(0.01)


# --- the scene ------------------------------------------------------------------------------


def test_edge_colour_runs_from_green_to_red() -> None:
    assert edge_colour(0.0) == edge_colour(-EDGE_GOOD) == (0.0, 1.0, 0.1, 1.0)
    assert edge_colour(EDGE_BAD) == edge_colour(-5.0) == (1.0, 0.0, 0.1, 1.0)
    mid = edge_colour((EDGE_GOOD + EDGE_BAD) / 2)
    assert mid[0] == pytest.approx(1.0) and mid[1] == pytest.approx(1.0)


def test_uav_states_inactive_respawned_stale() -> None:
    st = UavStates(stale_after=0.5)
    ids = (1, 2, 3)
    assert st.update(0.0, ids, (True, True, True), (0.01, 0.9, 0.0)) == [
        'active',
        'stale',
        'active',
    ]
    assert st.update(1.0, ids, (True, True, False), (0.01, 0.01, 0.0))[2] == 'inactive'
    assert st.update(2.0, ids, (True, True, True), (0.01, 0.01, 0.9))[2] == 'respawned'
    assert st.update(2.0 + RESPAWN_SHOWN - 0.01, ids, (True,) * 3, (0.0,) * 3)[2] == 'respawned'
    assert st.update(2.0 + RESPAWN_SHOWN + 0.01, ids, (True,) * 3, (0.0,) * 3)[2] == 'active'
    # a looped bag starts again at t = 0: nothing is respawned then
    assert st.update(9.0, ids, (True, False, True), (0.0,) * 3)[1] == 'inactive'
    assert st.update(0.0, ids, (True,) * 3, (0.0,) * 3) == ['active'] * 3


def test_server_sends_scene_frames_and_metrics_that_decode_to_the_sample(
    foxglove_client: Any,
) -> None:
    view = LiveView(port=0, designs=[np.full(3, D)])
    try:
        assert not view.show(sample(TRI)), 'nothing is built without a client'
        c = foxglove_client(view.url)
        assert set(c.channels) == {'/swarm/scene', '/swarm/frames', '/swarm/metrics'}
        assert c.channels['/swarm/scene']['schemaName'] == 'foxglove.SceneUpdate'
        assert c.channels['/swarm/frames']['schemaName'] == 'foxglove.FrameTransform'
        assert c.channels['/swarm/metrics']['encoding'] == 'json'
        c.subscribe('/swarm/scene', '/swarm/frames', '/swarm/metrics')
        wait_watched(view)
        stretched = TRI * np.array([1.1, 1.0, 1.0])  # edges off the design
        assert view.show(sample(stretched, step=7, active=(True, False, True)), 123_000)
        got = {topic: (ts, payload) for topic, ts, payload in c.messages(timeout=5.0)}
        c.close()
    finally:
        view.close()
    assert {ts for ts, _ in got.values()} == {123_000}
    scene = c.decoder('/swarm/scene').FromString(got['/swarm/scene'][1])
    ents = {e.id: e for e in scene.entities}
    for j in range(3):
        e = ents[f'uav_{j + 1}']
        p = e.spheres[0].pose.position
        assert (p.x, p.y, p.z) == pytest.approx(tuple(stretched[j]), abs=1e-12)
        assert e.frame_id == 'world'
        meta = {m.key: m.value for m in e.metadata}
        assert meta == {'state': 'inactive' if j == 1 else 'active', 'step': '7'}
    # one line per neighbour pair, coloured by formation_edges' error
    i, _k, design, err = formation_edges(stretched, np.full(3, D))
    edges = ents['formation'].lines
    assert len(edges) == len(i) == 3
    for line, d, e in zip(edges, design, err, strict=True):
        want = edge_colour(float(e / d))
        assert (line.color.r, line.color.g) == pytest.approx(want[:2], abs=1e-6)
    tf = c.decoder('/swarm/frames').FromString(got['/swarm/frames'][1])
    assert (tf.parent_frame_id, tf.child_frame_id) == ('world', 'target')
    assert tf.translation.x == pytest.approx(stretched.mean(axis=0)[0])
    metrics = json.loads(got['/swarm/metrics'][1])
    assert metrics['step'] == 7
    assert metrics['uavs'] == {'active': 2, 'stale': 0, 'inactive': 1, 'respawned': 0}


def test_a_busy_port_is_a_clear_error() -> None:
    from apf_swarm_nodes.view.errors import ViewError

    view = LiveView(port=0)
    try:
        with pytest.raises(ViewError, match=f'cannot serve the view on 127.0.0.1:{view.port}'):
            LiveView(port=view.port)
    finally:
        view.close()


# --- a bag of a simulated run ---------------------------------------------------------------


def swarm_bag(path: Path, duration: float = 2.0) -> tuple[Path, dict[str, Any], Any]:
    """A bag of /swarm/state as the recorder writes it, from a simulator run."""
    from apf_swarm_core.config_files import to_ros_params
    from apf_swarm_nodes.conversions import step_stamp, swarm_state_msg
    from apf_swarm_nodes.dds.qos import qos_from_dict
    from rclpy.serialization import serialize_message

    cfg = load_preset('triangle').replace(duration=duration)
    traj = simulate(cfg).trajectory
    n = cfg.n_trackers
    dt_ns = round(cfg.dt * 1e9)
    qos = qos_from_dict(
        {'history': 'keep_last', 'depth': 10, 'reliability': 'reliable', 'durability': 'volatile'}
    )
    with bags.BagWriter(path) as w:
        w.set_custom_data(bags.CUSTOM_MODE, 'lockstep', early=True)
        w.set_custom_data(bags.CUSTOM_CONFIG, yaml.safe_dump(to_ros_params(cfg)), early=True)
        conn = w.add_topic('/swarm/state', 'apf_swarm_msgs/msg/SwarmState', offered_qos=[qos])
        for k in range(len(traj['t'])):
            msg = swarm_state_msg(
                step=k,
                sim_time=float(traj['t'][k]),
                stamp=step_stamp(k, dt_ns),
                uav_ids=range(1, n + 1),
                x=traj['x'][k],
                v=traj['v'][k],
                u=traj['u'][k],
                s=traj['s'][k],
                target_x=traj['target_x'][k],
                target_v=traj['target_v'][k],
                potential=0.0,
                centroid_error=0.0,
                formation_error=0.0,
                missed_deadlines=0,
                stale_inputs=0,
                rejected_inputs=0,
            )
            w.write(conn, 10**18 + k * dt_ns, serialize_message(msg))
    return path, traj, cfg


@pytest.mark.skipif(APF is None, reason='apf-swarm is not on PATH: source scripts/activate.sh')
def test_bag_view_serves_the_recorded_positions(tmp_path: Path, foxglove_client: Any) -> None:
    bag, traj, _cfg = swarm_bag(tmp_path / 'bag')
    err_path = tmp_path / 'view.stderr'
    with open(err_path, 'w') as err:
        proc = subprocess.Popen(
            [APF, 'bag', 'view', str(bag), '--port', '0', '--rate', '2', '--wait-client', '60'],
            stderr=err,
            env={**os.environ, 'PYTHONWARNINGS': 'ignore'},
        )
    try:
        deadline = time.monotonic() + 60
        while not (found := re.search(r'ws://127\.0\.0\.1:\d+', err_path.read_text())):
            assert proc.poll() is None, err_path.read_text()
            assert time.monotonic() < deadline, 'no address:\n' + err_path.read_text()
            time.sleep(0.05)
        url = found.group(0)
        c = foxglove_client(url)
        c.subscribe('/swarm/scene')
        decode = c.decoder('/swarm/scene')
        seen = 0
        for _topic, _ts, payload in c.messages(timeout=20.0):
            ents = {e.id: e for e in decode.FromString(payload).entities}
            step = int({m.key: m.value for m in ents['uav_1'].metadata}['step'])
            for j in range(traj['x'].shape[1]):
                p = ents[f'uav_{j + 1}'].spheres[0].pose.position
                assert (p.x, p.y, p.z) == pytest.approx(tuple(traj['x'][step, j]), abs=1e-9)
            seen += 1
        c.close()
        assert proc.wait(timeout=30) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    # 2 s of run at twice the speed, at most 20 frames a second: about 20 frames
    assert 10 <= seen <= 21, seen


# --- animations -----------------------------------------------------------------------------


def test_frame_indices_follow_the_speed() -> None:
    t = np.arange(0.0, 10.0 + 1e-9, 0.01)
    idx = frame_indices(t, speed=2.0, fps=10)
    assert len(idx) == 51  # 10 s at 2x in frames of 0.1 s: 5 s of film
    np.testing.assert_allclose(t[idx], np.arange(51) * 0.2, atol=1e-9)


def test_gif_has_the_frames_and_size_asked_for(tmp_path: Path) -> None:
    from PIL import Image

    cfg = load_preset('triangle').replace(duration=2.0)
    traj = simulate(cfg).trajectory
    for projection in ('3d', 'top'):
        out = tmp_path / f'{projection}.gif'
        frames = animate(
            traj,
            out,
            designs=design_pair_sets(cfg),
            speed=1.0,
            fps=5,
            view=projection,
            size=(4.0, 3.0),
            dpi=50,
        )
        with Image.open(out) as im:
            assert (im.n_frames, im.size) == (frames, (200, 150))
        # a frame every 0.2 s of the run, from its first sample to its last
        assert frames == len(np.arange(traj['t'][0], traj['t'][-1] + 1e-9, 0.2))


@pytest.mark.skipif(APF is None, reason='apf-swarm is not on PATH: source scripts/activate.sh')
def test_bag_animate_and_bad_formats(tmp_path: Path) -> None:
    from PIL import Image

    bag, traj, _cfg = swarm_bag(tmp_path / 'bag', duration=1.0)
    out = tmp_path / 'a.gif'
    p = subprocess.run(
        [APF, 'bag', 'animate', str(bag), '--out', str(out), '--fps', '4', '--quiet'],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert p.returncode == 0, p.stderr
    with Image.open(out) as im:
        assert im.n_frames == len(np.arange(traj['t'][0], traj['t'][-1] + 1e-9, 0.25))
    p = subprocess.run(
        [APF, 'bag', 'animate', str(bag), '--out', str(tmp_path / 'a.avi')],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert p.returncode == 2 and "unknown animation format '.avi'" in p.stderr, p.stderr
    if shutil.which('ffmpeg') is None:
        p = subprocess.run(
            [APF, 'simulate', '--preset', 'triangle', '--duration', '0.1', '--out',
             str(tmp_path / 'sim'), '--animate', str(tmp_path / 'a.mp4')],
            capture_output=True,
            text=True,
            timeout=120,
        )  # fmt: skip
        assert p.returncode == 2 and 'needs ffmpeg' in p.stderr, p.stderr
        assert not (tmp_path / 'sim').exists(), 'refused before the run'


# --- progress -------------------------------------------------------------------------------


def test_progress_in_a_pipe_is_whole_lines() -> None:
    s = io.StringIO()
    p = Progress('simulate', stream=s)
    for i in range(0, 1001, 100):
        p(i, 1000)
    text = s.getvalue()
    assert '\r' not in text
    lines = text.splitlines()
    # the first and the last: the rest fall within PIPE_INTERVAL (10 s) of the first
    assert len(lines) == 2, lines
    assert lines[0].startswith('simulate:   0%') and lines[-1].startswith('simulate: 100%')
    assert '1000/1000' in lines[-1] and text.endswith('\n')
    s = io.StringIO()
    assert sum(progress_iter(range(5), 'bag', total=5, stream=s)) == 10
    assert s.getvalue().splitlines()[-1].startswith('bag: 100%')
    s = io.StringIO()
    assert list(progress_iter(range(3), 'bag', stream=s, quiet=True)) == [0, 1, 2]
    assert s.getvalue() == ''


def test_progress_on_a_terminal_redraws_in_place() -> None:
    class Tty(io.StringIO):
        def isatty(self) -> bool:
            return True

    s = Tty()
    p = Progress('simulate', stream=s)
    for i in range(11):
        p(i, 10)
    text = s.getvalue()
    # redrawn in place: one line of carriage returns, the last drawing at 100 %
    assert text.count('\r') >= 2 and text.count('\n') == 1, repr(text)
    assert text.rsplit('\r', 1)[-1].startswith('simulate: 100%')


def test_bags_carry_the_distro_as_rosbag2_writes_it(tmp_path: Path) -> None:
    from mcap.reader import make_reader

    bag, _traj, _cfg = swarm_bag(tmp_path / 'bag', duration=0.1)
    meta = yaml.safe_load((bag / 'metadata.yaml').read_text())
    assert meta['rosbag2_bagfile_information']['ros_distro'] == 'jazzy'
    (mcap_file,) = bag.glob('*.mcap')
    with open(mcap_file, 'rb') as fh:
        reader = make_reader(fh)
        assert reader.get_header().profile == 'ros2'
        records = {m.name: m.metadata for m in reader.iter_metadata()}
    assert records['rosbag2']['ros_distro'] == 'jazzy'
    assert 'serialized_metadata' in records['rosbag2']


def test_a_played_bag_is_shown_once_per_new_step(tmp_path: Path, foxglove_client: Any) -> None:
    """``bag play --view``: the player hands each message to the view's observer; the view
    decodes and shows the newest /swarm/state, once per step."""
    from apf_swarm_nodes.bags.read import iter_raw
    from apf_swarm_nodes.view.bag import live_view_of_bag

    bag, traj, _cfg = swarm_bag(tmp_path / 'bag', duration=0.1)
    view, observe = live_view_of_bag(bags.open_bag(bag), host='127.0.0.1', port=0)
    try:
        c = foxglove_client(view.url)
        c.subscribe('/swarm/scene')
        wait_watched(view)
        raws = [raw for _t, _ty, _ts, raw in iter_raw(bag)]
        observe('/other', b'not a state')  # ignored
        observe('/swarm/state', raws[7])
        frames = list(c.messages(timeout=2.0))
        observe('/swarm/state', raws[7])  # the same step again: no new frame
        again = list(c.messages(timeout=0.5))
    finally:
        view.close()
    assert len(frames) == 1 and again == [], (len(frames), len(again))
    ents = {e.id: e for e in c.decoder('/swarm/scene').FromString(frames[0][2]).entities}
    p = ents['uav_2'].spheres[0].pose.position
    assert (p.x, p.y, p.z) == pytest.approx(tuple(traj['x'][7, 1]), abs=1e-12)
