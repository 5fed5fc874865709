"""The configuration of a run: :class:`SwarmConfig`, every key declared once with
:func:`~apf_swarm_core.config_schema.key` (default, meaning, unit, range) and validated on
construction, and what follows from the keys. A configuration file is a ROS 2 parameter file
(docs/USAGE.md, "Configuration"), read by :mod:`apf_swarm_core.config_files`."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from typing import Any

from .compensation import COMPENSATIONS
from .config_schema import NON_NEGATIVE, POSITIVE, key, validate
from .laws import LAWS, SATURATIONS, SWITCHINGS
from .neighbours import NEIGHBOUR_RULES
from .plant import NOISE_KINDS
from .potential import PotentialParams
from .target import TRAJECTORIES, Trajectory, make_trajectory

__all__ = ['DEFAULT_LATENCY', 'KEYS', 'REALTIME_RATE', 'REQUIRED_KEYS', 'SwarmConfig']

#: realtime rate of the plant's publications and the trackers' control [Hz] when
#: ``control_rate`` is 0
REALTIME_RATE = 100.0
#: control-loop latency [s] that ``apf-swarm check --mode realtime`` and ``design`` assume
#: when neither the configuration, ``--latency`` nor this machine's probe (``apf-swarm
#: probe``) gives one
DEFAULT_LATENCY = 0.005


@dataclass(frozen=True)
class SwarmConfig:
    """All parameters of a run. Units are SI; angles in degrees where the name says ``_deg``."""

    # swarm and laws
    n_trackers: int = key(3, 'number of tracking UAVs n = N - 1', '', '[1, 10000]', read_only=True)
    law: str = key(
        'proposed',
        'proposed (saturated, eq. 22-31) or traditional (sign law of Yao et al.)',
        choices=LAWS,
        required=True,
    )
    saturation: str = key(
        'paper', 'paper: eq. 8 as printed; continuous: g / max(|g|, gamma)', choices=SATURATIONS
    )
    # potential, eq. 2 / 44
    k_n: float = key(1.0, 'weight of the tracking term', '', POSITIVE, required=True)
    k_f: float = key(1.0, 'weight of the formation term', '', POSITIVE, required=True)
    a: float = key(1.0, 'attraction gain of eq. 44', '', POSITIVE, required=True)
    b: float = key(6.0, 'repulsion gain of eq. 44', '', NON_NEGATIVE, required=True)
    b_growth: float = key(
        0.0,
        'eq. 44 uses b (n/3)^b_growth for n > 3 trackers (0: b for every size, the paper; '
        'docs/THEORY.md, "Large swarms")',
        '',
        NON_NEGATIVE,
    )
    c: float = key(1.7, 'repulsion range of eq. 44', 'm^2', POSITIVE, required=True)
    # neighbour set of each tracker's potential (not in the paper: the paper's is all-to-all)
    neighbours: str = key(
        'all',
        "which trackers enter a tracker's formation term: all (eq. 2), nearest (the "
        'neighbour_count nearest) or radius (those within sensing_radius)',
        choices=NEIGHBOUR_RULES,
    )
    neighbour_count: int = key(2, 'neighbours = nearest: how many', '', '[1, inf)')
    sensing_radius: float = key(5.0, 'neighbours = radius: the sensing range', 'm', POSITIVE)
    # sliding-mode controller
    alpha: float = key(0.01, 'linear gain of eq. 7 / 22', '1/s', NON_NEGATIVE, required=True)
    beta: float = key(
        2.0,
        'switching gain of eq. 7 / 22; the proof needs beta >= v_N',
        'm/s',
        POSITIVE,
        required=True,
    )
    gamma: float = key(0.5, 'boundary-layer thickness of eq. 8', 'm', POSITIVE, required=True)
    lambda_filter: float = key(
        0.1, 'time constant of the low-pass filter of eq. 26', 's', POSITIVE, required=True
    )
    u0: float = key(125.0, 'switching force gain of eq. 24', 'N', POSITIVE, required=True)
    switching: str = key(
        'sign',
        'switching force of eq. 24: sign (the paper) or layer, -u0 sat(s/phi) (Slotine & '
        'Li; not in the paper, for sampled control)',
        choices=SWITCHINGS,
    )
    phi: float = key(
        0.15, 'switching = layer: boundary-layer width of the sliding surface', 'm/s', POSITIVE
    )
    feedforward: float = key(
        0.0,
        'weight w of the target velocity in the sliding surface, s = v - w v_N + ... (0: '
        'the paper; 1 removes the lag of a moving target)',
        '',
        '[0, 1]',
    )
    precondition: str = key(
        'none',
        'direction the manifold descends: none, the gradient of J (the paper); newton, '
        '|H|_mu^-1 grad J (O(n^3) per command); block, each gradient row scaled by its own '
        '3x3 Hessian block, the centroid apart (O(n) per tracker; both not in the paper)',
        choices=('none', 'newton', 'block'),
    )
    newton_mu: float = key(
        0.1,
        'precondition = newton or block: the smallest curvature of |H|_mu (same unit as '
        'the Hessian of J)',
        '',
        POSITIVE,
    )
    newton_every: int = key(
        1,
        "precondition = newton: recompute the Hessian's eigendecomposition every this many "
        'control samples (it costs most)',
        '',
        '[1, inf)',
    )
    newton_trust: float = key(
        0.0,
        'precondition = newton or block: trust radius of the step (newton: RMS per tracker; '
        'block: each tracker, apart from the centroid), above which the curvature floor '
        'rises above newton_mu (0: none)',
        'm',
        NON_NEGATIVE,
    )
    compensation: str = key(
        'none',
        'sampled control (control_rate > 0): none, or predict, the state predicted forward '
        "by the latency with each tracker's own held command (not in the paper)",
        choices=COMPENSATIONS,
    )
    epsilon: float = key(1.0, 'reaching margin of Theorem 1 / eq. 37', 'm/s^2', POSITIVE)
    mu: float = key(0.1, 'reaching margin of eq. 43', 'm/s^2', POSITIVE)
    # plant, eq. 19-21
    mass: tuple[float, ...] = key(
        (1.0,),
        'mass M, scalar or diagonal of M (eq. 19)',
        'kg',
        POSITIVE,
        length=(1, 3),
        required=True,
    )
    mass_lo: float = key(0.5, 'lower mass bound of eq. 21', 'kg', POSITIVE)
    mass_hi: float = key(1.5, 'upper mass bound of eq. 21', 'kg', POSITIVE)
    drag: float = key(0.0, 'known disturbance f_known = drag * v', 'N s/m', NON_NEGATIVE)
    f_bar: float = key(
        1.0,
        'bound of the unknown disturbance |f_unknown| <= f_bar',
        'N',
        NON_NEGATIVE,
        required=True,
    )
    noise: str = key(
        'uniform_ball',
        'distribution of f_unknown: uniform in the ball of radius f_bar, or none',
        choices=NOISE_KINDS,
    )
    # target, eq. 1
    target_trajectory: str = key('circle', 'shape of the target path', choices=TRAJECTORIES)
    target_speed: float = key(1.5, 'target speed v (peak for figure_eight)', 'm/s', NON_NEGATIVE)
    target_yaw_deg: float = key(0.0, 'initial yaw chi of the target (eq. 1)', 'deg')
    target_pitch_deg: float = key(
        0.0, 'pitch delta of the target (eq. 1), straight and helix', 'deg', '[-90, 90]'
    )
    target_radius: float = key(
        20.0, 'turn radius of circle / helix, half-width of figure_eight', 'm', POSITIVE
    )
    target_start: tuple[float, ...] = key(
        (0.0, 0.0, 5.0), 'initial target position', 'm', length=(3,)
    )
    target_waypoints: tuple[float, ...] = key(
        (), 'waypoint offsets from target_start, flat x,y,z list', 'm'
    )
    v_n: float = key(
        0.0,
        'bound v_N on the target speed; 0 means the trajectory peak speed',
        'm/s',
        NON_NEGATIVE,
    )
    # initial conditions
    init_center: tuple[float, ...] = key(
        (0.0, 0.0, 0.0), 'centre of the random initial tracker positions', 'm', length=(3,)
    )
    init_spread: float = key(
        1.0, 'trackers start uniformly in a ball of this radius', 'm', NON_NEGATIVE
    )
    init_layout: str = key(
        'ball',
        "how the trackers start: ball, uniform in the init_spread ball (the paper's); "
        'formation, the design formation at 0.7 of its size turned at random by the seed '
        "(not in the paper; 3 or fewer trackers: the paper's ball)",
        choices=('ball', 'formation'),
    )
    init_separation: float = key(
        0.0,
        'no two trackers start closer than this; the ball grows to hold them (0: the '
        "paper's start, any distance)",
        'm',
        NON_NEGATIVE,
    )
    # run
    seed: int = key(0, 'seed of initial positions and noise', '', NON_NEGATIVE, read_only=True)
    dt: float = key(
        0.001,
        'fixed step of plant and controller',
        's',
        '(0, 1]',
        required=True,
        read_only=True,
    )
    duration: float = key(30.0, 'simulated time', 's', POSITIVE)
    control_rate: float = key(
        0.0,
        'rate of the controller: 0 commands every step of dt (lockstep); > 0 samples the '
        'state and holds each command for 1/control_rate s (real time; the realtime plant '
        'publishes at this rate); 1/(control_rate dt) must be a whole number of steps',
        'Hz',
        '[0, 1e6]',
    )
    latency: float = key(
        0.0,
        'headless emulation of real time: delay from a state sample to its command taking '
        'effect (control-loop latency)',
        's',
        '[0, 10]',
    )
    steady_fraction: float = key(
        0.25, 'the last fraction of a run that metrics call steady', '', '(0, 1]'
    )
    record_every: int = key(1, 'keep every k-th step in trajectory.npz', '', '[1, inf)')
    # per-UAV overrides, from /uav_<i>/... sections: {i: {key: value}}
    uav_overrides: Mapping[int, Mapping[str, Any]] = field(
        default_factory=dict, metadata={'internal': True}
    )

    def __post_init__(self) -> None:
        validate(self)

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
        over = self.uav_overrides  # validated: every mass a tuple of 1 or 3
        masses = [over.get(i, {}).get('mass', self.mass) for i in range(1, self.n_trackers + 1)]
        return [list(m) * 3 if len(m) == 1 else list(m) for m in masses]

    def swarm_b(self) -> float:
        """The repulsion gain b of eq. 44 for this swarm's size: ``b (n/3)^b_growth`` for
        more than 3 trackers, ``b`` otherwise (docs/THEORY.md, "Large swarms")."""
        if self.b_growth == 0.0 or self.n_trackers <= 3:
            return self.b
        return self.b * (self.n_trackers / 3.0) ** self.b_growth

    def potential_params(self) -> PotentialParams:
        """Keyword arguments of :func:`apf_swarm_core.gradients.gradient` (b:
        :meth:`swarm_b`)."""
        return {'k_n': self.k_n, 'k_f': self.k_f, 'a': self.a, 'b': self.swarm_b(), 'c': self.c}

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
        out = {f.name: getattr(self, f.name) for f in fields(self)}
        out = {k: list(v) if isinstance(v, tuple) else v for k, v in out.items()}
        out['uav_overrides'] = {int(k): dict(v) for k, v in self.uav_overrides.items()}
        return out


#: every key of a configuration (what files, ``--set`` and the nodes' parameters may set)
KEYS = tuple(f.name for f in fields(SwarmConfig) if not f.metadata.get('internal'))
#: the keys a configuration file must set
REQUIRED_KEYS = tuple(f.name for f in fields(SwarmConfig) if f.metadata.get('required'))
