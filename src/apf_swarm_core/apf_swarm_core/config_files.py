"""Configurations from outside: flat mappings of keys (a node's parameters,
:func:`config_from_mapping`), ROS 2 parameter files (with per-UAV sections), the named
presets of ``config/``, ``--set KEY=VALUE`` overrides, and the parameter file a run writes
for its nodes (:func:`to_ros_params`)."""

from __future__ import annotations

import difflib
import os
import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import yaml

from .config import KEYS, REQUIRED_KEYS, SwarmConfig
from .errors import ConfigError, UnknownPresetError
from .names import tracker_node_name

__all__ = [
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

_UAV_SECTION = re.compile(r'^/?uav_(\d+)(/.*)?$')
#: a number in exponent notation without a dot, which YAML 1.1 leaves a string
_EXPONENT = re.compile(r'[-+]?\d+[eE][-+]?\d+')


#: keys the ROS nodes declare that are not part of the swarm configuration
_NODE_KEYS = ('uav_id', 'mode', 'use_sim_time')


def _unknown(name: str, where: str) -> ConfigError:
    close = difflib.get_close_matches(name, KEYS, n=3)
    hint = f' (did you mean {", ".join(close)}?)' if close else ''
    return ConfigError(f'unknown key {name!r} in {where}{hint}; known keys: {", ".join(KEYS)}')


def config_from_mapping(
    params: Mapping[str, Any],
    *,
    source: str = 'configuration',
    overrides: Mapping[int, Mapping[str, Any]] | None = None,
    require_all: bool = True,
) -> SwarmConfig:
    """A validated :class:`SwarmConfig` from a flat ``{key: value}`` mapping; a
    :class:`ConfigError` names an unknown key, a missing required one (``require_all``), or a
    wrong type or value and what is allowed."""
    kwargs: dict[str, Any] = {}
    for name, val in params.items():
        if name in _NODE_KEYS or name.startswith('node.'):
            continue
        if name not in KEYS:
            raise _unknown(name, source)
        kwargs[name] = val
    if require_all:
        missing = [k for k in REQUIRED_KEYS if k not in kwargs]
        if missing:
            raise ConfigError(f'{source} is missing required keys: {", ".join(missing)}')
    return SwarmConfig(**kwargs, uav_overrides=dict(overrides or {}))


def load_config(path: str | os.PathLike[str]) -> SwarmConfig:
    """Load a ROS 2 parameter file (``/**: ros__parameters:`` plus ``/uav_<i>/...`` sections)."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(
            f'configuration file {path} does not exist; pass an existing YAML file '
            f'or a preset name ({", ".join(preset_names())})'
        )
    try:
        doc = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        mark = getattr(exc, 'problem_mark', None)
        where = f' at line {mark.line + 1}, column {mark.column + 1}' if mark else ''
        problem = getattr(exc, 'problem', None) or str(exc).splitlines()[0]
        raise ConfigError(f'{path} is not valid YAML{where}: {problem}') from None
    if not isinstance(doc, dict):
        raise ConfigError(
            f"{path}: expected a ROS 2 parameter file with a '/**: ros__parameters:' "
            'section at the top level'
        )
    base: dict[str, Any] = {}
    overrides: dict[int, dict[str, Any]] = {}
    for section, body in doc.items():
        params = body.get('ros__parameters') if isinstance(body, dict) else None
        if not isinstance(params, dict):
            raise ConfigError(
                f"{path}: section {section!r} must contain a 'ros__parameters:' mapping"
            )
        # sections of other nodes (/plant, /target, ...) carry node-only settings: skipped
        m = _UAV_SECTION.match(str(section))
        if str(section) in ('/**', '**'):
            base.update(params)
        elif m:
            overrides.setdefault(int(m.group(1)), {}).update(
                {k: v for k, v in params.items() if k not in _NODE_KEYS}
            )
    if not base:
        raise ConfigError(f"{path}: no '/**: ros__parameters:' section with the swarm keys")
    return config_from_mapping(base, source=str(path), overrides=overrides)


def preset_dirs() -> list[Path]:
    """Directories searched for presets, first match wins: ``$APF_SWARM_CONFIG_PATH``
    (os.pathsep-separated), the source tree's ``config/``, the installed
    ``share/apf_swarm_core/config``."""
    env = os.environ.get('APF_SWARM_CONFIG_PATH', '')
    dirs = [Path(p) for p in env.split(os.pathsep) if p]
    source = (p / 'config' for p in Path(__file__).resolve().parents)
    share = (p / 'share' / 'apf_swarm_core' / 'config' for p in Path(__file__).absolute().parents)
    dirs += [d for d in source if (d / 'triangle.yaml').is_file()][:1]
    return dirs + [d for d in share if d.is_dir()][:1]


def preset_names() -> list[str]:
    """Names of the presets found in :func:`preset_dirs`."""
    names: set[str] = set()
    for d in preset_dirs():
        names.update(p.stem for p in d.glob('*.yaml'))
    return sorted(names)


def preset_path(name: str) -> Path:
    """Path of preset ``name``; :class:`UnknownPresetError` lists the available ones."""
    for d in preset_dirs():
        p = d / f'{name}.yaml'
        if p.is_file():
            return p
    raise UnknownPresetError(
        f'unknown preset {name!r}; available presets: '
        f'{", ".join(preset_names()) or "(none found)"}; or pass --config FILE'
    )


def load_preset(name: str) -> SwarmConfig:
    """Load a named preset (``config/<name>.yaml``)."""
    return load_config(preset_path(name))


def parse_set(items: list[str] | tuple[str, ...]) -> dict[str, Any]:
    """Parse ``KEY=VALUE`` strings (VALUE in YAML syntax: ``3``, ``0.5``, ``[1, 2, 3]``)."""
    out: dict[str, Any] = {}
    for item in items:
        key, sep, raw = item.partition('=')
        key = key.strip()
        if not sep or not key:
            raise ConfigError(f'--set {item!r}: expected KEY=VALUE, e.g. --set gamma=0.5')
        if key not in KEYS:
            raise _unknown(key, '--set')
        try:
            value = yaml.safe_load(raw)
        except yaml.YAMLError:
            raise ConfigError(f'--set {item!r}: the value is not valid YAML') from None
        # YAML 1.1 reads 1e-5 (no dot) as a string; on a command line it is a number
        if isinstance(value, str) and _EXPONENT.fullmatch(value.strip()):
            value = float(value)
        out[key] = value
    return out


def apply_overrides(cfg: SwarmConfig, values: Mapping[str, Any]) -> SwarmConfig:
    """A copy of ``cfg`` with ``values`` applied and validated."""
    merged = {k: v for k, v in cfg.to_dict().items() if k != 'uav_overrides'}
    for key in values:
        if key not in KEYS:
            raise _unknown(key, 'overrides')
    merged.update(values)
    return config_from_mapping(merged, overrides=cfg.uav_overrides, source='overrides')


def to_ros_params(cfg: SwarmConfig) -> dict[str, Any]:
    """The configuration as a ROS 2 parameter file document (for the resolved config of a run)."""
    d = cfg.to_dict()
    over = d.pop('uav_overrides')
    doc: dict[str, Any] = {'/**': {'ros__parameters': d}}
    for i, vals in sorted(over.items()):
        doc[tracker_node_name(i)] = {
            'ros__parameters': {k: list(v) if isinstance(v, tuple) else v for k, v in vals.items()}
        }
    return doc


def resolve(
    config: str | os.PathLike[str] | None,
    preset: str | None,
    sets: Sequence[str] | None = (),
    **overrides: Any,
) -> SwarmConfig:
    """The configuration of a command: a parameter file (``config``) or a named preset, then
    the ``KEY=VALUE`` overrides of ``sets`` (``--set``), then the keyword ``overrides``
    that are not None (a command's own options, e.g. ``n_trackers``). The one loader of
    ``apf-swarm`` and the bring-up."""
    cfg = load_config(config) if config is not None else load_preset(preset or '')
    values = parse_set(list(sets or []))
    values.update({k: v for k, v in overrides.items() if v is not None})
    return apply_overrides(cfg, values) if values else cfg
