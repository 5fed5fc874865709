"""Faults and bad input at topic level: real node processes over DDS (docs/RELIABILITY.md).

Each test starts the nodes itself in an isolated domain (``graph`` fixture), provokes one
fault with a real signal or real bad messages, and checks what the graph does, by number.
"""

from __future__ import annotations

import math
import os
import signal
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import rclpy.duration
from apf_swarm_core.agents import brake_force
from apf_swarm_core.design import expected_spacing
from apf_swarm_nodes.conversions import (
    dt_to_ns,
    force_msg,
    odom_msg,
    step_stamp,
    swarm_odom_msg,
    swarm_state_arrays,
)
from apf_swarm_nodes.node_common import START_QOS, STATE_QOS, control_qos
from nav_msgs.msg import Odometry
from std_msgs.msg import Empty

from apf_swarm_core import load_preset, simulate
from apf_swarm_msgs.msg import ForceCommand, SwarmOdometry, SwarmState

CONFIG = Path(__file__).resolve().parents[2] / 'config'
TRIANGLE = str(CONFIG / 'triangle.yaml')


def start_nodes(
    g,
    duration: float,
    *extra: str,
    trackers=(1, 2, 3),
    timeout: float = 0.2,
    plant: bool = True,
    target: bool = True,
    target_env: dict[str, str] | None = None,
) -> None:
    common = ['--params-file', TRIANGLE, '-p', f'duration:={duration}', *extra]
    if target:
        g.start('target', 'target', *common, '-r', '__ns:=/target', env=target_env)
    for i in trackers:
        g.start(f'tracker{i}', 'tracker', *common, '-p', f'uav_id:={i}', '-r', f'__ns:=/uav_{i}')
    if plant:
        g.start(
            'plant',
            'plant',
            *common,
            '-p',
            'wait_for_start:=true',
            '-p',
            f'command_timeout:={timeout}',
        )


def lone_tracker(g, uav: int, mode: str, params_file: str, *extra: str):
    """One tracker process fed by the test: (the ForceCommands it sends, a /swarm/odom
    publisher), once both are matched."""
    g.start(
        'tracker',
        'tracker',
        '--params-file',
        params_file,
        '-p',
        f'uav_id:={uav}',
        '-p',
        f'mode:={mode}',
        *extra,
        '-r',
        f'__ns:=/uav_{uav}',
    )
    qos = control_qos(mode)
    forces: list[ForceCommand] = []
    g.node.create_subscription(ForceCommand, f'/uav_{uav}/force_cmd', forces.append, qos)
    spub = g.node.create_publisher(SwarmOdometry, '/swarm/odom', qos)
    g.spin_until(
        lambda: (
            spub.get_subscription_count() == 1
            and g.node.count_publishers(f'/uav_{uav}/force_cmd') == 1
        ),
        30,
        'the tracker endpoints',
    )
    return forces, spub


class StateLog:
    """Every /swarm/state sample the observer receives, as arrays, by step."""

    def __init__(self, g) -> None:
        self.by_step: dict[int, object] = {}
        g.node.create_subscription(SwarmState, '/swarm/state', self._on, STATE_QOS)

    def _on(self, msg: SwarmState) -> None:
        self.by_step[int(msg.step)] = swarm_state_arrays(msg)

    @property
    def last(self):
        return self.by_step[max(self.by_step)] if self.by_step else None

    def step(self) -> int:
        return max(self.by_step) if self.by_step else -1


def go(g, procs_ready) -> None:
    start = g.node.create_publisher(Empty, '/swarm/start', START_QOS)
    g.spin_until(procs_ready, 30, 'the graph')
    start.publish(Empty())


def graph_ready(g, n: int = 3):
    node = g.node
    return lambda: (
        all(node.count_publishers(f'/uav_{i}/force_cmd') >= 1 for i in range(1, n + 1))
        and node.count_subscribers('/swarm/odom') >= n
        and node.count_publishers('/swarm/state') == 1
        and node.count_subscribers('/swarm/start') >= 1
    )


def pair(x: np.ndarray, i: int, j: int) -> np.ndarray:
    return np.linalg.norm(x[..., i, :] - x[..., j, :], axis=-1)


def test_a_killed_tracker_drops_out_and_the_others_form_the_pair(graph) -> None:
    """Lockstep: SIGKILL tracker 3 once the triangle stands. The barrier does not hang:
    after 2 x command_timeout uav_3 is inactive (zero force, flagged in /swarm/state); the
    others take it out of the formation term and avoid it as an obstacle, and once it has
    drifted away uav_1 and uav_2 settle at the pair spacing of n = 2,
    sqrt(c ln(b / (a + k_N/(2 k_f)))), on opposite sides of the target."""
    cfg = load_preset('triangle')
    d2 = expected_spacing(2, **cfg.potential_params())
    d3 = expected_spacing(3, **cfg.potential_params())
    assert abs(d2 - d3) > 0.03 * d3  # the two shapes are told apart below
    log = StateLog(graph)
    start_nodes(graph, 60.0)
    go(graph, graph_ready(graph))
    graph.spin_until(lambda: log.step() >= 3000, 60, '3 s of simulated flight')
    x = log.last.x
    assert np.allclose([pair(x, 0, 1), pair(x, 0, 2), pair(x, 1, 2)], d3, rtol=0.01)
    os.kill(graph.procs['tracker3'].pid, signal.SIGKILL)
    graph.procs.pop('tracker3').wait(5)
    killed = time.monotonic()
    graph.spin_until(
        lambda: log.last is not None and not log.last.active[2], 30, 'uav_3 marked inactive'
    )
    # the barrier waited 2 x command_timeout (0.2 s each), then went on without uav_3
    assert time.monotonic() - killed < 2 * 0.2 + 3.0
    gone = log.step()
    graph.spin_until(lambda: log.step() >= gone + 8000, 90, '8 s more of simulated flight')
    assert 'no command from' in graph.log('plant') and "['uav_3']" in graph.log('plant')
    last = log.last
    assert last.missed_deadlines == 1
    assert last.active == (True, True, False)
    after = [log.by_step[k] for k in range(gone, log.step() + 1) if k in log.by_step]
    xa = np.array([s.x for s in after])
    # uav_3 is avoided, not followed: the others never come close to the drifting UAV
    assert np.min([pair(xa, 0, 2), pair(xa, 1, 2)]) > 0.5
    steady = [log.by_step[k] for k in range(gone + 6000, log.step() + 1) if k in log.by_step]
    assert len(steady) > 1900
    xs = np.array([s.x for s in steady])
    assert np.allclose(pair(xs, 0, 1), d2, rtol=0.01), (pair(xs, 0, 1).min(), d2)
    tx = np.array([s.target_x for s in steady])
    # the pair's midpoint sits on the target (within the moving target's lag)
    assert np.max(np.linalg.norm(xs[:, :2].mean(axis=1) - tx, axis=-1)) < 0.3
    # uav_3 gets no force and drifts, far from the formation it left
    assert all(np.array_equal(s.u[2], np.zeros(3)) for s in steady)
    assert np.min([pair(xs, 0, 2), pair(xs, 1, 2)]) > 2.5  # repulsion weight < 0.15 there
    for i in (1, 2):
        assert 'potential over 1 neighbours (was 2)' in graph.log(f'tracker{i}')


def test_a_silent_target_is_held_then_the_trackers_brake_and_recover(graph) -> None:
    """Lockstep: SIGSTOP the target. After 2 x command_timeout the plant holds its last
    state and stops waiting for it; its age grows in /swarm/state; past input_timeout
    (0.5 s of simulated time) every tracker sends the safe brake, flagged stale. SIGCONT:
    the target publishes again, its age returns to 0 and the trackers command again.

    The target runs off shared memory (``Graph.no_shared_memory``): a target stopped while
    one of its threads holds the mutex of the plant's shared-memory port stalls every
    tracker's command into that port for the lock's 1 s timeout, and the plant counts all
    three trackers missed at one step besides the target (missed_deadlines 4, not 1)."""
    cfg = load_preset('triangle')
    log = StateLog(graph)
    commands: list[tuple[int, int, bool]] = []  # step, uav_id, stale
    for i in (1, 2, 3):
        graph.node.create_subscription(
            ForceCommand,
            f'/uav_{i}/force_cmd',
            lambda m: commands.append((int(m.step), int(m.uav_id), bool(m.stale))),
            control_qos('lockstep'),
        )
    start_nodes(graph, 60.0, target_env=graph.no_shared_memory())
    go(graph, graph_ready(graph))
    graph.spin_until(lambda: log.step() >= 2000, 60, '2 s of simulated flight')
    target = graph.procs['target']
    os.killpg(target.pid, signal.SIGSTOP)
    try:
        stopped = log.step()
        graph.spin_until(lambda: log.last.target_age > 1.0, 60, 'a target older than 1 s')
        held = log.last
        assert held.stale_inputs >= 3
        assert held.missed_deadlines == 1
        # the target state is frozen while it is silent
        k0 = next(k for k in sorted(log.by_step) if k > stopped and log.by_step[k].target_age > 0)
        assert np.array_equal(log.by_step[k0].target_x, held.target_x)
        # every tracker brakes once the target is older than input_timeout = 0.5 s: judged
        # on every command this observer saw (a loaded observer may miss some, never the
        # order), a brake never comes early and every command later than 2 steps is one
        seen = [(k, u, st, log.by_step[k].target_age) for k, u, st in commands if k in log.by_step]
        for u in (1, 2, 3):
            mine = [(k, st, age) for k, uu, st, age in seen if uu == u]
            assert any(st for _, st, _ in mine), (u, 'no brake seen')
            early = [(k, age) for k, st, age in mine if st and age <= 0.5]
            late = [(k, age) for k, st, age in mine if not st and age > 0.5 + 2 * cfg.dt]
            assert not early and not late, (u, early[:3], late[:3])
        # braking: the speed of every UAV falls
        assert np.all(np.linalg.norm(held.v, axis=-1) < 1.0)
        plant_log = graph.log('plant')
        assert 'no target state' in plant_log and 'holding the last one' in plant_log
        for i in (1, 2, 3):
            assert "stale inputs ['target']" in graph.log(f'tracker{i}')
    finally:
        os.killpg(target.pid, signal.SIGCONT)
    graph.spin_until(lambda: log.last.target_age == 0.0, 30, 'the target back')
    back = log.step()
    graph.spin_until(lambda: log.step() >= back + 500, 30, '0.5 s more')
    # no brake for any step after the target came back (by step: answers still in flight
    # for the steps before may arrive late)
    stale = sorted(k for k, _, st in commands if st)
    assert not [k for k in stale if k > back], stale[-5:]
    assert 'the target publishes again' in graph.log('plant')


def test_the_plant_refuses_bad_commands_and_counts_them(graph) -> None:
    """A plant and a target; the test plays the three trackers and sends, besides valid
    commands, one of each bad kind. Each is refused with its reason, the run goes on, and
    /swarm/state counts the refusals plus what the trackers report."""
    log = StateLog(graph)
    qos = control_qos('lockstep')
    pubs = {
        i: graph.node.create_publisher(ForceCommand, f'/uav_{i}/force_cmd', qos) for i in (1, 2, 3)
    }
    bad_target = graph.node.create_publisher(Odometry, '/target/odom', qos)
    dt_ns = dt_to_ns(0.001)
    zero = np.zeros(3)
    plan: dict[int, list] = {
        5: [
            (1, 1, [math.nan, 0, 0]),  # NaN force
            (2, 2, [2e6, 0, 0]),  # out of range
            (3, 2, [0, 0, 0]),  # on /uav_3/force_cmd, claims uav_id 2
            (1, 7, [0, 0, 0]),
        ],  # an id that is not in the swarm
        6: [('dup', 1, [0, 0, 0])],  # a second command of uav_1 for step 6
        7: [('old', 2, [0, 0, 0])],  # uav_2 answers step 3 again (out of order)
    }

    def cmd(uav: int, step: int, f, rejected: int = 0) -> ForceCommand:
        return force_msg(
            uav_id=uav,
            step=step,
            law='proposed',
            stamp=step_stamp(step, dt_ns),
            force=np.asarray(f, float),
            sliding_surface=zero,
            gradient=zero,
            filter_state=zero,
            saturated=False,
            rejected_inputs=rejected,
        )

    def on_odom(msg: SwarmOdometry) -> None:
        k = int(msg.step)
        for topic, uav, f in plan.get(k, []):
            if isinstance(topic, int):
                pubs[topic].publish(cmd(uav, k, f))
        if k == 5:
            bad_target.publish(
                odom_msg(np.array([math.inf, 0, 0]), zero, step_stamp(k + 1, dt_ns), 'target')
            )
        for i in (1, 2, 3):  # the valid answers; uav_3 reports 2 rejections of its own
            pubs[i].publish(cmd(i, k, zero, rejected=2 if i == 3 else 0))
        for topic, uav, f in plan.get(k, []):
            if topic == 'dup':
                pubs[uav].publish(cmd(uav, k, f))
            elif topic == 'old':
                pubs[uav].publish(cmd(uav, 3, f))

    # the plant starts step 0 once n readers of /swarm/odom are matched: one per "tracker"
    graph.node.create_subscription(SwarmOdometry, '/swarm/odom', on_odom, qos)
    for _ in (2, 3):
        graph.node.create_subscription(SwarmOdometry, '/swarm/odom', lambda m: None, qos)
    # the test answers from its own single-threaded executor: a generous deadline, so that a
    # loaded machine cannot turn a slow answer into a missed deadline (not what this tests)
    start_nodes(graph, 0.02, trackers=(), timeout=2.0)
    go(
        graph,
        lambda: (
            graph.node.count_subscribers('/uav_1/force_cmd') == 1
            and all(p.get_subscription_count() == 1 for p in pubs.values())
            and graph.node.count_subscribers('/swarm/odom') >= 3
            and graph.node.count_publishers('/swarm/odom') == 1
            and graph.node.count_subscribers('/swarm/start') >= 1
        ),
    )
    graph.spin_until(lambda: log.step() >= 19, 30, 'the 20 steps')
    assert sorted(log.by_step) == list(range(20))
    last = log.last
    assert last.missed_deadlines == 0
    assert last.rejected_inputs == 7 + 2, last.rejected_inputs
    assert np.all(np.isfinite([s.x for s in log.by_step.values()]))
    # zero force all along: the bad commands never reached the plant's model
    assert all(np.array_equal(s.u, np.zeros((3, 3))) for s in log.by_step.values())
    text = graph.log('plant')
    # one line per kind of reason (the same kind is not repeated within a second)
    for needle in (
        'force is not finite',
        'exceeds 1e+06',
        'claims uav_id',
        'second command of uav_1 for step 6',
        'out of order',
        'target state: x is not finite',
    ):
        assert needle in text, needle


def test_the_tracker_refuses_bad_odometry_and_reports_the_count(graph) -> None:
    """A lone tracker: out-of-range, out-of-order and malformed /swarm/odom messages get
    no command; the next valid one does, and its ForceCommand carries the count."""
    forces, spub = lone_tracker(graph, 2, 'lockstep', TRIANGLE)
    dt_ns = dt_to_ns(0.001)
    x = np.array([[3.0, 0.0, 0.0], [0.0, 2.0, 0.5], [-1.0, -1.0, 0.0]])
    v = np.zeros((3, 3))
    tx = np.array([0.0, 0.0, 4.0])

    def send(step: int, xs=x, vs=v, ids=(1, 2, 3), active=None) -> None:
        spub.publish(
            swarm_odom_msg(
                step=step,
                stamp=step_stamp(step, dt_ns),
                uav_ids=ids,
                x=xs,
                v=vs,
                target_x=tx,
                target_v=np.zeros(3),
                active=active,
            )
        )

    send(10)
    graph.spin_until(lambda: len(forces) == 1, 10, 'the command of step 10')
    huge = x.copy()
    huge[0, 0] = 5e6
    send(11, xs=huge)  # position out of range
    fast = v.copy()
    fast[2, 1] = -2e4
    send(12, vs=fast)  # speed out of range
    send(9)  # older than step 10: out of order
    send(13, ids=(1, 2, 2))  # an id twice
    send(14, active=[True, True])  # flags do not match the ids
    send(15)
    graph.spin_until(lambda: len(forces) == 2, 10, 'the command of step 15')
    assert [f.step for f in forces] == [10, 15]
    assert forces[0].rejected_inputs == 0
    assert forces[1].rejected_inputs == 5, forces[1].rejected_inputs
    text = graph.log('tracker')
    for needle in (
        'exceeds 1e+06',
        'exceeds 10000',
        'out of order',
        'lists a uav_id twice',
        '2 active flags',
    ):
        assert needle in text, needle


def test_a_duplicate_tracker_is_detected_and_the_run_stays_exact(graph) -> None:
    """A second tracker process with uav_id 2: the plant logs the duplicate, follows the
    process that commanded first and refuses the other, so the run still equals the
    simulator."""
    steps = 1500
    log = StateLog(graph)
    start_nodes(graph, steps * 0.001, timeout=1.0)
    graph.start(
        'tracker2dup',
        'tracker',
        '--params-file',
        TRIANGLE,
        '-p',
        f'duration:={steps * 0.001}',
        '-p',
        'uav_id:=2',
        '-r',
        '__ns:=/uav_2',
        '-r',
        '__node:=tracker_copy',
    )
    go(
        graph,
        lambda: (
            graph_ready(graph)()
            and graph.node.count_publishers('/uav_2/force_cmd') == 2
            and graph.node.count_subscribers('/swarm/odom') == 4
        ),
    )
    graph.spin_until(lambda: log.step() >= steps - 1, 120, f'{steps} steps')
    cfg = load_preset('triangle').replace(duration=steps * 0.001)
    sim = simulate(cfg).trajectory
    ros = np.array([log.by_step[k].x for k in range(steps)])
    assert np.max(np.abs(ros - sim['x'])) <= 1e-9
    last = log.last
    assert last.missed_deadlines == 0
    assert last.rejected_inputs >= steps // 2  # the copy's answers, refused
    assert 'duplicate uav_id 2: 2 publishers on /uav_2/force_cmd' in graph.log('plant')
    assert 'duplicate uav_id 2: a command from a second tracker process' in graph.log('plant')


def test_realtime_tracker_treats_old_stamps_as_stale_and_refuses_out_of_order(graph) -> None:
    """Realtime: /swarm/odom stamped 2 s in the past arrives, but its state is old, so the
    tracker brakes (flagged stale); fresh stamps give controller commands again; a message
    stamped before the one held is refused as out of order and counted."""
    forces, spub = lone_tracker(
        graph, 1, 'realtime', str(CONFIG / 'realtime.yaml'), '-p', 'input_timeout:=0.3'
    )
    cfg = load_preset('realtime')
    x = np.array([[3.0, 0.0, 0.0], [0.0, 2.0, 0.5], [-1.0, -1.0, 0.0]])
    v = np.full((3, 3), 0.2)
    clock = graph.node.get_clock()

    def send(offset_s: float) -> None:
        stamp = (clock.now() - rclpy.duration.Duration(seconds=offset_s)).to_msg()
        spub.publish(
            swarm_odom_msg(
                step=0,
                stamp=stamp,
                uav_ids=[1, 2, 3],
                x=x,
                v=v,
                target_x=np.zeros(3),
                target_v=np.zeros(3),
            )
        )

    def stream(offset_of: Callable[[int], float], until: Callable[[], bool], what: str) -> None:
        """Publish at 100 Hz, message k stamped offset_of(k) s ago, until ``until()``."""
        sent = [0]

        def tick() -> None:
            send(offset_of(sent[0]))
            sent[0] += 1

        timer = graph.node.create_timer(0.01, tick)
        graph.spin_until(lambda: sent[0] >= 30 and until(), 20, what)
        timer.cancel()

    # 2 s old (each message a little newer than the last): received, but stale. The brake is
    # that of the received own velocity, -u0 sign(v) + drag v (with nothing received it
    # would be zero), so these commands prove the old states arrived and were judged stale
    brake = brake_force(v[0], u0=cfg.u0, drag=cfg.drag)

    def brakes_on_old_input() -> bool:
        return sum(np.array_equal([m.force.x, m.force.y, m.force.z], brake) for m in forces) >= 5

    stream(lambda k: 2.0 - 0.001 * k, brakes_on_old_input, 'brakes on the old states')
    n_old = len(forces)
    assert all(m.stale for m in forces), [m.stale for m in forces]
    stream(
        lambda k: 0.0,
        lambda: any(not m.stale for m in forces[n_old:]),
        'controller commands on fresh inputs',
    )
    before = forces[-1].rejected_inputs

    def older() -> bool:  # older than the newest held
        send(1.0)  # (best effort, depth 1: resend)
        graph.executor.spin_once(timeout_sec=0.05)
        return 'out of order' in graph.log('tracker')

    graph.spin_until(older, 10, 'the out-of-order refusal')

    def fresh_again() -> bool:
        send(0.0)
        graph.executor.spin_once(timeout_sec=0.05)
        return forces[-1].rejected_inputs > before

    graph.spin_until(fresh_again, 10, 'the refusal counted in the next command')
    assert not forces[-1].stale
