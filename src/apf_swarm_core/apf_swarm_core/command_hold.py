"""The plant's side of a sampled, delayed control loop (:class:`CommandHold`): which command
each UAV holds when commands take effect after a latency, as the realtime plant holds them.
The headless emulation of real time (:mod:`apf_swarm_core.simulator`) applies every command
through it; :func:`answers` turns a realtime run's record into delays it replays."""

from __future__ import annotations

import bisect

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ['STALE_AFTER', 'CommandHold', 'answers']

#: the plant's default ``stale_after`` [s]: a tracker that has not answered a state published
#: this long ago gets zero force instead of its held command (the live view draws it stale)
STALE_AFTER = 0.1
#: the delay [steps] of a command that never arrives
NEVER = 2**40


def answers(t: ArrayLike, held: ArrayLike) -> NDArray[np.float64]:
    """Each tracker's delay (m, n) [s] for each published state, ``inf`` for one it never
    answered, from a realtime run's record: ``t`` (m,) [s] the publications and ``held``
    (m, n) [s] the age of each tracker's held command at each (``command_latency``), for
    :class:`CommandHold` to replay."""
    t = np.asarray(t, dtype=float)
    held = np.asarray(held, dtype=float)
    out = np.full(held.shape, np.inf)
    for r in range(1, len(t)):
        new = np.isfinite(held[r]) & (held[r] > 0) & (held[r] != held[r - 1])
        # the state it answered: the last publication at or before t[r] - held[r]
        s = np.searchsorted(t, t[r] - held[r][new] + 1e-9, side='right') - 1
        ok = s >= 0
        out[s[ok], np.flatnonzero(new)[ok]] = held[r][new][ok]
    return out


class CommandHold:
    """Which command each UAV of ``shape`` (R runs, n trackers) holds at each step.

    The commands of step k (:meth:`submit`) take effect at step ``k + d``, d the delay [s]
    rounded to steps of ``dt``: a fixed ``latency`` (float or (R,)); a draw (``rng``) from
    ``latency_samples`` (k,) per tracker and submission; or with ``latency_samples`` (m, n)
    row ``c mod m`` for the c-th submission (a run's delays replayed in order). Until then
    the UAV keeps its held command (zero before the first); one that arrives after a newer
    one is dropped. With ``stale_after`` [s], as
    :meth:`~apf_swarm_core.plant_model.PlantModel.expire` does, a UAV whose command answers a
    state older than the newest one submitted ``stale_after`` ago gets zero force.
    """

    def __init__(
        self,
        shape: tuple[int, int],
        latency: ArrayLike,
        dt: float,
        latency_samples: ArrayLike | None = None,
        rng: np.random.Generator | None = None,
        stale_after: float | None = None,
    ) -> None:
        self.shape = shape
        self.stale_steps = None if stale_after is None else int(np.rint(stale_after / dt))
        self.fixed = np.broadcast_to(
            np.rint(np.asarray(latency, dtype=float) / dt).astype(np.int64).reshape(-1, 1), shape
        )
        self.samples = None
        if latency_samples is not None:
            delays = np.asarray(latency_samples, dtype=float)
            # an unanswered state (inf): its command never arrives
            samples = np.where(
                np.isposinf(delays), NEVER, np.rint(np.nan_to_num(delays, posinf=0.0) / dt)
            ).astype(np.int64)
            if samples.size == 0 or np.any(samples < 0):
                raise ValueError('latency_samples must be a non-empty array of delays >= 0 s')
            if samples.ndim == 2 and samples.shape[1] != shape[1]:
                raise ValueError(
                    f'latency_samples of shape {samples.shape}: a replayed sequence needs '
                    f'one column per tracker ({shape[1]})'
                )
            self.samples = samples
        self.rng = rng if rng is not None else np.random.default_rng()
        self.force = np.zeros((*shape, 3))
        self.seq = np.full(shape, -1, dtype=np.int64)
        #: the step of the state each held command answers, and of every state submitted
        self.source = np.full(shape, -1, dtype=np.int64)
        self.states: list[int] = []
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
        self.states.append(k)
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
                self.source[newer] = self.states[seq]
            if not arrived.all():
                keep.append((seq, at, force))
        self.pending = keep
        if self.stale_steps is not None:
            # the newest state submitted stale_after ago or earlier: not answered, zero force
            ref = bisect.bisect_right(self.states, k - self.stale_steps) - 1
            if ref >= 0:
                self.force[self.source < self.states[ref]] = 0.0
        return self.force
