"""The ROS-free logic of the nodes: TrackerAgent and PlantModel against the simulator."""

from __future__ import annotations

import math

import numpy as np
import pytest
from apf_swarm_core.agents import TrackerAgent, brake_force
from apf_swarm_core.inputs import MAX_FORCE, MAX_POSITION, MAX_SPEED, input_problem
from apf_swarm_core.plant_model import PlantModel
from apf_swarm_core.simulator import BatchSimulator

from apf_swarm_core import load_preset


@pytest.fixture
def cfg():
    return load_preset('triangle')


def feed(agent: TrackerAgent, step: int, x, v, tx, tv, now: float = 0.0) -> None:
    for j in range(1, agent.cfg.n_trackers + 1):
        assert agent.offer(j, step, x[j - 1], v[j - 1], now)
    assert agent.offer(0, step, tx, tv, now)


def test_trackers_and_plant_reproduce_the_simulator_bit_for_bit(cfg) -> None:
    """Three agents and a PlantModel stepped by hand == BatchSimulator, 300 steps, exactly."""
    sim = BatchSimulator([cfg])
    agents = [TrackerAgent(cfg, i) for i in (1, 2, 3)]
    plant = PlantModel(cfg)
    assert np.array_equal(plant.x, sim.x[0])
    for k in range(300):
        tx, tv = sim.target.state(k)
        for a in agents:
            feed(a, k, plant.x, plant.v, tx[0], tv[0])
            assert a.ready(k)
        outs = [a.command(k) for a in agents]
        for i, (a, out) in enumerate(zip(agents, outs, strict=False), start=1):
            assert not a.ready(k)  # answered once
            assert plant.offer_command(i, k, out.force[0], out.sliding_surface[0])
        assert plant.missing(k) == []
        ref, _, _ = sim.step()
        assert np.array_equal(np.concatenate([o.force for o in outs]), ref.force[0])
        plant.advance()
        assert np.array_equal(plant.x, sim.x[0]) and np.array_equal(plant.v, sim.v[0])
    assert plant.k == 300


def test_offer_refuses_non_finite_unknown_and_out_of_order_inputs(cfg) -> None:
    a = TrackerAgent(cfg, 2)
    ok = np.zeros(3)
    assert not a.offer(1, 0, np.array([0.0, math.nan, 0.0]), ok, 0.0)
    assert not a.offer(0, 0, ok, np.array([math.inf, 0.0, 0.0]), 0.0)
    assert not a.offer(7, 0, ok, ok, 0.0)  # no tracker 7 in a swarm of 3
    assert a.rejected == 3
    assert a.offer(1, 5, ok, ok, 0.0)
    assert not a.offer(1, 4, ok, ok, 0.0)  # older than the held step 5
    assert a.rejected == 4
    assert not a.ready(5)  # 0, 2 and 3 are still missing
    with pytest.raises(ValueError, match='uav_id = 4'):
        TrackerAgent(cfg, 4)


def _input_problem_reference(name: str, arr) -> str | None:
    """The check as it was written before the one-reduction fast path (the reference)."""
    lim = {
        'x': MAX_POSITION,
        'target_x': MAX_POSITION,
        'v': MAX_SPEED,
        'force': MAX_FORCE,
        's': MAX_SPEED,
    }[name]
    a = np.asarray(arr, dtype=float)
    if not np.all(np.isfinite(a)):
        return f'{name} is not finite ({a.tolist()})'
    if np.any(np.abs(a) > lim):
        return f'{name} = {a.tolist()} exceeds {lim:g} in magnitude'
    return None


@pytest.mark.parametrize('name', ['x', 'target_x', 'v', 'force', 's'])
def test_input_problem_equals_the_elementwise_checks(name: str) -> None:
    """The fast path (max |value| <= limit, false for NaN) gives the same verdict and message
    as isfinite + a comparison per element, for every kind of value."""
    lim = {
        'x': MAX_POSITION,
        'target_x': MAX_POSITION,
        'v': MAX_SPEED,
        'force': MAX_FORCE,
        's': MAX_SPEED,
    }[name]
    cases = [
        np.zeros(3),
        np.array([1.0, -2.0, 3.0]),
        np.array([math.nan, 0, 0]),
        np.array([0, math.inf, 0]),
        np.array([0, 0, -math.inf]),
        np.zeros(0),
        np.array([1, 2, 3]),
        np.float64(2.0),
        np.array(math.nan),
        np.array([lim, -lim, 0]),
        np.array([np.nextafter(lim, np.inf), 0, 0]),
        np.array([[0.0, 1.0, 2.0], [3.0, math.nan, 5.0]]),
        [0.5, 0.25, -lim],
    ]
    for arr in cases:
        assert input_problem(**{name: arr}) == _input_problem_reference(name, arr), arr


def test_offer_swarm_refuses_a_bad_row_and_ignores_rows_of_non_neighbours(cfg) -> None:
    """All rows are checked at once; a message that fails is checked row by row: a NaN in a
    neighbour's row refuses the whole message (one rejection, nothing stored), a NaN in the
    row of a tracker outside this one's neighbour set is ignored."""
    a = TrackerAgent(cfg, 1, neighbour_ids=[2])
    x, v, t = np.arange(9.0).reshape(3, 3), np.zeros((3, 3)), np.zeros(3)
    act = [True] * 3
    bad = x.copy()
    bad[1, 0] = math.nan  # uav_2: a neighbour
    assert not a.offer_swarm(0, [1, 2, 3], bad, v, act, t, t, 0.0, 0.0)
    assert a.rejected == 1 and 'uav_2' in a.last_rejection and a.inputs == {}
    bad = x.copy()
    bad[2, 0] = math.nan  # uav_3: not a neighbour of uav_1
    assert a.offer_swarm(0, [1, 2, 3], bad, v, act, t, t, 0.0, 0.0)
    assert a.rejected == 1 and sorted(a.inputs) == [0, 1, 2] and a.ready(0)


def test_a_repeated_target_window_is_ignored_not_refused(cfg) -> None:
    """The lockstep target repeats a window of states for a late step: states of steps
    already answered or already held are ignored without a rejection."""
    a = TrackerAgent(cfg, 2)
    ok = np.zeros(3)
    for k in range(4):  # the target's batch, 0..3
        assert a.offer(0, k, ok, ok, 0.0)
    for j in (1, 2, 3):
        assert a.offer(j, 0, ok, ok, 0.0)
    a.command(0)
    for k in range(4):  # the window again
        assert a.offer(0, k, ok + 1.0, ok, 0.0)
    assert a.rejected == 0
    assert np.array_equal(a.pending[1][0].x, ok)  # the first copy is kept
    assert not a.offer(0, 4, np.array([math.nan, 0, 0]), ok, 0.0)  # a new step: checked
    assert a.rejected == 1


def test_stale_sources_and_the_brake(cfg) -> None:
    a = TrackerAgent(cfg, 1)
    assert a.stale_sources(0.0, 0.5) == [0, 1, 2, 3]  # nothing known yet
    assert np.array_equal(a.safe_command(), np.zeros(3))
    x = np.eye(3)
    v = np.array([[0.2, -0.1, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    feed(a, -1, x, v, np.zeros(3), np.zeros(3), now=10.0)
    assert a.stale_sources(10.4, 0.5) == []
    assert a.offer(2, -1, x[1], v[1], 10.8)
    assert a.stale_sources(10.6, 0.5) == [0, 1, 3]
    # eq. 24 on s = v: -u0 sign(v) + drag v; a zero component gets no switching force
    expect = -cfg.u0 * np.sign(v[0]) + cfg.drag * v[0]
    assert np.array_equal(a.safe_command(), expect)
    assert np.array_equal(brake_force(v[0], u0=cfg.u0, drag=cfg.drag), expect)


def test_retune_changes_gains_and_keeps_the_filter_state(cfg) -> None:
    a = TrackerAgent(cfg, 2)
    x = np.array([[3.0, 0.0, 0.0], [0.0, 2.0, 0.5], [-1.0, -1.0, 0.0]])
    v = np.array([[0.0, 0.0, 0.0], [0.4, -0.3, 0.2], [0.0, 0.0, 0.0]])
    feed(a, 0, x, v, np.zeros(3), np.zeros(3))
    out0 = a.command(0)
    z = a.controller.z.copy()
    assert a.retune(cfg.replace(u0=40.0, b=7.0)) == ['u0', 'b']
    assert np.array_equal(a.controller.z, z)
    feed(a, 1, x, v, np.zeros(3), np.zeros(3))
    out1 = a.command(1)
    assert np.allclose(np.abs(out1.force[0] - cfg.drag * v[1]), 40.0)
    fresh = TrackerAgent(cfg.replace(u0=40.0, b=7.0), 2)
    feed(fresh, 1, x, v, np.zeros(3), np.zeros(3))
    assert np.array_equal(fresh.command(1).gradient, out1.gradient)
    assert not np.array_equal(out0.gradient, out1.gradient)  # b moved the potential
    with pytest.raises(ValueError, match='seed cannot change'):
        a.retune(cfg.replace(seed=9))


def test_plant_refuses_bad_commands_and_holds_missing_ones(cfg) -> None:
    p = PlantModel(cfg)
    assert not p.offer_command(4, 0, np.ones(3), np.ones(3))
    assert not p.offer_command(1, 0, np.array([math.nan, 0, 0]), np.ones(3))
    assert p.rejected == 2
    assert p.offer_command(1, 3, np.ones(3), np.ones(3))
    assert not p.offer_command(1, 2, np.ones(3), np.ones(3))  # out of order
    assert p.missing(3) == [2, 3]
    x0 = p.x.copy()
    p.advance()  # 2 and 3 hold their zero command
    assert p.k == 1 and not np.array_equal(p.x, x0)
    j, ce, fe = p.metrics(np.array([0.0, 0.0, 5.0]))
    assert j > 0 and ce > 0 and math.isfinite(fe)


def test_obstacle_gradient_matches_finite_differences_of_the_repulsion() -> None:
    from apf_swarm_core.gradients import obstacle_gradient

    rng = np.random.default_rng(5)
    x = rng.normal(size=(2, 3))
    obs = rng.normal(size=(3, 3))
    k_f, b, c = 1.3, 6.0, 1.7

    def rep(xi):
        r2 = np.sum((xi - obs) ** 2, axis=-1)
        return k_f * np.sum(0.5 * b * c * np.exp(-r2 / c))

    g = obstacle_gradient(x, obs, k_f=k_f, b=b, c=c)
    h = 1e-6
    for m in range(2):
        for k in range(3):
            e = np.zeros(3)
            e[k] = h
            fd = (rep(x[m] + e) - rep(x[m] - e)) / (2 * h)
            assert g[m, k] == pytest.approx(fd, rel=1e-7, abs=1e-9)
    assert np.array_equal(obstacle_gradient(x, np.zeros((0, 3))), np.zeros((2, 3)))


def test_an_inactive_neighbour_leaves_the_formation_term_and_repels(cfg) -> None:
    """With uav_3 inactive, uav_2's gradient is that of the pair (1, 2) plus the repulsion
    of uav_3 only: far away uav_3 changes nothing, close by it pushes uav_2 away."""
    from apf_swarm_core.gradients import gradient

    p = cfg.potential_params()
    x = np.array([[1.0, 0.0, 5.0], [-1.0, 0.0, 5.0], [30.0, 0.0, 5.0]])
    v = np.zeros((3, 3))
    tx = np.array([0.0, 0.0, 5.0])
    a = TrackerAgent(cfg, 2)
    for j in (1, 2, 3):
        assert a.offer(j, 0, x[j - 1], v[j - 1], 0.0, active=j != 3)
    assert a.offer(0, 0, tx, np.zeros(3), 0.0)
    g = a.command(0).gradient[0]
    assert a.neighbours_used == 1
    assert np.allclose(g, gradient(x[:2], tx, **p)[1], atol=1e-12)  # uav_3 is 29 m away
    near = x.copy()
    near[2] = [-1.5, 0.0, 5.0]  # 0.5 m from uav_2
    b = TrackerAgent(cfg, 2)
    for j in (1, 2, 3):
        assert b.offer(j, 0, near[j - 1], v[j - 1], 0.0, active=j != 3)
    assert b.offer(0, 0, tx, np.zeros(3), 0.0)
    g_near = b.command(0).gradient[0]
    # descent direction -grad points away from uav_3 (towards +x) more than without it
    assert -g_near[0] > -g[0] + 1.0
    # an active uav_3 at the same place would attract too: the full potential differs
    c3 = TrackerAgent(cfg, 2)
    for j in (1, 2, 3):
        assert c3.offer(j, 0, near[j - 1], v[j - 1], 0.0)
    assert c3.offer(0, 0, tx, np.zeros(3), 0.0)
    assert np.allclose(c3.command(0).gradient[0], gradient(near, tx, **p)[1], atol=1e-12)


def test_plant_follows_one_tracker_process_per_id(cfg) -> None:
    p = PlantModel(cfg)
    f = np.ones(3)
    assert p.offer_command(2, 0, f, f, instance=11)
    assert not p.offer_command(2, 1, f, f, instance=22)  # a second process
    assert 'duplicate uav_id 2' in p.last_rejection
    assert p.offer_command(2, 1, f, f, instance=11)
    p.deactivate([2])  # the followed one is silent
    assert p.offer_command(2, 0, f, f, instance=22)  # a respawn starts anew
    assert p.active[1] and p.instances[2] == 22
    assert not p.offer_command(2, 5, f, f, instance=11)


def test_plant_counts_stale_brakes_only_after_a_tracker_has_commanded(cfg) -> None:
    """Brakes before a tracker's first inputs are its start-up; brakes after it commanded
    from its inputs are stale inputs; a respawned process starts again without inputs."""
    p = PlantModel(cfg)
    f = np.ones(3)
    for k in range(5):
        assert p.offer_command(1, k, f, f, stale=True, instance=7)  # waiting for inputs
    assert p.stale == 0
    assert p.offer_command(1, 5, f, f, instance=7)  # commands
    for k in range(6, 9):
        assert p.offer_command(1, k, f, f, stale=True, instance=7)  # inputs went silent
    assert p.stale == 3
    p.deactivate([1])
    assert p.offer_command(1, 0, f, f, stale=True, instance=8)  # respawned, waiting
    assert p.stale == 3
    assert p.offer_command(1, 1, f, f, instance=8)
    assert p.offer_command(1, 2, f, f, stale=True, instance=8)
    assert p.stale == 4


def test_the_realtime_clock_waits_for_the_trackers_that_have_not_commanded(cfg) -> None:
    p = PlantModel(cfg)
    f = np.ones(3)
    assert p.uncommanded() == [1, 2, 3]
    assert p.offer_command(2, 0, f, f, stale=True)  # a brake: no inputs yet
    assert p.offer_command(3, 0, f, f)
    assert p.uncommanded() == [1, 2]
    p.deactivate([1])  # inactive ones are not waited for
    assert p.uncommanded() == [2]
    assert p.clock_start(5.0, deadline=10.0) is None  # uav_2 still waited for
    assert p.clock_start(10.0, deadline=10.0) == [2]  # the deadline: without it
    assert p.offer_command(2, 1, f, f)
    assert p.uncommanded() == []
    assert p.clock_start(5.0, deadline=10.0) == []  # every tracker commands


def test_realtime_expiry_zeroes_first_and_deactivates_later(cfg) -> None:
    """Judged against publications: a tracker that has not answered the state published
    0.1 s ago gets zero force; not answered one published 1 s ago, it is inactive."""
    p = PlantModel(cfg)
    f = np.ones(3)
    assert p.expire(100.0, 0.1, 1.0) == []  # nothing published yet
    for k in range(21):  # the state goes out every 50 ms
        p.published(10.0 + 0.05 * k)
    for i in (1, 2, 3):
        assert p.offer_command(i, i, f, f, now=10.02)  # all answered the 10.00 state
    assert p.expire(10.1, 0.1, 1.0) == []  # asked at 10.00: answered
    assert np.array_equal(p.u, np.ones((3, 3)))
    assert p.expire(10.2, 0.1, 1.0) == []  # asked at 10.10: no answer, zero
    assert np.array_equal(p.u, np.zeros((3, 3))) and p.active.all()
    for i in (1, 3):
        assert p.offer_command(i, 10 + i, f, f, now=10.96)
    assert p.expire(11.05, 0.1, 1.0) == [2]  # uav_2 never answered 10.05
    assert list(p.active) == [True, False, True]
    assert np.array_equal(p.u[0], f)  # uav_1 answered 10.95
    assert p.expire(11.06, 0.1, 1.0) == []  # reported once


def test_a_late_plant_does_not_blame_the_trackers(cfg) -> None:
    """The plant published nothing for 2 s (itself starved): no tracker is zeroed or
    deactivated for not answering states that were never sent."""
    p = PlantModel(cfg)
    f = np.ones(3)
    p.published(10.0)
    for i in (1, 2, 3):
        assert p.offer_command(i, i, f, f, now=10.01)
    assert p.expire(12.0, 0.1, 1.0) == []
    assert p.active.all() and np.array_equal(p.u, np.ones((3, 3)))


@pytest.mark.parametrize(
    'rule',
    [
        {'neighbours': 'nearest', 'neighbour_count': 2},
        {'neighbours': 'radius', 'sensing_radius': 1.7},
    ],
)
def test_limited_neighbour_sets_agents_equal_the_simulator(cfg, rule) -> None:
    """6 trackers, each seeing only its 2 nearest (or those within 1.7 m): trackers and
    plant stepped by hand equal the batch simulator bit for bit, and the sets are used."""
    c = cfg.replace(n_trackers=6, **rule)
    sim = BatchSimulator([c])
    agents = [TrackerAgent(c, i) for i in range(1, 7)]
    plant = PlantModel(c)
    used = set()
    for k in range(200):
        tx, tv = sim.target.state(k)
        for a in agents:
            feed(a, k, plant.x, plant.v, tx[0], tv[0])
        outs = [a.command(k) for a in agents]
        used.update(a.neighbours_used for a in agents)
        for i, out in enumerate(outs, start=1):
            plant.offer_command(i, k, out.force[0], out.sliding_surface[0])
        ref, _, _ = sim.step()
        assert np.array_equal(np.concatenate([o.force for o in outs]), ref.force[0])
        plant.advance()
        assert np.array_equal(plant.x, sim.x[0])
    if rule['neighbours'] == 'nearest':
        assert used == {2}
    else:
        assert min(used) < 5


def test_neighbour_mask_rules() -> None:
    from apf_swarm_core.neighbours import neighbour_mask

    x = np.array([[0.0, 0, 0], [1.0, 0, 0], [3.0, 0, 0], [10.0, 0, 0]])
    near = neighbour_mask(x, rule='nearest', count=2)
    assert near.tolist() == [
        [False, True, True, False],
        [True, False, True, False],
        [True, True, False, False],
        [False, True, True, False],
    ]
    assert neighbour_mask(x, rule='radius', radius=2.5).sum(axis=1).tolist() == [1, 2, 1, 0]
    assert neighbour_mask(x, rule='all').sum() == 12
    assert neighbour_mask(x, rule='nearest', count=1, rows=[3]).tolist() == [
        [False, False, True, False]
    ]
    assert neighbour_mask(x, rule='nearest', count=9).sum(axis=1).tolist() == [3, 3, 3, 3]
    with pytest.raises(ValueError, match='neighbours must be one of'):
        neighbour_mask(x, rule='psychic')


def test_simulate_honours_the_neighbour_rule_like_step(cfg) -> None:
    """BatchSimulator.run (the recorded fast path) and step() apply the same rule."""
    c = cfg.replace(n_trackers=5, neighbours='nearest', neighbour_count=2, duration=0.3)
    traj = BatchSimulator([c]).run()
    stepped = BatchSimulator([c])
    xs = []
    for _ in range(c.steps):
        xs.append(stepped.x[0].copy())
        stepped.step()
    assert np.array_equal(traj['x'][0], np.array(xs))
    other = BatchSimulator([c.replace(neighbours='all')]).run()
    assert np.max(np.abs(other['x'][0, -1] - traj['x'][0, -1])) > 1e-4


def test_setpoints_take_the_vehicle_where_the_plant_takes_it(cfg) -> None:
    """Flown at the acceleration setpoint (or reaching the velocity setpoint) for one step,
    a vehicle ends where the plant model, without its unknown disturbance, takes it."""
    from apf_swarm_core.plant import plant_step

    cfg = cfg.replace(drag=0.4, uav_overrides={2: {'mass': 1.3}})
    rng = np.random.default_rng(11)
    x, v = rng.normal(size=(2, 3, 3))
    agent = TrackerAgent(cfg, 2)
    feed(agent, 0, x, v, np.zeros(3), np.zeros(3))
    force = agent.command(0).force[0]
    a, vsp = agent.setpoints(force, cfg.dt)
    _, v1 = plant_step(x[1], v[1], force, mass=1.3, dt=cfg.dt, drag=0.4)
    np.testing.assert_allclose(v[1] + a * cfg.dt, v1, rtol=1e-13, atol=1e-15)
    np.testing.assert_allclose(vsp, v1, rtol=1e-13, atol=1e-15)


def test_messages_of_another_run_are_refused_and_counted(cfg) -> None:
    """A tracker and a plant of run 5 refuse /swarm/odom and commands of run 6, counted with
    the reason; run 0 (no identity) accepts any."""
    rng = np.random.default_rng(2)
    x, v = rng.normal(size=(2, 3, 3))
    tx, tv = np.zeros(3), np.zeros(3)
    ids, act = [1, 2, 3], [True] * 3
    agent = TrackerAgent(cfg, 1, run=5)
    assert not agent.offer_swarm(0, ids, x, v, act, tx, tv, 0.0, 0.0, run=6)
    assert agent.rejected == 1 and 'another run (6; this run: 5)' in agent.last_rejection
    assert not agent.ready(0)
    assert agent.offer_swarm(0, ids, x, v, act, tx, tv, 0.0, 0.0, run=5)
    assert agent.ready(0)
    assert TrackerAgent(cfg, 1).offer_swarm(0, ids, x, v, act, tx, tv, 0.0, 0.0, run=6)
    plant = PlantModel(cfg, run=5)
    f, s = np.zeros(3), np.zeros(3)
    assert not plant.offer_command(1, 0, f, s, run=6)
    assert plant.rejected == 1 and 'from another run (6; this run: 5)' in plant.last_rejection
    assert plant.missing(0) == [1, 2, 3]
    assert plant.offer_command(1, 0, f, s, run=5)
    assert plant.missing(0) == [2, 3]
    assert PlantModel(cfg).offer_command(1, 0, f, s, run=6)


def test_a_realtime_swarm_state_held_as_arrays_answers_as_one_sample_per_tracker(cfg) -> None:
    """A realtime /swarm/odom is kept as arrays (no Sample per tracker until one is needed):
    staleness, the out-of-order check of a single tracker's input, the row it replaces, the
    brake and the command are those of an agent fed the same states one by one."""
    rng = np.random.default_rng(3)
    x, v = rng.normal(size=(3, 3)), rng.normal(scale=0.1, size=(3, 3))
    tx, tv = np.array([0.0, 0.0, 5.0]), np.array([1.0, 0.0, 0.0])
    a, b = TrackerAgent(cfg, 2), TrackerAgent(cfg, 2)
    assert a.offer_swarm(-1, [1, 2, 3], x, v, [True] * 3, tx, tv, 10.0, 10.0, seq=100)
    for j in (1, 2, 3):
        assert b.offer(j, -1, x[j - 1], v[j - 1], 10.0, seq=100)
    assert b.offer(0, -1, tx, tv, 10.0, seq=100)
    for agent in (a, b):
        assert agent.stale_sources(10.4, 0.5) == []
        assert agent.stale_sources(10.6, 0.5) == [0, 1, 2, 3]
    np.testing.assert_array_equal(a.command(-1).force, b.command(-1).force)
    assert not a.offer(3, -1, x[2], v[2], 10.5, seq=99)  # older than the swarm's row
    assert 'out of order' in a.last_rejection
    for agent in (a, b):
        assert agent.offer(3, -1, x[2] + 0.5, v[2], 10.8, seq=101)
        assert agent.stale_sources(10.7, 0.5) == [0, 1, 2]
    np.testing.assert_array_equal(a.command(-1).force, b.command(-1).force)
    np.testing.assert_array_equal(a.safe_command(), b.safe_command())
