"""A bag in the live view: served with its recorded timing and no ROS graph
(:func:`serve_bag`, ``apf-swarm bag view``), or shown while the player replays it
(:func:`live_view_of_bag`, ``apf-swarm bag play --view``)."""

from __future__ import annotations

import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from ..analysis.samples import RawSample
from ..topics import SWARM_STATE
from .errors import ViewError
from .server import VIEW_RATE, LiveView

__all__ = ['bag_samples', 'live_view_of_bag', 'serve_bag']


def _raw_sample() -> Callable[[bytes], RawSample]:
    """``/swarm/state`` CDR bytes as a RawSample, decoded by rosbags only when shown."""
    from ..bags.read import swarm_state_decoder
    from ..conversions import swarm_state_step

    decode = swarm_state_decoder()
    return lambda raw: RawSample(swarm_state_step(raw), raw, decode)


def bag_samples(info: Any) -> list[tuple[int, RawSample]]:
    """``(timestamp_ns, RawSample)`` of every ``/swarm/state`` message of a bag."""
    from ..bags import iter_raw

    info.topic(SWARM_STATE)  # BagError naming the topic when the bag has none
    sample = _raw_sample()
    return [(ts, sample(raw)) for *_x, ts, raw in iter_raw(info.path, [SWARM_STATE], info=info)]


def _designs(info: Any, config: Path | None, say: Callable[[str], None]) -> list[Any]:
    """The design minima of the bag's run (its stored configuration or ``config``); none,
    with a warning, for a bag that stores none (the edges are then not drawn)."""
    from apf_swarm_core.formation import design_pair_sets

    from ..bags import BagError, bag_config

    try:
        cfg, _mode = bag_config(info, config)
    except BagError as exc:
        say(f'warning: {exc}; the formation edges are not drawn')
        return []
    return design_pair_sets(cfg)


def live_view_of_bag(
    info: Any, *, host: str, port: int, config: Path | None = None
) -> tuple[LiveView, Callable[[str, bytes], None]]:
    """A live view of a bag being played and the observer to hand each played message to:
    it keeps the newest ``/swarm/state``, which the view shows (decoded only while a
    client watches)."""
    view = LiveView(host=host, port=port)
    view.builder.designs = _designs(info, config, lambda m: print(m, file=sys.stderr))
    sample = _raw_sample()
    newest: list[RawSample | None] = [None]

    def observe(topic: str, raw: bytes) -> None:
        if topic == SWARM_STATE:
            newest[0] = sample(raw)

    view.follow(lambda: newest[0])
    return view, observe


def serve_bag(
    path: Path,
    *,
    host: str = '127.0.0.1',
    port: int = 0,
    rate: float = 1.0,
    loop: bool = False,
    wait_client: float | None = None,
    config: Path | None = None,
    say: Callable[[str], None] = print,
    stop: threading.Event | None = None,
) -> int:
    """Serve the bag's ``/swarm/state`` to Foxglove at ``rate`` times the recorded speed;
    returns the number of frames sent.

    ``wait_client``: wait this long [s] (None: without limit) for a client to subscribe
    before playing, so the run is seen from its start (ViewError when none came); ``loop``:
    play again until ``stop`` is set (or Ctrl-C)."""
    from ..bags import open_bag

    info = open_bag(path)
    view = LiveView(host=host, port=port)  # a busy port is found before the bag is read
    stop = stop or threading.Event()
    try:
        view.builder.designs = _designs(info, config, say)
        samples = bag_samples(info)
        say(f'serving {view.url} (Foxglove: Open connection, Foxglove WebSocket)')
        if not samples:
            say(f'{info.path}: /swarm/state has no message; nothing to show')
            return 0
        deadline = None if wait_client is None else time.monotonic() + wait_client
        if not view.watched():
            say('waiting for a client to subscribe')
        while not view.watched():
            if stop.wait(0.05):
                return 0
            if deadline is not None and time.monotonic() > deadline:
                raise ViewError(
                    f'no client subscribed within {wait_client:g} s; open {view.url} in '
                    'Foxglove, or give --wait-client more time'
                )
        while True:
            _play(view, samples, rate, stop)
            if not loop or stop.is_set():
                break
        return view.frames
    finally:
        view.close()


def _play(view: LiveView, samples: list[tuple[int, RawSample]], rate: float, stop: Any) -> None:
    """One pass: sample i shown at ``t0 + (ts_i - ts_0) / rate`` (an absolute schedule), at
    most :data:`VIEW_RATE` frames per second of wall time, the last sample always."""
    first = samples[0][0]
    t0 = time.monotonic()
    next_frame = 0.0
    for k, (ts, raw) in enumerate(samples):
        due = t0 + (ts - first) / 1e9 / rate
        if due < next_frame and k < len(samples) - 1:
            continue
        if stop.wait(max(0.0, due - time.monotonic())):
            return
        next_frame = due + 1.0 / VIEW_RATE
        view.show(raw.sample, ts)
