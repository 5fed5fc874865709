"""The saturation of eq. 8 and its continuous variant (their numpy forms in reference.py)."""

import numpy as np
import pytest
from reference import outside_layer, sat, sat_continuous, saturate, sign


def test_sign_is_componentwise_with_sign_of_zero_zero():
    np.testing.assert_array_equal(sign([[-2.0, 0.0, 1e-300]]), [[-1.0, 0.0, 1.0]])


@pytest.mark.parametrize('fn', [sat, sat_continuous])
def test_zero_gradient_gives_zeros(fn):
    out = fn(np.zeros((4, 3)), 0.5)
    assert out.shape == (4, 3)
    np.testing.assert_array_equal(out, 0.0)


def test_exactly_on_the_boundary_takes_the_sign_branch():
    # ||(3, 4, 0)|| == 5 exactly in floating point; eq. 8 uses >=
    g = np.array([[3.0, 4.0, 0.0]])
    assert np.linalg.norm(g) == 5.0
    np.testing.assert_array_equal(sat(g, 5.0), [[1.0, 1.0, 0.0]])
    assert outside_layer(g, 5.0).tolist() == [True]


def test_just_inside_the_boundary_is_linear():
    g = np.array([[3.0, 4.0, 0.0]])
    gamma = 5.0 * (1.0 + 1e-12)
    np.testing.assert_allclose(sat(g, gamma), g / gamma, rtol=1e-15)
    assert outside_layer(g, gamma).tolist() == [False]
    # the paper's sat jumps at the boundary: from norm ~1 to norm sqrt(2) here
    assert np.linalg.norm(sat(g, gamma)) == pytest.approx(1.0, rel=1e-11)
    assert np.linalg.norm(sat(g, 5.0)) == pytest.approx(np.sqrt(2.0), rel=1e-15)


def test_sign_branch_is_componentwise():
    g = np.array([[10.0, -0.001, 0.0], [-3.0, -4.0, 12.0]])
    np.testing.assert_array_equal(sat(g, 1.0), [[1.0, -1.0, 0.0], [-1.0, -1.0, 1.0]])


@pytest.mark.parametrize('seed', range(3))
def test_sat_random_rows_follow_eq8(seed):
    rng = np.random.default_rng(seed)
    g = rng.normal(size=(200, 3)) * rng.uniform(0.01, 3.0, size=(200, 1))
    gamma = 1.0
    out = sat(g, gamma)
    norms = np.linalg.norm(g, axis=1)
    for row, gi, ni in zip(out, g, norms, strict=False):
        expected = np.sign(gi) if ni >= gamma else gi / gamma
        np.testing.assert_array_equal(row, expected)
    assert (norms < gamma).any() and (norms >= gamma).any()


def test_sat_continuous_is_continuous_at_the_boundary_and_unit_outside():
    d = np.array([0.3, -0.5, 0.8])
    d /= np.linalg.norm(d)
    gamma = 0.7
    for eps in (1e-3, 1e-6, 1e-9):
        below = sat_continuous((gamma * (1 - eps) * d)[None], gamma)[0]
        above = sat_continuous((gamma * (1 + eps) * d)[None], gamma)[0]
        assert np.linalg.norm(above - below) <= 2 * eps
    np.testing.assert_allclose(sat_continuous((gamma * d)[None], gamma)[0], d, rtol=1e-15)
    rng = np.random.default_rng(4)
    g = rng.normal(size=(100, 3))
    g *= (gamma * rng.uniform(1.0, 50.0, size=(100, 1))) / np.linalg.norm(g, axis=1, keepdims=True)
    out = sat_continuous(g, gamma)
    np.testing.assert_allclose(np.linalg.norm(out, axis=1), 1.0, rtol=1e-14)
    np.testing.assert_allclose(out, g / np.linalg.norm(g, axis=1, keepdims=True), rtol=1e-14)
    # inside the layer it equals eq. 8
    gi = 0.5 * gamma * d[None]
    np.testing.assert_allclose(sat_continuous(gi, gamma), sat(gi, gamma), rtol=1e-15)


@pytest.mark.parametrize('fn', [sat, sat_continuous])
def test_batch_gamma_array_equals_per_run_calls(fn):
    rng = np.random.default_rng(7)
    R, m = 4, 5
    g = rng.normal(size=(R, m, 3))
    gamma = np.array([0.3, 1.0, 1.7, 5.0])
    out = fn(g, gamma)
    assert out.shape == (R, m, 3)
    for r in range(R):
        np.testing.assert_array_equal(out[r], fn(g[r], float(gamma[r])))
    inside = outside_layer(g, gamma)
    assert inside.shape == (R, m)
    for r in range(R):
        np.testing.assert_array_equal(inside[r], np.linalg.norm(g[r], axis=-1) >= gamma[r])


def test_saturate_dispatches_and_rejects_unknown_kind():
    g = np.array([[2.0, -1.0, 0.5]])
    np.testing.assert_array_equal(saturate(g, 1.0, 'paper'), sat(g, 1.0))
    np.testing.assert_array_equal(saturate(g, 1.0, 'continuous'), sat_continuous(g, 1.0))
    with pytest.raises(ValueError, match='saturation'):
        saturate(g, 1.0, 'tanh')
