"""Topic-level tests of the tracker, plant and target nodes: real processes over DDS."""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np
import pytest
from apf_swarm_core.agents import TrackerAgent
from apf_swarm_core.lockstep import LOOKAHEAD
from apf_swarm_nodes.conversions import dt_to_ns, odom_msg, step_stamp, swarm_state_arrays
from apf_swarm_nodes.node_common import REQUEST_QOS, START_QOS, STATE_QOS, control_qos
from nav_msgs.msg import Odometry
from std_msgs.msg import Empty, UInt64

from apf_swarm_core import load_preset, simulate
from apf_swarm_msgs.msg import ForceCommand, SwarmState

CONFIG = Path(__file__).resolve().parents[2] / 'config'


def start_swarm(g, duration: float, *extra: str, n: int = 3) -> None:
    cfg = str(CONFIG / 'triangle.yaml')
    common = [
        '--params-file',
        cfg,
        '-p',
        f'duration:={duration}',
        '-p',
        f'n_trackers:={n}',
        *extra,
    ]
    g.start('target', 'target', *common, '-r', '__ns:=/target')
    for i in range(1, n + 1):
        g.start(f'tracker{i}', 'tracker', *common, '-p', f'uav_id:={i}', '-r', f'__ns:=/uav_{i}')
    g.start('plant', 'plant', *common, '-p', 'wait_for_start:=true')


def test_lockstep_equals_headless_simulator(graph) -> None:
    """Same preset, seed and dt: the ROS trajectory equals simulate() to 1e-9."""
    steps = 600
    got: dict[int, object] = {}
    graph.node.create_subscription(
        SwarmState,
        '/swarm/state',
        lambda m: got.__setitem__(m.step, swarm_state_arrays(m)),
        STATE_QOS,
    )
    start = graph.node.create_publisher(Empty, '/swarm/start', START_QOS)
    start_swarm(graph, steps * 0.001)
    node = graph.node
    graph.spin_until(
        lambda: (
            all(node.count_publishers(f'/uav_{i}/force_cmd') == 1 for i in (1, 2, 3))
            and node.count_subscribers('/swarm/odom') == 3
            and node.count_publishers('/swarm/state') == 1
            and node.count_subscribers('/target/request') >= 1
            and node.count_subscribers('/swarm/start') >= 1
        ),
        30,
        'the graph',
    )
    start.publish(Empty())
    graph.spin_until(lambda: steps - 1 in got, 120, f'{steps} steps of /swarm/state')
    assert sorted(got) == list(range(steps))
    sim = simulate(load_preset('triangle').replace(duration=steps * 0.001)).trajectory
    for key, attr in (('x', 'x'), ('v', 'v'), ('u', 'u'), ('s', 's'), ('target_x', 'target_x')):
        ros = np.array([getattr(got[k], attr) for k in range(steps)])
        assert np.max(np.abs(ros - sim[key])) <= 1e-9, key
    assert got[steps - 1].missed_deadlines == 0
    # every topic exists with the expected type
    topics = dict(graph.node.get_topic_names_and_types())
    expected = {
        '/uav_1/odom': 'nav_msgs/msg/Odometry',
        '/target/odom': 'nav_msgs/msg/Odometry',
        '/uav_2/force_cmd': 'apf_swarm_msgs/msg/ForceCommand',
        '/swarm/state': 'apf_swarm_msgs/msg/SwarmState',
        '/swarm/odom': 'apf_swarm_msgs/msg/SwarmOdometry',
        '/clock': 'rosgraph_msgs/msg/Clock',
        '/swarm/markers': 'visualization_msgs/msg/MarkerArray',
    }
    for name, typ in expected.items():
        assert topics.get(name) == [typ], name
    assert node.count_publishers('/target/odom') == 1
    assert node.count_subscribers('/target/odom') == 1  # the plant
    assert node.count_subscribers('/uav_3/force_cmd') == 1  # the plant
    for name in list(graph.procs):
        assert graph.stop(name) == 0, graph.log(name)


def test_lockstep_target_answers_requests_ahead_with_the_exact_trajectory(graph) -> None:
    """The lockstep target publishes the states the plant asks for on /target/request:
    every step up to the request, once, each exactly trajectory.state(k dt); asked far
    ahead of what it sent (a target that was stopped, or one that joins late), it skips to
    the last LOOKAHEAD steps instead of replaying the run from step 0; asked the same
    again, it sends that window again."""
    cfg = load_preset('triangle')
    graph.start(
        'target', 'target', '--params-file', str(CONFIG / 'triangle.yaml'), '-r', '__ns:=/target'
    )
    got: dict[int, list] = {}
    dt_ns = dt_to_ns(cfg.dt)

    def on_odom(msg: Odometry) -> None:
        k = (msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec) // dt_ns
        p, v = msg.pose.pose.position, msg.twist.twist.linear
        got.setdefault(int(k), []).append((p.x, p.y, p.z, v.x, v.y, v.z))

    sub = graph.node.create_subscription(
        Odometry, '/target/odom', on_odom, control_qos('lockstep')
    )
    req = graph.node.create_publisher(UInt64, '/target/request', REQUEST_QOS)
    graph.spin_until(
        lambda: req.get_subscription_count() == 1 and sub.get_publisher_count() == 1,
        30,
        'the target',
    )
    # our reader matching the target's writer does not mean its writer has matched our
    # reader yet (what it publishes before that is lost, as for the plant, which repeats its
    # request for a late step): ask for step 0 until it arrives; a repeated request sends
    # that window ([0]) again
    for _ in range(50):
        req.publish(UInt64(data=0))
        if graph.spin_until(lambda: 0 in got, 0.2, 'the state of step 0', fail=False):
            break
    assert 0 in got
    got.clear()
    req.publish(UInt64(data=9))
    graph.spin_until(lambda: 9 in got, 10, 'the states of steps 1..9')
    req.publish(UInt64(data=20))
    graph.spin_until(lambda: 20 in got, 10, 'the states of steps 10..20')
    far = 5000
    req.publish(UInt64(data=far))
    graph.spin_until(lambda: far in got, 10, f'the state of step {far}')
    window = list(range(far + 1 - LOOKAHEAD, far + 1))
    assert sorted(got) == list(range(1, 21)) + window
    assert all(len(v) == 1 for v in got.values())  # each step once
    # the same request again (the plant's step is late): that window once more
    req.publish(UInt64(data=far))
    graph.spin_until(lambda: all(len(got[k]) == 2 for k in window), 10, 'the window again')
    assert all(len(got[k]) == 1 for k in range(1, 21))
    traj = cfg.target_trajectory_obj
    for k, states in got.items():
        x, v = traj.state(k * cfg.dt)
        for px, py, pz, vx, vy, vz in states:
            assert np.array_equal([px, py, pz], x) and np.array_equal([vx, vy, vz], v), k


@pytest.mark.parametrize('inputs', ['odom', 'aggregate'])
def test_lone_tracker_publishes_the_core_force_and_rejects_nan(graph, inputs: str) -> None:
    cfg = load_preset('triangle')
    forces, sub = graph.lone_tracker(f'inputs:={inputs}')
    qos = control_qos('lockstep')
    rng = np.random.default_rng(7)
    x = rng.normal(scale=2.0, size=(3, 3))
    v = rng.normal(size=(3, 3))
    tx, tv = np.array([0.5, -0.2, 4.0]), np.array([1.0, 0.0, 0.0])
    dt_ns = dt_to_ns(cfg.dt)
    if inputs == 'odom':
        pubs = {j: graph.node.create_publisher(Odometry, f'/uav_{j}/odom', qos) for j in (1, 2, 3)}
        tpub = graph.node.create_publisher(Odometry, '/target/odom', qos)
        graph.spin_until(
            lambda: (
                all(p.get_subscription_count() == 1 for p in pubs.values())
                and tpub.get_subscription_count() == 1
            ),
            30,
            'the tracker subscriptions',
        )

        def send(step: int, xs: np.ndarray) -> None:
            stamp = step_stamp(step, dt_ns)
            tpub.publish(odom_msg(tx, tv, stamp, 'target'))
            for j in (1, 2, 3):
                pubs[j].publish(odom_msg(xs[j - 1], v[j - 1], stamp, f'uav_{j}'))
    else:
        from apf_swarm_nodes.conversions import swarm_odom_msg

        from apf_swarm_msgs.msg import SwarmOdometry

        spub = graph.node.create_publisher(SwarmOdometry, '/swarm/odom', qos)
        graph.spin_until(lambda: spub.get_subscription_count() == 1, 30, 'the subscription')

        def send(step: int, xs: np.ndarray) -> None:
            spub.publish(
                swarm_odom_msg(
                    step=step,
                    stamp=step_stamp(step, dt_ns),
                    uav_ids=[1, 2, 3],
                    x=xs,
                    v=v,
                    target_x=tx,
                    target_v=tv,
                )
            )

    # matched, not only discovered: a command sent before this reader matched is lost
    graph.spin_until(lambda: sub.get_publisher_count() == 1, 30, 'the force publisher matched')
    send(0, x)
    graph.spin_until(lambda: len(forces) == 1, 10, 'the force of step 0')
    ref = TrackerAgent(cfg, 2)
    for j in (1, 2, 3):
        ref.offer(j, 0, x[j - 1], v[j - 1], 0.0)
    ref.offer(0, 0, tx, tv, 0.0)
    out = ref.command(0)
    f = forces[0]
    assert f.uav_id == 2 and f.step == 0
    assert np.allclose([f.force.x, f.force.y, f.force.z], out.force[0], atol=1e-12, rtol=0)
    assert np.allclose([f.gradient.x, f.gradient.y, f.gradient.z], out.gradient[0], atol=1e-12)
    assert np.allclose(
        [f.sliding_surface.x, f.sliding_surface.y, f.sliding_surface.z],
        out.sliding_surface[0],
        atol=1e-12,
    )
    # a NaN position is refused: no command for that step, a log line saying so
    bad = x.copy()
    bad[0, 1] = math.nan
    send(1, bad)
    graph.spin_until(lambda: 'rejected' in graph.log('tracker'), 10, 'the rejection log')
    send(2, x + 0.01)
    graph.spin_until(lambda: len(forces) == 2, 10, 'the force of step 2')
    assert forces[1].step == 2
    assert all(math.isfinite(c) for c in (forces[1].force.x, forces[1].force.y, forces[1].force.z))


@pytest.mark.parametrize(
    'args, needle',
    [
        (('-p', 'beta:=-1.0'), 'beta'),
        (('-p', 'uav_id:=4'), 'uav_id'),
        (('-p', 'law:=fuzzy'), 'law'),
        (('-p', 'mode:=sometimes'), 'mode'),
        (('-p', 'n_trackers:=0'), 'n_trackers'),
        (('-p', 'gamma:=not_a_number'), 'gamma'),  # wrong type (without a file, see below)
        (('-p', 'qos_depth:=0'), 'qos_depth'),
    ],
)
def test_bad_parameter_stops_the_node_naming_it(graph, args: tuple[str, ...], needle: str) -> None:
    # rcl lets a params file's value win over a wrongly typed -p, so the type case has none
    files = [] if 'not_a_number' in args[-1] else ['--params-file', str(CONFIG / 'triangle.yaml')]
    p = graph.start('tracker', 'tracker', *files, '-p', 'uav_id:=1', *args)
    assert p.wait(30) == 2
    graph.procs.pop('tracker')
    log = graph.log('tracker')
    assert 'tracker: error:' in log and needle in log, log
    assert 'Traceback' not in log


def test_qos_depth_sets_the_realtime_control_topics_depth(graph) -> None:
    """qos_depth: 7: a realtime tracker's command publisher and its /swarm/odom subscription
    are best effort, keep last 7; lockstep ignores it (reliable, keep last 1000). The nodes
    are built in this process (remote endpoint info does not carry the depth)."""
    from apf_swarm_nodes.tracker_node import TrackerNode
    from rclpy.parameter import Parameter
    from rclpy.qos import ReliabilityPolicy

    for mode, want in (
        ('realtime', (ReliabilityPolicy.BEST_EFFORT, 7)),
        ('lockstep', (ReliabilityPolicy.RELIABLE, 1000)),
    ):
        node = TrackerNode(
            context=graph.node.context,
            namespace='/uav_2',
            parameter_overrides=[
                Parameter('uav_id', value=2),
                Parameter('mode', value=mode),
                Parameter('qos_depth', value=7),
            ],
        )
        try:
            qos = [node.pub.qos_profile] + [sub.qos_profile for sub in node.subscriptions]
            assert {(q.reliability, q.depth) for q in qos} == {want}, mode
        finally:
            node.destroy_node()


def test_realtime_tracker_commands_on_fresh_inputs_and_brakes_when_they_go_stale(graph) -> None:
    """Realtime: commands follow /swarm/odom; once it stops for input_timeout, the tracker
    sends the safe brake (eq. 24 on s = v, brake_force of the last own velocity), flagged."""
    from apf_swarm_core.agents import brake_force
    from apf_swarm_nodes.conversions import swarm_odom_msg

    from apf_swarm_msgs.msg import SwarmOdometry

    # eq. 24 as printed, below; at 50 Hz the tracker predicts the state by the latency
    # (compensation), as the reference agent does before any latency is reported
    cfg = load_preset('realtime').replace(switching='sign', control_rate=50.0)
    timeout = 0.3
    graph.start(
        'tracker',
        'tracker',
        '--params-file',
        str(CONFIG / 'realtime.yaml'),
        '-p',
        'uav_id:=2',
        '-p',
        'mode:=realtime',
        '-p',
        f'input_timeout:={timeout}',
        '-p',
        'control_rate:=50.0',
        '-p',
        'switching:=sign',
        '-r',
        '__ns:=/uav_2',
    )
    qos = control_qos('realtime')
    forces: list[tuple[float, ForceCommand]] = []
    sub = graph.node.create_subscription(
        ForceCommand, '/uav_2/force_cmd', lambda m: forces.append((time.monotonic(), m)), qos
    )
    spub = graph.node.create_publisher(SwarmOdometry, '/swarm/odom', qos)
    graph.spin_until(
        lambda: spub.get_subscription_count() == 1 and sub.get_publisher_count() == 1,
        30,
        'the tracker endpoints',
    )
    rng = np.random.default_rng(3)
    x = rng.normal(scale=2.0, size=(3, 3))
    v = np.array([[0.3, -0.2, 0.1], [0.5, -0.4, 0.2], [0.0, 0.1, -0.3]])
    tx, tv = np.array([0.5, -0.2, 4.0]), np.array([1.0, 0.0, 0.0])
    sent = 0

    def publish() -> None:
        nonlocal sent
        spub.publish(
            swarm_odom_msg(
                step=sent,
                stamp=graph.node.get_clock().now().to_msg(),
                uav_ids=[1, 2, 3],
                x=x,
                v=v,
                target_x=tx,
                target_v=tv,
            )
        )
        sent += 1

    # fresh inputs at ~100 Hz until 20 controller commands came back (the first messages may
    # go out before both sides of the best-effort topics are matched): every command from
    # the first controller command on is one while the inputs keep coming
    feeding = [True]

    def fresh_commands() -> int:
        first = next((i for i, (_, m) in enumerate(forces) if not m.stale), None)
        return 0 if first is None else len(forces) - first

    graph.node.create_timer(0.01, lambda: publish() if feeding[0] else None)
    graph.spin_until(
        lambda: sent >= 40 and fresh_commands() >= 20, 30, '20 controller commands on fresh inputs'
    )
    feeding[0] = False
    stopped = time.monotonic()
    # before the first input the watchdog brakes (nothing is known yet); from the first
    # controller command on, every command is one while the inputs keep coming
    assert forces and any(not m.stale for _, m in forces)
    first = next(i for i, (_, m) in enumerate(forces) if not m.stale)
    fresh = [m for _, m in forces[first:]]
    assert len(fresh) >= 20, len(fresh)  # trigger:=odom, best effort
    assert not any(m.stale for m in fresh)
    ref = TrackerAgent(cfg, 2)
    for j in (1, 2, 3):
        ref.offer(j, -1, x[j - 1], v[j - 1], 0.0)
    ref.offer(0, -1, tx, tv, 0.0)
    grad = ref.command(-1).gradient[0]
    for m in fresh:
        assert np.allclose([m.gradient.x, m.gradient.y, m.gradient.z], grad, atol=1e-12)
        f = np.array([m.force.x, m.force.y, m.force.z])
        assert np.all(np.isfinite(f))
        # eq. 24: -u0 sign(s) + drag v, componentwise, with the velocity predicted by the
        # latency under the held command (at most u0 + drag |v| per axis)
        from apf_swarm_core.config import DEFAULT_LATENCY

        dv = DEFAULT_LATENCY * (cfg.u0 + cfg.drag) / (0.5 * (cfg.mass_lo + cfg.mass_hi))
        assert np.allclose(np.abs(f - cfg.drag * v[1]), cfg.u0, atol=cfg.drag * dv + 1e-9), f
    # inputs stop: within the timeout plus a watchdog period or two, the brake goes out
    graph.spin_until(
        lambda: any(m.stale for t, m in forces if t > stopped), 10, 'a stale-flagged command'
    )
    first_stale = next(t for t, m in forces if m.stale and t > stopped)
    assert timeout <= first_stale - stopped + 0.02 <= timeout + 1.0, first_stale - stopped
    graph.spin_until(
        lambda: sum(m.stale for t, m in forces if t > stopped) >= 5, 10, 'a stream of brakes'
    )
    stale = [m for t, m in forces if m.stale and t > stopped]
    brake = brake_force(v[1], u0=cfg.u0, drag=cfg.drag)
    for m in stale:
        assert np.array_equal([m.force.x, m.force.y, m.force.z], brake)
        assert [m.sliding_surface.x, m.sliding_surface.y, m.sliding_surface.z] == [0, 0, 0]
    assert 'stale inputs' in graph.log('tracker') and 'safe brake' in graph.log('tracker')
    # fresh inputs again: controller commands resume
    n_before = len(forces)
    publish()
    graph.spin_until(
        lambda: any(not m.stale for _, m in forces[n_before:]),
        10,
        'a controller command after the inputs came back',
    )


def test_parameters_set_at_run_time_are_applied_or_refused_with_a_reason(graph) -> None:
    """A running tracker takes a valid gain at once, refuses a bad one with the core's
    reason, and refuses read-only keys; the plant and the target refuse every key."""
    from apf_swarm_nodes.conversions import swarm_odom_msg
    from rclpy.parameter import Parameter
    from rclpy.parameter_client import AsyncParameterClient

    from apf_swarm_msgs.msg import SwarmOdometry

    cfg = load_preset('triangle')
    graph.start(
        'tracker',
        'tracker',
        '--params-file',
        str(CONFIG / 'triangle.yaml'),
        '-p',
        'uav_id:=2',
        '-r',
        '__ns:=/uav_2',
    )
    qos = control_qos('lockstep')
    forces: list[ForceCommand] = []
    sub = graph.node.create_subscription(ForceCommand, '/uav_2/force_cmd', forces.append, qos)
    spub = graph.node.create_publisher(SwarmOdometry, '/swarm/odom', qos)
    client = AsyncParameterClient(graph.node, '/uav_2/tracker')
    graph.spin_until(
        lambda: (
            spub.get_subscription_count() == 1
            and sub.get_publisher_count() == 1
            and client.services_are_ready()
        ),
        30,
        'the tracker endpoints',
    )

    def set_params(**values) -> list:
        return graph.call(
            lambda: client.set_parameters([Parameter(k, value=v) for k, v in values.items()]),
            30,
            f'the answer to setting {values}',
        ).results

    x = np.array([[3.0, 0.0, 0.0], [0.0, 2.0, 0.5], [-1.0, -1.0, 0.0]])
    v = np.array([[0.0, 0.0, 0.0], [0.4, -0.3, 0.2], [0.0, 0.0, 0.0]])
    tx, tv = np.array([0.0, 0.0, 4.0]), np.zeros(3)

    def command(step: int) -> np.ndarray:
        spub.publish(
            swarm_odom_msg(
                step=step,
                stamp=step_stamp(step, dt_to_ns(cfg.dt)),
                uav_ids=[1, 2, 3],
                x=x,
                v=v,
                target_x=tx,
                target_v=tv,
            )
        )
        graph.spin_until(lambda: any(m.step == step for m in forces), 10, f'step {step}')
        m = next(m for m in forces if m.step == step)
        return np.array([m.force.x, m.force.y, m.force.z])

    f0 = command(0)
    assert np.allclose(np.abs(f0 - cfg.drag * v[1]), cfg.u0, atol=1e-9)
    # a bad value: refused with the core's reason, nothing changes
    (res,) = set_params(gamma=-1.0)
    assert not res.successful and 'gamma' in res.reason, res.reason
    (res,) = set_params(u0=-5.0)
    assert not res.successful and 'u0' in res.reason, res.reason
    # read-only: refused by rclpy
    (res,) = set_params(dt=0.002)
    assert not res.successful and 'read-only' in res.reason, res.reason
    assert np.allclose(np.abs(command(1) - cfg.drag * v[1]), cfg.u0, atol=1e-9)
    # a good value: applied from the next command on
    (res,) = set_params(u0=40.0)
    assert res.successful, res.reason
    assert np.allclose(np.abs(command(2) - cfg.drag * v[1]), 40.0, atol=1e-9)
    graph.spin_until(lambda: 'retuned: u0 = 40.0' in graph.log('tracker'), 10, 'the log line')
    # the target's parameters are all read-only
    graph.start(
        'target', 'target', '--params-file', str(CONFIG / 'triangle.yaml'), '-r', '__ns:=/target'
    )
    tclient = AsyncParameterClient(graph.node, '/target/target')
    graph.spin_until(tclient.services_are_ready, 30, 'the target parameter services')
    (res,) = graph.call(
        lambda: tclient.set_parameters([Parameter('target_speed', value=3.0)]),
        30,
        'the target answer',
    ).results
    assert not res.successful and 'read-only' in res.reason, res.reason
