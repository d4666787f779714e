"""The live view: a run's steps served to Foxglove as they are taken, through the Foxglove
SDK's WebSocket server (the `live` extra), on the log's topics with the log's schemas and
encodings (terl_rt.logs.format), built as the log's writer builds them (terl_rt.logs.steps):
what Foxglove shows of a log, the layout of `terl-rt layout` shows live.

`LiveSink` is a step sink (terl_rt.logs.sink) for `terl_rt.evaluate(log=...)`; `stream_log`
sends a recorded log through one at its log times, at real time or faster.

Threads and backpressure: `write_step` builds the step's messages in the run's thread and
hands them to the SDK, which queues them for each subscribed client (at most `backlog`
messages: a client that reads slower loses the oldest) and sends them from threads of its
own. Nothing waits on a client, so a slow client, or one that vanishes, never holds the run
back or fails it, and `close` waits for one at most STOP_WAIT_S. /world, Foxglove's 3-D
scene and most of a step's building time, is built only while a client subscribes to it;
the first scene built in an episode, at its step 0 or when a client subscribes later,
deletes every entity first (what a viewer still shows of an earlier episode).

With workers or on Ray the steps come back to the process that runs the evaluation, which
gives them to every sink in episode order (terl_rt.evaluation.runs): the live view shows one
episode after another, as the log holds them, never the episodes running side by side.
"""

from __future__ import annotations

import re
import threading
import time
from collections.abc import Iterable
from typing import Any

from terl_rt.extras import install_hint
from terl_rt.logs.format import SCHEMAS, TOPIC_WORLD, StepRecord
from terl_rt.logs.foxglove import scene_protobuf
from terl_rt.logs.reader import EpisodeLogReader
from terl_rt.logs.steps import OpenEpisode
from terl_rt.sim.metrics import EpisodeMetrics
from terl_rt.sim.scenario import Scenario

DEFAULT_HOST = "127.0.0.1"
"""The interface served unless another is named: this machine alone."""
DEFAULT_PORT = 8765
"""Foxglove's default port for a WebSocket connection."""
DEFAULT_BACKLOG = 1024
"""Messages queued for each client at most (the SDK's default); a slow client loses the oldest."""
LIVE_INSTALL = install_hint("live")
WATCH_POLL_S = 0.05
"""s: how often `wait_watched` looks for a subscribed client."""
FLUSH_S = 0.25
"""s: how long `close` leaves the SDK to send what it has queued for subscribed clients before
it stops the server (the SDK's stop drops what is still queued: closed at once, one server
in five lost the last ten messages it was given)."""
STOP_WAIT_S = 2.0
"""s: how long `close` waits for the server to see its clients off. The SDK's stop waits until
each client's connection takes its goodbye, which that of a client that reads nothing (a
frozen viewer) never does: past this, the connection is left to end with the process (the
server takes no new client from the start of the stop)."""


class LiveMissing(ImportError):
    """A live view was asked for and the Foxglove SDK is not installed; the message says how to install it."""


class LiveServerError(OSError):
    """The live view's server cannot start (the port is taken, the host unknown); the message says which."""


def parse_address(text: str) -> tuple[str, int]:
    """(host, port) of "HOST:PORT", "[IPV6]:PORT" or "PORT" (on DEFAULT_HOST); port 0 takes
    any free one. ValueError for anything else."""
    match = re.fullmatch(r"(?:(\[[0-9A-Fa-f:.]+\]|[^\s:\[\]]+):)?(\d{1,5})", text.strip())
    if match is None or int(match[2]) > 65535:
        raise ValueError(f"{text!r} is no HOST:PORT (e.g. {DEFAULT_HOST}:{DEFAULT_PORT}, or a port alone)")
    return (match[1] or DEFAULT_HOST).strip("[]"), int(match[2])


def _sdk() -> Any:
    """The Foxglove SDK module; LiveMissing without it."""
    try:
        import foxglove
    except ImportError as error:
        if error.name != "foxglove":
            raise
        raise LiveMissing(f"the live view needs the Foxglove SDK, which is not installed; install it with: {LIVE_INSTALL}") from None
    return foxglove


class LiveSink:
    """A Foxglove WebSocket server on `host`:`port` (port 0: any free one, `port` tells which)
    serving the log's topics, and a step sink that sends every step to it (see the module
    docstring). backlog: messages queued for each client at most. Close it (or use a `with`
    block) to stop the server."""

    def __init__(self, host: str = DEFAULT_HOST, port: int = DEFAULT_PORT, backlog: int = DEFAULT_BACKLOG):
        foxglove = _sdk()
        self.host = host
        """the interface served."""
        self._context = foxglove.Context()  # the server sees this sink's channels alone
        try:
            self._server = foxglove.start_server(
                name="terl-rt", host=host, port=port, context=self._context, message_backlog_size=backlog,
            )
        except RuntimeError as error:  # the SDK's FoxgloveError: "Failed to bind port: ..."
            reason = str(error).removeprefix("FoxgloveError: ")
            raise LiveServerError(f"cannot serve the live view on {host}:{port}: {reason}") from None
        self.port: int = self._server.port
        """the port served (the one taken, when asked for port 0)."""
        self.app_url: str | None = self._server.app_url()
        """the Foxglove app's address that opens this server as its data source."""
        self._channels = {
            topic: foxglove.Channel(
                topic, schema=foxglove.Schema(name=schema.name, encoding=schema.encoding, data=schema.data),
                message_encoding=schema.message_encoding, context=self._context,
            )
            for topic, schema in SCHEMAS.items()
        }
        self._episode: OpenEpisode | None = None
        self._episodes = 0
        self._next_offset_ns = 0
        self._closed = False

    def __enter__(self) -> LiveSink:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    @property
    def url(self) -> str:
        """ws://HOST:PORT, what Foxglove's "Open connection" takes."""
        return f"ws://{f'[{self.host}]' if ':' in self.host else self.host}:{self.port}"

    def watched(self, topic: str = TOPIC_WORLD) -> bool:
        """Whether a client subscribes to `topic` now."""
        return self._channels[topic].has_sinks()

    def wait_watched(self, topic: str = TOPIC_WORLD) -> None:
        """Wait until a client subscribes to `topic` (Ctrl-C stops the wait)."""
        while not self.watched(topic):
            time.sleep(WATCH_POLL_S)

    def publish(self, topic: str, data: bytes, time_ns: int) -> None:
        """Send a message of one of the log's topics, encoded as the log holds it, with log
        time `time_ns` (ns); a topic the log does not have is left out."""
        channel = self._channels.get(topic)
        if channel is not None:
            channel.log(data, log_time=time_ns)

    # --- the step sink

    def begin_episode(self, scenario: Scenario, seed: int, index: int) -> int:
        """Start an episode; returns its number in this sink (as a log numbers it)."""
        if self._episode is not None:
            raise RuntimeError(f"begin_episode: episode {self._episode.number} has not ended")
        self._episode = OpenEpisode(self._episodes, scenario, self._next_offset_ns)
        self._episodes += 1
        return self._episode.number

    def write_step(self, record: StepRecord) -> None:
        """Send one step (its /world scene only while a client subscribes to it)."""
        episode = self._episode
        if episode is None:
            raise RuntimeError("write_step: call begin_episode first")
        step = episode.messages(record, scenes=self.watched(TOPIC_WORLD))
        episode.last_ns = step.time_ns
        for topic, data in step.messages:
            self.publish(topic, data, step.time_ns)
        if step.scene_ids is not None:
            episode.scene_ids = step.scene_ids

    def end_episode(self, metrics: EpisodeMetrics) -> None:
        """The episode has ended; the next one starts a second of log time later."""
        self._leave("end_episode")

    def abandon_episode(self) -> None:
        """The run stopped before the episode ended; the next one may begin."""
        self._leave("abandon_episode")

    def close(self) -> None:
        """Stop the server, FLUSH_S after the last message when a client subscribes: it then
        takes no new client, and its clients are disconnected within STOP_WAIT_S (see there).
        Closing again does nothing."""
        if self._closed:
            return
        self._closed = True
        if any(channel.has_sinks() for channel in self._channels.values()):
            time.sleep(FLUSH_S)
        stopping = threading.Thread(target=self._server.stop, name="live-view-stop", daemon=True)
        stopping.start()
        stopping.join(STOP_WAIT_S)
        for channel in self._channels.values():
            channel.close()

    def _leave(self, call: str) -> None:
        episode = self._episode
        if episode is None:
            raise RuntimeError(f"{call}: no episode is open")
        self._next_offset_ns = episode.next_offset_ns
        self._episode = None


def stream_log(reader: EpisodeLogReader, sink: LiveSink, episodes: Iterable[int], rate: float = 1.0) -> int:
    """Send the steps of `episodes` (file-order numbers) of the log to `sink`, each when its
    log time has come: log time / `rate` after the first step's (1: real time, 2: twice as
    fast). A /world scene of a version-1 log (JSON) goes as protobuf, as the live channel
    says. Returns the steps sent."""
    if not rate > 0:
        raise ValueError(f"rate must be positive, got {rate!r}")
    start: tuple[float, int] | None = None
    sent = 0
    for number in episodes:
        for step in reader.steps(number):
            if start is None:
                start = (time.monotonic(), step.time_ns)
            wait = start[0] + (step.time_ns - start[1]) / 1e9 / rate - time.monotonic()
            if wait > 0:
                time.sleep(wait)
            for topic, data in step.messages.items():
                if topic == TOPIC_WORLD and topic not in step.protobuf:
                    data = scene_protobuf(step.payload(topic))
                sink.publish(topic, data, step.time_ns)
            sent += 1
    return sent
