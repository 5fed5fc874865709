"""The live view: a Foxglove WebSocket server (``foxglove-sdk``) that shows a run or a bag
(:class:`LiveView`).

Channels: ``/swarm/scene`` (``foxglove.SceneUpdate``), ``/swarm/frames``
(``foxglove.FrameTransform`` world -> target) and ``/swarm/metrics`` (JSON time series).
A frame is built only while a client subscribes to one of them: without a client the view
costs a wake-up and a flag read per frame period, nothing per ``/swarm/state`` sample.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from apf_swarm_core.command_hold import STALE_AFTER
from numpy.typing import NDArray

from ..analysis.samples import RawSample
from ..topics import FOXGLOVE_FRAMES, FOXGLOVE_METRICS, FOXGLOVE_SCENE
from .errors import ViewError
from .scene import SceneBuilder

__all__ = ['DEFAULT_PORT', 'VIEW_RATE', 'LiveView']

#: the Foxglove app's default WebSocket port
DEFAULT_PORT = 8765
#: frames per second the view sends at most
VIEW_RATE = 20.0


class LiveView:
    """A Foxglove WebSocket server on ``host:port`` (port 0: any free port, see
    :attr:`port`) and the channels of the view.

    :meth:`show` sends one sample (a SwarmSample) when a client subscribes;
    :meth:`follow` shows the newest sample of a source at :data:`VIEW_RATE` from a thread of
    its own; :meth:`close` stops both."""

    def __init__(
        self,
        *,
        host: str = '127.0.0.1',
        port: int = DEFAULT_PORT,
        designs: Sequence[NDArray[np.float64]] = (),
        stale_after: float = STALE_AFTER,
    ) -> None:
        import foxglove
        from foxglove.channels import FrameTransformChannel, SceneUpdateChannel

        self.builder = SceneBuilder(designs, stale_after=stale_after)
        try:
            self.server = foxglove.start_server(name='apf_swarm', host=host, port=port)
        except Exception as exc:  # the SDK raises its own error types for a busy port
            raise ViewError(
                f'cannot serve the view on {host}:{port} ({exc}); choose another port '
                '(--view PORT, 0 for any free one)'
            ) from None
        self.host = host
        self.port = int(self.server.port)
        self.scene_ch = SceneUpdateChannel(FOXGLOVE_SCENE)
        self.frames_ch = FrameTransformChannel(FOXGLOVE_FRAMES)
        self.metrics_ch = foxglove.Channel(FOXGLOVE_METRICS, message_encoding='json')
        self.frames = 0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._last_step: int | None = None

    @property
    def url(self) -> str:
        """The address to open in the Foxglove app (Open connection, Foxglove WebSocket)."""
        return f'ws://{self.host}:{self.port}'

    def watched(self) -> bool:
        """A client subscribes to one of the view's channels."""
        return any(ch.has_sinks() for ch in (self.scene_ch, self.frames_ch, self.metrics_ch))

    def show(self, sample: Any, stamp_ns: int | None = None) -> bool:
        """Send ``sample`` (stamped ``stamp_ns``, default now) if a client watches; True
        when it was sent."""
        if not self.watched():
            return False
        ns = time.time_ns() if stamp_ns is None else int(stamp_ns)
        self.scene_ch.log(self.builder.scene(sample, ns), log_time=ns)
        self.frames_ch.log(self.builder.target_frame(sample, ns), log_time=ns)
        self.metrics_ch.log(self.builder.metrics(sample), log_time=ns)
        self.frames += 1
        return True

    def follow(self, latest: Callable[[], Any], rate: float = VIEW_RATE) -> None:
        """Show the newest sample, ``latest()`` (a SwarmSample, a not yet decoded
        :class:`~apf_swarm_nodes.analysis.samples.RawSample`, or None), whenever its step
        changed, at most ``rate`` times a second, from a daemon thread, until :meth:`close`.
        ``latest`` is called from that thread, only while a client watches: it must return
        an object nobody changes afterwards (the bring-up's accumulator replaces its newest
        sample by reference; a RawSample is decoded here, once per frame shown)."""
        if self._thread is not None:
            raise RuntimeError('the view already follows a source')

        def loop() -> None:
            period = 1.0 / rate
            while not self._stop.wait(period):
                if not self.watched():
                    continue
                item = latest()
                if item is None or int(item.step) == self._last_step:
                    continue
                self._last_step = int(item.step)
                self.show(item.sample if isinstance(item, RawSample) else item)

        self._thread = threading.Thread(target=loop, name='apf_swarm-view', daemon=True)
        self._thread.start()

    def close(self) -> None:
        """Stop the thread (it ends within one frame period and one frame) and the server."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
        self.server.stop()
