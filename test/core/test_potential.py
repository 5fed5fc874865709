"""Unit and theory tests of apf_swarm_core.potential (eq. 2 with eq. 44)."""

import numpy as np
import pytest
from apf_swarm_core.gains import shaped
from apf_swarm_core.gradients import gradient
from apf_swarm_core.potential import pair_weight, potential
from reference import kinematic_velocity


def _random_params(rng):
    return {
        'k_n': rng.uniform(0.2, 3.0),
        'k_f': rng.uniform(0.2, 3.0),
        'a': rng.uniform(0.2, 2.0),
        'b': rng.uniform(0.0, 10.0),
        'c': rng.uniform(0.3, 3.0),
    }


def target_gradient(x, x_target, *, k_n=1.0):
    """Gradient of J with respect to the target, ``-k_N sum_i (x_i - x_N)`` (eq. 6, 17), shape
    (..., 3), from x (..., n, 3) and x_target (..., 3) [m]: no controller uses it (the target
    is not steered), the tests check J's target term against it."""
    x = np.asarray(x, dtype=float)
    x_target = np.asarray(x_target, dtype=float)
    return -shaped(k_n, 1) * np.sum(x - x_target[..., None, :], axis=-2)


def _fd_gradient(x, xt, params, h=1e-5):
    """Central finite differences of ``potential`` with respect to every tracker coordinate."""
    g = np.zeros_like(x)
    for i in range(x.shape[0]):
        for k in range(3):
            xp, xm = x.copy(), x.copy()
            xp[i, k] += h
            xm[i, k] -= h
            g[i, k] = (potential(xp, xt, **params) - potential(xm, xt, **params)) / (2 * h)
    return g


def _hand_potential(x, xt, k_n, k_f, a, b, c):
    """J of docs/THEORY.md section 1 written with explicit loops (independent of the
    vectorized code)."""
    n = x.shape[0]
    j = 0.0
    for i in range(n):
        j += k_n * 0.5 * float(np.sum((x[i] - xt) ** 2))
        for m in range(i + 1, n):
            r2 = float(np.sum((x[i] - x[m]) ** 2))
            j += k_f * (0.5 * a * r2 + 0.5 * b * c * np.exp(-r2 / c))
    return j


@pytest.mark.parametrize('n', [1, 2, 3, 7])
@pytest.mark.parametrize('seed', [0, 1, 2])
def test_potential_matches_hand_written_sum(n, seed):
    rng = np.random.default_rng([seed, n, 10])
    params = _random_params(rng)
    x = rng.normal(scale=1.5, size=(n, 3))
    xt = rng.normal(size=3)
    assert float(potential(x, xt, **params)) == pytest.approx(
        _hand_potential(x, xt, **params), rel=1e-12, abs=1e-12
    )


def test_potential_known_value():
    # two trackers at (+-1, 0, 0), target at the origin, unit k's, a = 1, b = 6, c = 1.7:
    # J = 2 * 0.5 * 1 + [0.5 * 4 + 0.5 * 6 * 1.7 * exp(-4 / 1.7)]
    x = np.array([[1.0, 0, 0], [-1.0, 0, 0]])
    expected = 1.0 + 2.0 + 5.1 * np.exp(-4.0 / 1.7)
    assert float(potential(x, np.zeros(3))) == pytest.approx(expected, rel=1e-14)


def test_gains_default_one_by_one_and_a_misspelt_gain_is_refused():
    # POTENTIAL_DEFAULTS stand in for each gain not given, the others as given
    from apf_swarm_core.newton import hessian
    from apf_swarm_core.potential import POTENTIAL_DEFAULTS

    x = np.array([[1.0, 0, 0], [-1.0, 0.5, 0], [0.0, 0.2, 1.0]])
    some = {'k_f': 2.0, 'c': 1.2}
    full = {**POTENTIAL_DEFAULTS, **some}
    for f in (potential, gradient, hessian):
        np.testing.assert_array_equal(f(x, np.zeros(3), **some), f(x, np.zeros(3), **full))
    for f in (potential, gradient, hessian):
        with pytest.raises(TypeError, match=r"unexpected gain.*'kn'"):
            f(x, np.zeros(3), kn=2.0)


@pytest.mark.parametrize('n', [1, 2, 3, 7])
@pytest.mark.parametrize('seed', [0, 1, 2, 3])
def test_gradient_matches_finite_differences(n, seed):
    rng = np.random.default_rng([seed, n])
    params = _random_params(rng)
    x = rng.normal(scale=1.5, size=(n, 3))
    xt = rng.normal(size=3)
    g = gradient(x, xt, **params)
    assert g.shape == (n, 3)
    g_fd = _fd_gradient(x, xt, params)
    np.testing.assert_allclose(g, g_fd, rtol=1e-6, atol=1e-7 * (1.0 + np.abs(g_fd).max()))


@pytest.mark.parametrize('seed', [0, 1])
def test_gradient_with_mask_matches_masked_potential(seed):
    rng = np.random.default_rng([seed, 77])
    n = 5
    params = _random_params(rng)
    x = rng.normal(scale=1.5, size=(n, 3))
    xt = rng.normal(size=3)
    m = rng.random((n, n)) < 0.5
    mask = m | m.T
    g = gradient(x, xt, **params, mask=mask)
    g_fd = np.zeros_like(x)
    h = 1e-5
    for i in range(n):
        for k in range(3):
            xp, xm = x.copy(), x.copy()
            xp[i, k] += h
            xm[i, k] -= h
            g_fd[i, k] = (
                potential(xp, xt, **params, mask=mask) - potential(xm, xt, **params, mask=mask)
            ) / (2 * h)
    np.testing.assert_allclose(g, g_fd, rtol=1e-6, atol=1e-7 * (1.0 + np.abs(g_fd).max()))
    # a mask that removes every pair leaves only the tracking term
    g0 = gradient(x, xt, **params, mask=np.zeros((n, n), dtype=bool))
    np.testing.assert_allclose(g0, params['k_n'] * (x - xt), rtol=1e-14, atol=1e-14)


@pytest.mark.parametrize('n', [2, 3, 7])
def test_gradient_rows_equal_rows_of_full_gradient(n):
    rng = np.random.default_rng([n, 3])
    params = _random_params(rng)
    x = rng.normal(scale=1.5, size=(n, 3))
    xt = rng.normal(size=3)
    full = gradient(x, xt, **params)
    for i in range(n):
        row = gradient(x, xt, **params, rows=[i])
        assert row.shape == (1, 3)
        np.testing.assert_allclose(row[0], full[i], rtol=1e-13, atol=1e-13)
    rows = [n - 1, 0]
    np.testing.assert_allclose(
        gradient(x, xt, **params, rows=rows), full[rows], rtol=1e-13, atol=1e-13
    )


@pytest.mark.parametrize('n', [1, 3, 7])
def test_batched_inputs_equal_per_run_calls(n):
    rng = np.random.default_rng([n, 4])
    R = 4
    x = rng.normal(scale=1.5, size=(R, n, 3))
    xt = rng.normal(size=(R, 3))
    per_run = [_random_params(rng) for _ in range(R)]
    batched = {k: np.array([p[k] for p in per_run]) for k in per_run[0]}
    g = gradient(x, xt, **batched)
    j = potential(x, xt, **batched)
    gt = target_gradient(x, xt, k_n=batched['k_n'])
    assert g.shape == (R, n, 3) and j.shape == (R,) and gt.shape == (R, 3)
    for r in range(R):
        np.testing.assert_allclose(
            g[r], gradient(x[r], xt[r], **per_run[r]), rtol=1e-13, atol=1e-13
        )
        assert j[r] == pytest.approx(float(potential(x[r], xt[r], **per_run[r])), rel=1e-13)
        np.testing.assert_allclose(
            gt[r], target_gradient(x[r], xt[r], k_n=per_run[r]['k_n']), rtol=1e-13, atol=1e-13
        )
    # batched rows as well
    np.testing.assert_allclose(
        gradient(x, xt, **batched, rows=[0])[:, 0], g[:, 0], rtol=1e-13, atol=1e-13
    )


def test_batched_with_scalar_gains_equals_per_run_calls():
    rng = np.random.default_rng(5)
    x = rng.normal(size=(3, 4, 3))
    xt = rng.normal(size=(3, 3))
    g = gradient(x, xt, k_n=2.0, b=4.0)
    for r in range(3):
        np.testing.assert_allclose(
            g[r], gradient(x[r], xt[r], k_n=2.0, b=4.0), rtol=1e-14, atol=1e-14
        )


@pytest.mark.parametrize('n', [1, 3, 7])
def test_target_gradient_matches_finite_differences(n):
    rng = np.random.default_rng([n, 6])
    params = _random_params(rng)
    x = rng.normal(scale=1.5, size=(n, 3))
    xt = rng.normal(size=3)
    gt = target_gradient(x, xt, k_n=params['k_n'])
    h = 1e-5
    fd = np.zeros(3)
    for k in range(3):
        tp, tm = xt.copy(), xt.copy()
        tp[k] += h
        tm[k] -= h
        fd[k] = (potential(x, tp, **params) - potential(x, tm, **params)) / (2 * h)
    np.testing.assert_allclose(gt, fd, rtol=1e-6, atol=1e-7 * (1.0 + np.abs(fd).max()))
    # translation invariance of the pair term: sum_i grad_i J + grad_N J = 0
    np.testing.assert_allclose(gradient(x, xt, **params).sum(axis=0) + gt, 0.0, atol=1e-10)


@pytest.mark.parametrize(
    'n, seed, saturation',
    [(3, 0, 'paper'), (3, 1, 'continuous'), (7, 2, 'paper'), (2, 3, 'paper')],
)
def test_potential_decreases_along_kinematic_law(n, seed, saturation):
    """Eq. 7 is a descent law: dJ/dt = -alpha|g|^2 - beta g.sat(g) <= 0 for a static target."""
    rng = np.random.default_rng([seed, 8])
    params = {'k_n': 1.0, 'k_f': 1.0, 'a': 1.0, 'b': 6.0, 'c': 1.7}
    x = rng.normal(scale=2.0, size=(n, 3))
    xt = rng.normal(size=3)
    dt = 2e-3
    js = [float(potential(x, xt, **params))]
    for _ in range(4000):
        g = gradient(x, xt, **params)
        x = x + dt * kinematic_velocity(g, alpha=0.5, beta=2.0, gamma=0.5, saturation=saturation)
        js.append(float(potential(x, xt, **params)))
    js = np.array(js)
    dj = np.diff(js)
    assert np.all(dj <= 1e-12 * np.abs(js[:-1])), dj.max()
    # and it actually went somewhere: J fell and the swarm is near an equilibrium
    assert js[-1] < js[0] - 1.0
    assert np.linalg.norm(gradient(x, xt, **params), axis=-1).max() < 1e-3


@pytest.mark.parametrize('seed', range(5))
def test_pair_term_never_repels_when_b_below_a(seed):
    rng = np.random.default_rng([seed, 9])
    a = rng.uniform(0.1, 5.0)
    b = rng.uniform(0.0, a * 0.999)
    c = rng.uniform(0.1, 5.0)
    r2 = np.concatenate([[0.0], np.logspace(-8, 3, 2000)])
    w = pair_weight(r2, a, b, c)
    assert np.all(w > 0)
    assert w.min() == pytest.approx(a - b, rel=1e-12)  # the minimum is at r = 0


def test_pair_weight_sign_change_at_gazi_passino_distance():
    # b > a: repels below delta = sqrt(c ln(b/a)), attracts above
    a, b, c = 1.0, 6.0, 1.7
    delta2 = c * np.log(b / a)
    assert float(pair_weight(delta2, a, b, c)) == pytest.approx(0.0, abs=1e-14)
    assert float(pair_weight(0.9 * delta2, a, b, c)) < 0
    assert float(pair_weight(1.1 * delta2, a, b, c)) > 0
    assert float(pair_weight(0.0, a, b, c)) == pytest.approx(a - b)
