"""Writing episode logs (terl_rt.logs.format) as episodes run.

The writer flushes after every step, and a step lives in one chunk, so everything up
to the last complete step is on disk whatever happens next (Ctrl-C, a crash, a kill).
"""

from __future__ import annotations

import json
import os
import signal
import threading
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from mcap.writer import CompressionType, Writer

from terl_rt import __version__
from terl_rt.files import NamingFile, OutputHold, publish, temporary_beside
from terl_rt.logs.format import (
    LOG_FORMAT,
    LOG_VERSION,
    META_EPISODE,
    META_EPISODE_END,
    META_LOG,
    SCHEMAS,
    StepRecord,
)
from terl_rt.logs.steps import OpenEpisode
from terl_rt.sim.metrics import EpisodeMetrics
from terl_rt.sim.scenario import Scenario
from terl_rt.sim.world import WORLD_VERSION

_NO_CHUNK_LIMIT = 1 << 40
"""Chunk size the writer never reaches: chunks end only where a step ends."""


@contextmanager
def sigint_deferred() -> Iterator[None]:
    """Hold back Ctrl-C (SIGINT) inside the block and deliver it at its end (main thread
    only): what the block changes is changed whole. Blocks nest: an inner one hands the
    signal on to the outer one at its end."""
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


class EpisodeLogWriter:
    """Writes episodes to an MCAP log at `path` (replaced if it exists).

    policy_info: `policy_info(policy)`, or a mapping with at least name and sha256.
    Call `begin_episode`, then `write_step` for step 0 (after reset) and every step,
    then `end_episode`; `close()` (or a `with` block) writes the summary. Each step is
    on disk when `write_step` returns.

    staged: write under a temporary name beside `path` (`staging_path`) and publish it at
    `path` at the first step (`terl_rt.files.publish`), so that a run that fails before its
    first step leaves an earlier file at `path` untouched (closed without a step, the
    temporary file is removed).
    replace: replace a file at `path`; without, a file there (even one another run
    published meanwhile) raises FileExistsError naming `path`. Either way the writer holds
    `path` until `close` (terl_rt.files.OutputHold): a writer of the same path opened
    meanwhile, by any run, raises OutputBusy, and the first run's log stays whole.
    scenes: write /world, Foxglove's 3-D scene of each step (most of a step's writing
    time); without, the log holds every other topic and reads, replays and verifies alike.
    """

    def __init__(
        self, path: str | os.PathLike, policy_info: Mapping[str, Any], staged: bool = False, replace: bool = True,
        scenes: bool = True,
    ):
        for key in ("name", "sha256"):
            if key not in policy_info:
                raise ValueError(f"policy_info lacks {key!r}; build it with terl_rt.policy.onnx_policy.policy_info(policy)")
        self.path = Path(path)
        self.policy_info = dict(policy_info)
        """the policy_info the log was opened with."""
        self.staging_path: Path | None = temporary_beside(self.path) if staged else None
        self._replace = replace
        self._scenes = scenes
        self.steps_written = 0
        """steps written so far, all episodes."""
        self._hold = OutputHold(self.path)
        try:
            self._file = NamingFile(open(self.staging_path or self.path, "wb" if replace or staged else "xb"), self.path)
            self._mcap = Writer(self._file, chunk_size=_NO_CHUNK_LIMIT, compression=CompressionType.ZSTD)
            self._mcap.start(profile="", library=f"terl-rt {__version__}")
            self._channels: dict[str, int] = {}
            self._sequence: dict[str, int] = {}
            for topic, schema in SCHEMAS.items():
                schema_id = self._mcap.register_schema(name=schema.name, encoding=schema.encoding, data=schema.data)
                self._channels[topic] = self._mcap.register_channel(
                    topic=topic, message_encoding=schema.message_encoding, schema_id=schema_id,
                )
                self._sequence[topic] = 0
            self._policy = {"policy": str(policy_info["name"]), "policy_sha256": str(policy_info["sha256"])}
            self._mcap.add_metadata(META_LOG, {
                "format": LOG_FORMAT,
                "version": LOG_VERSION,
                "world": WORLD_VERSION,
                "terl_rt": __version__,
                **self._policy,
                "policy_path": str(policy_info.get("path", "")),
                "policy_metadata": json.dumps(dict(policy_info.get("metadata", {}))),
            })
            self._mcap.flush()
        except BaseException:
            self._hold.release()
            raise
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
        self._episode = OpenEpisode(number, scenario, self._next_offset_ns)
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
        step = episode.messages(record, self._scenes)
        episode.last_ns = step.time_ns

        # From the first message to the flush the step is half in the chunk buffer: Ctrl-C
        # waits until the step is on disk and counted (the log published at its first
        # step), and any other interruption keeps close() from writing the half step out.
        with sigint_deferred():
            self._step_pending = True
            for topic, data in step.messages:
                self._mcap.add_message(
                    channel_id=self._channels[topic], log_time=step.time_ns, publish_time=step.time_ns,
                    data=data, sequence=self._sequence[topic],
                )
                self._sequence[topic] += 1
            self._mcap.flush()
            self._step_pending = False
            episode.scene_ids = step.scene_ids
            self.steps_written += 1
            if self.staging_path is not None:
                publish(self.staging_path, self.path, self._replace)
                self.staging_path = None

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
        self._next_offset_ns = episode.next_offset_ns
        self._episode = None

    def abandon_episode(self) -> None:
        """Leave the current episode without its end record (it reads back as cut off) so
        that the next one can begin: what an interrupted run does with an unfinished episode."""
        self._check_open()
        episode = self._episode
        if episode is None:
            raise RuntimeError("abandon_episode: no episode is open")
        self._next_offset_ns = episode.next_offset_ns
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
        # Each part runs whatever failed before it (a full disk or a file-size limit fails
        # the summary, then the close's flush): the path is given back in any case.
        try:
            if not self._step_pending and self.staging_path is None:
                self._mcap.finish()
        finally:
            try:
                self._file.close()
            finally:
                if self.staging_path is not None:  # no step was taken: leave `path` as it was
                    self.staging_path.unlink(missing_ok=True)
                self._hold.release()

    def _check_open(self) -> None:
        if self._closed:
            raise RuntimeError(f"{self.path}: the log writer is closed")
