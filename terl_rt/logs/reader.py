"""Reading episode logs (terl_rt.logs.format), complete or cut off.

A complete file (one with its summary and footer) is read through the MCAP library's
reader (`mcap.reader.make_reader`): its summary's chunk and metadata indexes, so any
chunking and compression another tool rewrote the log with reads the same. A file cut
off before its summary is scanned record by record by hand: it reads back up to the last
complete step and says so (`EpisodeLogReader.problem`). Either way every chunk is read and
its CRC checked when the file is opened, and the steps are found in the chunks themselves
(never in the message indexes beside them, which a damaged byte can move to another
episode): an episode with a chunk that fails is listed as damaged (`LoggedEpisode.damaged`)
and reads up to that chunk, the problem says so, and the other episodes read as they are.
Anything else that does not parse is an `EpisodeLogError` naming the byte offset and,
where known, the episode and step.
"""

from __future__ import annotations

import bisect
import io
import os
import struct
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from google.protobuf.message import DecodeError
from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.reader import make_reader
from mcap.records import Channel, Chunk, Message, Metadata, Schema
from mcap.stream_reader import breakup_chunk

from terl_rt.logs.format import (
    LOG_FORMAT,
    READ_VERSIONS,
    META_EPISODE,
    META_EPISODE_END,
    META_LOG,
    TOPIC_ACTIONS,
    TOPIC_EVENTS,
    TOPIC_STATE,
    EpisodeLogError,
    decode,
)
from terl_rt.logs.foxglove import scene_from_protobuf
from terl_rt.sim.metrics import EpisodeMetrics
from terl_rt.sim.scenario import Scenario, ScenarioError
from terl_rt.sim.state import LOGGED_FIELDS

_MAGIC = b"\x89MCAP0\r\n"
_RECORD_HEAD = struct.Struct("<BQ")
_ZERO_SCAN_BYTES = 1 << 16
"""bytes read at a time, backwards, to find where a zeroed tail begins."""
ZEROED_TAIL_BYTES = 512
"""A file that ends in at least this many zero bytes (a disk sector) lost them in a crash:
the records of a log never end so (a few zeros can end a record that was cut off)."""


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
        self.policy: dict[str, Any] = {}
        """The policy the episodes ran: name, sha256, path, metadata."""
        self.world_version = "1"
        """terl_rt.sim.world.WORLD_VERSION of the simulator that wrote the log (logs before versions: "1")."""
        self.truncated = False
        """True when the file stops before its footer (cut off, or its writer never closed)."""
        self.problem: str | None = None
        """What is wrong with the file (cut off, damaged chunks), in one sentence; None for a sound one."""
        self.channels: dict[int, Channel] = {}
        self.schemas: dict[int, Schema] = {}
        self._scanned: list[dict] = []
        self.indexed = False
        """True when the file was read through its summary (complete), False when scanned."""
        with open(self.path, "rb") as handle:
            if not self._read_indexed(handle):
                self._scan(handle)
        self._episodes = tuple(
            LoggedEpisode(
                number=raw["number"], index=raw["index"], seed=raw["seed"], scenario=raw["scenario"],
                steps=max(self._readable_steps(raw) - 1, 0), metrics=raw["metrics"], chunks=tuple(raw["chunks"]),
                damaged=tuple(raw["damaged"]),
            )
            for raw in self._scanned
        )
        self._note_damage()

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

    def _fail(self, message: str) -> EpisodeLogError:
        return EpisodeLogError(f"{self.path}: {message}")

    def _readable_steps(self, raw: dict) -> int:
        """Steps of an episode that read back, the reset frame included: those before its
        first damaged chunk."""
        if self.indexed:
            return len(raw["times"])  # cut at the first damaged chunk already
        offsets = [offset for offset, _ in raw["chunks"]]
        return offsets.index(raw["damaged"][0]) if raw["damaged"] else len(offsets)

    def _note_damage(self) -> None:
        """Add the damaged chunks, if any, to `problem`."""
        damaged = [raw["number"] for raw in self._scanned if raw["damaged"]]
        if not damaged:
            return
        first = min(offset for raw in self._scanned for offset in raw["damaged"])
        count = len({offset for raw in self._scanned for offset in raw["damaged"]})
        note = (
            f"{count} chunk(s) fail their CRC check or do not parse, the first at byte {first}: "
            f"episode(s) {', '.join(map(str, damaged))} read only up to their first damaged chunk; "
            f"the other episodes are intact"
        )
        self.problem = note if self.problem is None else f"{self.problem}; {note}"

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

    def _data_end(self, handle) -> int:
        """Where the file's trailing run of zero bytes begins when it is ZEROED_TAIL_BYTES
        long or longer, else its size: a machine that crashed while the log was written
        leaves its last blocks zeroed, and those bytes were never written."""
        end = self.size
        while end > 0:
            start = max(end - _ZERO_SCAN_BYTES, 0)
            handle.seek(start)
            block = handle.read(end - start).rstrip(b"\0")
            if block:
                end = start + len(block)
                break
            end = start
        handle.seek(0)
        return end if self.size - end >= ZEROED_TAIL_BYTES else self.size

    def _scan(self, handle) -> None:
        # A zeroed tail counts as missing: the log reads as cut off where its data ends.
        size = self._data_end(handle)
        zeros = f"; its last {self.size - size} bytes are zeros, as a crash leaves" if size < self.size else ""
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
            if offset == size:
                self._cut(f"it ends after a whole record but without the MCAP footer: its writer was never closed{zeros}")
                break
            record_head = handle.read(_RECORD_HEAD.size)
            if offset + _RECORD_HEAD.size > size:
                self._cut(f"{size} bytes, inside the header of a record that starts at byte {offset}{zeros}")
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
            if body_start + length > size:
                self._cut(
                    f"{size} bytes, inside a {kind.name.lower()} record that starts at byte {offset} and needs {length}{zeros}"
                )
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
        except UnicodeDecodeError as error:
            raise self._not_text(f"at byte {offset}", error) from None
        except Exception as error:  # any parse failure of a complete record is corruption
            raise self._fail(f"corrupt metadata record at byte {offset}: {error!r}") from None
        self._on_metadata_record(offset, record)

    def _not_text(self, where: str, error: UnicodeDecodeError) -> EpisodeLogError:
        return self._fail(
            f"corrupt metadata record {where}: a name or value is not UTF-8 text ({error.reason} at byte {error.start} of it)"
        )

    def _on_metadata_record(self, offset: int, record: Metadata) -> None:
        data = record.metadata
        try:
            if record.name == META_LOG:
                if data.get("format") != LOG_FORMAT:
                    raise self._fail(f"metadata 'terl.log' has format {data.get('format')!r}, expected {LOG_FORMAT!r}")
                if data.get("version") not in READ_VERSIONS:
                    raise self._fail(
                        f"episode log version {data.get('version')!r}; this terl-rt reads versions {', '.join(READ_VERSIONS)}"
                    )
                self.world_version = data.get("world", "1")
                self.policy = {
                    "name": data["policy"], "sha256": data["policy_sha256"], "path": data.get("policy_path", ""),
                    "metadata": decode(data.get("policy_metadata", "{}")),
                }
            elif record.name == META_EPISODE:
                number = int(data["episode"])
                if number != len(self._scanned):
                    raise self._fail(f"episode records out of order at byte {offset}: episode {number} follows {len(self._scanned) - 1}")
                self._scanned.append({
                    "number": number, "index": int(data["index"]), "seed": int(data["seed"]),
                    "scenario": Scenario.from_dict(decode(data["scenario"])),
                    "metrics": None, "chunks": [], "times": [], "damaged": [], "damaged_from_ns": None,
                    "start_ns": int(data["start_time_ns"]) if "start_time_ns" in data else None,
                })
            elif record.name == META_EPISODE_END:
                number = int(data["episode"])
                if not self._scanned or self._scanned[-1]["number"] != number:
                    raise self._fail(f"end of episode {number} at byte {offset} without its start")
                self._scanned[-1]["metrics"] = EpisodeMetrics(**decode(data["metrics"]))
        except EpisodeLogError:
            raise
        except (KeyError, ValueError, TypeError, ScenarioError) as error:
            raise self._fail(f"corrupt {record.name!r} metadata record at byte {offset}: {error}") from None

    def _on_chunk(self, handle, offset: int, length: int) -> None:
        if not self.policy:
            raise self._fail(f"a chunk at byte {offset} precedes the 'terl.log' metadata; not an episode log")
        if not self._scanned:
            raise self._fail(f"a chunk at byte {offset} precedes the first episode record")
        raw = self._scanned[-1]
        try:
            records = self._chunk_records(handle, offset, length, f"episode {raw['number']}, step {len(raw['chunks'])}")
        except EpisodeLogError:
            if not self.channels:
                raise  # the first chunk holds the channels: without them no step reads
            raw["damaged"].append(offset)
            records = []
        if not self.channels:
            # The writer registers every schema and channel before the first step: they
            # ride in the first chunk of the file.
            for record in records:
                if isinstance(record, Schema):
                    self.schemas[record.id] = record
                elif isinstance(record, Channel):
                    self.channels[record.id] = record
        raw["chunks"].append((offset, length))

    def _chunk_records(self, handle, offset: int, length: int, what: str) -> list:
        """The records of the chunk record at `offset` whose body is `length` bytes, its CRC
        checked; EpisodeLogError naming `what` when it is damaged."""
        handle.seek(offset)
        head = handle.read(_RECORD_HEAD.size)
        body = handle.read(length)
        try:
            if len(head) < _RECORD_HEAD.size or _RECORD_HEAD.unpack(head) != (Opcode.CHUNK, length):
                raise ValueError(f"no chunk record of {length} bytes there")
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
                    head = decode(record.data)
                except ValueError as error:
                    raise self._fail(f"corrupt /state message in the chunk at byte {offset} ({what}): {error}") from None
        if head is None:
            raise self._fail(f"corrupt chunk at byte {offset} ({what}): it has no /state message")
        return LoggedStep(int(head["episode"]), int(head["step"]), time_ns, messages, self._protobuf_topics())

    # --- complete files, through the MCAP library's reader and the summary's indexes
    def _read_indexed(self, handle) -> bool:
        """Read a complete file through its summary; False (nothing read) for a file without
        one (cut off, never closed, or not an indexed MCAP), which is then scanned."""
        if self.size < 2 * len(_MAGIC):
            return False
        handle.seek(self.size - len(_MAGIC))
        at_end = handle.read(len(_MAGIC))
        handle.seek(0)
        if at_end != _MAGIC or handle.read(len(_MAGIC) + 1)[len(_MAGIC):] != bytes([Opcode.HEADER]):
            handle.seek(0)
            return False  # cut off, or a damaged start the scanner names
        handle.seek(0)
        try:
            reader = make_reader(handle)
            summary = reader.get_summary()
        except Exception:  # a damaged footer or summary: the scanner says what is wrong
            summary = None
        if summary is None or not summary.chunk_indexes:
            handle.seek(0)
            return False
        if summary.metadata_indexes:
            for index in sorted(summary.metadata_indexes, key=lambda i: i.offset):
                handle.seek(index.offset)
                opcode, length = _RECORD_HEAD.unpack(handle.read(_RECORD_HEAD.size))
                if opcode != Opcode.METADATA:
                    raise self._fail(f"the metadata index points at byte {index.offset}, which holds no metadata record")
                self._on_metadata(index.offset, handle.read(length))
        else:
            try:
                records = list(reader.iter_metadata())
            except UnicodeDecodeError as error:
                raise self._not_text("(no index)", error) from None
            for record in records:
                self._on_metadata_record(0, record)
        if not self.policy:
            raise self._fail("an MCAP file but not a terl-rt episode log (no 'terl.log' metadata record)")
        if any(raw["start_ns"] is None for raw in self._scanned):
            handle.seek(0)  # a log from before episodes carried their start time: scan it
            self._scanned = []
            self.policy = {}
            return False
        self.indexed = True
        self.schemas = dict(summary.schemas)
        self.channels = dict(summary.channels)
        state_channels = {cid for cid, channel in self.channels.items() if channel.topic == TOPIC_STATE}
        starts = [raw["start_ns"] for raw in self._scanned]
        for chunk in sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset):
            where = (chunk.chunk_start_offset, chunk.chunk_length - _RECORD_HEAD.size)
            try:
                records = self._chunk_records(handle, *where, "while listing the steps")
            except EpisodeLogError:
                self._on_damaged_chunk(where, chunk.message_start_time, chunk.message_end_time, starts)
                continue
            times = [r.log_time for r in records if isinstance(r, Message) and r.channel_id in state_channels]
            for time_ns in times:
                number = bisect.bisect_right(starts, time_ns) - 1
                if number < 0:
                    raise self._fail(
                        f"the chunk at byte {chunk.chunk_start_offset} holds a step logged before the first episode began"
                    )
                raw = self._scanned[number]
                raw["times"].append(time_ns)
                if not raw["chunks"] or raw["chunks"][-1] != where:
                    raw["chunks"].append(where)
        for raw in self._scanned:
            cut = raw["damaged_from_ns"]
            raw["times"] = sorted(t for t in set(raw["times"]) if cut is None or t < cut)
        return True

    def _on_damaged_chunk(self, where: tuple[int, int], start_ns: int, end_ns: int, starts: list[int]) -> None:
        """Mark the chunk at `where` (offset, length) damaged in every episode its log times
        [start_ns, end_ns] (from the summary's chunk index) reach; `starts`: the episodes'
        start times (ns)."""
        first = max(bisect.bisect_right(starts, start_ns) - 1, 0)
        for raw in self._scanned[first: max(bisect.bisect_right(starts, end_ns), first + 1)]:
            raw["damaged"].append(where[0])
            raw["chunks"].append(where)
            known = raw["damaged_from_ns"]
            raw["damaged_from_ns"] = start_ns if known is None else min(known, start_ns)

    def _indexed_steps(self, number: int) -> Iterator[LoggedStep]:
        raw = self._scanned[number]
        low = raw["start_ns"]
        high = self._scanned[number + 1]["start_ns"] if number + 1 < len(self._scanned) else None
        wanted = set(raw["times"])
        gathered: dict[int, dict[str, bytes]] = {}
        damage: EpisodeLogError | None = None
        with open(self.path, "rb") as handle:
            for offset, length in raw["chunks"]:
                what = f"episode {number}, step {len(gathered)}"
                try:
                    records = self._chunk_records(handle, offset, length, what)
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
                        raise self._fail(f"corrupt chunk at byte {offset} ({what}): message on unknown channel {record.channel_id}")
                    gathered.setdefault(record.log_time, {})[channel.topic] = record.data
        for expected, time_ns in enumerate(sorted(gathered)):
            messages = gathered[time_ns]
            try:
                head = decode(messages[TOPIC_STATE])
                step = LoggedStep(int(head["episode"]), int(head["step"]), time_ns, messages, self._protobuf_topics())
            except (KeyError, ValueError, TypeError) as error:
                raise self._fail(f"the /state message of episode {number} at log time {time_ns} is corrupt ({error!r})") from None
            if step.episode != number or step.step != expected:
                raise self._fail(
                    f"log time {time_ns} holds episode {step.episode} step {step.step}, "
                    f"expected episode {number} step {expected}; the file is corrupt"
                )
            yield step
        if damage is not None:
            raise damage
