"""A run of episodes: what to run (`EpisodeSpec`), where (a `Backend`), and how the results
come back in order.

A backend runs the specs in batches (`batches`), the episodes of a batch together in one
World (terl_rt.evaluation.play.batch_steps), wherever it runs them (this process, spawned
processes, Ray tasks), and hands each message to the run as it arrives: ("step", i, StepRecord) for every
step of spec i when the run is logged, then ("end", i, EpisodeMetrics). `run_episodes`
puts them in spec order: a log keeps each episode's records together, so the lowest
unfinished episode is written as its steps arrive and later episodes' steps wait in
memory until their turn; episodes are reported in spec order. Interrupted or failed, the
run writes what waits before the error goes on (the episodes that did not end stay
unended in the log). Every episode is the same, bit for bit, in any batch, so the
results and the log never depend on the backend or on how many workers it has.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any, Protocol

from terl_rt.logs.format import StepRecord
from terl_rt.logs.writer import EpisodeLogWriter
from terl_rt.policy.onnx_policy import OnnxPolicy
from terl_rt.sim.metrics import EpisodeMetrics
from terl_rt.sim.scenario import Scenario


@dataclass(frozen=True)
class EpisodeSpec:
    """One episode to run: `Simulator(scenario, seed)` driven by policy number `policy` of the run."""

    policy: int
    """index into the run's policies."""
    scenario: Scenario
    seed: int
    index: int
    """the episode's number in its evaluation (its seed is the evaluation's seed + index)."""


def batches(specs: Sequence[EpisodeSpec], parts: int) -> list[list[int]]:
    """The spec numbers in batches, each run in one World (terl_rt.evaluation.play.batch_steps):
    every run of consecutive specs with the same policy and the same Scenario object is
    split into at most `parts` batches, its k-th spec going to batch k mod parts (so that
    the episodes running at any time are close in spec order). Batches come in the order
    of their first spec."""
    out: list[list[int]] = []
    start = 0
    for number in range(1, len(specs) + 1):
        if number < len(specs) and specs[number].policy == specs[start].policy \
                and specs[number].scenario is specs[start].scenario:
            continue
        group = range(start, number)
        out += [list(group[part::parts]) for part in range(min(parts, len(group)))]
        start = number
    return out


Deliver = Callable[[str, int, Any], None]
"""deliver(kind, spec number, payload): ("step", i, StepRecord) or ("end", i, EpisodeMetrics)."""


class BackendError(RuntimeError):
    """Where the episodes run cannot run them (a cluster that cannot be reached, a worker
    that died more often than it is retried); the message says what happened."""


class Backend(Protocol):
    """Where episodes run."""

    workers: int
    """batches run at the same time (`batches(specs, workers)`)."""

    def run(self, policies: Sequence[OnnxPolicy], specs: Sequence[EpisodeSpec], record: bool,
            deliver: Deliver) -> None:
        """Run every spec with `policies[spec.policy]`, in the batches of `batches(specs,
        workers)`, and call `deliver` in this thread for each message as it arrives (steps
        only when `record`). Returns once every spec has ended; interrupted or failed, it
        first delivers what has already arrived, then raises."""

    def close(self) -> None:
        """Give back what the backend holds (a Ray instance it started)."""

    def __enter__(self) -> Backend: ...

    def __exit__(self, *exc) -> None: ...


Finished = Callable[[int, EpisodeMetrics], None]
"""finished(spec number, metrics), in spec order."""


def run_episodes(
    policies: Sequence[OnnxPolicy],
    specs: Sequence[EpisodeSpec],
    backend: Backend,
    log: EpisodeLogWriter | None,
    finished: Finished,
) -> None:
    """Run `specs` on `backend`, write every step to `log` (when given) and report each
    episode to `finished`, all in spec order (see the module's docstring)."""
    order = InOrderLog(specs, log, finished)
    try:
        backend.run(policies, specs, log is not None, order.receive)
    except BaseException:
        order.flush_waiting()
        raise


@contextmanager
def sigint_as_flag() -> Iterator[list[int]]:
    """Inside the block Ctrl-C (SIGINT) only appends to the list yielded, which a backend
    checks between messages: a message taken off its queue is always delivered. Outside
    the main thread the list stays empty and SIGINT is left alone."""
    received: list[int] = []
    if threading.current_thread() is not threading.main_thread():
        yield received
        return
    previous = signal.signal(signal.SIGINT, lambda signum, frame: received.append(signum))
    try:
        yield received
    finally:
        signal.signal(signal.SIGINT, previous)


class InOrderLog:
    """Writes the episodes that a backend streams, in spec order, and reports them in that order.

    Only one episode is written as its steps arrive (the lowest that has not ended); the
    steps of later episodes wait in memory until it ends. An interrupted run writes what
    waits (`flush_waiting`) before it closes the log.
    """

    def __init__(self, specs: Sequence[EpisodeSpec], log: EpisodeLogWriter | None, finished: Finished):
        self.specs, self.log, self.finished = specs, log, finished
        self.current = 0
        """the spec being written (every lower one is done)."""
        self.begun = False
        self.waiting: dict[int, list[StepRecord]] = {}
        self.ended: dict[int, EpisodeMetrics] = {}

    def receive(self, kind: str, number: int, payload) -> None:
        if number != self.current:
            if kind == "step":
                self.waiting.setdefault(number, []).append(payload)
            else:
                self.ended[number] = payload
            return
        if kind == "step":
            self._write(payload)
            return
        self._end(payload)
        while self.current in self.waiting or self.current in self.ended:
            for record in self.waiting.pop(self.current, []):
                self._write(record)
            if self.current not in self.ended:
                break
            self._end(self.ended.pop(self.current))

    def flush_waiting(self) -> None:
        """Write every waiting step, in spec order; the episodes that did not end stay unended."""
        for number in sorted(set(self.waiting) | set(self.ended)):
            if self.log is None:
                break
            if self.begun:
                self.log.abandon_episode()
            self.current, self.begun = number, False
            for record in self.waiting.pop(number, []):
                self._write(record)
            if number in self.ended:
                self._end(self.ended.pop(number), report=False)

    def _begin(self) -> None:
        spec = self.specs[self.current]
        self.log.begin_episode(spec.scenario, spec.seed, spec.index)
        self.begun = True

    def _write(self, record: StepRecord) -> None:
        if self.log is None:
            return
        if not self.begun:
            self._begin()
        self.log.write_step(record)

    def _end(self, metrics: EpisodeMetrics, report: bool = True) -> None:
        if self.log is not None:
            if not self.begun:
                self._begin()
            self.log.end_episode(metrics)
        self.begun = False
        if report:
            self.finished(self.current, metrics)
        self.current += 1
