"""Unit tests of apf_swarm_core.checks and apf_swarm_core.gain_bounds: the paper's conditions
and the u0 bounds."""

import math

import numpy as np
import pytest
from apf_swarm_core.checks import check_config
from apf_swarm_core.gain_bounds import gain_bounds, gain_bounds_from_run, pair_hessian_bound

from apf_swarm_core import load_preset


def _by_code(rep):
    return {f.code: f for f in rep.findings}


def test_triangle_preset_is_consistent():
    cfg = load_preset('triangle')
    rep = check_config(cfg)
    f = _by_code(rep)
    assert f['beta_vs_vn'].level == 'ok'
    assert f['formation'].level == 'ok'
    assert '1.599' in f['formation'].message
    assert rep.exit_code == 0
    assert rep.warnings == []
    # the boundary-layer lag of docs/THEORY.md section 2:
    # v_N / (k_N (alpha + beta/gamma)) = 1.5 / 10.01
    assert f['lag'].level == 'info' and '0.15' in f['lag'].message


def test_paper_preset_warns_about_beta_and_formation():
    cfg = load_preset('paper')
    rep = check_config(cfg)
    f = _by_code(rep)
    assert f['beta_vs_vn'].level == 'warning'
    assert 'beta = 2 < v_N = 10' in f['beta_vs_vn'].message
    assert f['formation'].level == 'warning'
    assert 'never repels' in f['formation'].message and 'collapse' in f['formation'].message
    assert rep.exit_code == 1
    assert len(rep.warnings) == 2
    assert rep.as_dict()['exit_code'] == 1


@pytest.mark.parametrize(
    'changes, code, level',
    [
        ({'b': 1.3}, 'formation', 'warning'),  # a < b < a + k_n/(3 k_f): no triangle
        ({'b': 1.34}, 'formation', 'ok'),
        ({'beta': 1.5}, 'beta_vs_vn', 'ok'),  # beta == v_N is enough (eq. 10-11: >=)
        ({'beta': 1.49}, 'beta_vs_vn', 'warning'),
        ({'lambda_filter': 0.005}, 'filter_dt', 'warning'),
    ],
)
def test_individual_conditions(changes, code, level):
    cfg = load_preset('triangle').replace(**changes)
    assert _by_code(check_config(cfg))[code].level == level


def test_formation_check_for_other_n():
    base = load_preset('triangle')
    assert _by_code(check_config(base.replace(n_trackers=4)))['formation'].level == 'ok'
    assert (
        _by_code(check_config(base.replace(n_trackers=4, b=0.9)))['formation'].level == 'warning'
    )
    assert _by_code(check_config(base.replace(n_trackers=1)))['formation'].level == 'info'


def test_a_crowded_start_is_warned_of_and_a_separated_one_is_not():
    """128 trackers in the paper's 1 m ball start 4.5 cm apart (3 % of the formation's
    spacing): a warning naming init_separation; with it, 0.5 m apart, ok; the preset's
    formation start: 0.7 of the design's closest pair, 1.11 m."""
    cfg = load_preset('realtime').replace(n_trackers=128)
    ball = cfg.replace(init_layout='ball')
    crowded = _by_code(check_config(ball.replace(init_separation=0.0)))['start']
    assert crowded.level == 'warning'
    assert 'start 0.0454 m apart, 3% of the formation spacing 1.58 m' in crowded.message
    assert 'init_separation' in crowded.message
    apart = _by_code(check_config(ball))['start']
    assert apart.level == 'ok' and 'start 0.501 m apart' in apart.message
    shaped = _by_code(check_config(cfg))['start']
    assert shaped.level == 'ok' and 'start 1.11 m apart' in shaped.message


@pytest.mark.parametrize('preset', ['triangle', 'paper'])
@pytest.mark.parametrize('j_bar, j_bar_s', [(0.5, 3.0), (0.0, 0.0), (2.25, 40.0)])
def test_gain_bound_arithmetic(preset, j_bar, j_bar_s):
    cfg = load_preset(preset).replace(lambda_filter=0.08, f_bar=1.3, epsilon=0.7, mu=0.2)
    bounds, est = gain_bounds(cfg, j_bar=j_bar, j_bar_s=j_bar_s)
    m_lo, m_hi, f = 0.5, 1.5, 1.3
    j_sign = 2 * 2.0 / 0.08  # eq. 35: 2 beta / lambda = 50
    assert est['J_bar_sign'] == pytest.approx(50.0, rel=1e-14)
    assert est['J_bar'] == j_bar and est['J_bar_s'] == j_bar_s
    b = {bd.name: bd for bd in bounds}
    assert set(b) == {'theorem1_eq29', 'eq37', 'eq43'}
    # eq. 29 as printed: M_hi (-f/M_lo + J + J_sign + eps); corrected: +f/M_lo
    assert b['theorem1_eq29'].printed == pytest.approx(
        m_hi * (-f / m_lo + j_bar + j_sign + 0.7), rel=1e-14
    )
    assert b['theorem1_eq29'].corrected == pytest.approx(
        m_hi * (f / m_lo + j_bar + j_sign + 0.7), rel=1e-14
    )
    # eq. 37 as printed: M_hi (-f/M_hi + J_sign + J + eps)
    assert b['eq37'].printed == pytest.approx(m_hi * (-f / m_hi + j_sign + j_bar + 0.7), rel=1e-14)
    assert b['eq37'].corrected == pytest.approx(
        m_hi * (f / m_lo + j_sign + j_bar + 0.7), rel=1e-14
    )
    # eq. 43 as printed: M_hi (-f/M_hi + J_s + mu)
    assert b['eq43'].printed == pytest.approx(m_hi * (-f / m_hi + j_bar_s + 0.2), rel=1e-14)
    assert b['eq43'].corrected == pytest.approx(m_hi * (f / m_lo + j_bar_s + 0.2), rel=1e-14)
    for bd in bounds:
        assert bd.corrected > bd.printed
        assert bd.u0 == 125.0
        assert bd.holds_printed == (bd.printed < 125.0)
        assert bd.holds_corrected == (bd.corrected < 125.0)


def test_gain_bound_verdicts_between_printed_and_corrected():
    # choose u0 between the printed and the corrected eq. 29 bound
    cfg = load_preset('triangle').replace(lambda_filter=0.1, f_bar=1.0, epsilon=1.0)
    # printed 1.5 (-2 + 0 + 40 + 1) = 58.5, corrected 1.5 (2 + 40 + 1) = 64.5
    b = {bd.name: bd for bd in gain_bounds(cfg.replace(u0=60.0), j_bar=0.0, j_bar_s=0.0)[0]}
    assert b['theorem1_eq29'].printed == pytest.approx(58.5)
    assert b['theorem1_eq29'].corrected == pytest.approx(64.5)
    assert b['theorem1_eq29'].holds_printed and not b['theorem1_eq29'].holds_corrected


def test_a_priori_estimates():
    cfg = load_preset('triangle')
    _, est = gain_bounds(cfg)
    h = pair_hessian_bound(1.0, 6.0)
    assert h == pytest.approx(max(5.0, 1.0 + 12.0 * math.exp(-1.5)), rel=1e-14)
    assert est['lipschitz_grad'] == pytest.approx(1.0 + 2 * 2 * 1.0 * h, rel=1e-14)
    lip, g0, a, beta, gam, vn = (
        est['lipschitz_grad'],
        est['initial_gradient_max'],
        0.01,
        2.0,
        0.2,
        1.5,
    )
    assert est['J_bar'] == pytest.approx(
        a * (lip * (a * g0 + math.sqrt(3) * beta) + vn), rel=1e-14
    )
    assert est['J_bar_s'] == pytest.approx(
        (a + beta / gam) * (lip * (a * gam + beta) + vn), rel=1e-14
    )
    assert est['J_bar_sign'] == pytest.approx(40.0)


def test_pair_hessian_bound_bounds_the_true_hessian_eigenvalues():
    """Eigenvalues of the pair Hessian, w and a - b e^{-u}(1 - 2u), over a grid of r."""
    for a, b in [(1.0, 6.0), (1.0, 0.6), (2.0, 3.0)]:
        c = 1.7
        r2 = np.linspace(0, 30, 30001)
        u = r2 / c
        eig = np.concatenate([a - b * np.exp(-u), a - b * np.exp(-u) * (1 - 2 * u)])
        assert np.abs(eig).max() <= pair_hessian_bound(a, b) * (1 + 1e-12)
        assert np.abs(eig).max() >= 0.999 * pair_hessian_bound(a, b)


def test_gain_bounds_from_run_by_hand():
    cfg = load_preset('triangle').replace(n_trackers=1)
    t = np.array([0.0, 0.1, 0.2])
    tx = np.zeros((3, 3))
    # one tracker, gradient = x (k_n = 1): |g| 1.0, 0.5 (outside gamma = 0.2), 0.1 (inside)
    x = np.array([[[1.0, 0.0, 0.0]], [[0.5, 0.0, 0.0]], [[0.1, 0.0, 0.0]]])
    bounds, est = gain_bounds_from_run(cfg, t, x, tx, steady_fraction=1.0)
    # rates |0.5 - 1| / 0.1 = 5 and |0.1 - 0.5| / 0.1 = 4, both from outside samples
    assert est['J_bar'] == pytest.approx(0.01 * 5.0, rel=1e-12)
    assert est['J_bar_s'] == 0.0
    assert est['fraction_inside_layer'] == 0.0
    x[1, 0, 0] = 0.15  # now sample 1 is inside the layer
    _, est = gain_bounds_from_run(cfg, t, x, tx, steady_fraction=1.0)
    assert est['J_bar'] == pytest.approx(0.01 * 8.5, rel=1e-12)
    assert est['J_bar_s'] == pytest.approx((0.01 + 2.0 / 0.2) * 0.5, rel=1e-12)
    assert est['fraction_inside_layer'] == pytest.approx(0.5)
    b = {bd.name: bd for bd in bounds}
    assert b['eq43'].printed == pytest.approx(1.5 * (-1.0 / 1.5 + 0.0 + 0.1), rel=1e-12)


def test_gain_bounds_from_run_uses_the_steady_part():
    cfg = load_preset('triangle').replace(n_trackers=1)
    t = np.arange(5) * 0.1
    x = np.array([2.0, 1.0, 0.8, 0.5, 0.45])[:, None, None] * np.array([1.0, 0.0, 0.0])
    tx = np.zeros((5, 3))
    # rates 10, 2, 3, 0.5 [1/s]; every sample is outside gamma = 0.2
    _, full = gain_bounds_from_run(cfg, t, x, tx, steady_fraction=1.0)
    assert full['J_bar'] == pytest.approx(0.01 * 10.0, rel=1e-12)
    _, half = gain_bounds_from_run(cfg, t, x, tx, steady_fraction=0.5)
    assert half['J_bar'] == pytest.approx(0.01 * 3.0, rel=1e-12)


def test_check_config_with_run_adds_measured_bounds():
    cfg = load_preset('triangle').replace(duration=0.05)
    from apf_swarm_core import simulate

    run = simulate(cfg).trajectory
    rep = check_config(cfg, run)
    names = [b.name for b in rep.bounds]
    assert names == [
        'theorem1_eq29',
        'eq37',
        'eq43',
        'theorem1_eq29_measured',
        'eq37_measured',
        'eq43_measured',
    ]
    assert 'measured_J_bar' in rep.estimates and 'a_priori_J_bar' in rep.estimates
    codes = {f.code for f in rep.findings}
    assert {'u0_theorem1_eq29_measured', 'u0_eq43_measured'} <= codes
    # the traditional law has no boundary layer: eq. 43 is not reported for it
    rep_t = check_config(cfg.replace(law='traditional'), run)
    assert not any(f.code.startswith('u0_eq43') for f in rep_t.findings)


def test_an_emulation_that_does_not_fly_is_a_warning_whatever_the_prediction():
    """The emulation outranks the linear prediction: a run of it that flies is information,
    one that does not (here the same run with every tracker pushed onto one spot over the
    judged window) is a warning with its remedies."""
    from apf_swarm_core.checks import sampled_findings
    from apf_swarm_core.simulator import simulate

    cfg = load_preset('realtime').replace(duration=6.0, record_every=10, control_rate=100.0)
    run = dict(simulate(cfg).trajectory)
    (ok,) = [f for f in sampled_findings(cfg, run) if f.code == 'emulation']
    assert ok.level == 'info' and 'flies' in ok.message
    crowded = np.array(run['x'], copy=True)
    crowded[len(crowded) // 2 :] = crowded[len(crowded) // 2 :, :1]  # all at the first's spot
    (bad,) = [f for f in sampled_findings(cfg, {**run, 'x': crowded}) if f.code == 'emulation']
    assert bad.level == 'warning' and 'does not fly' in bad.message
    assert 'fewer trackers' in bad.message
