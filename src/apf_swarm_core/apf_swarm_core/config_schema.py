"""The schema of the keys of :class:`~apf_swarm_core.config.SwarmConfig`: how a key is
declared (:func:`key`, the metadata validation and the nodes' parameter descriptors read) and
how a configuration is held to it (:func:`validate`)."""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import field, fields
from typing import TYPE_CHECKING, Any

from .errors import ConfigError

if TYPE_CHECKING:
    from .config import SwarmConfig

__all__ = ['NON_NEGATIVE', 'PER_UAV_KEYS', 'POSITIVE', 'key', 'validate']

#: keys a ``/uav_<i>/...`` section may override for one tracker
PER_UAV_KEYS = ('mass', 'initial_position')

#: the intervals of a number > 0 and >= 0, for :func:`key`
POSITIVE, NON_NEGATIVE = '(0, inf)', '[0, inf)'

_INTERVAL = re.compile(r'([\[(])\s*(\S+)\s*,\s*(\S+)\s*([\])])')


def _interval(bounds: str) -> tuple[float | None, bool, float | None]:
    """``(lo, lo_open, hi)`` of an interval written ``'(0, inf)'``, ``'[0, 1]'``, ...: the
    lower end open with ``(``, closed with ``[``; the upper end closed, or ``inf)``."""
    if not bounds:
        return None, False, None
    m = _INTERVAL.fullmatch(bounds)
    if m is None or (m[3] == 'inf') != (m[4] == ')'):
        raise ValueError(f'bounds {bounds!r}: expected an interval such as (0, inf) or [0, 1]')
    lo, hi = float(m[2]), float(m[3])
    bounded = lo > -math.inf
    return (lo if bounded else None), bounded and m[1] == '(', (hi if hi < math.inf else None)


def key(
    default: Any,
    help: str,
    unit: str = '',
    bounds: str = '',
    *,
    choices: tuple[str, ...] | None = None,
    length: tuple[int, ...] | None = None,
    required: bool = False,
    read_only: bool = False,
) -> Any:
    """A configuration key: a dataclass field with its ``default`` (a list becomes a tuple),
    what it means (``help``), its SI ``unit``, the range of a number or of each number of a
    list (``bounds``, an interval such as ``'(0, inf)'`` or ``'[0, 1]'``, '' for any), the
    allowed strings (``choices``) and list lengths (``length``); ``required``: a file must
    set it, ``read_only``: a running node cannot change it."""
    lo, lo_open, hi = _interval(bounds)
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


def _describe(meta: Mapping[str, Any]) -> str:
    parts = ['one of ' + ', '.join(meta['choices'])] if meta.get('choices') else []
    lo, hi = meta.get('lo'), meta.get('hi')
    if lo is not None:
        upper = f' and <= {hi:g}' if hi is not None else ''
        parts.append(f'{">" if meta.get("lo_open") else ">="} {lo:g}{upper}')
    elif hi is not None:
        parts.append(f'<= {hi:g}')
    return ' '.join(parts) or 'any value'


def _check_number(name: str, value: float, meta: Mapping[str, Any]) -> None:
    if not math.isfinite(value):
        raise ConfigError(f'{name} = {value!r}: must be a finite number ({_describe(meta)})')
    lo, hi = meta.get('lo'), meta.get('hi')
    below = lo is not None and (value < lo or (meta.get('lo_open') and value == lo))
    if below or (hi is not None and value > hi):
        unit = f' [{meta["unit"]}]' if below and meta.get('unit') else ''
        raise ConfigError(f'{name} = {value!r}: must be {_describe(meta)}{unit}')


def _coerce(name: str, value: Any, ftype: Any, meta: Mapping[str, Any]) -> Any:
    """Return ``value`` converted to the field's type, or raise ConfigError naming the key."""
    tname = ftype if isinstance(ftype, str) else getattr(ftype, '__name__', str(ftype))
    if tname in ('int', 'float'):
        whole = tname == 'int'
        if (
            isinstance(value, bool)
            or not isinstance(value, (int, float))
            or (whole and isinstance(value, float) and not value.is_integer())
        ):
            what = 'an integer' if whole else 'a number'
            raise ConfigError(f'{name} = {value!r}: expected {what} ({_describe(meta)})')
        value = int(value) if whole else float(value)
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


def validate(cfg: SwarmConfig) -> None:
    """Convert every key of ``cfg`` to its type in place and check it against its metadata
    and the rules between keys; raise :class:`ConfigError` naming the key and what is
    allowed."""
    declared = {f.name: f for f in fields(cfg)}
    for f in declared.values():
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
    if cfg.target_speed == 0.0 and cfg.target_trajectory not in ('straight', 'hover'):
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
        for name, val in over.items():
            if name not in PER_UAV_KEYS:
                raise ConfigError(
                    f'uav_{i} overrides {name!r}: only {", ".join(PER_UAV_KEYS)} can differ '
                    'per UAV'
                )
            meta = declared['mass'].metadata if name == 'mass' else {'length': (3,)}
            value = _coerce(f'uav_{i}.{name}', val, 'tuple', meta)
            normalized.setdefault(int(i), {})[name] = value
    object.__setattr__(cfg, 'uav_overrides', normalized)
    for m_row in cfg.mass_matrix_diag():
        for m in m_row:
            if not cfg.mass_lo <= m <= cfg.mass_hi:
                raise ConfigError(
                    f'mass {m:g} is outside [mass_lo, mass_hi] = '
                    f'[{cfg.mass_lo:g}, {cfg.mass_hi:g}] (eq. 21)'
                )
