"""Reading episode logs (terl_rt.logs.format), complete or cut off.

`EpisodeLogReader` lists a log's episodes and serves their steps. Where they lie is found
when the file is opened (terl_rt.logs.scan: through a complete file's summary, or record by
record in a file cut off before it, which reads back up to its last complete step and says
so in `EpisodeLogReader.problem`). Every chunk's CRC is checked then, and the steps are found
in the chunks themselves (never in the message indexes beside them, which a damaged byte can
move to another episode): an episode with a chunk that fails is listed as damaged
(`LoggedEpisode.damaged`) and reads up to that chunk, the problem says so, and the other
episodes read as they are. Anything else that does not parse is an `EpisodeLogError` naming
the byte offset and, where known, the episode and step.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from google.protobuf.message import DecodeError
from mcap.records import Channel, Message, Schema

from terl_rt.logs.format import TOPIC_ACTIONS, TOPIC_EVENTS, TOPIC_STATE, EpisodeLogError, decode
from terl_rt.logs.foxglove import scene_from_protobuf
from terl_rt.logs.scan import LogScan
from terl_rt.sim.metrics import EpisodeMetrics
from terl_rt.sim.scenario import Scenario
from terl_rt.sim.state import LOGGED_FIELDS


@dataclass(frozen=True)
class LoggedEpisode:
    """One episode of a log, as listed by `EpisodeLogReader.episodes`."""

    number: int
    """position in the file, 0-based (what `--episode` selects)."""
    index: int
    """episode index in its evaluation run (episode k ran with seed run_seed + k)."""
    seed: int
    """the Simulator seed of this episode."""
    scenario: Scenario
    steps: int
    """decision steps on disk (complete steps after the reset frame)."""
    metrics: EpisodeMetrics | None
    """final metrics; None when the episode was cut off before its end."""
    chunks: tuple[tuple[int, int], ...] = field(repr=False, default=())
    """(byte offset, record length) of the chunks that hold its steps, in file order (in a
    log as terl-rt writes it: one chunk per step, step 0 first)."""
    damaged: tuple[int, ...] = ()
    """byte offsets of its chunks that fail their CRC check or do not parse: `steps` counts
    the steps before the first, where `EpisodeLogReader.steps` stops with an EpisodeLogError."""

    @property
    def complete(self) -> bool:
        return self.metrics is not None


class LoggedStep:
    """One step of a logged episode: the raw message of each topic, decoded on demand."""

    def __init__(
        self, episode: int, step: int, time_ns: int, messages: dict[str, bytes], protobuf: frozenset[str] = frozenset(),
    ):
        self.episode = episode
        self.step = step
        self.time_ns = time_ns
        """log time of the step's messages (ns)."""
        self.messages = messages
        """topic -> message bytes (JSON, or protobuf for the topics in `protobuf`), for the
        topics present in this step."""
        self.protobuf = protobuf
        """topics whose messages are protobuf (/world from log version 2 on)."""

    def __repr__(self) -> str:
        return f"LoggedStep(episode={self.episode}, step={self.step}, topics={sorted(self.messages)})"

    def payload(self, topic: str) -> dict | None:
        """The decoded message of `topic` as a JSON object, or None when the step has none
        (/world: the same object whether the log holds it as protobuf or as JSON)."""
        data = self.messages.get(topic)
        if data is None:
            return None
        try:
            return scene_from_protobuf(data) if topic in self.protobuf else decode(data)
        except (ValueError, DecodeError) as error:
            raise EpisodeLogError(f"corrupt {topic} message of episode {self.episode} step {self.step}: {error}") from None

    @property
    def state(self) -> dict[str, np.ndarray]:
        """The world state after the step, as `Simulator.state()` (float64, bool, int64)."""
        payload = self.payload(TOPIC_STATE)
        out: dict[str, np.ndarray] = {}
        try:
            for f in LOGGED_FIELDS:
                value = np.asarray(payload[f.key], dtype=f.dtype)
                out[f.key] = value.reshape(-1, 2) if f.pairs else value
        except (KeyError, TypeError, ValueError) as error:
            raise EpisodeLogError(
                f"the /state message of episode {self.episode} step {self.step} is malformed ({error!r})"
            ) from None
        return out

    @property
    def pursuer_actions(self) -> np.ndarray | None:
        """[N] int64 fed to the simulator in this step (None at step 0)."""
        payload = self.payload(TOPIC_ACTIONS)
        return None if payload is None else np.asarray(payload["pursuer"], np.int64)

    @property
    def shield_overrode(self) -> np.ndarray | None:
        """[n] bool, one per pursuer that decided (/actions `decided`): the shield overrode its
        action in this step; None at step 0 and in logs of runs without the shield."""
        payload = self.payload(TOPIC_ACTIONS)
        if payload is None or "shield_overrode" not in payload:
            return None
        return np.asarray(payload["shield_overrode"], bool)

    @property
    def evader_actions(self) -> np.ndarray | None:
        """[M] int64 the evaders took in this step (None at step 0)."""
        payload = self.payload(TOPIC_ACTIONS)
        return None if payload is None else np.asarray(payload["evader"], np.int64)

    @property
    def events(self) -> list[dict]:
        payload = self.payload(TOPIC_EVENTS)
        return [] if payload is None else payload["events"]


class EpisodeLogReader:
    """Reads an episode log written by `EpisodeLogWriter`, complete or cut off.

    Raises EpisodeLogError for a file that is missing, not MCAP, not an episode log,
    or corrupt. A file cut off mid-write reads back up to its last complete step:
    then `truncated` is True and `problem` says what was lost.
    """

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        if not self.path.exists():
            raise FileNotFoundError(2, "no episode log at this path", str(self.path))
        if self.path.is_dir():
            raise EpisodeLogError(f"{self.path}: is a directory, not an episode log")
        if not self.path.is_file():
            raise EpisodeLogError(f"{self.path}: not a regular file (a device or a pipe), not an episode log")
        self.size = self.path.stat().st_size
        self._log = LogScan(self.path, self.size)
        with open(self.path, "rb") as handle:
            self._log.read(handle)
        self.policy: dict[str, Any] = self._log.policy
        """The policy the episodes ran: name, sha256, path, metadata."""
        self.world_version = self._log.world_version
        """terl_rt.sim.world.WORLD_VERSION of the simulator that wrote the log (logs before versions: "1")."""
        self.truncated = self._log.truncated
        """True when the file stops before its footer (cut off, or its writer never closed)."""
        self.problem: str | None = self._log.problem
        """What is wrong with the file (cut off, damaged chunks), in one sentence; None for a sound one."""
        self.channels: dict[int, Channel] = self._log.channels
        self.schemas: dict[int, Schema] = self._log.schemas
        self.indexed = self._log.indexed
        """True when the file was read through its summary (complete), False when scanned."""
        self._episodes = tuple(
            LoggedEpisode(
                number=raw["number"], index=raw["index"], seed=raw["seed"], scenario=raw["scenario"],
                steps=max(self._log.readable_steps(raw) - 1, 0), metrics=raw["metrics"], chunks=tuple(raw["chunks"]),
                damaged=tuple(raw["damaged"]),
            )
            for raw in self._log.raw_episodes
        )

    # --- listing
    @property
    def episodes(self) -> list[LoggedEpisode]:
        """Every episode in file order (the last one may be incomplete)."""
        return list(self._episodes)

    def episode(self, number: int) -> LoggedEpisode:
        """The episode at file position `number`; EpisodeLogError when there is none."""
        if not 0 <= number < len(self._episodes):
            held = f"episodes 0-{len(self._episodes) - 1}" if self._episodes else "no episode"
            raise EpisodeLogError(f"{self.path}: no episode {number}; the log holds {held}")
        return self._episodes[number]

    @property
    def topics(self) -> dict[str, str]:
        """topic -> schema name, for every channel of the log."""
        return {
            channel.topic: self.schemas[channel.schema_id].name if channel.schema_id in self.schemas else ""
            for channel in self.channels.values()
        }

    def message_counts(self) -> dict[str, int]:
        """topic -> messages on disk in complete steps (decodes every chunk)."""
        counts = {channel.topic: 0 for channel in self.channels.values()}
        for episode in self._episodes:
            for step in self.steps(episode.number):
                for topic in step.messages:
                    counts[topic] += 1
        return counts

    def shield_overrides(self, number: int) -> np.ndarray | None:
        """[N] int64: the steps of episode `number` in which the shield overrode each pursuer's
        action, counted from /actions; None for an episode run without the shield."""
        counts = None
        for step in self.steps(number):
            overrode = step.shield_overrode
            if overrode is None:
                continue
            if counts is None:
                counts = np.zeros(self.episode(number).scenario.pursuers, np.int64)
            decided = np.asarray(step.payload(TOPIC_ACTIONS)["decided"], np.int64)
            np.add.at(counts, decided[overrode], 1)
        return counts

    # --- steps
    def steps(self, number: int) -> Iterator[LoggedStep]:
        """The steps of episode `number` in order, step 0 (after reset) first."""
        episode = self.episode(number)
        if self.indexed:
            yield from self._indexed_steps(number)
            return
        with open(self.path, "rb") as handle:
            for expected, (offset, length) in enumerate(episode.chunks):
                step = self._read_step(handle, offset, length, f"episode {number}, step {expected}")
                if step.episode != number or step.step != expected:
                    raise EpisodeLogError(
                        f"{self.path}: chunk at byte {offset} holds episode {step.episode} step {step.step}, "
                        f"expected episode {number} step {expected}; the file is corrupt"
                    )
                yield step

    # --- internals
    def _protobuf_topics(self) -> frozenset[str]:
        """The topics whose channels carry protobuf (only /world is ever written so)."""
        return frozenset(c.topic for c in self.channels.values() if c.message_encoding == "protobuf")

    def _read_step(self, handle, offset: int, length: int, what: str) -> LoggedStep:
        messages: dict[str, bytes] = {}
        head: dict | None = None
        time_ns = 0
        for record in self._log.chunk_records(handle, offset, length, what):
            if not isinstance(record, Message):
                continue
            channel = self.channels.get(record.channel_id)
            if channel is None:
                raise self._log.fail(f"corrupt chunk at byte {offset} ({what}): message on unknown channel {record.channel_id}")
            messages[channel.topic] = record.data
            time_ns = record.log_time
            if channel.topic == TOPIC_STATE:
                try:
                    head = decode(record.data)
                except ValueError as error:
                    raise self._log.fail(f"corrupt /state message in the chunk at byte {offset} ({what}): {error}") from None
        if head is None:
            raise self._log.fail(f"corrupt chunk at byte {offset} ({what}): it has no /state message")
        return LoggedStep(int(head["episode"]), int(head["step"]), time_ns, messages, self._protobuf_topics())

    def _indexed_steps(self, number: int) -> Iterator[LoggedStep]:
        raw = self._log.raw_episodes[number]
        low = raw["start_ns"]
        high = self._log.raw_episodes[number + 1]["start_ns"] if number + 1 < len(self._log.raw_episodes) else None
        wanted = set(raw["times"])
        gathered: dict[int, dict[str, bytes]] = {}
        damage: EpisodeLogError | None = None
        with open(self.path, "rb") as handle:
            for offset, length in raw["chunks"]:
                what = f"episode {number}, step {len(gathered)}"
                try:
                    records = self._log.chunk_records(handle, offset, length, what)
                except EpisodeLogError as error:
                    damage = error  # the steps before it are served, then the error
                    break
                for record in records:
                    if not isinstance(record, Message) or record.log_time < low:
                        continue
                    if (high is not None and record.log_time >= high) or record.log_time not in wanted:
                        continue
                    channel = self.channels.get(record.channel_id)
                    if channel is None:
                        raise self._log.fail(f"corrupt chunk at byte {offset} ({what}): message on unknown channel {record.channel_id}")
                    gathered.setdefault(record.log_time, {})[channel.topic] = record.data
        for expected, time_ns in enumerate(sorted(gathered)):
            messages = gathered[time_ns]
            try:
                head = decode(messages[TOPIC_STATE])
                step = LoggedStep(int(head["episode"]), int(head["step"]), time_ns, messages, self._protobuf_topics())
            except (KeyError, ValueError, TypeError) as error:
                raise self._log.fail(f"the /state message of episode {number} at log time {time_ns} is corrupt ({error!r})") from None
            if step.episode != number or step.step != expected:
                raise self._log.fail(
                    f"log time {time_ns} holds episode {step.episode} step {step.step}, "
                    f"expected episode {number} step {expected}; the file is corrupt"
                )
            yield step
        if damage is not None:
            raise damage
