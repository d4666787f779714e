"""MCAP episode logs: every step of evaluated episodes, for Foxglove and for bit-exact replay.

Layout of a log (MCAP, one zstd chunk per step):

    Header
    Metadata "terl.log"           format version, policy name, sha256, path and metadata
    per episode, in order:
      Metadata "terl.episode"     file-order number, run index, seed, scenario JSON
      Chunk step 0                the state after reset: /world, /state
      Chunk step t = 1, 2, ...    /world, /actions, /target_weights, /rewards, [/events], /state
      Metadata "terl.episode_end" final metrics (missing when the run was interrupted)
    DataEnd, summary (schemas, channels, statistics, indexes), Footer, magic

Topics (JSON messages; log time = episode start + step * 0.5 s, in ns):

- `/world`: foxglove.SceneUpdate (terl_rt.logs.foxglove), the whole scene of the step;
- `/state`: the world's public state (`terl_rt.sim.state.LOGGED_FIELDS`: `Simulator.state()`
  less the derived `pursuer_collided`), floats written with Python's repr, so they read
  back exactly;
- `/actions`: the [N] pursuer action indices fed to the simulator for this step
  (0 for collided pursuers), which pursuers decided, and the [M] evader actions;
- `/target_weights`: [n, E] target weights of the n deciding pursuers (policies with
  target selection only);
- `/rewards`: [N] rewards and their terms;
- `/events`: captures, collisions and the episode's end, in steps that have any.

Interrupted runs: the writer flushes after every step, and a step lives in one chunk,
so everything up to the last complete step is on disk whatever happens next (Ctrl-C,
a crash, a kill). The reader scans the file record by record; a file that stops
inside a record, or without its footer, reads back up to the last complete step and
says so (`EpisodeLogReader.problem`). Anything else that does not parse is an
`EpisodeLogError` naming the byte offset and, where known, the episode and step.
"""

from __future__ import annotations

import importlib.metadata
import io
import json
import os
import signal
import struct
import threading
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, Message, Metadata, Schema
from mcap.stream_reader import breakup_chunk
from mcap.writer import CompressionType, Writer

from terl_rt.logs.foxglove import SCENE_UPDATE, SCENE_UPDATE_SCHEMA, scene_update
from terl_rt.sim.metrics import EpisodeMetrics
from terl_rt.sim.reward import REWARD_TERMS
from terl_rt.sim.scenario import Scenario, ScenarioError
from terl_rt.sim.simulator import StepInfo
from terl_rt.sim.state import LOGGED_FIELDS
from terl_rt.sim.world import WORLD_VERSION

LOG_FORMAT = "terl-rt episode log"
LOG_VERSION = "1"
"""Version of the layout above; readers refuse other versions."""

META_LOG = "terl.log"
META_EPISODE = "terl.episode"
META_EPISODE_END = "terl.episode_end"

TOPIC_WORLD = "/world"
TOPIC_STATE = "/state"
TOPIC_ACTIONS = "/actions"
TOPIC_TARGET_WEIGHTS = "/target_weights"
TOPIC_REWARDS = "/rewards"
TOPIC_EVENTS = "/events"

_GAP_NS = 1_000_000_000
"""Log time left between the last step of an episode and the next episode's start."""
_MAGIC = b"\x89MCAP0\r\n"
_RECORD_HEAD = struct.Struct("<BQ")
_NO_CHUNK_LIMIT = 1 << 40
"""Chunk size the writer never reaches: chunks end only where a step ends."""


class EpisodeLogError(ValueError):
    """A file that is not a readable episode log; the message names the file and the problem."""


def _version() -> str:
    try:
        return importlib.metadata.version("terl-rt")
    except importlib.metadata.PackageNotFoundError:
        return "unknown"


def _dumps(payload: Any) -> bytes:
    return json.dumps(payload, separators=(",", ":")).encode()


def _object_schema(title: str, description: str, properties: Mapping[str, Any]) -> bytes:
    return _dumps({"title": title, "description": description, "type": "object", "properties": dict(properties)})


_NUMBERS = {"type": "array", "items": {"type": "number"}}
_INTEGERS = {"type": "array", "items": {"type": "integer"}}
_HEAD = {"episode": {"type": "integer"}, "step": {"type": "integer"}}
_SCHEMAS: dict[str, tuple[str, bytes]] = {
    TOPIC_WORLD: (SCENE_UPDATE, _dumps(SCENE_UPDATE_SCHEMA)),
    TOPIC_STATE: ("terl.State", _object_schema(
        "terl.State", "Full world state after the step (m, rad, m/s); floats are exact float64 reprs",
        {**_HEAD, **{f.key: {"type": "array"} for f in LOGGED_FIELDS if f.key not in _HEAD}},
    )),
    TOPIC_ACTIONS: ("terl.Actions", _object_schema(
        "terl.Actions", "Actions of the step: pursuer [N] as fed to the simulator, evader [M]",
        {**_HEAD, "pursuer": _INTEGERS, "decided": _INTEGERS, "evader": _INTEGERS},
    )),
    TOPIC_TARGET_WEIGHTS: ("terl.TargetWeights", _object_schema(
        "terl.TargetWeights", "Target weights [n, E] of the pursuers that decided the step",
        {**_HEAD, "pursuer": _INTEGERS, "weights": {"type": "array", "items": _NUMBERS}},
    )),
    TOPIC_REWARDS: ("terl.Rewards", _object_schema(
        "terl.Rewards", "Reward [N] of each pursuer in the step and its terms",
        {**_HEAD, "total": _NUMBERS, "terms": {"type": "object", "properties": {t: _NUMBERS for t in REWARD_TERMS}}},
    )),
    TOPIC_EVENTS: ("terl.Events", _object_schema(
        "terl.Events", "Captures, collisions and the episode end in the step",
        {**_HEAD, "events": {"type": "array", "items": {"type": "object"}}},
    )),
}
TOPICS: tuple[str, ...] = tuple(_SCHEMAS)
"""Every topic of a log."""


@dataclass(frozen=True)
class StepRecord:
    """What the log keeps of one step; step 0 is the state after reset (no actions)."""

    step: int
    state: dict[str, np.ndarray]
    """`Simulator.state()` after the step."""
    pursuer_actions: np.ndarray | None = None
    """[N] int64 fed to `Simulator.step` (None at step 0)."""
    decided: np.ndarray | None = None
    """[n] int64: pursuers that chose an action (the active ones)."""
    target_weights: np.ndarray | None = None
    """[n, E] float32 of the deciding pursuers, or None."""
    info: StepInfo | None = None
    """What the step did (None at step 0)."""


def policy_info(policy) -> dict[str, Any]:
    """The facts a log keeps about an `OnnxPolicy`: name, sha256, path, metadata."""
    return {
        "name": policy.name,
        "sha256": policy.sha256,
        "path": str(policy.path),
        "metadata": dict(policy.metadata),
    }


# --- writing --------------------------------------------------------------------------


@contextmanager
def _sigint_deferred() -> Iterator[None]:
    """Hold back Ctrl-C (SIGINT) inside the block and deliver it at its end (main thread only)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    received: list[int] = []
    previous = signal.signal(signal.SIGINT, lambda signum, frame: received.append(signum))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
        if received and previous is not signal.SIG_IGN:
            if callable(previous):
                previous(signal.SIGINT, None)
            else:
                raise KeyboardInterrupt


@dataclass
class _OpenEpisode:
    number: int
    scenario: Scenario
    offset_ns: int
    step_ns: int
    last_ns: int


def _events(record: StepRecord) -> list[dict]:
    info = record.info
    events: list[dict] = []
    for j in np.flatnonzero(info.captured).tolist():
        events.append({"type": "capture", "evader": j, "pursuers": np.flatnonzero(info.pursuer_target == j).tolist()})
    for i in np.flatnonzero(info.collided).tolist():
        events.append({"type": "collision", "pursuer": i})
    if info.terminated or info.truncated:
        success = not bool(record.state["evader_active"].any())
        events.append({
            "type": "episode_end", "success": success,
            "terminated": info.terminated, "truncated": info.truncated,
        })
    return events


def _state_payload(number: int, state: Mapping[str, np.ndarray]) -> dict:
    payload: dict[str, Any] = {"episode": number}
    for f in LOGGED_FIELDS:
        payload[f.key] = np.asarray(state[f.key]).tolist()
    return payload


class EpisodeLogWriter:
    """Writes episodes to an MCAP log at `path` (replaced if it exists).

    policy_info: `policy_info(policy)`, or a mapping with at least name and sha256.
    Call `begin_episode`, then `write_step` for step 0 (after reset) and every step,
    then `end_episode`; `close()` (or a `with` block) writes the summary. Each step is
    on disk when `write_step` returns.
    """

    def __init__(self, path: str | os.PathLike, policy_info: Mapping[str, Any]):
        for key in ("name", "sha256"):
            if key not in policy_info:
                raise ValueError(f"policy_info lacks {key!r}; build it with terl_rt.logs.episode_log.policy_info(policy)")
        self.path = Path(path)
        self._file = open(self.path, "wb")
        self._mcap = Writer(self._file, chunk_size=_NO_CHUNK_LIMIT, compression=CompressionType.ZSTD)
        self._mcap.start(profile="", library=f"terl-rt {_version()}")
        self._channels: dict[str, int] = {}
        self._sequence: dict[str, int] = {}
        for topic, (name, schema) in _SCHEMAS.items():
            schema_id = self._mcap.register_schema(name=name, encoding="jsonschema", data=schema)
            self._channels[topic] = self._mcap.register_channel(topic=topic, message_encoding="json", schema_id=schema_id)
            self._sequence[topic] = 0
        self._policy = {"policy": str(policy_info["name"]), "policy_sha256": str(policy_info["sha256"])}
        self._mcap.add_metadata(META_LOG, {
            "format": LOG_FORMAT,
            "version": LOG_VERSION,
            "world": WORLD_VERSION,
            "terl_rt": _version(),
            **self._policy,
            "policy_path": str(policy_info.get("path", "")),
            "policy_metadata": json.dumps(dict(policy_info.get("metadata", {}))),
        })
        self._mcap.flush()
        self._episode: _OpenEpisode | None = None
        self._episodes = 0
        self._next_offset_ns = 0
        self._step_pending = False
        self._closed = False

    def __enter__(self) -> EpisodeLogWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    @property
    def episodes_written(self) -> int:
        """Episodes begun so far (their file-order numbers are 0 .. episodes_written - 1)."""
        return self._episodes

    def begin_episode(self, scenario: Scenario, seed: int, index: int) -> int:
        """Start an episode of `scenario` run as `Simulator(scenario, seed=seed)`, number
        `index` in its evaluation. Returns its number in the file."""
        self._check_open()
        if self._episode is not None:
            raise RuntimeError(f"begin_episode: episode {self._episode.number} has not ended")
        number = self._episodes
        self._episodes += 1
        params = scenario.params
        step_ns = int(round(params.dt * params.substeps * 1e9))
        self._episode = _OpenEpisode(number, scenario, self._next_offset_ns, step_ns, self._next_offset_ns)
        self._mcap.add_metadata(META_EPISODE, {
            "episode": str(number),
            "index": str(int(index)),
            "seed": str(int(seed)),
            "scenario": json.dumps(scenario.to_dict()),
            "start_time_ns": str(self._next_offset_ns),
            **self._policy,
        })
        self._mcap.flush()
        return number

    def write_step(self, record: StepRecord) -> None:
        """Write one step as one chunk and flush it to the file."""
        self._check_open()
        episode = self._episode
        if episode is None:
            raise RuntimeError("write_step: call begin_episode first")
        time_ns = episode.offset_ns + record.step * episode.step_ns
        episode.last_ns = time_ns
        head = {"episode": episode.number, "step": record.step}
        state = record.state
        params = episode.scenario.params
        status = (
            f"{episode.scenario.name}  episode {episode.number}  step {record.step}  "
            f"t={record.step * episode.step_ns / 1e9:g} s  "
            f"encircled {int((~state['evader_active']).sum())}/{len(state['evader_active'])}  "
            f"collided {int((~state['pursuer_active']).sum())}/{len(state['pursuer_active'])}"
        )
        messages = [(TOPIC_WORLD, scene_update(
            state, episode.scenario.arena, time_ns, params.robot_radius, params.vortex_core_radius, status,
        ))]
        info = record.info
        if info is not None:
            messages.append((TOPIC_ACTIONS, {
                **head,
                "pursuer": np.asarray(record.pursuer_actions).tolist(),
                "decided": np.asarray(record.decided).tolist(),
                "evader": info.evader_actions.tolist(),
            }))
            if record.target_weights is not None:
                messages.append((TOPIC_TARGET_WEIGHTS, {
                    **head,
                    "pursuer": np.asarray(record.decided).tolist(),
                    "weights": np.asarray(record.target_weights).tolist(),
                }))
            messages.append((TOPIC_REWARDS, {
                **head,
                "total": info.reward.tolist(),
                "terms": {name: values.tolist() for name, values in info.reward_terms.items()},
            }))
            events = _events(record)
            if events:
                messages.append((TOPIC_EVENTS, {**head, "events": events}))
        # /state last: its presence marks the step as complete for readers of other tools.
        messages.append((TOPIC_STATE, _state_payload(episode.number, state)))
        encoded = [(topic, _dumps(payload)) for topic, payload in messages]

        # From the first message to the flush the step is half in the chunk buffer: Ctrl-C
        # waits until the step is on disk, and any other interruption keeps close() from
        # writing the half step out.
        with _sigint_deferred():
            self._step_pending = True
            for topic, data in encoded:
                self._mcap.add_message(
                    channel_id=self._channels[topic], log_time=time_ns, publish_time=time_ns,
                    data=data, sequence=self._sequence[topic],
                )
                self._sequence[topic] += 1
            self._mcap.flush()
            self._step_pending = False

    def end_episode(self, metrics: EpisodeMetrics) -> None:
        """Close the current episode with its final metrics."""
        self._check_open()
        episode = self._episode
        if episode is None:
            raise RuntimeError("end_episode: no episode is open")
        self._mcap.add_metadata(META_EPISODE_END, {
            "episode": str(episode.number),
            "steps": str(metrics.steps),
            "metrics": json.dumps(metrics.to_dict()),
        })
        self._mcap.flush()
        self._next_offset_ns = episode.last_ns + _GAP_NS
        self._episode = None

    def close(self) -> None:
        """Write the summary and footer and close the file (an open episode stays unended).

        After a step interrupted half-way (Ctrl-C inside `write_step`) the summary is left
        out, so that half step never reaches the file: readers then stop at the last
        complete step and report the file as cut off.
        """
        if self._closed:
            return
        self._closed = True
        try:
            if not self._step_pending:
                self._mcap.finish()
        finally:
            self._file.close()

    def _check_open(self) -> None:
        if self._closed:
            raise RuntimeError(f"{self.path}: the log writer is closed")


# --- reading --------------------------------------------------------------------------


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
    """(byte offset, record length) of each complete step chunk, step 0 first."""

    @property
    def complete(self) -> bool:
        return self.metrics is not None


class LoggedStep:
    """One step of a logged episode: the raw JSON of each topic, decoded on demand."""

    def __init__(self, episode: int, step: int, time_ns: int, messages: dict[str, bytes]):
        self.episode = episode
        self.step = step
        self.time_ns = time_ns
        """log time of the step's messages (ns)."""
        self.messages = messages
        """topic -> JSON bytes, for the topics present in this step."""

    def __repr__(self) -> str:
        return f"LoggedStep(episode={self.episode}, step={self.step}, topics={sorted(self.messages)})"

    def payload(self, topic: str) -> dict | None:
        """The decoded message of `topic`, or None when the step has none."""
        data = self.messages.get(topic)
        return None if data is None else json.loads(data)

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
        self.size = self.path.stat().st_size
        self.policy: dict[str, Any] = {}
        """The policy the episodes ran: name, sha256, path, metadata."""
        self.world_version = "1"
        """terl_rt.sim.world.WORLD_VERSION of the simulator that wrote the log (logs before versions: "1")."""
        self.truncated = False
        """True when the file stops before its footer (cut off, or its writer never closed)."""
        self.problem: str | None = None
        """What is wrong with a truncated file, in one sentence; None for a whole file."""
        self.channels: dict[int, Channel] = {}
        self.schemas: dict[int, Schema] = {}
        self._scanned: list[dict] = []
        with open(self.path, "rb") as handle:
            self._scan(handle)
        self._episodes = tuple(
            LoggedEpisode(
                number=raw["number"], index=raw["index"], seed=raw["seed"], scenario=raw["scenario"],
                steps=max(len(raw["chunks"]) - 1, 0), metrics=raw["metrics"], chunks=tuple(raw["chunks"]),
            )
            for raw in self._scanned
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

    # --- steps
    def steps(self, number: int) -> Iterator[LoggedStep]:
        """The steps of episode `number` in order, step 0 (after reset) first."""
        episode = self.episode(number)
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
    def _fail(self, message: str) -> EpisodeLogError:
        return EpisodeLogError(f"{self.path}: {message}")

    def _cut(self, what: str) -> None:
        self.truncated = True
        if not self._scanned:
            kept = "no episode had begun"
        else:
            last = self._scanned[-1]
            if last["chunks"]:
                kept = f"the last complete step is episode {last['number']} step {len(last['chunks']) - 1}"
            else:
                kept = f"episode {last['number']} has no complete step"
        self.problem = f"the file was cut off ({what}); {kept}"

    def _scan(self, handle) -> None:
        head = handle.read(len(_MAGIC))
        if len(head) == 0:
            raise self._fail("the file is empty, not an episode log")
        if head != _MAGIC[: len(head)]:
            raise self._fail("not an MCAP file (it does not start with the MCAP magic bytes)")
        if len(head) < len(_MAGIC):
            raise self._fail(f"the file was cut off inside the MCAP magic ({self.size} bytes); nothing to read")
        offset = len(_MAGIC)
        first = True
        while True:
            if offset == self.size:
                self._cut("it ends after a whole record but without the MCAP footer: its writer was never closed")
                break
            record_head = handle.read(_RECORD_HEAD.size)
            if len(record_head) < _RECORD_HEAD.size:
                self._cut(f"{self.size} bytes, inside the header of a record that starts at byte {offset}")
                break
            opcode, length = _RECORD_HEAD.unpack(record_head)
            body_start = offset + _RECORD_HEAD.size
            try:
                kind = Opcode(opcode)
            except ValueError:
                raise self._fail(f"corrupt record at byte {offset}: unknown record type 0x{opcode:02x}") from None
            if first and kind != Opcode.HEADER:
                raise self._fail(f"corrupt file: the first record is {kind.name}, not the MCAP header")
            first = False
            if body_start + length > self.size:
                self._cut(f"{self.size} bytes, inside a {kind.name.lower()} record that starts at byte {offset} and needs {length}")
                break
            if kind == Opcode.CHUNK:
                self._on_chunk(handle, offset, length)
                handle.seek(body_start + length)
            elif kind in (Opcode.METADATA, Opcode.FOOTER):
                body = handle.read(length)
                if kind == Opcode.FOOTER:
                    if handle.read(len(_MAGIC)) != _MAGIC:
                        self._cut("inside the closing MCAP magic, after every step")
                    break
                self._on_metadata(offset, body)
            else:
                handle.seek(length, io.SEEK_CUR)
            offset = body_start + length
        if not self.policy:
            if self.truncated:
                raise self._fail(f"{self.problem}: nothing of the log is readable")
            raise self._fail("an MCAP file but not a terl-rt episode log (no 'terl.log' metadata record)")

    def _on_metadata(self, offset: int, body: bytes) -> None:
        try:
            record = Metadata.read(ReadDataStream(io.BytesIO(body)))
        except Exception as error:  # any parse failure of a complete record is corruption
            raise self._fail(f"corrupt metadata record at byte {offset}: {error!r}") from None
        data = record.metadata
        try:
            if record.name == META_LOG:
                if data.get("format") != LOG_FORMAT:
                    raise self._fail(f"metadata 'terl.log' has format {data.get('format')!r}, expected {LOG_FORMAT!r}")
                if data.get("version") != LOG_VERSION:
                    raise self._fail(
                        f"episode log version {data.get('version')!r}; this terl-rt reads version {LOG_VERSION}"
                    )
                self.world_version = data.get("world", "1")
                self.policy = {
                    "name": data["policy"], "sha256": data["policy_sha256"], "path": data.get("policy_path", ""),
                    "metadata": json.loads(data.get("policy_metadata", "{}")),
                }
            elif record.name == META_EPISODE:
                number = int(data["episode"])
                if number != len(self._scanned):
                    raise self._fail(f"episode records out of order at byte {offset}: episode {number} follows {len(self._scanned) - 1}")
                self._scanned.append({
                    "number": number, "index": int(data["index"]), "seed": int(data["seed"]),
                    "scenario": Scenario.from_dict(json.loads(data["scenario"])),
                    "metrics": None, "chunks": [],
                })
            elif record.name == META_EPISODE_END:
                number = int(data["episode"])
                if not self._scanned or self._scanned[-1]["number"] != number:
                    raise self._fail(f"end of episode {number} at byte {offset} without its start")
                self._scanned[-1]["metrics"] = EpisodeMetrics(**json.loads(data["metrics"]))
        except EpisodeLogError:
            raise
        except (KeyError, ValueError, TypeError, ScenarioError) as error:
            raise self._fail(f"corrupt {record.name!r} metadata record at byte {offset}: {error}") from None

    def _on_chunk(self, handle, offset: int, length: int) -> None:
        if not self.policy:
            raise self._fail(f"a chunk at byte {offset} precedes the 'terl.log' metadata; not an episode log")
        if not self._scanned:
            raise self._fail(f"a chunk at byte {offset} precedes the first episode record")
        if not self.channels:
            # The writer registers every schema and channel before the first step: they
            # ride in the first chunk of the file.
            for record in self._chunk_records(handle, offset, length, "step 0 of episode 0"):
                if isinstance(record, Schema):
                    self.schemas[record.id] = record
                elif isinstance(record, Channel):
                    self.channels[record.id] = record
        self._scanned[-1]["chunks"].append((offset, length))

    def _chunk_records(self, handle, offset: int, length: int, what: str) -> list:
        handle.seek(offset + _RECORD_HEAD.size)
        body = handle.read(length)
        try:
            chunk = Chunk.read(ReadDataStream(io.BytesIO(body)))
            return breakup_chunk(chunk, validate_crc=True)
        except Exception as error:  # zstd, CRC and struct errors all mean a damaged chunk
            raise self._fail(f"corrupt chunk at byte {offset} ({what}): {error}") from None

    def _read_step(self, handle, offset: int, length: int, what: str) -> LoggedStep:
        messages: dict[str, bytes] = {}
        head: dict | None = None
        time_ns = 0
        for record in self._chunk_records(handle, offset, length, what):
            if not isinstance(record, Message):
                continue
            channel = self.channels.get(record.channel_id)
            if channel is None:
                raise self._fail(f"corrupt chunk at byte {offset} ({what}): message on unknown channel {record.channel_id}")
            messages[channel.topic] = record.data
            time_ns = record.log_time
            if channel.topic == TOPIC_STATE:
                try:
                    head = json.loads(record.data)
                except ValueError as error:
                    raise self._fail(f"corrupt /state message in the chunk at byte {offset} ({what}): {error}") from None
        if head is None:
            raise self._fail(f"corrupt chunk at byte {offset} ({what}): it has no /state message")
        return LoggedStep(int(head["episode"]), int(head["step"]), time_ns, messages)
