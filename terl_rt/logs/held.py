"""Side logs of the episodes a batched run holds back: every step on disk as it is taken.

A log keeps each episode's records together, in episode order, so while the lowest
unfinished episode is written to the log, the steps of the later episodes running beside
it wait for their turn (terl_rt.evaluation.runs.InOrderLog). So that a killed run
(SIGKILL, power loss) still keeps every step taken, each waiting episode is also written,
step by step, to a log of its own in the folder `held_folder(log)` beside the log:
`episode-<number>.mcap`, number the episode's place in the run. When its turn comes its
steps go into the log and its side log is deleted; the folder goes once it is empty.

A side log left behind is an episode of a run that was killed before the episode reached
the log: a log of one episode (`terl-rt replay` reads and verifies it), cut off where the
run stopped unless the episode had ended. It leaves out /world, Foxglove's 3-D scene,
which takes most of a step's writing time (a logged batched run of 10 small-15 episodes
took about 1.35x the CPU time with it, 1.1x without; see `EpisodeLogWriter`'s `scenes`).

Only the MCAP log among a run's sinks (terl_rt.logs.sink) has side logs: for any other sink
(a live view, a user's own) the waiting episodes wait in memory alone.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from terl_rt.logs.format import StepRecord
from terl_rt.logs.sink import StepSink, sinks_in
from terl_rt.logs.writer import EpisodeLogWriter
from terl_rt.sim.metrics import EpisodeMetrics
from terl_rt.sim.scenario import Scenario

HELD_SUFFIX = ".held"
"""what the side folder's name adds to the log's file name."""


def held_folder(log: str | Path) -> Path:
    """The folder of the side logs of `log`: `<log>.held` beside it."""
    log = Path(log)
    return log.with_name(log.name + HELD_SUFFIX)


def held_logs(log: str | Path) -> list[Path]:
    """The side logs a killed run left beside `log`, in episode order (none: [])."""
    folder = held_folder(log)
    return sorted(folder.glob("episode-*.mcap")) if folder.is_dir() else []


def episode_log(sink: StepSink | None) -> EpisodeLogWriter | None:
    """The MCAP log among the sinks of a run (`terl_rt.logs.sink.sinks_in`), the one its
    waiting episodes are held beside; None when no sink is one. ValueError for several: a run
    writes one log."""
    logs = [each for each in sinks_in(sink) if isinstance(each, EpisodeLogWriter)]
    if len(logs) > 1:
        raise ValueError(f"a run writes one episode log, got {len(logs)}: " + ", ".join(str(log.path) for log in logs))
    return logs[0] if logs else None


class HeldEpisodes:
    """The side logs of one run's waiting episodes (see the module docstring).

    Side logs a killed earlier run left beside the same log are deleted at this run's first
    step (`clear_earlier`): the log they belonged to is then replaced. A run that fails
    before its first step leaves them, as it leaves the earlier log.
    """

    def __init__(self, log: str | Path, policy_info: Mapping[str, Any]):
        self.log = Path(log)
        self.folder = held_folder(log)
        self.policy_info = policy_info
        self.writers: dict[int, EpisodeLogWriter] = {}
        self.cleared = False

    def clear_earlier(self) -> None:
        """Delete the side logs of an earlier run of the same log (once; call at every step)."""
        if self.cleared:
            return
        self.cleared = True
        for earlier in held_logs(self.log):
            earlier.unlink()
        self._remove_folder_if_empty()

    def path(self, number: int) -> Path:
        """The side log of the run's episode `number`."""
        return self.folder / f"episode-{number:06d}.mcap"

    def write_step(self, number: int, scenario: Scenario, seed: int, index: int, record: StepRecord) -> None:
        """Write a step of the waiting episode `number` to its side log (begun at its first
        step) and flush it."""
        self.clear_earlier()
        writer = self.writers.get(number)
        if writer is None:
            self.folder.mkdir(exist_ok=True)
            writer = self.writers[number] = EpisodeLogWriter(self.path(number), self.policy_info, scenes=False)
            writer.begin_episode(scenario, seed, index)
        writer.write_step(record)

    def end_episode(self, number: int, metrics: EpisodeMetrics) -> None:
        """Record the end of the waiting episode `number` in its side log, if it has one."""
        writer = self.writers.get(number)
        if writer is not None:
            writer.end_episode(metrics)

    def release(self, number: int) -> None:
        """Episode `number`'s steps are in the log: delete its side log, and the folder once empty."""
        writer = self.writers.pop(number, None)
        if writer is None:
            return
        writer.close()
        self.path(number).unlink(missing_ok=True)
        if not self.writers:
            self._remove_folder_if_empty()

    def _remove_folder_if_empty(self) -> None:
        try:
            self.folder.rmdir()
        except OSError:  # absent, or not empty: files someone else put there stay
            pass

    def close(self) -> None:
        """Close the side logs of episodes that never reached the log; they stay on disk."""
        for writer in self.writers.values():
            writer.close()
        self.writers.clear()
