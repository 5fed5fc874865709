"""Typed, validated configuration, read from ROS 2 parameter files.

A configuration file is a ROS 2 parameter file, so that the nodes read the very same file::

    /**:
      ros__parameters:
        n_trackers: 3
        law: proposed
        ...
    /uav_2/tracker:          # per-UAV overrides (keys in PER_UAV_KEYS only)
      ros__parameters:
        mass: 1.2

Every key of :class:`SwarmConfig` is described by its field metadata (type, range, unit,
help); validation, the ``--set`` parser and the nodes' parameter descriptors all read it.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from typing import Any

from .errors import ConfigError
from .laws import LAWS, SWITCHINGS
from .neighbours import NEIGHBOUR_RULES
from .plant import NOISE_KINDS
from .potential import PotentialParams
from .prediction import COMPENSATIONS
from .saturation import SATURATIONS
from .target import TRAJECTORIES, Trajectory, make_trajectory

__all__ = [
    'DEFAULT_LATENCY',
    'PER_UAV_KEYS',
    'REALTIME_RATE',
    'REQUIRED_KEYS',
    'SwarmConfig',
    'apply_overrides',
    'config_from_mapping',
    'load_config',
    'load_preset',
    'parse_set',
    'preset_dirs',
    'preset_names',
    'preset_path',
    'resolve',
    'to_ros_params',
]

#: realtime rate of the plant's publications and the trackers' control [Hz] when
#: ``control_rate`` is 0
REALTIME_RATE = 100.0
#: control-loop latency [s] that ``apf-swarm check --mode realtime`` and ``design`` assume
#: when neither the configuration, ``--latency`` nor this machine's probe (``apf-swarm
#: probe``) gives one
DEFAULT_LATENCY = 0.005

#: keys a ``/uav_<i>/...`` section may override for one tracker
PER_UAV_KEYS = ('mass', 'initial_position')


def _p(
    default: Any,
    *,
    unit: str = '',
    help: str,
    lo: float | None = None,
    lo_open: bool = False,
    hi: float | None = None,
    choices: tuple[str, ...] | None = None,
    length: tuple[int, ...] | None = None,
    required: bool = False,
    read_only: bool = False,
) -> Any:
    meta = {
        'unit': unit,
        'help': help,
        'lo': lo,
        'lo_open': lo_open,
        'hi': hi,
        'choices': choices,
        'length': length,
        'required': required,
        'read_only': read_only,
    }
    if isinstance(default, (list, tuple)):
        return field(default_factory=lambda: tuple(default), metadata=meta)
    return field(default=default, metadata=meta)


@dataclass(frozen=True)
class SwarmConfig:
    """All parameters of a run. Units are SI; angles in degrees where the name says ``_deg``."""

    # swarm and laws
    n_trackers: int = _p(
        3, lo=1, hi=10000, help='number of tracking UAVs n = N - 1', read_only=True
    )
    law: str = _p(
        'proposed',
        choices=LAWS,
        required=True,
        help='proposed (saturated, eq. 22-31) or traditional (sign law of Yao et al.)',
    )
    saturation: str = _p(
        'paper',
        choices=SATURATIONS,
        help='paper: eq. 8 as printed; continuous: g / max(|g|, gamma)',
    )
    # potential, eq. 2 / 44
    k_n: float = _p(1.0, lo=0.0, lo_open=True, required=True, help='weight of the tracking term')
    k_f: float = _p(1.0, lo=0.0, lo_open=True, required=True, help='weight of the formation term')
    a: float = _p(1.0, lo=0.0, lo_open=True, required=True, help='attraction gain of eq. 44')
    b: float = _p(6.0, lo=0.0, required=True, help='repulsion gain of eq. 44')
    c: float = _p(
        1.7, unit='m^2', lo=0.0, lo_open=True, required=True, help='repulsion range of eq. 44'
    )
    # neighbour set of each tracker's potential (not in the paper: the paper's is all-to-all)
    neighbours: str = _p(
        'all',
        choices=NEIGHBOUR_RULES,
        help="which trackers enter a tracker's formation term: all (eq. 2), "
        'nearest (the neighbour_count nearest) or radius (those within '
        'sensing_radius)',
    )
    neighbour_count: int = _p(2, lo=1, help='neighbours = nearest: how many')
    sensing_radius: float = _p(
        5.0, unit='m', lo=0.0, lo_open=True, help='neighbours = radius: the sensing range'
    )
    # sliding-mode controller
    alpha: float = _p(0.01, unit='1/s', lo=0.0, required=True, help='linear gain of eq. 7 / 22')
    beta: float = _p(
        2.0,
        unit='m/s',
        lo=0.0,
        lo_open=True,
        required=True,
        help='switching gain of eq. 7 / 22; the proof needs beta >= v_N',
    )
    gamma: float = _p(
        0.5,
        unit='m',
        lo=0.0,
        lo_open=True,
        required=True,
        help='boundary-layer thickness of eq. 8',
    )
    lambda_filter: float = _p(
        0.1,
        unit='s',
        lo=0.0,
        lo_open=True,
        required=True,
        help='time constant of the low-pass filter of eq. 26',
    )
    u0: float = _p(
        125.0, unit='N', lo=0.0, lo_open=True, required=True, help='switching force gain of eq. 24'
    )
    switching: str = _p(
        'sign',
        choices=SWITCHINGS,
        help='switching force of eq. 24: sign (the paper) or layer, '
        '-u0 sat(s/phi) with a continuous boundary layer (Slotine & Li; '
        'not in the paper, for sampled control)',
    )
    phi: float = _p(
        0.15,
        unit='m/s',
        lo=0.0,
        lo_open=True,
        help='switching = layer: boundary-layer width of the sliding surface',
    )
    feedforward: float = _p(
        0.0,
        lo=0.0,
        hi=1.0,
        help='weight of the target velocity in the sliding surface, '
        's = v - w v_N + ... (0: the paper; 1 removes the lag of a '
        'moving target; not in the paper)',
    )
    precondition: str = _p(
        'none',
        choices=('none', 'newton'),
        help='direction the manifold descends: none, the gradient of J '
        '(the paper); newton, the saddle-free Newton direction '
        '|H|_mu^-1 grad J, which descends every mode of J at one rate '
        '(not in the paper, for large swarms under sampling)',
    )
    newton_mu: float = _p(
        0.1,
        lo=0.0,
        lo_open=True,
        help='precondition = newton: the smallest curvature of |H|_mu '
        '(same unit as the Hessian of J)',
    )
    newton_every: int = _p(
        1,
        lo=1,
        help="precondition = newton: recompute the Hessian's "
        'eigendecomposition every this many control '
        'samples (it costs most)',
    )
    newton_trust: float = _p(
        0.0,
        unit='m',
        lo=0.0,
        help='precondition = newton: trust radius of the Newton step '
        '(RMS per tracker); where the step would be longer the '
        'curvature floor rises above newton_mu (0: the floor is '
        'newton_mu)',
    )
    compensation: str = _p(
        'none',
        choices=COMPENSATIONS,
        help='sampled control (control_rate > 0): none, or predict, the '
        'state predicted forward by the latency (the age it has when '
        "its command reaches the plant), with each tracker's own "
        'held command (not in the paper)',
    )
    epsilon: float = _p(
        1.0, unit='m/s^2', lo=0.0, lo_open=True, help='reaching margin of Theorem 1 / eq. 37'
    )
    mu: float = _p(0.1, unit='m/s^2', lo=0.0, lo_open=True, help='reaching margin of eq. 43')
    # plant, eq. 19-21
    mass: tuple[float, ...] = _p(
        (1.0,),
        unit='kg',
        lo=0.0,
        lo_open=True,
        length=(1, 3),
        required=True,
        help='mass M, scalar or diagonal of M (eq. 19)',
    )
    mass_lo: float = _p(0.5, unit='kg', lo=0.0, lo_open=True, help='lower mass bound of eq. 21')
    mass_hi: float = _p(1.5, unit='kg', lo=0.0, lo_open=True, help='upper mass bound of eq. 21')
    drag: float = _p(0.0, unit='N s/m', lo=0.0, help='known disturbance f_known = drag * v')
    f_bar: float = _p(
        1.0,
        unit='N',
        lo=0.0,
        required=True,
        help='bound of the unknown disturbance |f_unknown| <= f_bar',
    )
    noise: str = _p(
        'uniform_ball',
        choices=NOISE_KINDS,
        help='distribution of f_unknown: uniform in the ball of radius f_bar, or none',
    )
    # target, eq. 1
    target_trajectory: str = _p('circle', choices=TRAJECTORIES, help='shape of the target path')
    target_speed: float = _p(
        1.5, unit='m/s', lo=0.0, help='target speed v (peak for figure_eight)'
    )
    target_yaw_deg: float = _p(0.0, unit='deg', help='initial yaw chi of the target (eq. 1)')
    target_pitch_deg: float = _p(
        0.0,
        unit='deg',
        lo=-90.0,
        hi=90.0,
        help='pitch delta of the target (eq. 1), straight and helix',
    )
    target_radius: float = _p(
        20.0,
        unit='m',
        lo=0.0,
        lo_open=True,
        help='turn radius of circle / helix, half-width of figure_eight',
    )
    target_start: tuple[float, ...] = _p(
        (0.0, 0.0, 5.0), unit='m', length=(3,), help='initial target position'
    )
    target_waypoints: tuple[float, ...] = _p(
        (), unit='m', help='waypoint offsets from target_start, flat x,y,z list'
    )
    v_n: float = _p(
        0.0,
        unit='m/s',
        lo=0.0,
        help='bound v_N on the target speed; 0 means the trajectory peak speed',
    )
    # initial conditions
    init_center: tuple[float, ...] = _p(
        (0.0, 0.0, 0.0),
        unit='m',
        length=(3,),
        help='centre of the random initial tracker positions',
    )
    init_spread: float = _p(
        1.0, unit='m', lo=0.0, help='trackers start uniformly in a ball of this radius'
    )
    # run
    seed: int = _p(0, lo=0, help='seed of initial positions and noise', read_only=True)
    dt: float = _p(
        0.001,
        unit='s',
        lo=0.0,
        lo_open=True,
        hi=1.0,
        required=True,
        help='fixed step of plant and controller',
        read_only=True,
    )
    duration: float = _p(30.0, unit='s', lo=0.0, lo_open=True, help='simulated time')
    control_rate: float = _p(
        0.0,
        unit='Hz',
        lo=0.0,
        hi=1.0e6,
        help='rate of the controller: 0 commands every step of dt '
        '(lockstep); > 0 samples the state and holds each command '
        'for 1/control_rate s (real time; the realtime plant '
        'publishes at this rate); 1/(control_rate dt) must be a '
        'whole number of steps',
    )
    latency: float = _p(
        0.0,
        unit='s',
        lo=0.0,
        hi=10.0,
        help='headless emulation of real time: delay from a state sample to '
        'its command taking effect (control-loop latency)',
    )
    steady_fraction: float = _p(
        0.25,
        lo=0.0,
        lo_open=True,
        hi=1.0,
        help='the last fraction of a run that metrics call steady',
    )
    record_every: int = _p(1, lo=1, help='keep every k-th step in trajectory.npz')
    # per-UAV overrides, from /uav_<i>/... sections: {i: {key: value}}
    uav_overrides: Mapping[int, Mapping[str, Any]] = field(
        default_factory=dict, metadata={'internal': True}
    )

    def __post_init__(self) -> None:
        _validate(self)

    # --- derived quantities ---------------------------------------------------------------
    @property
    def target_trajectory_obj(self) -> Trajectory:
        """The target trajectory built from the ``target_*`` keys."""
        wp = self.target_waypoints
        return make_trajectory(
            self.target_trajectory,
            start=self.target_start,
            speed=self.target_speed,
            yaw=math.radians(self.target_yaw_deg),
            pitch=math.radians(self.target_pitch_deg),
            radius=self.target_radius,
            waypoints=[wp[i : i + 3] for i in range(0, len(wp), 3)],
        )

    @property
    def target_speed_bound(self) -> float:
        """v_N: ``v_n`` if set, else the trajectory's peak speed."""
        return self.v_n if self.v_n > 0 else self.target_trajectory_obj.max_speed

    @property
    def hold_steps(self) -> int:
        """Steps of dt each command is held for: 1 without ``control_rate``."""
        return 1 if self.control_rate <= 0 else int(round(1.0 / (self.control_rate * self.dt)))

    @property
    def control_period(self) -> float:
        """The controller's period T = hold_steps dt [s]."""
        return self.hold_steps * self.dt

    @property
    def steps(self) -> int:
        """Number of fixed steps in ``duration``."""
        return int(round(self.duration / self.dt))

    def mass_matrix_diag(self) -> list[list[float]]:
        """Per-tracker diagonal of M, shape (n, 3), with per-UAV overrides applied."""
        rows = []
        for i in range(1, self.n_trackers + 1):
            m = self.uav_overrides.get(i, {}).get('mass', self.mass)
            m = tuple(m) if isinstance(m, (list, tuple)) else (float(m),)
            rows.append(list(m) * 3 if len(m) == 1 else list(m))
        return rows

    def potential_params(self) -> PotentialParams:
        """Keyword arguments of :func:`apf_swarm_core.gradients.gradient`."""
        return {'k_n': self.k_n, 'k_f': self.k_f, 'a': self.a, 'b': self.b, 'c': self.c}

    def neighbour_rule(self) -> dict[str, Any]:
        """Keyword arguments of :func:`apf_swarm_core.neighbours.neighbour_mask`, or ``{}``
        for the paper's all-to-all potential."""
        if self.neighbours == 'all':
            return {}
        return {
            'rule': self.neighbours,
            'count': self.neighbour_count,
            'radius': self.sensing_radius,
        }

    def replace(self, **changes: Any) -> SwarmConfig:
        """A copy with some keys changed (validated)."""
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict[str, Any]:
        """Plain dict of every key (tuples as lists), for JSON and YAML."""
        out: dict[str, Any] = {}
        for f in fields(self):
            val = getattr(self, f.name)
            if f.name == 'uav_overrides':
                out[f.name] = {int(k): dict(v) for k, v in val.items()}
            else:
                out[f.name] = list(val) if isinstance(val, tuple) else val
        return out


def _describe(meta: Mapping[str, Any]) -> str:
    parts = []
    if meta.get('choices'):
        parts.append('one of ' + ', '.join(meta['choices']))
    lo, hi = meta.get('lo'), meta.get('hi')
    if lo is not None and hi is not None:
        parts.append(f'{">" if meta.get("lo_open") else ">="} {lo:g} and <= {hi:g}')
    elif lo is not None:
        parts.append(f'{">" if meta.get("lo_open") else ">="} {lo:g}')
    elif hi is not None:
        parts.append(f'<= {hi:g}')
    return ' '.join(parts) if parts else 'any value'


def _check_number(name: str, value: float, meta: Mapping[str, Any]) -> None:
    if not math.isfinite(value):
        raise ConfigError(f'{name} = {value!r}: must be a finite number ({_describe(meta)})')
    lo, hi = meta.get('lo'), meta.get('hi')
    if lo is not None and (value < lo or (meta.get('lo_open') and value == lo)):
        raise ConfigError(
            f'{name} = {value!r}: must be {_describe(meta)}'
            + (f' [{meta["unit"]}]' if meta.get('unit') else '')
        )
    if hi is not None and value > hi:
        raise ConfigError(f'{name} = {value!r}: must be {_describe(meta)}')


def _coerce(name: str, value: Any, ftype: Any, meta: Mapping[str, Any]) -> Any:
    """Return ``value`` converted to the field's type, or raise ConfigError naming the key."""
    tname = ftype if isinstance(ftype, str) else getattr(ftype, '__name__', str(ftype))
    if tname == 'int':
        if isinstance(value, bool) or not isinstance(value, int):
            if isinstance(value, float) and value.is_integer():
                value = int(value)
            else:
                raise ConfigError(f'{name} = {value!r}: expected an integer ({_describe(meta)})')
        _check_number(name, value, meta)
        return value
    if tname == 'float':
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f'{name} = {value!r}: expected a number ({_describe(meta)})')
        value = float(value)
        _check_number(name, value, meta)
        return value
    if tname == 'str':
        if not isinstance(value, str):
            raise ConfigError(f'{name} = {value!r}: expected a string ({_describe(meta)})')
        if meta.get('choices') and value not in meta['choices']:
            raise ConfigError(f'{name} = {value!r}: must be {_describe(meta)}')
        return value
    if tname.startswith('tuple'):
        seq = [value] if isinstance(value, (int, float)) and not isinstance(value, bool) else value
        if not isinstance(seq, (list, tuple)) or any(
            isinstance(v, bool) or not isinstance(v, (int, float)) for v in seq
        ):
            raise ConfigError(f'{name} = {value!r}: expected a list of numbers')
        seq = tuple(float(v) for v in seq)
        length = meta.get('length')
        if length and len(seq) not in length:
            raise ConfigError(
                f'{name} = {value!r}: expected a list of '
                f'{" or ".join(map(str, length))} numbers, got {len(seq)}'
            )
        for v in seq:
            _check_number(name, v, meta)
        return seq
    return value


def _validate(cfg: SwarmConfig) -> None:
    for f in fields(cfg):
        if f.metadata.get('internal'):
            continue
        value = _coerce(f.name, getattr(cfg, f.name), f.type, f.metadata)
        object.__setattr__(cfg, f.name, value)
    if cfg.control_rate > 0:
        hold = 1.0 / (cfg.control_rate * cfg.dt)
        if round(hold) < 1 or abs(hold - round(hold)) > 1e-6 * hold:
            raise ConfigError(
                f'control_rate = {cfg.control_rate:g} Hz with dt = {cfg.dt:g} s holds each '
                f'command for {hold:.4g} steps: 1/(control_rate dt) must be a whole number '
                f'>= 1 (e.g. control_rate = {1.0 / (max(1, round(hold)) * cfg.dt):g})'
            )
    if cfg.precondition == 'newton' and cfg.neighbours != 'all':
        raise ConfigError(
            f'precondition = newton needs neighbours = all (the Newton '
            f"direction mixes every tracker's gradient); got neighbours = "
            f'{cfg.neighbours}'
        )
    if cfg.mass_lo > cfg.mass_hi:
        raise ConfigError(
            f'mass_lo = {cfg.mass_lo} > mass_hi = {cfg.mass_hi}: '
            'the bounds of eq. 21 must satisfy mass_lo <= mass_hi'
        )
    if len(cfg.target_waypoints) % 3:
        raise ConfigError(
            f'target_waypoints has {len(cfg.target_waypoints)} numbers: '
            'expected a flat list x1, y1, z1, x2, ... (a multiple of 3)'
        )
    if cfg.target_speed == 0.0 and cfg.target_trajectory in (
        'waypoints',
        'circle',
        'helix',
        'figure_eight',
    ):
        raise ConfigError(
            f'target_speed = 0 with target_trajectory = {cfg.target_trajectory}: '
            'a moving trajectory needs target_speed > 0 (use hover for a '
            'stationary target)'
        )
    if cfg.target_trajectory == 'waypoints' and not cfg.target_waypoints:
        raise ConfigError(
            'target_trajectory = waypoints needs target_waypoints (a flat list of x, y, z offsets)'
        )
    normalized: dict[int, dict[str, Any]] = {}
    for i, over in cfg.uav_overrides.items():
        if not 1 <= int(i) <= cfg.n_trackers:
            raise ConfigError(
                f'override section for uav_{i}: there are only '
                f'{cfg.n_trackers} trackers (uav_1 .. uav_{cfg.n_trackers})'
            )
        for key, val in over.items():
            if key not in PER_UAV_KEYS:
                raise ConfigError(
                    f'uav_{i} overrides {key!r}: only {", ".join(PER_UAV_KEYS)} can differ per UAV'
                )
            meta = (
                {'length': (3,), 'lo': None}
                if key == 'initial_position'
                else _FIELDS['mass'].metadata
            )
            normalized.setdefault(int(i), {})[key] = _coerce(f'uav_{i}.{key}', val, 'tuple', meta)
    object.__setattr__(cfg, 'uav_overrides', normalized)
    for m_row in cfg.mass_matrix_diag():
        for m in m_row:
            if not cfg.mass_lo <= m <= cfg.mass_hi:
                raise ConfigError(
                    f'mass {m:g} is outside [mass_lo, mass_hi] = '
                    f'[{cfg.mass_lo:g}, {cfg.mass_hi:g}] (eq. 21)'
                )


_FIELDS = {f.name: f for f in fields(SwarmConfig)}
REQUIRED_KEYS = tuple(name for name, f in _FIELDS.items() if f.metadata.get('required'))
KEYS = tuple(name for name, f in _FIELDS.items() if not f.metadata.get('internal'))


def _unknown(key: str, where: str) -> ConfigError:
    close = difflib.get_close_matches(key, KEYS, n=3)
    hint = f' (did you mean {", ".join(close)}?)' if close else ''
    return ConfigError(f'unknown key {key!r} in {where}{hint}; known keys: {", ".join(KEYS)}')


# keys the ROS nodes declare that are not part of the swarm configuration
_NODE_KEYS = ('uav_id', 'mode', 'use_sim_time')


def config_from_mapping(
    params: Mapping[str, Any],
    *,
    source: str = 'configuration',
    overrides: Mapping[int, Mapping[str, Any]] | None = None,
    require_all: bool = True,
) -> SwarmConfig:
    """Build a validated :class:`SwarmConfig` from a flat ``{key: value}`` mapping.

    Raises
    ------
    ConfigError
        For an unknown key, a missing required key (``require_all``), a wrong type or an
        out-of-range value; the message names the key, the value and what is allowed.
    """
    kwargs: dict[str, Any] = {}
    for key, val in params.items():
        if key in _NODE_KEYS or key.startswith('node.'):
            continue
        if key not in _FIELDS or _FIELDS[key].metadata.get('internal'):
            raise _unknown(key, source)
        kwargs[key] = val
    if require_all:
        missing = [k for k in REQUIRED_KEYS if k not in kwargs]
        if missing:
            raise ConfigError(f'{source} is missing required keys: {", ".join(missing)}')
    if (
        'mass' in kwargs
        and isinstance(kwargs['mass'], (int, float))
        and not isinstance(kwargs['mass'], bool)
    ):
        kwargs['mass'] = (kwargs['mass'],)
    return SwarmConfig(**kwargs, uav_overrides=dict(overrides or {}))


# the file side of a configuration, one import away for every user of this module
from .config_files import (  # noqa: E402 (needs SwarmConfig above)
    apply_overrides,
    load_config,
    load_preset,
    parse_set,
    preset_dirs,
    preset_names,
    preset_path,
    resolve,
    to_ros_params,
)
