"""ROS 2 parameters of the nodes: every ``SwarmConfig`` key with its unit, range and help in
the descriptor (:func:`declare_config`, :func:`read_config`; :func:`install_validator` rejects a
bad run-time value with the core's reason), and the node-only parameters (:class:`NodeParam`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

from apf_swarm_core.command_hold import STALE_AFTER
from apf_swarm_core.config import SwarmConfig
from apf_swarm_core.config_files import config_from_mapping
from apf_swarm_core.errors import ConfigError
from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    ParameterType,
    SetParametersResult,
)
from rclpy.exceptions import ParameterUninitializedException
from rclpy.node import Node
from rclpy.parameter import Parameter

from .node_common import DEFAULT_EXECUTOR, EXECUTORS, INPUTS

__all__ = [
    'EXECUTOR_PARAM',
    'MODES',
    'OUTPUTS',
    'PLANT_PARAMS',
    'SWARM_NODE_PARAMS',
    'TRACKER_PARAMS',
    'WATCHDOG_RATE',
    'NodeParam',
    'declare_config',
    'declare_node_params',
    'declare_str_array',
    'declare_swarm_node',
    'install_validator',
    'parse_outputs',
    'read_config',
]

MODES = ('lockstep', 'realtime')
_FIELDS = {f.name: f for f in dataclasses.fields(SwarmConfig) if not f.metadata.get('internal')}
_DEFAULTS = SwarmConfig()


def _descriptor(
    name: str, ptype: int, meta: Mapping[str, Any], read_only: bool, dynamic: bool = False
) -> ParameterDescriptor:
    text = meta.get('help', '')
    if meta.get('unit'):
        text += f' [{meta["unit"]}]'
    if meta.get('choices'):
        text += ' (one of: ' + ', '.join(meta['choices']) + ')'
    d = ParameterDescriptor(
        name=name, type=ptype, description=text, read_only=read_only, dynamic_typing=dynamic
    )
    lo, hi = meta.get('lo'), meta.get('hi')
    if lo is None and hi is None:
        return d
    if ptype == ParameterType.PARAMETER_DOUBLE:
        lo, hi = (-1e300 if lo is None else lo), (1e300 if hi is None else hi)
        d.floating_point_range = [
            FloatingPointRange(from_value=float(lo), to_value=float(hi), step=0.0)
        ]
    elif ptype == ParameterType.PARAMETER_INTEGER:
        lo, hi = (-(2**62) if lo is None else lo), (2**62 if hi is None else hi)
        d.integer_range = [IntegerRange(from_value=int(lo), to_value=int(hi), step=0)]
    return d


_PARAMETER_TYPES = {
    bool: ParameterType.PARAMETER_BOOL,
    int: ParameterType.PARAMETER_INTEGER,
    float: ParameterType.PARAMETER_DOUBLE,
    str: ParameterType.PARAMETER_STRING,
}


def declare_config(node: Node, *, writable: tuple[str, ...] = ()) -> None:
    """Declare every SwarmConfig key as a parameter with the preset-independent default.

    Keys in ``writable`` may be set while the node runs (the node applies them, see
    :func:`install_validator`); every other key is read-only. Sequence keys (``mass``,
    ``target_start``, ...) accept a number or a list (dynamic typing); the core validates
    the length.
    """
    batch: list[tuple[str] | tuple[str, Parameter.Type] | tuple[str, Any, Any]] = []
    for name, f in _FIELDS.items():
        default = getattr(_DEFAULTS, name)
        ro = name not in writable or bool(f.metadata.get('read_only'))
        if isinstance(default, tuple):
            array = ParameterType.PARAMETER_DOUBLE_ARRAY
            if default:
                desc = _descriptor(name, array, f.metadata, ro, True)
                batch.append((name, [float(v) for v in default], desc))
            else:
                desc = _descriptor(name, array, f.metadata, ro)
                batch.append((name, Parameter.Type.DOUBLE_ARRAY, desc))
        else:
            ptype = _PARAMETER_TYPES[type(default)]
            batch.append((name, default, _descriptor(name, ptype, f.metadata, ro)))
    # one call: one /parameter_events message for all of them, not one per parameter
    node.declare_parameters('', batch)


@dataclass(frozen=True)
class NodeParam:
    """A node-only parameter (not part of the swarm configuration)."""

    name: str
    default: Any
    help: str
    lo: float | None = None
    hi: float | None = None
    read_only: bool = True
    choices: tuple[str, ...] | None = None


#: the executor the node spins with (see :func:`apf_swarm_nodes.node_common.spin`)
EXECUTOR_PARAM = NodeParam(
    'executor',
    DEFAULT_EXECUTOR,
    'executor: events (rclpy.experimental, driven by spin_once), single or multi',
    choices=EXECUTORS,
)
#: what every node of the swarm (plant, target, tracker) declares before its own parameters
SWARM_NODE_PARAMS = (
    EXECUTOR_PARAM,
    NodeParam(
        'qos_depth',
        1,
        'realtime: keep-last depth of the best-effort control topics (odometry, /swarm/odom, '
        'force commands; 1: the newest sample only); lockstep always uses reliable, keep '
        'last 1000',
        lo=1,
        hi=1000,
    ),
    NodeParam('mode', 'lockstep', 'timing mode', choices=MODES),
    NodeParam(
        'run',
        0,
        "the run's identity (the bring-up sets a random one for every node): the plant "
        'refuses commands, a tracker /swarm/odom messages, of another run (0: no identity, '
        'accept any)',
        lo=0,
        hi=2**63 - 1,
    ),
    NodeParam(
        'recorded',
        False,
        'lockstep: a recorder reads every topic of this node (the bring-up sets it with '
        '--record): each publisher holds its first message until it has matched the '
        'recorder too, or the bag would miss the first steps',
    ),
)


#: what a tracker can publish (the ``outputs`` parameter)
OUTPUTS = ('force', 'accel', 'velocity')
#: realtime with ``trigger:=odom``: the stale-input watchdog's rate [Hz] (at most the control
#: rate): staleness is judged against input_timeout (0.5 s), and the brakes it sends while
#: inputs are stale must come faster than the plant's stale_after (0.1 s)
WATCHDOG_RATE = 20.0
#: the tracker node's own parameters
TRACKER_PARAMS = (
    NodeParam(
        'inputs',
        'aggregate',
        'aggregate: one /swarm/odom message per step; odom: '
        'the n odometry topics and /target/odom',
        choices=INPUTS,
    ),
    NodeParam('uav_id', 1, 'id i of this tracker (namespace /uav_<i>)', lo=1, hi=10000),
    NodeParam(
        'batch_commands',
        False,
        'realtime, several trackers to a process reading /swarm/odom: the commands the '
        'process answers a state with go out as one /swarm/force_cmds message (one per '
        'process instead of one per tracker: the TLS transport costs per message)',
    ),
    NodeParam(
        'trigger',
        'odom',
        'realtime: odom computes on every new own odometry (lowest '
        'latency); timer computes at control_rate on the latest inputs',
        choices=('odom', 'timer'),
    ),
    NodeParam(
        'outputs',
        'force',
        'what the tracker publishes, comma-separated: force (force_cmd, '
        'apf_swarm_msgs/ForceCommand, always: the plant and the bring-up read it), accel '
        '(accel_cmd, geometry_msgs/AccelStamped), velocity (velocity_cmd, '
        'geometry_msgs/TwistStamped): setpoints in the world frame for a flight-stack bridge',
    ),
    NodeParam(
        'input_timeout',
        0.5,
        'an input older than this is stale and the safe brake '
        "is sent [s; lockstep: of simulated time, which only the target's state can "
        'exceed when the target is silent]',
        lo=0.001,
        hi=60.0,
    ),
)

#: the plant node's own parameters
PLANT_PARAMS = (
    NodeParam('wait_for_start', False, 'wait for /swarm/start before step 0'),
    NodeParam(
        'inputs',
        'aggregate',
        'what the trackers read (as their inputs parameter): '
        'lockstep step 0 waits until those subscriptions are matched',
        choices=INPUTS,
    ),
    NodeParam(
        'command_timeout',
        1.0,
        'lockstep: a command later than this is sent for '
        'again, then missed; realtime: a tracker silent for this long is inactive, and '
        'a command or target state stamped longer ago is refused [s of wall time]',
        lo=0.001,
        hi=600.0,
    ),
    NodeParam(
        'stale_after',
        STALE_AFTER,
        'realtime: a tracker whose latest command arrived longer '
        'ago than this gets zero force instead of its held bang-bang command (25 N held '
        'for 1 s would fling a 1 kg UAV 12 m) [s of wall time]',
        lo=0.001,
        hi=60.0,
    ),
    NodeParam('physics_rate', 200.0, 'realtime: physics timer rate [Hz]', lo=1.0, hi=5000.0),
    NodeParam(
        'arm_timeout',
        10.0,
        'realtime: after the start the clock waits until every '
        'tracker has commanded from its inputs (odometry goes out, the UAVs hold '
        'still), at most this long; then it starts without the silent ones (warned) '
        '[s of wall time]',
        lo=0.0,
        hi=600.0,
    ),
    NodeParam(
        'markers_rate',
        10.0,
        '/swarm/markers (visualization_msgs/MarkerArray) per second '
        'of simulated (lockstep) or wall (realtime) time; 0 turns them off',
        lo=0.0,
        hi=1000.0,
    ),
    NodeParam(
        'publish_rate',
        0.0,
        'realtime: odometry and state rate [Hz]; 0: the '
        "configuration's control_rate, or 100 Hz when that is 0",
        lo=0.0,
        hi=2000.0,
    ),
)


def parse_outputs(text: str) -> set[str]:
    """The ``outputs`` parameter as a set, ``force`` always in it (ConfigError naming what
    is wrong)."""
    got = {part.strip() for part in str(text).split(',') if part.strip()}
    if got - set(OUTPUTS):
        raise ConfigError(
            f'outputs = {text!r}: expected a comma-separated subset of {", ".join(OUTPUTS)}'
        )
    return got | {'force'}


def declare_node_params(node: Node, params: tuple[NodeParam, ...]) -> dict[str, Any]:
    """Declare node-only parameters and return their values, validated (ConfigError if bad)."""
    node.declare_parameters(
        '',
        [
            (
                p.name,
                p.default,
                _descriptor(
                    p.name,
                    _PARAMETER_TYPES[type(p.default)],
                    {'help': p.help, 'lo': p.lo, 'hi': p.hi, 'choices': p.choices},
                    p.read_only,
                ),
            )
            for p in params
        ],
    )
    out = {}
    for p in params:
        val = node.get_parameter(p.name).value
        if p.choices and val not in p.choices:
            raise ConfigError(f'{p.name} = {val!r}: must be one of {", ".join(p.choices)}')
        numeric = isinstance(val, (int, float)) and not isinstance(val, bool)
        if numeric and ((p.lo is not None and val < p.lo) or (p.hi is not None and val > p.hi)):
            raise ConfigError(f'{p.name} = {val!r}: must be within [{p.lo}, {p.hi}]')
        out[p.name] = val
    return out


def declare_swarm_node(
    node: Node, params: tuple[NodeParam, ...], *, writable: tuple[str, ...] = ()
) -> tuple[SwarmConfig, dict[str, Any]]:
    """The parameters of a swarm node: every configuration key (:func:`declare_config`,
    ``writable`` as there), :data:`SWARM_NODE_PARAMS` and its own ``params``; returns the
    validated configuration and the node parameters' values (ConfigError if bad)."""
    declare_config(node, writable=writable)
    values = declare_node_params(node, SWARM_NODE_PARAMS + params)
    return read_config(node), values


def declare_str_array(node: Node, name: str, text: str) -> list[str]:
    """Declare a read-only string-list parameter (default: empty) described by ``text``;
    returns its non-empty values."""
    desc = ParameterDescriptor(
        name=name, type=ParameterType.PARAMETER_STRING_ARRAY, description=text, read_only=True
    )
    node.declare_parameter(name, [''], desc)
    return [t for t in node.get_parameter(name).value if t]


def _values(node: Node, changed: Mapping[str, Any] | None = None) -> dict[str, Any]:
    vals = {}
    for name in _FIELDS:
        try:
            p = node.get_parameter(name)
        except ParameterUninitializedException:
            continue  # a typed parameter without default that nobody set
        if p.type_ == Parameter.Type.NOT_SET:
            continue
        vals[name] = p.value
    vals.update(changed or {})
    return {
        k: (tuple(v) if isinstance(v, (list, tuple)) or hasattr(v, 'tolist') else v)
        for k, v in vals.items()
    }


def read_config(node: Node) -> SwarmConfig:
    """The validated configuration from the node's parameters (raises ConfigError)."""
    return config_from_mapping(
        _values(node), source=f'parameters of {node.get_fully_qualified_name()}', require_all=False
    )


def install_validator(node: Node, apply: Callable[[SwarmConfig], None]) -> None:
    """Reject a run-time parameter change that the core would reject, with its reason, and
    hand every accepted change to ``apply`` as the new validated configuration.

    Read-only keys never get here: rclpy refuses them itself ("parameter ... cannot be set
    because it is read-only").
    """

    def check(params: list[Parameter]) -> SetParametersResult:
        changed = {p.name: p.value for p in params if p.name in _FIELDS}
        if not changed:
            return SetParametersResult(successful=True)
        try:
            config_from_mapping(
                _values(node, changed), require_all=False, source='parameter update'
            )
        except ConfigError as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        return SetParametersResult(successful=True)

    def applied(params: list[Parameter]) -> None:
        if any(p.name in _FIELDS for p in params):
            apply(read_config(node))

    node.add_on_set_parameters_callback(check)
    node.add_post_set_parameters_callback(applied)
