"""Where an episode log's episodes and steps lie (`LogScan`): found through a complete file's
summary, or by scanning a cut-off or damaged file record by record.

A complete file (one with its summary and footer) is read through the MCAP library's
reader (`mcap.reader.make_reader`): its summary's chunk and metadata indexes, so any
chunking and compression another tool rewrote the log with reads the same. A file cut
off before its summary is scanned record by record by hand, up to the last complete step,
and `LogScan.problem` says what was lost; a zeroed tail (`ZEROED_TAIL_BYTES`) counts as cut
off. Either way every chunk is read and its CRC checked, and an episode with a chunk that
fails is marked damaged from that chunk on. terl_rt.logs.reader serves the steps it finds.
"""

from __future__ import annotations

import bisect
import io
import struct
from pathlib import Path
from typing import Any

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
    TOPIC_STATE,
    EpisodeLogError,
    decode,
)
from terl_rt.sim.metrics import EpisodeMetrics
from terl_rt.sim.scenario import Scenario, ScenarioError

_MAGIC = b"\x89MCAP0\r\n"
_RECORD_HEAD = struct.Struct("<BQ")
_ZERO_SCAN_BYTES = 1 << 16
"""bytes read at a time, backwards, to find where a zeroed tail begins."""
ZEROED_TAIL_BYTES = 512
"""A file that ends in at least this many zero bytes (a disk sector) lost them in a crash:
the records of a log never end so (a few zeros can end a record that was cut off)."""


class LogScan:
    """What opening an episode log finds: its policy and world version, channels and schemas,
    each episode's records and chunks (`raw_episodes`), and what is wrong with the file: what
    `EpisodeLogReader` lists and serves the steps of.

    Raises EpisodeLogError (`read`) for a file that is not MCAP, not an episode log, or corrupt.
    """

    def __init__(self, path: Path, size: int) -> None:
        self.path = path
        self.size = size
        """bytes of the file."""
        self.policy: dict[str, Any] = {}
        self.world_version = "1"
        self.truncated = False
        self.problem: str | None = None
        self.channels: dict[int, Channel] = {}
        self.schemas: dict[int, Schema] = {}
        self.raw_episodes: list[dict] = []
        """per episode in file order: its number, index, seed, scenario, metrics (None until its
        end record), chunks (offset, length), log times of its steps (indexed files), damaged
        chunk offsets, the log time damage starts at and its start time (ns)."""
        self.indexed = False

    def read(self, handle) -> None:
        """Find the episodes and their chunks in the open file `handle`: through the summary
        of a complete file, else by scanning it; then add damaged chunks to `problem`."""
        if not self._read_indexed(handle):
            self._scan(handle)
        self._note_damage()

    def fail(self, message: str) -> EpisodeLogError:
        """The error `message` about this file, the path first."""
        return EpisodeLogError(f"{self.path}: {message}")

    def readable_steps(self, raw: dict) -> int:
        """Steps of an episode that read back, the reset frame included: those before its
        first damaged chunk."""
        if self.indexed:
            return len(raw["times"])  # cut at the first damaged chunk already
        offsets = [offset for offset, _ in raw["chunks"]]
        return offsets.index(raw["damaged"][0]) if raw["damaged"] else len(offsets)

    def _note_damage(self) -> None:
        """Add the damaged chunks, if any, to `problem`."""
        damaged = [raw["number"] for raw in self.raw_episodes if raw["damaged"]]
        if not damaged:
            return
        first = min(offset for raw in self.raw_episodes for offset in raw["damaged"])
        count = len({offset for raw in self.raw_episodes for offset in raw["damaged"]})
        note = (
            f"{count} chunk(s) fail their CRC check or do not parse, the first at byte {first}: "
            f"episode(s) {', '.join(map(str, damaged))} read only up to their first damaged chunk; "
            f"the other episodes are intact"
        )
        self.problem = note if self.problem is None else f"{self.problem}; {note}"

    def _cut(self, what: str) -> None:
        self.truncated = True
        if not self.raw_episodes:
            kept = "no episode had begun"
        else:
            last = self.raw_episodes[-1]
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
            raise self.fail("the file is empty, not an episode log")
        if head != _MAGIC[: len(head)]:
            raise self.fail("not an MCAP file (it does not start with the MCAP magic bytes)")
        if len(head) < len(_MAGIC):
            raise self.fail(f"the file was cut off inside the MCAP magic ({self.size} bytes); nothing to read")
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
                raise self.fail(f"corrupt record at byte {offset}: unknown record type 0x{opcode:02x}") from None
            if first and kind != Opcode.HEADER:
                raise self.fail(f"corrupt file: the first record is {kind.name}, not the MCAP header")
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
                raise self.fail(f"{self.problem}: nothing of the log is readable")
            raise self.fail("an MCAP file but not a terl-rt episode log (no 'terl.log' metadata record)")

    def _on_metadata(self, offset: int, body: bytes) -> None:
        try:
            record = Metadata.read(ReadDataStream(io.BytesIO(body)))
        except UnicodeDecodeError as error:
            raise self._not_text(f"at byte {offset}", error) from None
        except Exception as error:  # any parse failure of a complete record is corruption
            raise self.fail(f"corrupt metadata record at byte {offset}: {error!r}") from None
        self._on_metadata_record(offset, record)

    def _not_text(self, where: str, error: UnicodeDecodeError) -> EpisodeLogError:
        return self.fail(
            f"corrupt metadata record {where}: a name or value is not UTF-8 text ({error.reason} at byte {error.start} of it)"
        )

    def _on_metadata_record(self, offset: int, record: Metadata) -> None:
        data = record.metadata
        try:
            if record.name == META_LOG:
                if data.get("format") != LOG_FORMAT:
                    raise self.fail(f"metadata 'terl.log' has format {data.get('format')!r}, expected {LOG_FORMAT!r}")
                if data.get("version") not in READ_VERSIONS:
                    raise self.fail(
                        f"episode log version {data.get('version')!r}; this terl-rt reads versions {', '.join(READ_VERSIONS)}"
                    )
                self.world_version = data.get("world", "1")
                self.policy = {
                    "name": data["policy"], "sha256": data["policy_sha256"], "path": data.get("policy_path", ""),
                    "metadata": decode(data.get("policy_metadata", "{}")),
                }
            elif record.name == META_EPISODE:
                number = int(data["episode"])
                if number != len(self.raw_episodes):
                    raise self.fail(f"episode records out of order at byte {offset}: episode {number} follows {len(self.raw_episodes) - 1}")
                self.raw_episodes.append({
                    "number": number, "index": int(data["index"]), "seed": int(data["seed"]),
                    "scenario": Scenario.from_dict(decode(data["scenario"])),
                    "metrics": None, "chunks": [], "times": [], "damaged": [], "damaged_from_ns": None,
                    "start_ns": int(data["start_time_ns"]) if "start_time_ns" in data else None,
                })
            elif record.name == META_EPISODE_END:
                number = int(data["episode"])
                if not self.raw_episodes or self.raw_episodes[-1]["number"] != number:
                    raise self.fail(f"end of episode {number} at byte {offset} without its start")
                self.raw_episodes[-1]["metrics"] = EpisodeMetrics(**decode(data["metrics"]))
        except EpisodeLogError:
            raise
        except (KeyError, ValueError, TypeError, ScenarioError) as error:
            raise self.fail(f"corrupt {record.name!r} metadata record at byte {offset}: {error}") from None

    def _on_chunk(self, handle, offset: int, length: int) -> None:
        if not self.policy:
            raise self.fail(f"a chunk at byte {offset} precedes the 'terl.log' metadata; not an episode log")
        if not self.raw_episodes:
            raise self.fail(f"a chunk at byte {offset} precedes the first episode record")
        raw = self.raw_episodes[-1]
        try:
            records = self.chunk_records(handle, offset, length, f"episode {raw['number']}, step {len(raw['chunks'])}")
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

    def chunk_records(self, handle, offset: int, length: int, what: str) -> list:
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
            raise self.fail(f"corrupt chunk at byte {offset} ({what}): {error}") from None

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
                    raise self.fail(f"the metadata index points at byte {index.offset}, which holds no metadata record")
                self._on_metadata(index.offset, handle.read(length))
        else:
            try:
                records = list(reader.iter_metadata())
            except UnicodeDecodeError as error:
                raise self._not_text("(no index)", error) from None
            for record in records:
                self._on_metadata_record(0, record)
        if not self.policy:
            raise self.fail("an MCAP file but not a terl-rt episode log (no 'terl.log' metadata record)")
        if any(raw["start_ns"] is None for raw in self.raw_episodes):
            handle.seek(0)  # a log from before episodes carried their start time: scan it
            self.raw_episodes = []
            self.policy = {}
            return False
        self.indexed = True
        self.schemas = dict(summary.schemas)
        self.channels = dict(summary.channels)
        state_channels = {cid for cid, channel in self.channels.items() if channel.topic == TOPIC_STATE}
        starts = [raw["start_ns"] for raw in self.raw_episodes]
        for chunk in sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset):
            where = (chunk.chunk_start_offset, chunk.chunk_length - _RECORD_HEAD.size)
            try:
                records = self.chunk_records(handle, *where, "while listing the steps")
            except EpisodeLogError:
                self._on_damaged_chunk(where, chunk.message_start_time, chunk.message_end_time, starts)
                continue
            times = [r.log_time for r in records if isinstance(r, Message) and r.channel_id in state_channels]
            for time_ns in times:
                number = bisect.bisect_right(starts, time_ns) - 1
                if number < 0:
                    raise self.fail(
                        f"the chunk at byte {chunk.chunk_start_offset} holds a step logged before the first episode began"
                    )
                raw = self.raw_episodes[number]
                raw["times"].append(time_ns)
                if not raw["chunks"] or raw["chunks"][-1] != where:
                    raw["chunks"].append(where)
        for raw in self.raw_episodes:
            cut = raw["damaged_from_ns"]
            raw["times"] = sorted(t for t in set(raw["times"]) if cut is None or t < cut)
        return True

    def _on_damaged_chunk(self, where: tuple[int, int], start_ns: int, end_ns: int, starts: list[int]) -> None:
        """Mark the chunk at `where` (offset, length) damaged in every episode its log times
        [start_ns, end_ns] (from the summary's chunk index) reach; `starts`: the episodes'
        start times (ns)."""
        first = max(bisect.bisect_right(starts, start_ns) - 1, 0)
        for raw in self.raw_episodes[first: max(bisect.bisect_right(starts, end_ns), first + 1)]:
            raw["damaged"].append(where[0])
            raw["chunks"].append(where)
            known = raw["damaged_from_ns"]
            raw["damaged_from_ns"] = start_ns if known is None else min(known, start_ns)
