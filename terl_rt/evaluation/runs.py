"""A run of episodes: what to run (`EpisodeSpec`), where (a `Backend`), and how the results
come back in order.

A backend runs the specs in batches (`batches`), the episodes of a batch together in one
World (terl_rt.evaluation.play.batch_steps), wherever it runs them (this process, worker
processes, Ray tasks), and hands each message to the run as it arrives: ("step", i, StepRecord) for every
step of spec i when the run is logged, then ("end", i, EpisodeMetrics). `run_episodes`
puts them in spec order: the run's log (a sink of steps, terl_rt.logs.sink: the MCAP log,
a live view, both, a user's own) takes each episode whole, so the lowest unfinished episode
is written as its steps arrive and later episodes' steps wait in this process's memory until
their turn, each also written step by step to a side log of its own beside the MCAP log
(terl_rt.logs.held), deleted once its steps are in the log: a killed run keeps every step
taken. So every sink sees the steps of workers and Ray tasks as it sees those of one process,
in episode order. Episodes are reported in spec order. Interrupted or failed, the run
writes what waits before the error goes on (the episodes that did not end stay unended
in the log). Every episode is the same, bit for bit, in any batch, so the
results and the log never depend on the backend or on how many workers it has.
"""

from __future__ import annotations

import signal
import threading
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any, Protocol

from terl_rt.logs.format import StepRecord
from terl_rt.logs.held import HeldEpisodes, episode_log
from terl_rt.logs.sink import StepSink
from terl_rt.logs.writer import sigint_deferred
from terl_rt.policy.onnx_policy import OnnxPolicy
from terl_rt.safety.acting import Acting
from terl_rt.sim.metrics import EpisodeMetrics
from terl_rt.sim.scenario import Scenario


@dataclass(frozen=True)
class EpisodeSpec:
    """One episode to run: `Simulator(scenario, seed)` driven by policy number `policy` of the
    run, acting by `acting` (terl_rt.safety.acting)."""

    policy: int
    """index into the run's policies."""
    scenario: Scenario
    seed: int
    index: int
    """the episode's number in its evaluation (its seed is the evaluation's seed + index)."""
    acting: Acting = Acting()
    """how the policy's outputs become actions: greedy (the default), risk-aware, shielded."""


def batches(specs: Sequence[EpisodeSpec], parts: int) -> list[list[int]]:
    """The spec numbers in batches, each run in one World (terl_rt.evaluation.play.batch_steps):
    every run of consecutive specs with the same policy, acting rule and Scenario object is
    split into at most `parts` batches, its k-th spec going to batch k mod parts (so that
    the episodes running at any time are close in spec order). Batches come in the order
    of their first spec."""
    out: list[list[int]] = []
    start = 0
    for number in range(1, len(specs) + 1):
        if number < len(specs) and specs[number].policy == specs[start].policy \
                and specs[number].acting == specs[start].acting and specs[number].scenario is specs[start].scenario:
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
        """Run every spec with `policies[spec.policy]` acting by `spec.acting`, in the batches of `batches(specs,
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
    log: StepSink | None,
    finished: Finished,
) -> None:
    """Run `specs` on `backend`, write every step to `log` (a sink, terl_rt.logs.sink; when
    given) and report each episode to `finished`, all in spec order (see the module's docstring)."""
    order = InOrderLog(specs, log, finished)
    try:
        backend.run(policies, specs, log is not None, order.receive)
    except BaseException:
        order.flush_waiting()
        raise
    finally:
        order.close()


STOP_SIGNALS = tuple(getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, name))
"""What stops a run: Ctrl-C, `kill PID` and a closed terminal (no SIGHUP on Windows)."""


class Stopped(KeyboardInterrupt):
    """A run with workers (or on Ray) was stopped by SIGINT, SIGTERM or SIGHUP, and what had
    arrived was written first. The terl-rt group prints it as one line and exits with
    128 + `signum`, as a process ended by that signal would."""

    def __init__(self, signum: int):
        super().__init__(f"stopped by {signal.Signals(signum).name}; a --log keeps every step run so far")
        self.signum = signum


def raise_stop(received: Sequence[int]) -> None:
    """Raise Stopped for the first signal in `received` (from `stop_signals_as_flag`);
    nothing when it is empty."""
    if received:
        raise Stopped(received[0])


@contextmanager
def stop_signals_as_flag() -> Iterator[list[int]]:
    """Inside the block Ctrl-C, SIGTERM and SIGHUP (STOP_SIGNALS) only append their number to
    the list yielded, which a backend checks between messages (`raise_stop`): a message
    taken off its queue is always delivered. A signal ignored when the block starts stays
    ignored (`nohup` ignores SIGHUP; a shell ignores SIGINT in its background jobs). Outside
    the main thread the list stays empty and the signals are left alone."""
    received: list[int] = []
    if threading.current_thread() is not threading.main_thread():
        yield received
        return
    previous = {signum: signal.signal(signum, lambda signum, frame: received.append(signum))
                for signum in STOP_SIGNALS if signal.getsignal(signum) is not signal.SIG_IGN}
    try:
        yield received
    finally:
        for signum, handler in previous.items():
            if handler is not None:  # None: a handler not installed from Python, which cannot be put back
                signal.signal(signum, handler)


class InOrderLog:
    """Writes the episodes that a backend streams, in spec order, and reports them in that order.

    Only one episode is written as its steps arrive (the lowest that has not ended); the
    steps of later episodes wait in memory until it ends, and in their side logs
    (`HeldEpisodes`) until they are in the log. An interrupted run writes what waits
    (`flush_waiting`) before it closes the log. Ctrl-C is held back within each change of
    the log and of what waits (a message kept for later, a step written with the episode
    it begins, a waiting step moved to the log, an episode's end): a run stopped at any
    moment stops between two of them, so what waits is written once, and nothing twice.
    """

    def __init__(self, specs: Sequence[EpisodeSpec], log: StepSink | None, finished: Finished):
        self.specs, self.log, self.finished = specs, log, finished
        self.current = 0
        """the spec being written (every lower one is done)."""
        self.begun = False
        """the current spec's episode is begun in the log."""
        self.waiting: dict[int, deque[StepRecord]] = {}
        """spec -> its steps not yet in the log, oldest first."""
        self.ended: dict[int, EpisodeMetrics] = {}
        """spec -> its metrics, for later specs that ended before their turn."""
        mcap = episode_log(log)
        self.held = None if mcap is None else HeldEpisodes(mcap.path, mcap.policy_info)
        """the side logs of the waiting episodes, beside the MCAP log among the sinks (if one is)."""

    def receive(self, kind: str, number: int, payload) -> None:
        if number != self.current:
            with sigint_deferred():
                self._keep(kind, number, payload)
        elif kind == "step":
            with sigint_deferred():
                self._write(payload)
        else:
            with sigint_deferred():
                self._end(payload)
            self._catch_up()

    def flush_waiting(self) -> None:
        """Write every waiting step, in spec order; the episodes that did not end stay unended."""
        for number in sorted(set(self.waiting) | set(self.ended)):
            if self.log is None:
                break
            if number != self.current:  # the current one (stopped while it caught up) goes on
                with sigint_deferred():
                    if self.begun:
                        self.log.abandon_episode()
                    self.current, self.begun = number, False
            self._write_waiting(number)
            if number in self.ended:
                with sigint_deferred():
                    self._end(self.ended.pop(number), report=False)

    def close(self) -> None:
        """Close the side logs; those of episodes that never reached the log stay on disk."""
        if self.held is not None:
            self.held.close()

    def _keep(self, kind: str, number: int, payload) -> None:
        """Keep a message of a later spec until its turn (and in its side log)."""
        if kind == "step":
            self.waiting.setdefault(number, deque()).append(payload)
            if self.held is not None:
                spec = self.specs[number]
                self.held.write_step(number, spec.scenario, spec.seed, spec.index, payload)
        else:
            self.ended[number] = payload
            if self.held is not None:
                self.held.end_episode(number, payload)

    def _catch_up(self) -> None:
        """Write the specs whose turn has come, as far as they have run."""
        while self.current in self.waiting or self.current in self.ended:
            self._write_waiting(self.current)
            if self.current not in self.ended:
                break
            with sigint_deferred():
                self._end(self.ended.pop(self.current))

    def _write_waiting(self, number: int) -> None:
        """Move the waiting steps of spec `number` (the current one) to the log, one at a
        time, then drop its side log."""
        steps = self.waiting.get(number, deque())
        while steps:
            with sigint_deferred():
                self._write(steps[0])
                steps.popleft()
        with sigint_deferred():
            self.waiting.pop(number, None)
            if self.held is not None:
                self.held.release(number)

    def _begin(self) -> None:
        spec = self.specs[self.current]
        self.log.begin_episode(spec.scenario, spec.seed, spec.index)
        self.begun = True

    def _write(self, record: StepRecord) -> None:
        if self.log is None:
            return
        if self.held is not None:
            self.held.clear_earlier()
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
