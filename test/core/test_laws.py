"""The control laws (eq. 7, 22-28, 31, 24, 26): their numpy forms (reference.py) against the
equations, and the controller's compiled kernel against them."""

import numpy as np
import pytest
from apf_swarm_core.controller import SlidingModeController
from apf_swarm_core.laws import known_force, switching_force
from reference import (
    filter_step,
    kinematic_velocity,
    sliding_surface_proposed,
    sliding_surface_traditional,
)
from scipy.integrate import solve_ivp


def test_kinematic_velocity_by_hand():
    g = np.array([[0.1, -0.2, 0.0], [3.0, -4.0, 1.0]])
    alpha, beta, gamma = 0.3, 2.0, 0.5
    v = kinematic_velocity(g, alpha=alpha, beta=beta, gamma=gamma)
    # row 0 inside the layer (|g| = 0.2236 < 0.5): -(alpha + beta/gamma) g
    np.testing.assert_allclose(v[0], -(0.3 + 4.0) * g[0], rtol=1e-15)
    # row 1 outside: -alpha g - beta sign(g)
    np.testing.assert_allclose(v[1], [-0.9 - 2.0, 1.2 + 2.0, -0.3 - 2.0], rtol=1e-15)


def test_filter_step_constant_input_equals_analytic_exponential():
    lam, beta, dt = 0.1, 2.0, 0.013
    z0 = np.array([[0.5, -1.5, 0.0]])
    g = np.array([[1.0, 2.0, -0.1]])
    s = np.sign(g)
    z = z0.copy()
    for k in range(1, 31):
        z = filter_step(z, g, beta=beta, lambda_filter=lam, dt=dt)
        exact = beta * s + (z0 - beta * s) * np.exp(-k * dt / lam)
        np.testing.assert_allclose(z, exact, rtol=1e-13, atol=1e-14)


def test_filter_step_matches_ode_solution_with_switching_input():
    """Piecewise-constant input: compare with an ODE solver on lambda z' + z = beta sign(g_k)."""
    rng = np.random.default_rng(11)
    lam, beta, dt = 0.07, 1.3, 0.02
    z = np.zeros((1, 3))
    z_ode = np.zeros(3)
    for _ in range(12):
        g = rng.normal(size=(1, 3))
        u = beta * np.sign(g[0])
        sol = solve_ivp(
            lambda t, y, u=u: (u - y) / lam,
            (0.0, dt),
            z_ode,
            rtol=1e-12,
            atol=1e-14,
            method='DOP853',
        )
        z_ode = sol.y[:, -1]
        z = filter_step(z, g, beta=beta, lambda_filter=lam, dt=dt)
        np.testing.assert_allclose(z[0], z_ode, rtol=1e-9, atol=1e-11)


@pytest.mark.parametrize('dt', [1e-4, 0.05, 3.0])
def test_filter_state_stays_within_beta(dt):
    rng = np.random.default_rng(12)
    beta = 2.0
    z = rng.uniform(-beta, beta, size=(5, 3))
    for _ in range(200):
        z = filter_step(z, rng.normal(size=(5, 3)), beta=beta, lambda_filter=0.1, dt=dt)
        assert np.all(np.abs(z) <= beta * (1 + 1e-15))


def test_filter_step_batched_gains():
    rng = np.random.default_rng(13)
    z = rng.normal(size=(3, 2, 3))
    g = rng.normal(size=(3, 2, 3))
    beta = np.array([1.0, 2.0, 3.0])
    lam = np.array([0.05, 0.1, 0.2])
    out = filter_step(z, g, beta=beta, lambda_filter=lam, dt=0.01)
    for r in range(3):
        np.testing.assert_allclose(
            out[r],
            filter_step(z[r], g[r], beta=beta[r], lambda_filter=lam[r], dt=0.01),
            rtol=1e-15,
        )


def test_sliding_surface_proposed_inside_and_outside_by_hand():
    alpha, beta, gamma = 0.01, 2.0, 0.2
    v = np.array([[0.1, 0.2, 0.3], [1.0, -1.0, 0.5]])
    g = np.array(
        [
            [0.05, -0.1, 0.0],  # |g| = 0.112 < 0.2: eq. 31
            [1.0, 0.0, -2.0],
        ]
    )  # |g| = 2.24 >= 0.2: eq. 28
    z = np.array([[9.0, 9.0, 9.0], [0.7, -0.3, 0.1]])
    s, outside = sliding_surface_proposed(v, g, z, alpha=alpha, beta=beta, gamma=gamma)
    assert outside.tolist() == [False, True]
    k = alpha + beta / gamma  # 10.01
    np.testing.assert_allclose(s[0], [0.1 + k * 0.05, 0.2 - k * 0.1, 0.3], rtol=1e-14)
    np.testing.assert_allclose(s[1], [1.0 + 0.01 + 0.7, -1.0 - 0.3, 0.5 - 0.02 + 0.1], rtol=1e-14)


def test_sliding_surface_proposed_continuous_saturation_uses_no_filter():
    alpha, beta, gamma = 0.5, 2.0, 1.0
    v = np.zeros((1, 3))
    g = np.array([[3.0, 0.0, 4.0]])
    s, outside = sliding_surface_proposed(
        v, g, np.full((1, 3), 100.0), alpha=alpha, beta=beta, gamma=gamma, saturation='continuous'
    )
    assert outside.tolist() == [True]
    np.testing.assert_allclose(s[0], [1.5 + 2.0 * 0.6, 0.0, 2.0 + 2.0 * 0.8], rtol=1e-14)


def test_sliding_surface_traditional_by_hand():
    v = np.array([[0.1, 0.2, 0.3]])
    g = np.array([[0.01, -0.02, 0.0]])  # tiny gradient: still s = v + alpha g + z
    z = np.array([[0.5, -0.5, 0.25]])
    s = sliding_surface_traditional(v, g, z, alpha=2.0)
    np.testing.assert_allclose(s, [[0.1 + 0.02 + 0.5, 0.2 - 0.04 - 0.5, 0.3 + 0.25]], rtol=1e-14)


def test_switching_force_and_known_force():
    s = np.array([[0.3, -1e-9, 0.0]])
    v = np.array([[2.0, -1.0, 4.0]])
    f = switching_force(s, v, u0=125.0, drag=0.1)
    np.testing.assert_allclose(f, [[-125.0 + 0.2, 125.0 - 0.1, 0.0 + 0.4]], rtol=1e-15)
    np.testing.assert_allclose(known_force(v, 0.1), 0.1 * v, rtol=1e-15)
    np.testing.assert_array_equal(switching_force(s, v, u0=3.0), [[-3.0, 3.0, 0.0]])


def _controller(law, **kw):
    args = {
        'alpha': 0.01,
        'beta': 2.0,
        'gamma': 0.2,
        'lambda_filter': 0.1,
        'u0': 125.0,
        'dt': 0.001,
        'shape': (2, 3),
        'drag': 0.1,
    }
    args.update(kw)
    return SlidingModeController(law=law, **args)


def test_controller_rejects_unknown_law():
    with pytest.raises(ValueError, match='law'):
        _controller('adaptive')


@pytest.mark.parametrize('law', ['proposed', 'traditional'])
def test_controller_step_reset_and_filter_advance(law):
    ctl = _controller(law)
    np.testing.assert_array_equal(ctl.z, np.zeros((2, 3)))
    v = np.array([[0.1, 0.0, -0.2], [0.0, 0.3, 0.0]])
    g = np.array([[1.0, -2.0, 0.5], [0.01, 0.02, -0.01]])
    out1 = ctl.step(v, g)
    # the command uses the filter state before the step (zeros); z then advances by eq. 26
    np.testing.assert_array_equal(out1.filter_state, np.zeros((2, 3)))
    expected_z = filter_step(np.zeros((2, 3)), g, beta=2.0, lambda_filter=0.1, dt=0.001)
    np.testing.assert_allclose(ctl.z, expected_z, rtol=1e-15)
    assert np.all(ctl.z != 0)
    if law == 'proposed':
        s_ref, out_ref = sliding_surface_proposed(
            v, g, np.zeros((2, 3)), alpha=0.01, beta=2.0, gamma=0.2
        )
    else:
        s_ref = sliding_surface_traditional(v, g, np.zeros((2, 3)), alpha=0.01)
        out_ref = np.linalg.norm(g, axis=-1) >= 0.2
    np.testing.assert_allclose(out1.sliding_surface, s_ref, rtol=1e-15)
    np.testing.assert_array_equal(out1.saturated, out_ref)
    np.testing.assert_allclose(out1.force, -125.0 * np.sign(s_ref) + 0.1 * v, rtol=1e-15)
    np.testing.assert_array_equal(out1.gradient, g)
    out2 = ctl.step(v, g)
    np.testing.assert_allclose(out2.filter_state, expected_z, rtol=1e-15)
    ctl.reset()
    np.testing.assert_array_equal(ctl.z, np.zeros((2, 3)))
    ctl.reset(np.ones(6))
    np.testing.assert_array_equal(ctl.z, np.ones((2, 3)))


def test_controller_batched_gains_equal_single_controllers():
    rng = np.random.default_rng(14)
    gam = np.array([0.1, 0.5, 2.0])
    batch = _controller('proposed', gamma=gam, shape=(3, 2, 3))
    singles = [_controller('proposed', gamma=float(g)) for g in gam]
    for _ in range(5):
        v = rng.normal(size=(3, 2, 3))
        g = rng.normal(size=(3, 2, 3)) * 0.5
        ob = batch.step(v, g)
        for r, c in enumerate(singles):
            o = c.step(v[r], g[r])
            np.testing.assert_allclose(ob.force[r], o.force, rtol=1e-15)
            np.testing.assert_allclose(ob.sliding_surface[r], o.sliding_surface, rtol=1e-15)
            np.testing.assert_array_equal(ob.saturated[r], o.saturated)


def test_realtime_sample_is_the_elapsed_time_within_bounds():
    c = _controller('proposed')
    c.sample_elapsed(None, 0.01)
    assert c.dt == 0.01  # before the first command: the nominal period
    c.sample_elapsed(0.013, 0.01)
    assert c.dt == 0.013
    lo, hi = c.SAMPLE_BOUNDS
    c.sample_elapsed(2.5, 0.01)  # a stall: one bounded sample
    assert c.dt == hi
    c.sample_elapsed(0.0, 0.01)
    assert c.dt == lo
