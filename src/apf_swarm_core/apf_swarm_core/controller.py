"""The sliding-mode controller of a set of trackers (:class:`SlidingModeController`): the
filter state of eq. 26 and one command per step by the paper's law (eq. 22-31) or the
traditional one, computed by the compiled kernel :func:`~apf_swarm_core.kernels.smc_rows`;
:class:`ControlOutput` is what a step returns."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .kernels import CTL_COLUMNS, as_kernel, smc_rows
from .laws import LAWS, SATURATIONS, SWITCHINGS

__all__ = ['CONTROLLER_GAINS', 'ControlOutput', 'SlidingModeController']


class ControlOutput(NamedTuple):
    """What one controller step produced for m trackers (arrays of shape (..., m, 3);
    ``saturated``, outside the boundary layer of eq. 8, (..., m))."""

    force: NDArray[np.float64]
    sliding_surface: NDArray[np.float64]
    gradient: NDArray[np.float64]
    filter_state: NDArray[np.float64]
    saturated: NDArray[np.bool_]


#: the configuration keys of the controller's gains (eq. 22-28, 31, 24, 26), each a number
#: that may differ from run to run of a batch; a running tracker takes them over
#: (:meth:`SlidingModeController.retune`)
CONTROLLER_GAINS = ('alpha', 'beta', 'gamma', 'lambda_filter', 'u0', 'drag', 'phi', 'feedforward')


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
    switching : 'sign' (eq. 24) or 'layer' (``-u0 clip(s / phi, -1, 1)``, not in the paper)
    phi : float [m/s]
        Boundary-layer width of ``switching='layer'``.
    feedforward : float
        Weight ``w`` of the target velocity in the manifold (0: the paper's manifolds); the
        target velocity is the ``v_ref`` argument of :meth:`step`.

    The gains are laid out for the kernel (:attr:`table`) on construction, by
    :meth:`retune` and by :meth:`sample_elapsed`: change them there, not by assignment.
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
    #: the gains of each run in the columns of ``kernels.CTL_COLUMNS``, (runs, 10)
    table: NDArray[np.float64] = field(init=False, repr=False)
    #: 0 the proposed manifold with eq. 8, 1 the traditional one, 2 the continuous sat
    manifold: int = field(init=False, repr=False)
    #: whether the manifold takes the target velocity (a feed-forward weight not 0)
    uses_feedforward: bool = field(init=False, repr=False)

    def __post_init__(self) -> None:
        if self.law not in LAWS:
            raise ValueError(f'law must be one of {LAWS}, got {self.law!r}')
        if self.law == 'proposed' and self.saturation not in SATURATIONS:
            raise ValueError(f'saturation must be one of {SATURATIONS}, got {self.saturation!r}')
        if self.switching not in SWITCHINGS:
            raise ValueError(f'switching must be one of {SWITCHINGS}, got {self.switching!r}')
        self.manifold = 1 if self.law == 'traditional' else 0 if self.saturation == 'paper' else 2
        self.reset()
        self.retune()

    def retune(self, **gains: ArrayLike) -> None:
        """Take over new values of some :data:`CONTROLLER_GAINS` (keywords) and lay every
        gain out for the kernel; the filter state is kept."""
        unknown = sorted(gains.keys() - set(CONTROLLER_GAINS))
        if unknown:
            raise TypeError(f'not a controller gain: {", ".join(unknown)}')
        for key, value in gains.items():
            setattr(self, key, value)
        alpha, beta, gamma, lam, u0, drag, phi, ff = (
            np.asarray(getattr(self, key), dtype=float) for key in CONTROLLER_GAINS
        )
        decay = np.exp(-self.dt / lam)  # eq. 26 over one sample
        columns = {
            'alpha': alpha,
            'beta': beta,
            'gamma': gamma,
            'layer_gain': alpha + beta / gamma,  # eq. 31
            'neg_u0': -u0,
            'drag': drag,
            'decay': decay,
            'gain_in': (1.0 - decay) * beta,
            'inv_phi': 1.0 / phi if self.switching == 'layer' else 0.0,
            'feedforward': ff,
        }
        table = np.empty((*self.shape[:-2], len(CTL_COLUMNS)))
        for q, name in enumerate(CTL_COLUMNS):
            table[..., q] = columns[name]
        self.table = table.reshape(-1, len(CTL_COLUMNS))
        self.uses_feedforward = bool(np.any(ff != 0.0))

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
        self.retune()

    def step(self, v: ArrayLike, grad: ArrayLike, v_ref: ArrayLike | None = None) -> ControlOutput:
        """Compute the command for velocities ``v`` and gradients ``grad`` (shape
        ``(..., m, 3)``, the controller's :attr:`shape`); ``v_ref`` (shape ``(..., 3)``),
        the target velocity, enters the manifold as ``v - feedforward v_ref`` when
        ``feedforward`` is not 0. The law is the compiled :func:`~apf_swarm_core.kernels.
        smc_rows` (eq. 8, 20, 22-28, 31, 24, 26), the one the simulator's loop runs."""
        shape = self.shape
        runs, m = self.table.shape[0], shape[-2]
        grad = np.asarray(grad, dtype=float)
        feedforward = v_ref is not None and self.uses_feedforward
        vref = np.zeros((runs, 3))
        if v_ref is not None and feedforward:
            vref = as_kernel(v_ref, (*shape[:-2], 3)).reshape(runs, 3)
        force, s, znew, outside = smc_rows(
            as_kernel(v, shape).reshape(runs, m, 3),
            as_kernel(grad, shape).reshape(runs, m, 3),
            as_kernel(self.z).reshape(runs, m, 3),
            vref,
            self.table,
            self.manifold,
            self.switching == 'layer',
            feedforward,
        )
        z, self.z = self.z, znew.reshape(shape)
        return ControlOutput(
            force.reshape(shape), s.reshape(shape), grad, z, outside.reshape(shape[:-1])
        )
