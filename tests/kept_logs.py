"""What a stopped run's episode log must still hold: every episode written complete and verified."""

from __future__ import annotations

from pathlib import Path

from terl_rt.logs.reader import EpisodeLogReader
from terl_rt.logs.resimulate import verify


def assert_log_keeps_complete_steps(log: Path, episodes_at_least: int = 1) -> None:
    """The log is closed (not truncated), holds at least `episodes_at_least` episodes, each with
    steps, and each re-simulates bit for bit."""
    reader = EpisodeLogReader(log)
    assert not reader.truncated, reader.problem
    assert len(reader.episodes) >= episodes_at_least
    assert all(e.steps > 0 for e in reader.episodes)
    assert all(verify(log, e.number).ok for e in reader.episodes)
