"""Trackers against a vehicle that speaks only standard messages: a stand-in plant, written
here with geometry_msgs and nav_msgs alone, publishes ``nav_msgs/Odometry`` per UAV and for
the target, and flies each UAV by its tracker's ``geometry_msgs/AccelStamped`` (the
tracker's ``outputs:=accel,velocity``). The plant reads no apf_swarm message (the test reads
each ForceCommand only to check the setpoints against it); the swarm must still hold its
formation, each acceleration setpoint must be eq. 19's acceleration under the force, without
the unknown term, and each velocity setpoint the velocity that acceleration reaches in one
step."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from apf_swarm_core.config_files import load_preset
from apf_swarm_core.formation import design_pair_sets
from apf_swarm_core.metrics import flight
from apf_swarm_core.simulator import initial_positions, simulate
from apf_swarm_nodes.node_common import control_qos
from geometry_msgs.msg import AccelStamped, TwistStamped
from nav_msgs.msg import Odometry

from apf_swarm_msgs.msg import ForceCommand

CONFIG = Path(__file__).resolve().parents[2] / 'config'
N = 3
RESEND = 0.2  # [s]
SECONDS = 6.0  # of simulated time: at DT the triangle converges in about 3 s
DT = 0.01  # [s]: 600 steps (the preset's 1 ms would be 6000 round trips)
MASS, DRAG = 1.4, 0.5  # off the preset's 1 and 0.1, so that a wrong M or f_known shows


def odometry(stamp_ns: int, x: np.ndarray, v: np.ndarray, child: str) -> Odometry:
    m = Odometry()
    m.header.stamp.sec, m.header.stamp.nanosec = divmod(stamp_ns, 1_000_000_000)
    m.header.frame_id = 'world'
    m.child_frame_id = child
    p, t = m.pose.pose.position, m.twist.twist.linear
    p.x, p.y, p.z = (float(c) for c in x)
    t.x, t.y, t.z = (float(c) for c in v)
    m.pose.pose.orientation.w = 1.0
    return m


def test_three_trackers_fly_a_plant_of_standard_messages(graph: Any) -> None:
    cfg = load_preset('triangle').replace(duration=SECONDS, dt=DT, mass=(MASS,), drag=DRAG)
    # the target's path as the headless simulator flies it (no control involved)
    ref = simulate(cfg).trajectory
    dt_ns = round(cfg.dt * 1e9)
    steps = len(ref['t'])
    for i in range(1, N + 1):
        graph.start(
            f'tracker{i}',
            'tracker',
            '--params-file',
            str(CONFIG / 'triangle.yaml'),
            '-p',
            f'uav_id:={i}',
            '-p',
            'inputs:=odom',
            '-p',
            'outputs:=accel,velocity',
            '-p',
            f'dt:={DT}',
            '-p',
            f'mass:=[{MASS}]',
            '-p',
            f'drag:={DRAG}',
            '-r',
            f'__ns:=/uav_{i}',
        )
    qos = control_qos('lockstep')
    node = graph.node
    odom = {i: node.create_publisher(Odometry, f'/uav_{i}/odom', qos) for i in range(1, N + 1)}
    target = node.create_publisher(Odometry, '/target/odom', qos)
    accel: dict[int, dict[int, np.ndarray]] = {i: {} for i in range(1, N + 1)}
    vel: dict[int, dict[int, np.ndarray]] = {i: {} for i in range(1, N + 1)}
    force: dict[int, dict[int, np.ndarray]] = {i: {} for i in range(1, N + 1)}

    def stamp_step(msg) -> int:
        return round((msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec) / dt_ns)

    def on_accel(i: int, msg: AccelStamped) -> None:
        assert msg.header.frame_id == 'world'
        a = msg.accel.linear
        accel[i][stamp_step(msg)] = np.array([a.x, a.y, a.z])

    def on_vel(i: int, msg: TwistStamped) -> None:
        assert msg.header.frame_id == 'world'
        v = msg.twist.linear
        vel[i][stamp_step(msg)] = np.array([v.x, v.y, v.z])

    def on_force(i: int, msg: ForceCommand) -> None:
        f = msg.force
        force[i][int(msg.step)] = np.array([f.x, f.y, f.z])

    subs = []
    for i in range(1, N + 1):
        subs.append(
            node.create_subscription(
                ForceCommand, f'/uav_{i}/force_cmd', lambda m, i=i: on_force(i, m), qos
            )
        )
        subs.append(
            node.create_subscription(
                AccelStamped, f'/uav_{i}/accel_cmd', lambda m, i=i: on_accel(i, m), qos
            )
        )
        subs.append(
            node.create_subscription(
                TwistStamped, f'/uav_{i}/velocity_cmd', lambda m, i=i: on_vel(i, m), qos
            )
        )
    graph.spin_until(
        lambda: (
            all(p.get_subscription_count() == N for p in odom.values())
            and target.get_subscription_count() == N
            and all(s.get_publisher_count() == 1 for s in subs)
        ),
        60,
        'the trackers matched to the stand-in plant',
    )
    x = initial_positions(cfg)
    v = np.zeros_like(x)
    xs = [x.copy()]
    dt = cfg.dt

    def publish(k: int) -> None:
        stamp = k * dt_ns
        target.publish(odometry(stamp, ref['target_x'][k], ref['target_v'][k], 'target'))
        for i in range(1, N + 1):
            odom[i].publish(odometry(stamp, x[i - 1], v[i - 1], f'uav_{i}'))

    for k in range(steps - 1):
        # as the plant does: a step whose commands have not all come within RESEND is sent
        # again (a reliable sample lost on the way is otherwise repaired only at Fast DDS's
        # next heartbeat, seconds later); a tracker ignores inputs it already has
        for _ in range(round(30 / RESEND)):
            publish(k)
            if graph.spin_until(
                lambda k=k: all(k in accel[i] and k in vel[i] and k in force[i] for i in accel),
                RESEND,
                f'every tracker commanding step {k}',
                fail=False,
            ):
                break
        else:
            raise AssertionError(f'no command of every tracker for step {k} in 30 s')
        a = np.stack([accel[i][k] for i in range(1, N + 1)])
        # the acceleration setpoint is eq. 19 under the tracker's force, without f_unknown
        u = np.stack([force[i][k] for i in range(1, N + 1)])
        np.testing.assert_allclose(a, (u - DRAG * v) / MASS, rtol=1e-12, atol=1e-12)
        # the velocity setpoint is where the acceleration takes the velocity in one step
        vsp = np.stack([vel[i][k] for i in range(1, N + 1)])
        np.testing.assert_allclose(vsp, v + a * dt, rtol=1e-12, atol=1e-12)
        x = x + v * dt + a * dt * dt / 2
        v = v + a * dt
        xs.append(x.copy())
    traj = {
        't': ref['t'],
        'x': np.stack(xs),
        'target_x': ref['target_x'],
        'target_v': ref['target_v'],
    }
    verdict = flight(traj, design_pair_sets(cfg))
    assert verdict['flies'], verdict
