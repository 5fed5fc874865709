"""Unit tests of apf_swarm_core.target (eq. 1 and the trajectories)."""

import math

import numpy as np
import pytest
from apf_swarm_core.target import (
    Circle,
    FigureEight,
    Helix,
    Straight,
    Waypoints,
    make_trajectory,
    target_velocity,
)


@pytest.mark.parametrize('seed', range(3))
def test_target_velocity_eq1_norm_and_components(seed):
    rng = np.random.default_rng(seed)
    v = rng.uniform(0, 10, size=50)
    yaw = rng.uniform(-np.pi, np.pi, size=50)
    pitch = rng.uniform(-np.pi / 2, np.pi / 2, size=50)
    vel = target_velocity(v, yaw, pitch)
    assert vel.shape == (50, 3)
    np.testing.assert_allclose(np.linalg.norm(vel, axis=-1), v, rtol=1e-13)
    np.testing.assert_allclose(vel[:, 2], v * np.sin(pitch), rtol=1e-13)
    np.testing.assert_allclose(np.arctan2(vel[:, 1], vel[:, 0]), yaw, rtol=1e-12, atol=1e-12)


def test_target_velocity_known_values():
    np.testing.assert_allclose(target_velocity(2.0, math.pi / 2, 0.0), [0.0, 2.0, 0.0], atol=1e-15)
    np.testing.assert_allclose(
        target_velocity(2.0, 0.0, math.pi / 6), [2.0 * math.cos(math.pi / 6), 0.0, 1.0], atol=1e-15
    )


TRAJECTORIES = [
    Straight((1.0, 2.0, 5.0), 3.0, yaw=0.4, pitch=0.2),
    Circle((0.0, 0.0, 5.0), 1.5, radius=20.0, yaw=0.3),
    Helix((0.0, 1.0, 5.0), 2.0, radius=5.0, yaw=-1.0, pitch=0.3),
    FigureEight((0.0, 0.0, 5.0), 2.0, radius=10.0, yaw=0.5),
    Waypoints((0.0, 0.0, 5.0), 2.0, points=((3.0, 0.0, 0.0), (3.0, 4.0, 0.0), (3.0, 4.0, -2.0))),
]


@pytest.mark.parametrize('traj', TRAJECTORIES, ids=lambda t: type(t).__name__)
def test_position_derivative_equals_velocity(traj):
    h = 1e-5
    for t in np.linspace(0.05, 40.0, 97):
        if isinstance(traj, Waypoints) and any(abs(t - tk) < 2 * h for tk in (1.5, 3.5, 4.5)):
            continue
        p_plus, _ = traj.state(t + h)
        p_minus, _ = traj.state(t - h)
        _, vel = traj.state(t)
        np.testing.assert_allclose((p_plus - p_minus) / (2 * h), vel, rtol=1e-6, atol=1e-7)


@pytest.mark.parametrize('traj', TRAJECTORIES[:4], ids=lambda t: type(t).__name__)
def test_trajectory_starts_at_start_and_speed_is_bounded(traj):
    p0, _ = traj.state(0.0)
    np.testing.assert_allclose(p0, traj.start, atol=1e-12)
    speeds = [np.linalg.norm(traj.state(t)[1]) for t in np.linspace(0, 60, 301)]
    assert max(speeds) <= traj.max_speed * (1 + 1e-12)


def test_circle_stays_on_its_circle():
    start, r, yaw = np.array([1.0, -2.0, 5.0]), 7.0, 0.8
    tr = Circle(tuple(start), 1.5, radius=r, yaw=yaw)
    centre = start + r * np.array([-math.sin(yaw), math.cos(yaw), 0.0])  # left of heading
    for t in np.linspace(0, 100, 201):
        p, v = tr.state(t)
        assert np.linalg.norm(p - centre) == pytest.approx(r, rel=1e-12)
        assert p[2] == pytest.approx(5.0)
        assert np.linalg.norm(v) == pytest.approx(1.5, rel=1e-12)
        assert abs(np.dot(v, p - centre)) < 1e-9  # tangent
    # one revolution takes 2 pi r / v
    p_end, _ = tr.state(2 * math.pi * r / 1.5)
    np.testing.assert_allclose(p_end, start, atol=1e-9)


def test_circle_forces_zero_pitch_and_helix_climbs():
    c = Circle((0.0, 0.0, 0.0), 1.0, radius=3.0, pitch=0.5)
    assert c.pitch == 0.0
    h = Helix((0.0, 0.0, 0.0), 2.0, radius=3.0, pitch=0.5)
    p, v = h.state(10.0)
    assert p[2] == pytest.approx(2.0 * math.sin(0.5) * 10.0, rel=1e-12)
    assert np.linalg.norm(v) == pytest.approx(2.0, rel=1e-12)
    assert math.hypot(*h.state(0.0)[0][:2]) == 0.0
    centre = 3.0 * np.array([0.0, 1.0])
    assert np.linalg.norm(p[:2] - centre) == pytest.approx(3.0, rel=1e-12)


def test_figure_eight_peak_speed_equals_speed():
    tr = FigureEight((0.0, 0.0, 5.0), 2.5, radius=12.0, yaw=0.3)
    period = 2 * math.pi / tr.omega
    ts = np.linspace(0, period, 20001)
    speeds = np.array([np.linalg.norm(tr.state(t)[1]) for t in ts])
    assert speeds.max() == pytest.approx(2.5, rel=1e-9)
    assert speeds.max() <= 2.5 * (1 + 1e-12)
    assert tr.max_speed == 2.5
    # closed curve, half-width radius along the rotated x axis
    np.testing.assert_allclose(tr.state(period)[0], tr.state(0.0)[0], atol=1e-9)
    p_q, _ = tr.state(period / 4)
    np.testing.assert_allclose(
        p_q - np.array(tr.start), [12.0 * math.cos(0.3), 12.0 * math.sin(0.3), 0.0], atol=1e-9
    )


def test_waypoints_reach_points_on_time_and_hover():
    start = np.array([1.0, 1.0, 5.0])
    pts = ((3.0, 0.0, 0.0), (3.0, 4.0, 0.0), (3.0, 4.0, 0.0), (3.0, 4.0, -2.0))
    speed = 2.0
    tr = Waypoints(tuple(start), speed, points=pts)
    # leg lengths 3, 4, 0 (repeated point), 2 -> arrival times 1.5, 3.5, 3.5, 4.5
    for t_arr, p in zip((1.5, 3.5, 3.5, 4.5), pts, strict=False):
        pos, _ = tr.state(t_arr)
        np.testing.assert_allclose(pos, start + np.array(p), atol=1e-12)
    # mid-leg: constant speed along the leg direction
    pos, vel = tr.state(2.5)
    np.testing.assert_allclose(pos, start + np.array([3.0, 2.0, 0.0]), atol=1e-12)
    np.testing.assert_allclose(vel, [0.0, 2.0, 0.0], atol=1e-12)
    _, vel = tr.state(4.0)  # the vertical leg
    np.testing.assert_allclose(vel, [0.0, 0.0, -2.0], atol=1e-12)
    for t in (4.5, 5.0, 100.0):
        pos, vel = tr.state(t)
        np.testing.assert_allclose(pos, start + np.array([3.0, 4.0, -2.0]), atol=1e-12)
        np.testing.assert_array_equal(vel, 0.0)


def test_make_trajectory_by_name():
    assert isinstance(make_trajectory('straight', speed=2.0), Straight)
    assert isinstance(make_trajectory('circle'), Circle)
    assert isinstance(make_trajectory('helix', pitch=0.1), Helix)
    assert isinstance(make_trajectory('figure_eight'), FigureEight)
    wp = make_trajectory('waypoints', waypoints=[[1, 0, 0]], speed=1.0)
    assert isinstance(wp, Waypoints) and wp.points == ((1.0, 0.0, 0.0),)
    hover = make_trajectory('hover', start=(1.0, 2.0, 3.0), speed=5.0)
    p, v = hover.state(10.0)
    np.testing.assert_array_equal(p, [1.0, 2.0, 3.0])
    np.testing.assert_array_equal(v, 0.0)
    with pytest.raises(ValueError, match='trajectory'):
        make_trajectory('spiral')


@pytest.mark.parametrize(
    'traj', [*TRAJECTORIES, make_trajectory('hover')], ids=lambda t: type(t).__name__
)
def test_state_is_vectorized_over_time(traj):
    ts = np.array([0.0, 0.37, 1.5, 2.9, 4.5, 7.0, 33.3])
    pos, vel = traj.state(ts)
    assert pos.shape == (7, 3) and vel.shape == (7, 3)
    for k, t in enumerate(ts):
        p1, v1 = traj.state(float(t))
        assert p1.shape == (3,) and v1.shape == (3,)
        np.testing.assert_allclose(pos[k], p1, rtol=1e-14, atol=1e-14)
        np.testing.assert_allclose(vel[k], v1, rtol=1e-14, atol=1e-14)
    p2, _ = traj.state(ts.reshape(7, 1))
    assert p2.shape == (7, 1, 3)
