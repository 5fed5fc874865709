"""Theory tests of apf_swarm_core.design: equilibrium spacings of eq. 44 and their inverses."""

import math

import numpy as np
import pytest
from apf_swarm_core.design import (
    b_for_spacing,
    equilibrium_formation,
    expected_spacing,
    pair_equilibrium_distance,
    polish_minimum,
    triangle_b_for_spacing,
    triangle_c_for_spacing,
    triangle_spacing,
)
from apf_swarm_core.errors import ConfigError
from apf_swarm_core.gradients import gradient
from apf_swarm_core.potential import potential
from reference import kinematic_velocity


def _spec_triangle_side(a, b, c, k_n, k_f):
    """docs/THEORY.md section 2: d = sqrt(c ln(b / (a + k_N/(3 k_f))))."""
    return math.sqrt(c * math.log(b / (a + k_n / (3.0 * k_f))))


def _equilateral(d, centre=None):
    """Equilateral triangle of side d in a tilted plane, centroid at ``centre``."""
    rho = d / math.sqrt(3.0)
    ang = np.array([0.0, 2 * np.pi / 3, 4 * np.pi / 3]) + 0.3
    x = np.stack([rho * np.cos(ang), rho * np.sin(ang), np.zeros(3)], axis=1)
    rot = np.array(
        [[1, 0, 0], [0, math.cos(0.7), -math.sin(0.7)], [0, math.sin(0.7), math.cos(0.7)]]
    )
    return x @ rot.T + (np.zeros(3) if centre is None else centre)


def test_triangle_spacing_value_for_default_parameters():
    d = triangle_spacing(1.0, 6.0, 1.7, 1.0, 1.0)
    assert d == pytest.approx(math.sqrt(1.7 * math.log(4.5)), rel=1e-14)
    assert d == pytest.approx(1.599, abs=5e-4)


@pytest.mark.parametrize(
    'a, b, c, k_n, k_f',
    [(1.0, 6.0, 1.7, 1.0, 1.0), (0.5, 3.0, 2.5, 2.0, 1.5), (2.0, 20.0, 0.8, 0.5, 3.0)],
)
def test_equilibrium_formation_of_three_is_the_spec_triangle(a, b, c, k_n, k_f):
    d = _spec_triangle_side(a, b, c, k_n, k_f)
    assert triangle_spacing(a, b, c, k_n, k_f) == pytest.approx(d, rel=1e-14)
    f = equilibrium_formation(3, k_n=k_n, k_f=k_f, a=a, b=b, c=c)
    np.testing.assert_allclose(f.pair_distances, d, atol=1e-6)
    assert f.spacing == pytest.approx(d, abs=1e-6)
    assert f.gradient_norm < 1e-6
    np.testing.assert_allclose(f.relative_positions.mean(axis=0), 0.0, atol=1e-6)
    # the gradient vanishes at the exact equilateral triangle of that side on the target
    target = np.array([3.0, -1.0, 5.0])
    g = gradient(_equilateral(d, target), target, k_n=k_n, k_f=k_f, a=a, b=b, c=c)
    np.testing.assert_allclose(g, 0.0, atol=1e-12)
    # and not at a slightly larger or smaller one
    for scale in (0.95, 1.05):
        g = gradient(_equilateral(scale * d, target), target, k_n=k_n, k_f=k_f, a=a, b=b, c=c)
        assert np.linalg.norm(g, axis=-1).min() > 1e-3


@pytest.mark.parametrize('d', [0.5, 1.599, 3.0])
def test_triangle_inverses(d):
    a, c, k_n, k_f = 1.0, 1.7, 1.0, 2.0
    b = triangle_b_for_spacing(d, a, c, k_n, k_f)
    assert triangle_spacing(a, b, c, k_n, k_f) == pytest.approx(d, rel=1e-12)
    c2 = triangle_c_for_spacing(d, a, 6.0, k_n, k_f)
    assert triangle_spacing(a, 6.0, c2, k_n, k_f) == pytest.approx(d, rel=1e-12)
    assert b_for_spacing(d, 3, k_n=k_n, k_f=k_f, a=a, c=c) == pytest.approx(b, rel=1e-14)


def test_triangle_c_for_spacing_refuses_without_triangle():
    with pytest.raises(ConfigError, match=r'b = 1\.2'):
        triangle_c_for_spacing(1.0, 1.0, 1.2, 1.0, 1.0)  # threshold 4/3


@pytest.mark.parametrize(
    'a, b, k_n, k_f',
    [
        (1.0, 0.6, 1.0, 1.0),  # the paper's b < a
        (1.0, 4.0 / 3.0, 1.0, 1.0),  # exactly the threshold
        (1.0, 1.3, 1.0, 1.0),
        (1.0, 1.9, 3.0, 1.0),
    ],
)  # threshold 2
def test_triangle_spacing_none_at_or_below_threshold(a, b, k_n, k_f):
    assert triangle_spacing(a, b, 1.7, k_n, k_f) is None
    assert expected_spacing(3, k_n=k_n, k_f=k_f, a=a, b=b, c=1.7) is None


def test_paper_parameters_collapse_onto_the_target():
    f = equilibrium_formation(3, a=1.0, b=0.6, c=1.7, starts=3)
    assert f.pair_distances.max() < 1e-5
    assert np.abs(f.relative_positions).max() < 1e-5


def test_gazi_passino_pair_distance_by_kinematic_law():
    """Two agents, no target (k_N = 0), eq. 7 with beta = 0: they rest at sqrt(c ln(b/a))."""
    a, b, c = 1.0, 6.0, 1.7
    delta = math.sqrt(c * math.log(b / a))
    assert pair_equilibrium_distance(a, b, c) == pytest.approx(delta, rel=1e-14)
    assert pair_equilibrium_distance(1.0, 0.6, 1.7) is None
    params = {'k_n': 0.0, 'k_f': 1.0, 'a': a, 'b': b, 'c': c}
    for start in (0.3, 4.0):  # from inside and from outside delta
        x = np.array([[0.0, 0.0, 0.0], [start, 0.2, -0.1]])
        dt = 1e-2
        for _ in range(3000):
            x = x + dt * kinematic_velocity(
                gradient(x, np.zeros(3), **params), alpha=1.0, beta=0.0, gamma=1.0
            )
        assert np.linalg.norm(x[0] - x[1]) == pytest.approx(delta, rel=1e-8)
    f = equilibrium_formation(2, **params, starts=2)
    assert f.spacing == pytest.approx(delta, rel=1e-6)


def swarm_size_bound(a, b, c):
    """Gazi--Passino bound on the distance of every agent from the centroid,
    ``epsilon = (b/a) sqrt(c/2) e^{-1/2}`` [m] (no target term; design.py's docstring)."""
    return (b / a) * math.sqrt(c / 2.0) * math.exp(-0.5)


def test_swarm_size_bound_formula_and_property():
    a, b, c = 1.0, 6.0, 1.7
    eps = swarm_size_bound(a, b, c)
    assert eps == pytest.approx(6.0 * math.sqrt(0.85) * math.exp(-0.5), rel=1e-14)
    assert eps == pytest.approx(3.3552, abs=1e-4)
    assert swarm_size_bound(2.0, 6.0, 1.7) == pytest.approx(eps / 2, rel=1e-14)
    # Gazi-Passino: without a target every agent ends within eps of the centroid
    rng = np.random.default_rng(3)
    x = rng.normal(scale=3.0, size=(7, 3))
    params = {'k_n': 0.0, 'k_f': 1.0, 'a': a, 'b': b, 'c': c}
    for _ in range(4000):
        x = x + 1e-2 * kinematic_velocity(
            gradient(x, np.zeros(3), **params), alpha=1.0, beta=0.0, gamma=1.0
        )
    assert np.linalg.norm(gradient(x, np.zeros(3), **params), axis=-1).max() < 1e-4
    r = np.linalg.norm(x - x.mean(axis=0), axis=-1)
    assert r.max() <= eps


def test_two_tracker_closed_form():
    a, b, c = 1.0, 6.0, 1.7
    d = expected_spacing(2, k_n=1.0, k_f=1.0, a=a, b=b, c=c)
    assert d == pytest.approx(math.sqrt(c * math.log(b / 1.5)), rel=1e-14)
    f = equilibrium_formation(2, a=a, b=b, c=c, starts=2)
    assert f.spacing == pytest.approx(d, abs=1e-6)
    assert expected_spacing(1, k_n=1.0, k_f=1.0, a=a, b=b, c=c) is None


def test_b_for_spacing_four_trackers():
    d = 1.5
    b = b_for_spacing(d, 4, a=1.0, c=1.7)
    f = equilibrium_formation(4, a=1.0, b=b, c=1.7, starts=4)
    assert f.spacing == pytest.approx(d, abs=1e-4)
    assert f.gradient_norm < 1e-5
    # four trackers around a target: a regular tetrahedron (all six pairs equal)
    np.testing.assert_allclose(f.pair_distances, d, atol=1e-4)


def test_polish_leaves_a_saddle_for_the_minimum():
    # four trackers on a square about the target, side at its planar equilibrium: every
    # gradient is zero, but out of the plane the square is a saddle of J. The polish must
    # leave it for the minimum, the regular tetrahedron: six equal pair distances.
    params = {'k_n': 1.0, 'k_f': 1.0, 'a': 1.0, 'b': 6.0, 'c': 1.7}
    from scipy.optimize import brentq

    def radial(r):
        sq = r * np.array([[1.0, 0, 0], [0, 1, 0], [-1, 0, 0], [0, -1, 0]])
        return gradient(sq, np.zeros(3), **params)[0, 0]

    r = brentq(radial, 0.05, 3.0)
    square = r * np.array([[1.0, 0, 0], [0, 1, 0], [-1, 0, 0], [0, -1, 0]])
    assert np.abs(gradient(square, np.zeros(3), **params)).max() < 1e-9
    x = polish_minimum(square, params)
    d = np.linalg.norm(x[:, None] - x[None], axis=-1)[np.triu_indices(4, 1)]
    np.testing.assert_allclose(d, d.mean(), rtol=1e-6)
    assert np.abs(gradient(x, np.zeros(3), **params)).max() < 1e-8
    assert potential(x, np.zeros(3), **params) < potential(square, np.zeros(3), **params)
