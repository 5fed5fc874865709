"""Unit tests of apf_swarm_core.plant (eq. 19-21 and the bounded disturbance)."""

import numpy as np
import pytest
from apf_swarm_core.plant import (
    DisturbanceSource,
    acceleration_setpoint,
    plant_step,
    uniform_ball,
    velocity_setpoint,
)
from scipy import stats


@pytest.mark.parametrize('dt, steps', [(1e-3, 500), (0.1, 37)])
def test_plant_step_is_exact_for_constant_acceleration(dt, steps):
    rng = np.random.default_rng(1)
    x0 = rng.normal(size=(3, 3))
    v0 = rng.normal(size=(3, 3))
    force = rng.normal(size=(3, 3)) * 5
    dist = rng.normal(size=(3, 3))
    mass = np.array([[1.0], [0.5], [1.5]]) * np.ones((3, 3))
    x, v = x0, v0
    for _ in range(steps):
        x, v = plant_step(x, v, force, mass=mass, dt=dt, disturbance=dist)
    t = steps * dt
    acc = (force - dist) / mass
    np.testing.assert_allclose(v, v0 + acc * t, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(x, x0 + v0 * t + 0.5 * acc * t * t, rtol=1e-11, atol=1e-11)


def test_plant_step_known_drag_by_hand():
    x = np.array([[0.0, 0.0, 0.0]])
    v = np.array([[2.0, -1.0, 0.0]])
    u = np.array([[1.0, 1.0, 1.0]])
    d = np.array([[0.5, 0.0, -0.5]])
    xn, vn = plant_step(x, v, u, mass=2.0, dt=0.1, drag=0.3, disturbance=d)
    acc = (u - 0.3 * v - d) / 2.0  # M xdd + f_known + f_unknown = u
    np.testing.assert_allclose(vn, v + 0.1 * acc, rtol=1e-15)
    np.testing.assert_allclose(xn, x + 0.1 * v + 0.005 * acc, rtol=1e-15)


def test_plant_step_batched_equals_per_run():
    rng = np.random.default_rng(2)
    x, v, u, d = (rng.normal(size=(4, 3, 3)) for _ in range(4))
    mass = rng.uniform(0.5, 1.5, size=(4, 3, 3))
    drag = np.array([0.0, 0.1, 0.2, 0.3])
    xb, vb = plant_step(x, v, u, mass=mass, dt=0.01, drag=drag, disturbance=d)
    for r in range(4):
        xr, vr = plant_step(
            x[r], v[r], u[r], mass=mass[r], dt=0.01, drag=float(drag[r]), disturbance=d[r]
        )
        np.testing.assert_allclose(xb[r], xr, rtol=1e-15)
        np.testing.assert_allclose(vb[r], vr, rtol=1e-15)


@pytest.mark.parametrize('f_bar', [0.3, 1.0, 7.5])
def test_disturbance_is_bounded(f_bar):
    src = DisturbanceSource(seed=3, n=4, f_bar=f_bar, block=100)
    f = np.array([src.next() for _ in range(2500)])
    assert f.shape == (2500, 4, 3)
    norms = np.linalg.norm(f, axis=-1)
    assert norms.max() <= f_bar * (1 + 1e-12)
    assert norms.max() > 0.95 * f_bar  # it does use the whole ball


def test_disturbance_same_seed_same_sequence_and_different_seed_differs():
    a = DisturbanceSource(seed=5, n=3, f_bar=1.0)
    b = DisturbanceSource(seed=5, n=3, f_bar=1.0)
    c = DisturbanceSource(seed=6, n=3, f_bar=1.0)
    fa = np.array([a.next() for _ in range(50)])
    fb = np.array([b.next() for _ in range(50)])
    fc = np.array([c.next() for _ in range(50)])
    np.testing.assert_array_equal(fa, fb)
    assert not np.allclose(fa, fc)
    assert len({tuple(f.ravel()) for f in fa}) == 50  # a new draw every step


def test_disturbance_block_size_does_not_change_the_sequence():
    seqs = []
    for block in (1, 7, 64, 1024):
        src = DisturbanceSource(seed=9, n=3, f_bar=2.0, block=block)
        seqs.append(np.array([src.next() for _ in range(300)]))
    for s in seqs[1:]:
        np.testing.assert_array_equal(s, seqs[0])


def test_disturbance_none_and_zero_bound_give_zeros():
    src = DisturbanceSource(seed=1, n=2, f_bar=1.0, kind='none')
    zero = DisturbanceSource(seed=1, n=2, f_bar=0.0)
    for _ in range(5):
        np.testing.assert_array_equal(src.next(), np.zeros((2, 3)))
        np.testing.assert_array_equal(zero.next(), np.zeros((2, 3)))


def test_disturbance_rejects_unknown_kind():
    with pytest.raises(ValueError, match='noise'):
        DisturbanceSource(seed=1, n=2, f_bar=1.0, kind='gaussian')


def test_uniform_ball_is_uniform_in_volume():
    rng = np.random.default_rng(20)
    N, R = 200_000, 2.5
    p = uniform_ball(rng.random((N, 3)), R)
    r = np.linalg.norm(p, axis=-1)
    assert r.max() <= R * (1 + 1e-12)
    # fraction inside R/2 is (1/2)^3 = 1/8; standard error sqrt(p(1-p)/N) = 7.4e-4
    frac = np.mean(r < R / 2)
    assert abs(frac - 0.125) < 5 * np.sqrt(0.125 * 0.875 / N)
    # (r/R)^3 is uniform on [0, 1]
    assert stats.kstest((r / R) ** 3, 'uniform').pvalue > 1e-3
    # isotropy: mean ~ 0, E[x^2] = E[y^2] = E[z^2] = R^2 / 5, no correlation
    se = R / np.sqrt(N)
    np.testing.assert_allclose(p.mean(axis=0), 0.0, atol=5 * se)
    cov = np.cov(p.T)
    np.testing.assert_allclose(np.diag(cov), R * R / 5, rtol=0.02)
    off = cov[~np.eye(3, dtype=bool)]
    assert np.all(np.abs(off) < 0.02 * R * R / 5)


def test_batched_disturbance_source_equals_single_sources():
    seeds, bounds = [3, 4, 3], [1.0, 2.0, 0.0]
    batch = DisturbanceSource(seeds, n=2, f_bar=bounds, block=5)
    singles = [
        DisturbanceSource(s, n=2, f_bar=f, block=8) for s, f in zip(seeds, bounds, strict=False)
    ]
    for _ in range(23):
        fb = batch.next()
        assert fb.shape == (3, 2, 3)
        for r, src in enumerate(singles):
            np.testing.assert_array_equal(fb[r], src.next())
    none = DisturbanceSource([1, 2], n=2, f_bar=[1.0, 1.0], kind='none')
    np.testing.assert_array_equal(none.next(), np.zeros((2, 2, 3)))


def test_setpoints_move_a_vehicle_as_the_model_moves_under_the_force():
    # a vehicle that flies the acceleration setpoint, or reaches the velocity setpoint, over
    # one step ends where eq. 19 (without the unknown term) takes it under the force
    rng = np.random.default_rng(5)
    x, v, u = rng.normal(size=(3, 4, 3))
    mass, drag, dt = 1.7, 0.3, 0.02
    a = acceleration_setpoint(u, v, mass=mass, drag=drag)
    x1, v1 = plant_step(x, v, u, mass=mass, dt=dt, drag=drag)
    np.testing.assert_allclose(v + a * dt, v1, rtol=1e-13, atol=1e-15)
    np.testing.assert_allclose(x + v * dt + a * dt * dt / 2, x1, rtol=1e-13, atol=1e-15)
    np.testing.assert_allclose(velocity_setpoint(v, a, dt), v1, rtol=1e-13, atol=1e-15)
    # by hand: no drag, unit mass: the force is the acceleration
    np.testing.assert_array_equal(acceleration_setpoint(u, v, mass=1.0), u)
