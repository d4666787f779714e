"""A minimal client of Foxglove's WebSocket protocol (v1, foxglove/ws-protocol docs/spec.md), as
the Foxglove app speaks it, for the tests of the live view: it keeps the channels the server
advertises, subscribes to topics and collects their message-data frames, all read by a thread
of its own. Nothing waits fixed times: `wait_for` polls a condition up to a generous deadline."""

from __future__ import annotations

import json
import socket
import struct
import threading
import time
from collections import defaultdict
from collections.abc import Callable
from contextlib import ExitStack

from websockets.exceptions import ConnectionClosed
from websockets.sync.client import ClientConnection, connect

SUBPROTOCOLS = ["foxglove.sdk.v1", "foxglove.websocket.v1"]
"""The protocol's names: the SDK's server (0.30) accepts only the first, the same protocol
under its new name; older servers the second."""
MESSAGE_DATA = 0x01
"""Opcode of a binary message-data frame: u32 subscription id, u64 log time (ns), payload."""
DEADLINE_S = 60.0
"""s: how long a condition may take before the test fails (a loaded CI machine is slow)."""


def wait_for(condition: Callable[[], bool], what: str, deadline_s: float = DEADLINE_S) -> None:
    """Poll `condition` until it holds; AssertionError naming `what` after `deadline_s`."""
    end = time.monotonic() + deadline_s
    while not condition():
        if time.monotonic() > end:
            raise AssertionError(f"waited {deadline_s:g} s for {what}")
        time.sleep(0.005)


class FoxgloveClient:
    """Connected to the server at `url` (ws://HOST:PORT); `reading=False` never reads a frame
    after the handshake (a client that stalls: the server's queue for it fills up)."""

    def __init__(self, url: str, reading: bool = True, receive_buffer: int | None = None):
        host, port = url.removeprefix("ws://").rsplit(":", 1)
        sock = socket.create_connection((host.strip("[]"), int(port)))
        if receive_buffer is not None:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, receive_buffer)
        self._open = ExitStack()
        self.connection: ClientConnection = self._open.enter_context(
            connect(url, sock=sock, subprotocols=SUBPROTOCOLS, max_queue=1))
        self.channels: dict[str, dict] = {}
        """topic -> the channel the server advertised for it (id, encoding, schemaName, schema)."""
        self.received: dict[str, list[tuple[int, bytes]]] = defaultdict(list)
        """topic -> (log time in ns, payload) of each message, in arrival order."""
        self.closed = threading.Event()
        self._topics: dict[int, str] = {}
        self._thread = threading.Thread(target=self._read, daemon=True)
        if reading:
            self._thread.start()
        else:  # the advertise message still has to be read to subscribe
            while not self.channels:
                self._handle(self.connection.recv(timeout=DEADLINE_S))

    def _read(self) -> None:
        try:
            for frame in self.connection:
                self._handle(frame)
        except (ConnectionClosed, OSError):
            pass
        finally:
            self.closed.set()

    def _handle(self, frame: str | bytes) -> None:
        if isinstance(frame, str):
            message = json.loads(frame)
            if message["op"] == "advertise":
                self.channels.update({channel["topic"]: channel for channel in message["channels"]})
        elif frame[0] == MESSAGE_DATA:
            subscription, time_ns = struct.unpack_from("<IQ", frame, 1)
            self.received[self._topics[subscription]].append((time_ns, bytes(frame[13:])))

    def subscribe(self, *topics: str) -> None:
        """Subscribe to `topics`, once the server has advertised them."""
        wait_for(lambda: all(topic in self.channels for topic in topics), f"the server to advertise {topics}")
        subscriptions = []
        for topic in topics:
            number = len(self._topics) + 1
            self._topics[number] = topic
            subscriptions.append({"id": number, "channelId": self.channels[topic]["id"]})
        self.connection.send(json.dumps({"op": "subscribe", "subscriptions": subscriptions}))

    def vanish(self) -> None:
        """Drop the connection without the closing handshake, as a killed viewer does."""
        self.connection.socket.shutdown(socket.SHUT_RDWR)
        self.connection.socket.close()

    def close(self) -> None:
        self._open.close()
