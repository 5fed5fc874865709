"""A bag in the live view (``apf-swarm bag view``): its ``/swarm/state`` shown as a live run
is shown, with the recorded timing, without a ROS graph."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from .server import VIEW_RATE, LiveView

__all__ = ['bag_samples', 'live_view_of_bag', 'serve_bag']


def bag_samples(info: Any) -> Iterator[tuple[int, Any]]:
    """``(timestamp_ns, SwarmSample)`` of every ``/swarm/state`` message of a bag, decoded
    by rosbags."""
    from ..bags import iter_raw
    from ..bags.types import SWARM_STATE_TOPIC, SWARM_STATE_TYPE, typestore
    from ..conversions import swarm_state_arrays

    info.topic(SWARM_STATE_TOPIC)  # CliError naming the topic when the bag has none
    store = typestore()
    for _topic, _type, ts, raw in iter_raw(info.path, [SWARM_STATE_TOPIC], info=info):
        yield ts, swarm_state_arrays(store.deserialize_cdr(raw, SWARM_STATE_TYPE))


def live_view_of_bag(
    info: Any, *, host: str, port: int
) -> tuple[LiveView, Callable[[str, bytes], None]]:
    """A live view of a bag being played (``apf-swarm bag play --view``) and the observer to
    hand each played message to: it keeps the newest ``/swarm/state``, which the view shows
    (decoded only while a client watches)."""
    from apf_swarm_core.formation import design_pair_sets

    from ..analysis.samples import RawSample
    from ..bags import bag_config
    from ..bags.types import SWARM_STATE_TOPIC, SWARM_STATE_TYPE, typestore
    from ..conversions import swarm_state_step

    cfg, _mode = bag_config(info)
    store = typestore()
    view = LiveView(host=host, port=port, designs=design_pair_sets(cfg))
    newest: list[Any] = [None]

    def decode(raw: bytes) -> Any:
        return store.deserialize_cdr(raw, SWARM_STATE_TYPE)

    def observe(topic: str, raw: bytes) -> None:
        if topic == SWARM_STATE_TOPIC:
            newest[0] = RawSample(swarm_state_step(raw), raw, decode)

    view.follow(lambda: None if newest[0] is None else newest[0].sample)
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
    before playing, so the run is seen from its start; ``loop``: play again until ``stop``
    is set (or Ctrl-C)."""
    from apf_swarm_core.formation import design_pair_sets

    from ..bags import bag_config, open_bag

    info = open_bag(path)
    cfg, _mode = bag_config(info, config)
    samples = list(bag_samples(info))
    stop = stop or threading.Event()
    view = LiveView(host=host, port=port, designs=design_pair_sets(cfg))
    try:
        say(f'serving {view.url} (Foxglove: Open connection, Foxglove WebSocket)')
        if not samples:
            say(f'{info.path}: /swarm/state has no message; nothing to show')
            return 0
        deadline = None if wait_client is None else time.monotonic() + wait_client
        if not view.watched():
            say('waiting for a client to subscribe')
        while not view.watched():
            if stop.wait(0.05) or (deadline is not None and time.monotonic() > deadline):
                return 0
        while True:
            _play(view, samples, rate, stop)
            if not loop or stop.is_set():
                break
        return view.frames
    finally:
        view.close()


def _play(view: LiveView, samples: list[tuple[int, Any]], rate: float, stop: Any) -> None:
    """One pass: sample i shown at ``t0 + (ts_i - ts_0) / rate`` (an absolute schedule), at
    most :data:`VIEW_RATE` frames per second of wall time."""
    first = samples[0][0]
    t0 = time.monotonic()
    next_frame = 0.0
    for ts, sample in samples:
        due = t0 + (ts - first) / 1e9 / rate
        if due < next_frame:
            continue
        if stop.wait(max(0.0, due - time.monotonic())):
            return
        next_frame = due + 1.0 / VIEW_RATE
        view.show(sample, ts)
