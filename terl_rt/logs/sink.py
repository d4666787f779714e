"""Where the steps of a run go: any `StepSink`, as Python's logging writes its records to
whatever handlers are attached. The MCAP episode log (terl_rt.logs.writer.EpisodeLogWriter)
is one sink, the live view in Foxglove (terl_rt.logs.live.LiveSink) another, and a user's
own class with the five methods a third; `StepSinks` makes several one.

A run (terl_rt.evaluation.runs) hands a sink whole episodes, one at a time and in episode
order, whatever the backend and its number of workers: `begin_episode`, then `write_step` for
step 0 (the state after reset) and every step after it, then `end_episode` with the episode's
metrics, or `abandon_episode` when the run stops before the episode ends; `close` once at the
end, by whoever opened the sink.
"""

from __future__ import annotations

from collections.abc import Sequence
from contextlib import ExitStack
from typing import Protocol, runtime_checkable

from terl_rt.logs.format import StepRecord
from terl_rt.sim.metrics import EpisodeMetrics
from terl_rt.sim.scenario import Scenario


@runtime_checkable
class StepSink(Protocol):
    """What takes a run's steps (see the module docstring)."""

    def begin_episode(self, scenario: Scenario, seed: int, index: int) -> object:
        """An episode of `scenario` begins, run as `Simulator(scenario, seed=seed)`, number
        `index` in its evaluation (what it returns is the sink's own)."""

    def write_step(self, record: StepRecord) -> None:
        """One step of the episode begun: step 0 (after reset) first, then every step."""

    def end_episode(self, metrics: EpisodeMetrics) -> None:
        """The episode begun has ended with `metrics`."""

    def abandon_episode(self) -> None:
        """The run stopped before the episode begun ended; another may begin after it."""

    def close(self) -> None:
        """The run is over: give back what the sink holds (a file, a server)."""


class StepSinks:
    """Several sinks as one (a run with a log and a live view): each call goes to every sink,
    in the order given. `close` closes every sink, even when one fails."""

    def __init__(self, sinks: Sequence[StepSink]):
        self.sinks = tuple(sinks)
        """the sinks, in the order each call reaches them."""

    def begin_episode(self, scenario: Scenario, seed: int, index: int) -> None:
        for sink in self.sinks:
            sink.begin_episode(scenario, seed, index)

    def write_step(self, record: StepRecord) -> None:
        for sink in self.sinks:
            sink.write_step(record)

    def end_episode(self, metrics: EpisodeMetrics) -> None:
        for sink in self.sinks:
            sink.end_episode(metrics)

    def abandon_episode(self) -> None:
        for sink in self.sinks:
            sink.abandon_episode()

    def close(self) -> None:
        with ExitStack() as closing:
            for sink in reversed(self.sinks):
                closing.callback(sink.close)


def sinks_in(sink: StepSink | None) -> tuple[StepSink, ...]:
    """The sinks `sink` writes to: the members of StepSinks, else `sink` itself (None: none)."""
    if sink is None:
        return ()
    return sink.sinks if isinstance(sink, StepSinks) else (sink,)
