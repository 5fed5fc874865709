"""The plant's side of a sampled, delayed control loop: which command each UAV holds at each
step when commands take effect after a latency (:class:`CommandHold`).

The headless emulation of real time (:mod:`apf_swarm_core.simulator` with ``latency`` or
measured ``latency_samples``) applies every command through it, as the realtime plant holds
the latest command of each tracker and refuses one that arrives out of order.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ['CommandHold']


class CommandHold:
    """The plant's side of a sampled, delayed control loop: which command each UAV holds.

    :meth:`submit` hands over the commands computed at step k; each tracker's takes effect at
    step ``k + d``, d its delay in steps (a fixed ``latency``; one drawn from
    ``latency_samples`` per tracker and sample; or, with ``latency_samples`` of shape (m, n),
    a run's own delays replayed in their order, row ``c mod m`` for the c-th submission, so
    that delays correlated in time and across trackers stay so; all rounded to steps of
    dt). Until then the
    UAV keeps the command it holds (zero force before the first). A command that arrives
    after a newer one of the same tracker is dropped (out of order).

    Parameters
    ----------
    shape : (R, n): runs and trackers.
    latency : float or array (R,) [s]; dt : float [s]
    latency_samples : array (k,) or (m, n) [s], optional; rng : numpy Generator for them
    """

    def __init__(
        self,
        shape: tuple[int, int],
        latency: ArrayLike,
        dt: float,
        latency_samples: ArrayLike | None = None,
        rng: np.random.Generator | None = None,
    ) -> None:
        self.shape = shape
        self.fixed = np.broadcast_to(
            np.rint(np.asarray(latency, dtype=float) / dt).astype(np.int64).reshape(-1, 1), shape
        )
        self.samples = (
            None
            if latency_samples is None
            else np.rint(np.asarray(latency_samples, dtype=float) / dt).astype(np.int64)
        )
        if self.samples is not None and (self.samples.size == 0 or np.any(self.samples < 0)):
            raise ValueError('latency_samples must be a non-empty array of delays >= 0 s')
        if (
            self.samples is not None
            and self.samples.ndim == 2
            and self.samples.shape[1] != shape[1]
        ):
            raise ValueError(
                f'latency_samples of shape {self.samples.shape}: a replayed sequence needs '
                f'one column per tracker ({shape[1]})'
            )
        self.rng = rng if rng is not None else np.random.default_rng()
        self.force = np.zeros((*shape, 3))
        self.seq = np.full(shape, -1, dtype=np.int64)
        self.pending: list[tuple[int, NDArray[np.int64], NDArray[np.float64]]] = []
        self.count = 0

    @property
    def delayed(self) -> bool:
        """Whether any command waits at all (False: a command acts at its own step)."""
        return self.samples is not None or bool(np.any(self.fixed > 0))

    def submit(self, k: int, force: NDArray[np.float64]) -> None:
        """The commands computed from the state of step k, shape (R, n, 3)."""
        if self.samples is None:
            delay = self.fixed
        elif self.samples.ndim == 2:
            delay = np.broadcast_to(self.samples[self.count % len(self.samples)], self.shape)
        else:
            delay = self.rng.choice(self.samples, size=self.shape)
        self.pending.append((self.count, k + delay, np.array(force, dtype=float)))
        self.count += 1

    def applied(self, k: int) -> NDArray[np.float64]:
        """The force every UAV holds over step k, shape (R, n, 3)."""
        keep = []
        for seq, at, force in self.pending:
            arrived = at <= k
            newer = arrived & (seq > self.seq)
            if newer.any():
                self.force[newer] = force[newer]
                self.seq[newer] = seq
            if not arrived.all():
                keep.append((seq, at, force))
        self.pending = keep
        return self.force
