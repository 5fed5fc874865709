"""Unit tests of apf_swarm_core.config, config_schema and config_files: presets, validation
errors, --set, round trips."""

import math

import numpy as np
import pytest
import yaml
from apf_swarm_core.config import KEYS, REQUIRED_KEYS, SwarmConfig
from apf_swarm_core.config_files import (
    apply_overrides,
    config_from_mapping,
    load_config,
    load_preset,
    parse_set,
    preset_names,
    to_ros_params,
)
from apf_swarm_core.errors import ConfigError, UnknownPresetError


def _base():
    """The triangle preset as a flat mapping (every key, valid)."""
    d = load_preset('triangle').to_dict()
    d.pop('uav_overrides')
    return d


def _write(path, base, sections=None):
    doc = {'/**': {'ros__parameters': base}}
    doc.update(sections or {})
    path.write_text(yaml.safe_dump(doc))
    return path


def test_both_presets_load_with_their_documented_values():
    tri = load_preset('triangle')
    pap = load_preset('paper')
    assert isinstance(tri, SwarmConfig) and isinstance(pap, SwarmConfig)
    assert {'triangle', 'paper'} <= set(preset_names())
    assert (tri.n_trackers, tri.a, tri.b, tri.c, tri.beta) == (3, 1.0, 6.0, 1.7, 2.0)
    assert tri.target_trajectory == 'circle' and tri.target_speed_bound == 1.5
    # paper section 3: a = 1, b = 0.6, c = 1.7, alpha = 0.01, beta = 2, u0 = 125, v_N = 10
    assert (pap.a, pap.b, pap.c, pap.alpha, pap.beta, pap.u0) == (1.0, 0.6, 1.7, 0.01, 2.0, 125.0)
    assert (pap.mass, pap.mass_lo, pap.mass_hi, pap.f_bar) == ((1.0,), 0.5, 1.5, 1.0)
    assert (pap.epsilon, pap.mu) == (1.0, 0.1)
    assert pap.target_speed_bound == 10.0
    assert tri.steps == 30000
    assert tri.mass_matrix_diag() == [[1.0, 1.0, 1.0]] * 3
    assert isinstance(tri.n_trackers, int) and isinstance(tri.dt, float)


def test_unknown_preset_lists_available_ones():
    with pytest.raises(UnknownPresetError) as exc:
        load_preset('triangel')
    msg = str(exc.value)
    assert 'triangel' in msg and 'triangle' in msg and 'paper' in msg
    assert isinstance(exc.value, ConfigError)


def test_unknown_key_with_suggestion(tmp_path):
    base = _base()
    base['gama'] = 0.3
    with pytest.raises(ConfigError, match=r"unknown key 'gama'.*did you mean gamma"):
        load_config(_write(tmp_path / 'c.yaml', base))


@pytest.mark.parametrize('key', ['gamma', 'law', 'mass', 'dt'])
def test_missing_required_key(tmp_path, key):
    assert key in REQUIRED_KEYS
    base = _base()
    del base[key]
    with pytest.raises(ConfigError, match=rf'missing required keys: .*\b{key}\b'):
        load_config(_write(tmp_path / 'c.yaml', base))


@pytest.mark.parametrize(
    'key, value, pattern',
    [
        ('gamma', 'big', r'gamma = .big.: expected a number'),
        ('n_trackers', 2.5, r'n_trackers = 2.5: expected an integer'),
        ('beta', True, r'beta = True: expected a number'),
        ('seed', False, r'seed = False: expected an integer'),
        ('law', 3, r'law = 3: expected a string'),
        ('mass', 'heavy', r'mass = .heavy.: expected a list of numbers'),
        ('target_start', [0.0, 1.0], r'target_start = .*expected a list of 3 numbers'),
        ('mass', [1.0, 1.0], r'mass = .*expected a list of 1 or 3 numbers'),
        ('k_n', -1.0, r'k_n = -1.0: must be > 0'),
        ('k_n', 0.0, r'k_n = 0.0: must be > 0'),
        ('alpha', -0.01, r'alpha = -0.01: must be >= 0'),
        ('u0', -5, r'u0 = -5.0: must be > 0'),
        ('b', -6.0, r'b = -6.0: must be >= 0'),
        ('gamma', math.inf, r'gamma = inf: must be a finite number'),
        ('n_trackers', 0, r'n_trackers = 0: must be >= 1'),
        ('law', 'pid', r"law = 'pid': must be one of proposed, traditional"),
        ('saturation', 'tanh', r"saturation = 'tanh': must be one of paper, continuous"),
        ('target_trajectory', 'spiral', r"target_trajectory = 'spiral'"),
        ('dt', 2.0, r'dt = 2.0: must be > 0 and <= 1'),
        ('target_pitch_deg', 95.0, r'target_pitch_deg = 95.0'),
        ('mass', [2.0], r'mass 2 is outside \[mass_lo, mass_hi\] = \[0.5, 1.5\]'),
        ('mass', [1.0, 0.4, 1.0], r'mass 0.4 is outside'),
        ('mass_lo', 2.0, r'mass_lo = 2.0 > mass_hi'),
        ('target_waypoints', [1.0, 2.0, 3.0, 4.0], r'target_waypoints has 4 numbers'),
    ],
)
def test_invalid_values_raise_config_error_naming_the_key(key, value, pattern):
    base = _base()
    base[key] = value
    with pytest.raises(ConfigError, match=pattern):
        config_from_mapping(base)


def test_integral_float_for_int_is_accepted_and_converted():
    base = _base()
    base['n_trackers'] = 4.0
    cfg = config_from_mapping(base)
    assert cfg.n_trackers == 4 and isinstance(cfg.n_trackers, int)
    base['gamma'] = 1  # an int for a float is fine
    assert isinstance(config_from_mapping(base).gamma, float)


def test_scalar_mass_is_wrapped():
    base = _base()
    base['mass'] = 1.2
    assert config_from_mapping(base).mass == (1.2,)


def test_waypoints_trajectory_needs_waypoints():
    base = _base()
    base['target_trajectory'] = 'waypoints'
    with pytest.raises(ConfigError, match='target_waypoints'):
        config_from_mapping(base)
    base['target_waypoints'] = [1.0, 0.0, 0.0, 1.0, 2.0, 0.0]
    cfg = config_from_mapping(base)
    assert cfg.target_trajectory_obj.points == ((1.0, 0.0, 0.0), (1.0, 2.0, 0.0))


def test_waypoints_with_zero_speed_is_rejected_or_well_defined():
    """target_speed = 0 is allowed by the schema (lo = 0); with waypoints the trajectory must
    then either be refused by the configuration or hover at its start, not crash."""
    base = _base()
    base.update(target_trajectory='waypoints', target_waypoints=[1.0, 0.0, 0.0], target_speed=0.0)
    try:
        cfg = config_from_mapping(base)
    except ConfigError as exc:
        assert 'target_speed' in str(exc)
        return
    # a target of speed 0 never moves: it stays at target_start with zero velocity (its
    # position must be the integral of its velocity, docs/THEORY.md, eq. 1)
    traj = cfg.target_trajectory_obj
    for t in (0.0, 1.0, 100.0):
        pos, vel = traj.state(t)
        np.testing.assert_array_equal(vel, 0.0)
        np.testing.assert_allclose(pos, cfg.target_start, atol=1e-12)


def test_per_uav_overrides_from_file(tmp_path):
    base = _base()
    path = _write(
        tmp_path / 'c.yaml',
        base,
        {
            '/uav_2/tracker': {'ros__parameters': {'mass': [1.2, 1.3, 1.4], 'uav_id': 2}},
            'uav_3': {'ros__parameters': {'initial_position': [1.0, 2.0, 3.0]}},
            '/plant': {'ros__parameters': {'rate_hz': 100}},
        },
    )
    cfg = load_config(path)
    assert cfg.mass_matrix_diag() == [[1.0] * 3, [1.2, 1.3, 1.4], [1.0] * 3]
    assert set(cfg.uav_overrides) == {2, 3}
    assert 'uav_id' not in cfg.uav_overrides[2]
    from apf_swarm_core.simulator import initial_positions

    np.testing.assert_array_equal(initial_positions(cfg)[2], [1.0, 2.0, 3.0])


@pytest.mark.parametrize(
    'section, params, pattern',
    [
        ('/uav_2/tracker', {'gamma': 0.3}, r"uav_2 overrides 'gamma'"),
        ('/uav_5/tracker', {'mass': 1.0}, r'override section for uav_5: there are only 3'),
        ('/uav_0/tracker', {'mass': 1.0}, r'override section for uav_0'),
        ('/uav_1/tracker', {'mass': 3.0}, r'mass 3 is outside \[mass_lo, mass_hi\]'),
        ('/uav_1/tracker', {'initial_position': [1.0, 2.0]}, r'uav_1.initial_position'),
        ('/uav_1/tracker', {'mass': 'x'}, r'uav_1.mass'),
    ],
)
def test_bad_per_uav_sections(tmp_path, section, params, pattern):
    path = _write(tmp_path / 'c.yaml', _base(), {section: {'ros__parameters': params}})
    with pytest.raises(ConfigError, match=pattern):
        load_config(path)


def test_file_level_errors(tmp_path):
    with pytest.raises(ConfigError, match='does not exist'):
        load_config(tmp_path / 'missing.yaml')
    bad = tmp_path / 'bad.yaml'
    bad.write_text('a: [1, 2\n')
    with pytest.raises(ConfigError, match='not valid YAML'):
        load_config(bad)
    flat = tmp_path / 'flat.yaml'
    flat.write_text(yaml.safe_dump(_base()))
    with pytest.raises(ConfigError, match='ros__parameters'):
        load_config(flat)
    other = tmp_path / 'other.yaml'
    other.write_text(yaml.safe_dump({'/plant': {'ros__parameters': {'x': 1}}}))
    with pytest.raises(ConfigError, match=r"no '/\*\*: ros__parameters:' section"):
        load_config(other)


def test_node_keys_are_ignored(tmp_path):
    base = _base()
    base.update(uav_id=3, use_sim_time=True, mode='lockstep')
    assert load_config(_write(tmp_path / 'c.yaml', base)) == load_preset('triangle')


def test_parse_set():
    out = parse_set(
        [
            'gamma=0.5',
            'n_trackers=4',
            'law=traditional',
            'mass=[1, 1.2, 1.3]',
            'target_start = [0, 0, 10]',
        ]
    )
    assert out == {
        'gamma': 0.5,
        'n_trackers': 4,
        'law': 'traditional',
        'mass': [1, 1.2, 1.3],
        'target_start': [0, 0, 10],
    }
    assert isinstance(out['gamma'], float) and isinstance(out['n_trackers'], int)
    # exponent notation without a dot is a number (YAML 1.1 alone would keep '1e-5')
    assert parse_set(['newton_mu=1e-5', 'u0=2E+1']) == {'newton_mu': 1e-5, 'u0': 20.0}
    with pytest.raises(ConfigError, match=r"'novalue': expected KEY=VALUE"):
        parse_set(['novalue'])
    with pytest.raises(ConfigError, match=r'expected KEY=VALUE'):
        parse_set(['=3'])
    with pytest.raises(ConfigError, match=r"unknown key 'gama' in --set.*did you mean gamma"):
        parse_set(['gama=0.3'])
    with pytest.raises(ConfigError, match='not valid YAML'):
        parse_set(['mass=[1, 2'])


def test_apply_overrides_validates():
    cfg = load_preset('triangle')
    new = apply_overrides(cfg, parse_set(['gamma=0.5', 'law=traditional']))
    assert (new.gamma, new.law) == (0.5, 'traditional')
    assert new.replace(gamma=0.2, law='proposed') == cfg
    assert cfg.gamma == 0.2  # the original is unchanged
    with pytest.raises(ConfigError, match='gamma'):
        apply_overrides(cfg, {'gamma': -1.0})
    with pytest.raises(ConfigError, match="unknown key 'uav_overrides'"):
        apply_overrides(cfg, {'uav_overrides': {}})
    with pytest.raises(ConfigError, match=r'n_trackers = 2.5'):
        apply_overrides(cfg, parse_set(['n_trackers=2.5']))
    with pytest.raises(ConfigError, match='beta'):
        cfg.replace(beta=0.0)


@pytest.mark.parametrize('preset', ['triangle', 'paper'])
def test_to_ros_params_round_trip(tmp_path, preset):
    cfg = load_preset(preset)
    path = tmp_path / 'resolved.yaml'
    path.write_text(yaml.safe_dump(to_ros_params(cfg)))
    assert load_config(path) == cfg


def test_to_ros_params_round_trip_with_overrides_from_file(tmp_path):
    src = _write(
        tmp_path / 'src.yaml',
        _base(),
        {
            '/uav_2/tracker': {
                'ros__parameters': {'mass': [1.2, 1.3, 1.4], 'initial_position': [1.0, 2.0, 3.0]}
            }
        },
    )
    cfg = load_config(src).replace(gamma=0.35, target_waypoints=(1.0, 2.0, 3.0))
    path = tmp_path / 'resolved.yaml'
    path.write_text(yaml.safe_dump(to_ros_params(cfg)))
    back = load_config(path)
    assert back == cfg
    assert back.mass_matrix_diag() == cfg.mass_matrix_diag()


def test_to_ros_params_round_trip_with_overrides_built_in_python(tmp_path):
    """Overrides given as Python tuples (as the dataclass fields themselves are) must survive
    a write/load cycle: the loaded configuration equals the one written."""
    cfg = config_from_mapping(
        _base(), overrides={2: {'mass': 1.2, 'initial_position': (1.0, 2.0, 3.0)}}
    )
    path = tmp_path / 'resolved.yaml'
    path.write_text(yaml.safe_dump(to_ros_params(cfg)))
    assert load_config(path) == cfg


def test_keys_and_to_dict_are_consistent():
    cfg = load_preset('triangle')
    d = cfg.to_dict()
    assert set(d) == set(KEYS) | {'uav_overrides'}
    assert d['mass'] == [1.0] and d['target_start'] == [0.0, 0.0, 5.0]
    assert cfg.potential_params() == {'k_n': 1.0, 'k_f': 1.0, 'a': 1.0, 'b': 6.0, 'c': 1.7}


def test_key_bounds_are_intervals():
    from apf_swarm_core.config_schema import key

    def bounds(text):
        meta = key(0.0, 'a key', 'm', text).metadata
        return meta['lo'], meta['lo_open'], meta['hi']

    assert bounds('(0, inf)') == (0.0, True, None)
    assert bounds('[0, inf)') == (0.0, False, None)
    assert bounds('(0, 1]') == (0.0, True, 1.0)
    assert bounds('[-90, 90]') == (-90.0, False, 90.0)
    assert bounds('(-inf, 1e6]') == (None, False, 1.0e6)
    assert bounds('') == (None, False, None)
    for bad in ('0, 1', '[0, 1)', '(0, inf]', '[0 1]'):
        with pytest.raises(ValueError, match='expected an interval'):
            bounds(bad)
