"""Fixtures shared by the unit and the integration tests."""

from __future__ import annotations

import base64
import json
import struct
import time
from collections.abc import Callable, Iterator
from typing import Any

import pytest

SUBPROTOCOL = 'foxglove.sdk.v1'


class Client:
    """The client side of the Foxglove WebSocket protocol: advertise, subscribe, decode."""

    def __init__(self, url: str, timeout: float = 10.0) -> None:
        from websockets.sync.client import connect

        self._conn: Any = connect(url, subprotocols=[SUBPROTOCOL], open_timeout=timeout)
        self.ws = self._conn.__enter__()
        self.channels: dict[str, dict[str, Any]] = {}
        self.info: dict[str, Any] = {}
        deadline = time.monotonic() + timeout
        while len(self.channels) < 3 and time.monotonic() < deadline:
            msg = json.loads(self.ws.recv(timeout=max(0.01, deadline - time.monotonic())))
            if msg['op'] == 'serverInfo':
                self.info = msg
            elif msg['op'] == 'advertise':
                self.channels.update({c['topic']: c for c in msg['channels']})
        if len(self.channels) < 3:
            self.close()
            raise AssertionError(f'{url} advertised {sorted(self.channels)} within {timeout} s')
        self.subs: dict[int, str] = {}

    def subscribe(self, *topics: str) -> None:
        subs = []
        for k, topic in enumerate(topics, start=len(self.subs) + 1):
            self.subs[k] = topic
            subs.append({'id': k, 'channelId': self.channels[topic]['id']})
        self.ws.send(json.dumps({'op': 'subscribe', 'subscriptions': subs}))

    def decoder(self, topic: str) -> Any:
        from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

        c = self.channels[topic]
        fds = descriptor_pb2.FileDescriptorSet.FromString(base64.b64decode(c['schema']))
        pool = descriptor_pool.DescriptorPool()
        for f in fds.file:
            pool.Add(f)
        return message_factory.GetMessageClass(pool.FindMessageTypeByName(c['schemaName']))

    def messages(self, timeout: float) -> Iterator[tuple[str, int, bytes]]:
        """``(topic, log_time_ns, payload)`` of each message data frame until ``timeout``."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            from websockets.exceptions import ConnectionClosed

            try:
                m = self.ws.recv(timeout=max(0.01, deadline - time.monotonic()))
            except (TimeoutError, ConnectionClosed):
                return
            if isinstance(m, bytes) and m[0] == 1:
                sub, ts = struct.unpack_from('<IQ', m, 1)
                yield self.subs[sub], ts, m[13:]

    def close(self) -> None:
        if self._conn is not None:
            self._conn.__exit__(None, None, None)
            self._conn = None


@pytest.fixture
def foxglove_client() -> Iterator[Callable[[str], Client]]:
    """Opens :class:`Client` connections to a Foxglove WebSocket server; every one is
    closed after the test, passed or failed."""
    opened: list[Client] = []

    def connect(url: str, timeout: float = 10.0) -> Client:
        opened.append(Client(url, timeout))
        return opened[-1]

    yield connect
    for c in opened:
        c.close()
