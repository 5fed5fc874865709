"""The sliding-mode controller of a set of trackers (:class:`SlidingModeController`): the
filter state of eq. 26 and one command per step by the paper's law (eq. 22-31) or the
traditional one, with the gains shaped once per run or batch; :class:`ControlOutput` is what
a step returns."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .gains import shaped
from .kernels import (
    CTL_ALPHA,
    CTL_BETA,
    CTL_BOUND,
    CTL_COLUMNS,
    CTL_DECAY,
    CTL_DRAG,
    CTL_FEEDFORWARD,
    CTL_GAIN_IN,
    CTL_GAMMA,
    CTL_INV_PHI,
    CTL_LAYER_GAIN,
    CTL_NEG_U0,
    as_kernel,
    smc_rows,
)
from .laws import LAWS, SWITCHINGS, _check_saturation, _decay
from .saturation import _layer_bound

__all__ = ['CONTROLLER_GAINS', 'ControlOutput', 'SlidingModeController']


@dataclass(frozen=True, init=False)
class ControlOutput:
    """What one controller step produced for m trackers (arrays of shape (..., m, 3))."""

    force: NDArray[np.float64]
    sliding_surface: NDArray[np.float64]
    gradient: NDArray[np.float64]
    filter_state: NDArray[np.float64]
    saturated: NDArray[np.bool_]

    def __init__(
        self,
        force: NDArray[np.float64],
        sliding_surface: NDArray[np.float64],
        gradient: NDArray[np.float64],
        filter_state: NDArray[np.float64],
        saturated: NDArray[np.bool_],
    ) -> None:
        # what the generated frozen __init__ does (one object.__setattr__ per field), at
        # less than half its cost: it is built once per controller step
        d = self.__dict__
        d['force'] = force
        d['sliding_surface'] = sliding_surface
        d['gradient'] = gradient
        d['filter_state'] = filter_state
        d['saturated'] = saturated


#: the configuration keys of the controller's gains (eq. 22-28, 31, 24, 26), each a number
#: that may differ from run to run of a batch; a running tracker takes them over
#: (:meth:`~apf_swarm_core.agents.TrackerAgent.retune`)
CONTROLLER_GAINS = ('alpha', 'beta', 'gamma', 'lambda_filter', 'u0', 'drag', 'phi', 'feedforward')
#: controller fields its prepared gains are derived from
_GAIN_FIELDS = frozenset({*CONTROLLER_GAINS, 'law', 'dt', 'saturation', 'switching'})


@dataclass(frozen=True)
class _ControllerGains:
    """Gains of a :class:`SlidingModeController` shaped once for the kernels."""

    alpha: NDArray[np.float64]
    beta: NDArray[np.float64]
    gamma: Any  # as given, for sat_continuous
    layer_bound: NDArray[np.float64]  # ||grad||^2 bound of the layer test, against (..., m)
    layer_gain: NDArray[np.float64]  # alpha + beta / gamma of eq. 31
    neg_u0: NDArray[np.float64]
    drag: NDArray[np.float64]
    decay: NDArray[np.float64]  # e^{-dt/lambda} of eq. 26
    gain_in: NDArray[np.float64]  # (1 - decay) beta
    manifold: int  # 0 proposed with eq. 8, 1 traditional, 2 continuous sat
    inv_phi: NDArray[np.float64] | None  # 1/phi of the boundary-layer switching, None: sign
    feedforward: NDArray[np.float64] | None  # weight w of the target velocity, None: 0
    ctl: NDArray[np.float64]  # every gain per run, (B, CTL_COLUMNS), for kernels.smc_rows


@dataclass
class SlidingModeController:
    """Stateful sliding-mode controller for m trackers (m = 1 in a tracker node).

    Holds the filter state z of eq. 26 explicitly; :meth:`reset` zeroes it. One call of
    :meth:`step` computes the manifold with the current z, the force of eq. 24, and advances z
    by one sample of length ``dt``.

    Parameters
    ----------
    law : 'proposed' or 'traditional'
    alpha [1/s], beta [m/s], gamma [m], lambda_filter [s], u0 [N], drag [N s/m] : gains, floats
        or arrays of shape (...) for a batch of runs.
    dt : float
        Control period [s].
    shape : tuple
        Shape of the state, ``(..., m, 3)``.
    saturation : 'paper' or 'continuous'
    switching : 'sign' (eq. 24) or 'layer' (:func:`layer_switching_force`, width ``phi``)
    phi : float [m/s]
        Boundary-layer width of ``switching='layer'``.
    feedforward : float
        Weight ``w`` of the target velocity in the manifold (0: the paper's manifolds); the
        target velocity is the ``v_ref`` argument of :meth:`step`.

    The gains are shaped for the kernels once and the result is cached; assigning any gain
    attribute (``ctl.gamma = 0.3``) invalidates the cache. Gain arrays must be replaced, not
    modified in place.
    """

    law: str  # 'proposed' or 'traditional' (LAWS), checked on construction
    alpha: ArrayLike
    beta: ArrayLike
    gamma: ArrayLike
    lambda_filter: ArrayLike
    u0: ArrayLike
    dt: float
    shape: tuple[int, ...] = (1, 3)
    drag: ArrayLike = 0.0
    saturation: str = 'paper'
    switching: str = 'sign'
    phi: ArrayLike = 0.15
    feedforward: ArrayLike = 0.0
    z: NDArray[np.float64] = field(init=False, repr=False)
    _gains: _ControllerGains | None = field(init=False, repr=False, compare=False, default=None)

    def __setattr__(self, name: str, value: Any) -> None:
        object.__setattr__(self, name, value)
        if name in _GAIN_FIELDS:
            object.__setattr__(self, '_gains', None)

    def _prepare(self) -> _ControllerGains:
        alpha, beta, gamma = shaped(self.alpha), shaped(self.beta), shaped(self.gamma)
        decay = _decay(shaped(self.lambda_filter), self.dt)
        if self.law == 'traditional':
            manifold = 1
        else:
            _check_saturation(self.saturation)
            manifold = 0 if self.saturation == 'paper' else 2
        if self.switching not in SWITCHINGS:
            raise ValueError(f'switching must be one of {SWITCHINGS}, got {self.switching!r}')
        ff = shaped(self.feedforward)
        # the layer bound depends on gamma only: kept while gamma is the same object (a
        # realtime tracker re-prepares for every command, with a new dt)
        cached = self.__dict__.get('_bound_of')
        if cached is not None and cached[0] is self.gamma:
            bound = cached[1]
        else:
            bound = _layer_bound(shaped(self.gamma, 1))
            object.__setattr__(self, '_bound_of', (self.gamma, bound))
        # np.asarray: arithmetic on 0-d arrays gives numpy scalars, which numpy treats like
        # Python floats, the slower operand (see the module docstring)
        layer_gain = np.asarray(alpha + beta / gamma)
        neg_u0 = np.asarray(-shaped(self.u0))
        drag = shaped(self.drag)
        gain_in = np.asarray((1.0 - decay) * beta)
        inv_phi = np.asarray(1.0 / shaped(self.phi)) if self.switching == 'layer' else None
        feedforward = ff if np.any(ff != 0.0) else None
        lead = self.shape[:-2]
        runs = math.prod(lead)
        ctl = np.zeros((runs, CTL_COLUMNS))
        for col, value in (
            (CTL_ALPHA, alpha),
            (CTL_BETA, beta),
            (CTL_GAMMA, gamma),
            (CTL_BOUND, bound),
            (CTL_LAYER_GAIN, layer_gain),
            (CTL_NEG_U0, neg_u0),
            (CTL_DRAG, drag),
            (CTL_DECAY, decay),
            (CTL_GAIN_IN, gain_in),
            (CTL_INV_PHI, inv_phi),
            (CTL_FEEDFORWARD, feedforward),
        ):
            if value is not None:
                arr = np.asarray(value, dtype=float)
                arr = arr.reshape(arr.shape[: len(lead)]) if arr.ndim else arr
                ctl[:, col] = np.broadcast_to(arr, lead).reshape(runs)
        gains = _ControllerGains(
            alpha=alpha,
            beta=beta,
            gamma=self.gamma,
            layer_bound=bound,
            layer_gain=layer_gain,
            neg_u0=neg_u0,
            drag=drag,
            decay=np.asarray(decay),
            gain_in=gain_in,
            manifold=manifold,
            inv_phi=inv_phi,
            feedforward=feedforward,
            ctl=ctl,
        )
        object.__setattr__(self, '_gains', gains)
        return gains

    def __post_init__(self) -> None:
        if self.law not in LAWS:
            raise ValueError(f'law must be one of {LAWS}, got {self.law!r}')
        self.reset()

    def reset(self, z: ArrayLike | None = None) -> None:
        """Set the filter state to ``z`` (default zeros), e.g. after a respawn."""
        self.z = (
            np.zeros(self.shape) if z is None else np.array(z, dtype=float).reshape(self.shape)
        )

    #: the bounds of a realtime sample's length [s] (:meth:`sample_elapsed`): a stall longer
    #: than the upper one does not throw the filter of eq. 26 far off in one step
    SAMPLE_BOUNDS = (1e-4, 0.1)

    def sample_elapsed(self, elapsed: float | None, nominal: float) -> None:
        """Realtime: the next sample of the filter of eq. 26 is as long as the time that
        actually elapsed since the previous command (``elapsed`` [s], clamped to
        :attr:`SAMPLE_BOUNDS`), or ``nominal`` [s] before the first command."""
        lo, hi = self.SAMPLE_BOUNDS
        self.dt = nominal if elapsed is None else min(hi, max(lo, float(elapsed)))

    def step(self, v: ArrayLike, grad: ArrayLike, v_ref: ArrayLike | None = None) -> ControlOutput:
        """Compute the command for velocities ``v`` and gradients ``grad`` (shape
        ``(..., m, 3)``, the controller's :attr:`shape`); ``v_ref`` (shape ``(..., 3)``),
        the target velocity, enters the manifold as ``v - feedforward v_ref`` when
        ``feedforward`` is not 0. The law is the compiled :func:`~apf_swarm_core.kernels.
        smc_rows` (eq. 8, 20, 22-28, 31, 24, 26), the one the simulator's loop runs."""
        p = self._gains or self._prepare()
        shape = self.shape
        v = np.asarray(v, dtype=float)
        grad = np.asarray(grad, dtype=float)
        runs, m = p.ctl.shape[0], shape[-2]
        feedforward = p.feedforward is not None and v_ref is not None
        vref = (
            as_kernel(v_ref, (*shape[:-2], 3)).reshape(runs, 3)
            if feedforward and v_ref is not None
            else np.zeros((runs, 3))
        )
        force, s, znew, outside = smc_rows(
            as_kernel(v, shape).reshape(runs, m, 3),
            as_kernel(grad, shape).reshape(runs, m, 3),
            as_kernel(self.z).reshape(runs, m, 3),
            vref,
            p.ctl,
            p.manifold,
            p.inv_phi is not None,
            feedforward,
        )
        z = self.z
        object.__setattr__(self, 'z', znew.reshape(shape))  # not a gain
        return ControlOutput(
            force.reshape(shape), s.reshape(shape), grad, z, outside.reshape(shape[:-1])
        )
