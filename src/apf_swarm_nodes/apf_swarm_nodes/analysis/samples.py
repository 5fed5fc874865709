"""A run's ``/swarm/state`` samples accumulated into a trajectory
(:class:`StateAccumulator`): the live bring-up and the bag tools share it."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from .errors import AnalysisError

__all__ = ['RawSample', 'StateAccumulator', 'rclpy_decode']


def rclpy_decode(raw: bytes) -> Any:
    """A serialized ``SwarmState`` deserialized by rclpy (the live run's path)."""
    from rclpy.serialization import deserialize_message

    from apf_swarm_msgs.msg import SwarmState

    return deserialize_message(raw, SwarmState)


@dataclass
class RawSample:
    """A serialized ``/swarm/state`` message and its step; ``sample`` deserializes it with
    ``decode`` (rclpy's by default; the bag tools pass rosbags')."""

    step: int
    raw: bytes
    decode: Callable[[bytes], Any] = rclpy_decode

    @property
    def sample(self) -> Any:
        from ..conversions import swarm_state_arrays

        return swarm_state_arrays(self.decode(self.raw))


class StateAccumulator:
    """Collects ``/swarm/state`` samples (:class:`~apf_swarm_nodes.conversions.SwarmSample`).

    Lockstep: steps must be consecutive from 0; a gap counts its missing steps as dropped, a
    step that is not newer than the last one is counted as out of order and ignored. The run
    is complete when step ``steps - 1`` arrived. Realtime: steps advance with wall time and
    may skip; a sample whose step is not newer than the last one (the publish timer ran
    twice between two physics steps) is counted as repeated and ignored, so ``t`` increases
    strictly.
    """

    def __init__(
        self,
        mode: str,
        steps: int,
        record_every: int = 1,
        decode: Callable[[bytes], Any] = rclpy_decode,
    ) -> None:
        self.decode = decode
        self.mode, self.steps, self.record_every = mode, int(steps), max(1, int(record_every))
        self.samples: list[Any] = []
        self.received = 0
        self.dropped = 0
        self.out_of_order = 0
        self.repeated = 0
        self.gaps: list[tuple[int, int]] = []
        self._last: Any = None
        self.last_step = -1
        self.last_time: float | None = None

    def add_raw(self, raw: bytes) -> None:
        """A serialized SwarmState: kept as bytes, deserialized only when needed (the
        bring-up shares the CPU with the swarm)."""
        from ..conversions import swarm_state_step

        try:
            step = swarm_state_step(raw)
        except ValueError:
            self.received += 1
            self.out_of_order += 1
            return
        self.add(RawSample(step, raw, self.decode))

    def add(self, sample: Any) -> None:
        self.received += 1
        self.last_time = time.monotonic()
        step = int(sample.step)
        if step <= self.last_step:
            if self.mode == 'lockstep':
                self.out_of_order += 1
            else:  # the publish timer repeated a step the physics timer has not advanced
                self.repeated += 1
            return
        if self.mode == 'lockstep' and step != self.last_step + 1:
            self.dropped += step - self.last_step - 1
            self.gaps.append((self.last_step + 1, step - 1))
        self.last_step = step
        self._last = sample
        self.samples.append(sample)

    @property
    def last(self) -> Any:
        """The newest sample as arrays (a SwarmSample), or None."""
        s = self._last
        return s.sample if isinstance(s, RawSample) else s

    @property
    def newest(self) -> Any:
        """The newest sample as it was added (a RawSample is not decoded), or None."""
        return self._last

    @property
    def complete(self) -> bool:
        """The plant's last state arrived: lockstep step ``steps - 1``; realtime the state
        at the end of the run (its physics step reaches ``steps``)."""
        return self.last_step >= (self.steps - 1 if self.mode == 'lockstep' else self.steps)

    def kept(self) -> list[Any]:
        """The samples of the trajectory, as arrays."""
        samples = self.samples
        if self.mode == 'lockstep' and self.record_every > 1:
            samples = [s for s in samples if int(s.step) % self.record_every == 0]
        return [s.sample if isinstance(s, RawSample) else s for s in samples]

    def trajectory(self) -> dict[str, Any] | None:
        """Arrays of the ``trajectory.npz`` schema, or None without samples."""
        import numpy as np

        kept = self.kept()
        if not kept:
            return None
        n = kept[0].x.shape[0]
        bad = [int(s.step) for s in kept if s.x.shape[0] != n]
        if bad:
            raise AnalysisError(
                f'/swarm/state changed its number of trackers from {n} (steps '
                f'{bad[:5]}...); cannot build one trajectory'
            )
        return {
            't': np.array([s.t for s in kept], dtype=float),
            'x': np.stack([s.x for s in kept]),
            'v': np.stack([s.v for s in kept]),
            'u': np.stack([s.u for s in kept]),
            's': np.stack([s.s for s in kept]),
            'target_x': np.stack([s.target_x for s in kept]),
            'target_v': np.stack([s.target_v for s in kept]),
            # the per-sample arrays of a ROS run (runio.RUN_ARRAYS)
            'active': np.array([s.active or (True,) * n for s in kept], dtype=bool),
            'target_age': np.array([s.target_age for s in kept], dtype=float),
            'stale_inputs': np.array([s.stale_inputs for s in kept], dtype=int),
            'command_latency': np.array(
                [s.command_latency or (0.0,) * n for s in kept], dtype=float
            ),
        }

    def messages(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            'received': self.received,
            'dropped': self.dropped,
            'gaps': [list(g) for g in self.gaps[:20]],
            'out_of_order': self.out_of_order,
        }
        if self.mode == 'lockstep':
            out['expected'] = self.steps
        else:
            out['repeated'] = self.repeated
        return out
