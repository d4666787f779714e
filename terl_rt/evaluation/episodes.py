"""Evaluate a policy on a scenario: success rate, travel time, collision ratio (world.md section 10).

Episode k of an evaluation with seed s runs `Simulator(scenario, seed=s + k)`, so any
episode can be run again alone. Each step the policy sees every active pursuer's
observation in one call; `terl_rt.sim.rollout.Rollout` scatters its greedy actions to
the [N] action vector (collided pursuers get 0, which the simulator ignores).
With `workers > 1` the episodes are spread over processes (spawn), each reopening the
policy file; results (and logs) are the same as with one process, in episode order.
Workers send each step to the parent as it is taken; the parent writes the lowest
unfinished episode as its steps arrive and holds later episodes' steps in memory until
their turn (a log keeps each episode's records together). Interrupted or failed, it
writes what it holds before closing the log; killed (SIGKILL), what it held is lost.
Workers end with their parent, even when it is killed.
"""

from __future__ import annotations

import ctypes
import os
import signal
import sys
import threading
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass
from multiprocessing import get_context
from pathlib import Path

import numpy as np

from terl_rt.evaluation.stats import episode_intervals
from terl_rt.logs.format import StepRecord
from terl_rt.logs.writer import EpisodeLogWriter
from terl_rt.policy.onnx_policy import ContractError, OnnxPolicy, policy_info
from terl_rt.sim.metrics import EpisodeMetrics, summarize
from terl_rt.sim.rollout import Rollout
from terl_rt.sim.scenario import Scenario
from terl_rt.sim.simulator import StepInfo
from terl_rt.sim.state import snapshot
from terl_rt.sim.world import World


class PolicyOutputError(ContractError):
    """A policy returned a non-finite q-value or target weight during a run (a user error:
    the policy file is at fault, not the runtime)."""


def check_finite_output(policy: OnnxPolicy, q_values: np.ndarray, target_weights: np.ndarray | None,
                        step: int, seed: int) -> None:
    """Raise PolicyOutputError naming the policy, the step and the seed when an output is NaN or Inf."""
    for name, values in (("q_values", q_values), ("target_weights", target_weights)):
        if values is None or np.isfinite(values).all():
            continue
        row = int(np.argwhere(~np.isfinite(values))[0][0])
        bad = values.reshape(len(values), -1)[row]
        bad = bad[~np.isfinite(bad)][0]
        raise PolicyOutputError(
            f"policy {policy.name} ({policy.path}) output a non-finite {name} ({bad}) at step {step} "
            f"of the episode with seed {seed} (decision row {row}); the run is stopped"
        )

Progress = Callable[[int, EpisodeMetrics], None]
"""Called after each finished episode with its index and metrics (in episode order)."""


@dataclass(frozen=True)
class ScenarioResult:
    """A policy's results on one scenario."""

    name: str
    """scenario name."""
    episodes: int
    seed: int
    """episode k ran with seed + k."""
    max_steps: int
    """the step limit in force."""
    success_rate: float
    travel_time_s_mean: float
    travel_time_s_std: float
    collision_ratio_mean: float
    steps_mean: float
    wall_s: float
    """s: wall-clock time of the whole evaluation."""
    per_episode: tuple[EpisodeMetrics, ...]

    def ci95(self) -> dict[str, tuple[float, float]]:
        """95 % bootstrap intervals (fixed seed) of the success rate, mean travel time (s)
        and mean collision ratio over the episodes (terl_rt.evaluation.stats)."""
        return episode_intervals(self.per_episode)

    def episode_rows(self) -> list[dict]:
        """One row per episode: index, seed, outcome (success, too_few_pursuers or
        step_limit), steps, travel time, collisions (pursuers), collision ratio and
        captures (evaders encircled)."""
        return [
            {
                "episode": k,
                "seed": self.seed + k,
                "outcome": episode_outcome(m, self.max_steps),
                "success": m.success,
                "steps": m.steps,
                "travel_time_s": m.travel_time_s,
                "collisions": m.pursuers_collided,
                "collision_ratio": m.collision_ratio,
                "captures": m.evaders_encircled,
            }
            for k, m in enumerate(self.per_episode)
        ]

    def to_dict(self, per_episode: bool = False) -> dict:
        """The JSON row of `terl-rt eval --json`; `per_episode` adds every episode's row
        (`episode_rows`)."""
        row = {
            "name": self.name,
            "episodes": self.episodes,
            "seed": self.seed,
            "max_steps": self.max_steps,
            "success_rate": self.success_rate,
            "travel_time_s_mean": self.travel_time_s_mean,
            "travel_time_s_std": self.travel_time_s_std,
            "collision_ratio_mean": self.collision_ratio_mean,
            "steps_mean": self.steps_mean,
            "ci95": {name: list(interval) for name, interval in self.ci95().items()},
            "wall_s": self.wall_s,
        }
        if per_episode:
            row["per_episode"] = self.episode_rows()
        return row


def episode_outcome(metrics: EpisodeMetrics, max_steps: int) -> str:
    """How an episode ended: "success" (every evader encircled), "too_few_pursuers"
    (fewer than 3 left) or "step_limit"."""
    if metrics.success:
        return "success"
    return "step_limit" if metrics.steps >= max_steps else "too_few_pursuers"


def run_episode(
    policy: OnnxPolicy,
    scenario: Scenario,
    seed: int,
    on_step: Callable[[StepRecord], None] | None = None,
) -> EpisodeMetrics:
    """Run one episode of `Simulator(scenario, seed)` with the policy's greedy actions
    (its world: environment 0 of `World(scenario, 1, seed)`).

    `on_step` receives a StepRecord for the state after reset (step 0) and after each step.
    """
    world = World(scenario, num_envs=1, seed=seed)
    rollout = Rollout(world)
    if on_step is not None:
        on_step(StepRecord(step=0, state=snapshot(world.state, 0)))
    while True:
        turn = rollout.turn()
        output = policy.evaluate(turn.observation.rows(turn.rows))
        check_finite_output(policy, output.q_values, output.target_weights, int(world.state.steps[0]) + 1, seed)
        step = rollout.step(output.actions)
        if on_step is not None:
            on_step(StepRecord(
                step=int(world.state.steps[0]), state=snapshot(world.state, 0), pursuer_actions=step.actions[0],
                decided=turn.rows, target_weights=output.target_weights, info=StepInfo.of(step.result),
            ))
        if step.outcomes:
            return step.outcomes[0]


# --- worker processes ------------------------------------------------------------------

_worker_policy: OnnxPolicy | None = None
_worker_stop = None
_worker_channel = None
"""(connection, lock): the pipe end every worker sends on, one message at a time."""

_PR_SET_PDEATHSIG = 1
_WATCHDOG_S = 0.5
"""s: how often a worker checks that its parent is still alive."""


class _Stopped(Exception):
    """The parent asked the workers to stop (it was interrupted)."""


def _die_with_parent(parent: int) -> None:
    """End this worker when its parent process (pid `parent`, the evaluating process) dies,
    even by SIGKILL: the kernel's parent-death signal where there is one (Linux), and a
    watchdog thread everywhere. A parent that died while the worker started ends it at once."""
    if sys.platform.startswith("linux"):
        try:
            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
        except (OSError, AttributeError):  # no prctl: the watchdog alone
            pass
    if os.getppid() != parent:  # the parent died before the signal was armed
        os._exit(1)

    def watch() -> None:
        while True:
            time.sleep(_WATCHDOG_S)
            if os.getppid() != parent:
                os._exit(1)

    threading.Thread(target=watch, name="terl-parent-watchdog", daemon=True).start()


def _init_worker(path: str, threads: int | None, sha256: str, stop, channel, parent: int) -> None:
    global _worker_policy, _worker_stop, _worker_channel
    # Ctrl-C reaches the whole process group: the parent handles it and sets `stop`,
    # which the workers check every step (killing them could leave a result half sent).
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    _die_with_parent(parent)
    _worker_stop = stop
    _worker_channel = channel
    _worker_policy = OnnxPolicy(path, threads=threads)
    if _worker_policy.sha256 != sha256:
        raise ContractError(f"{path}: the policy file changed on disk during the evaluation")


def _worker_episode(scenario: Scenario, seed: int, index: int, record: bool) -> None:
    """Run episode `index`, sending ("step", index, StepRecord) for every step (when
    `record`) and then ("end", index, metrics) to the parent as they happen."""

    def on_step(step: StepRecord) -> None:
        if _worker_stop.is_set():
            raise _Stopped
        if record:
            _send(("step", index, step))

    metrics = run_episode(_worker_policy, scenario, seed, on_step)
    _send(("end", index, metrics))


def _send(message: tuple) -> None:
    # Sent synchronously (no feeder thread): when the episode's future is done, every
    # message it sent is in the pipe, and a worker never exits with a message unsent.
    connection, lock = _worker_channel
    with lock:
        connection.send(message)


# --- evaluation ---------------------------------------------------------------------


def evaluate_policy(
    policy: OnnxPolicy | str | os.PathLike,
    scenario: Scenario,
    episodes: int,
    seed: int,
    max_steps: int | None = None,
    workers: int = 1,
    log_path: str | os.PathLike | EpisodeLogWriter | None = None,
    progress: Progress | None = None,
    threads: int | None = None,
) -> ScenarioResult:
    """Evaluate `policy` on `episodes` episodes of `scenario`; episode k uses seed + k.

    max_steps overrides the scenario's step limit. workers > 1 runs episodes in that many
    spawned processes. threads: onnxruntime intra-op threads of a policy given as a path
    and of each worker's policy (workers default to 1). log_path: an MCAP file to write every step to (see terl_rt.logs.format),
    or an open EpisodeLogWriter to append to (the caller closes it). Episodes are logged
    and reported to `progress` in episode order as they finish.
    """
    if isinstance(policy, (str, os.PathLike)):
        policy = OnnxPolicy(policy, threads=threads)
    if isinstance(episodes, bool) or not isinstance(episodes, int) or episodes < 1:
        raise ValueError(f"episodes must be a positive integer, got {episodes!r}")
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise ValueError(f"workers must be a positive integer, got {workers!r}")
    if max_steps is not None:
        scenario = scenario.replace(max_steps=max_steps)

    owns_log = log_path is not None and not isinstance(log_path, EpisodeLogWriter)
    log = EpisodeLogWriter(Path(log_path), policy_info(policy)) if owns_log else log_path
    start = time.perf_counter()
    per_episode: list[EpisodeMetrics] = []

    def finished(index: int, metrics: EpisodeMetrics) -> None:
        per_episode.append(metrics)
        if progress is not None:
            progress(index, metrics)

    try:
        workers = min(workers, episodes)
        if workers == 1:
            for k in range(episodes):
                if log is not None:
                    log.begin_episode(scenario, seed + k, k)
                metrics = run_episode(policy, scenario, seed + k, log.write_step if log is not None else None)
                if log is not None:
                    log.end_episode(metrics)
                finished(k, metrics)
        else:
            _evaluate_in_workers(policy, scenario, episodes, seed, workers, threads, log, finished)
    finally:
        if owns_log:
            log.close()

    summary = summarize(per_episode)
    return ScenarioResult(
        name=scenario.name, episodes=episodes, seed=seed, max_steps=scenario.max_steps,
        **asdict(summary), wall_s=time.perf_counter() - start, per_episode=tuple(per_episode),
    )


class _InOrderLog:
    """Writes the episodes that workers stream, in episode order.

    A log holds each episode's records together, so only one episode is written as its
    steps arrive (the lowest that has not ended); the steps of later episodes wait in
    memory until it ends. An interrupted run writes what waits before it closes the log.
    """

    def __init__(self, scenario: Scenario, seed: int, log: EpisodeLogWriter | None,
                 finished: Callable[[int, EpisodeMetrics], None]):
        self.scenario, self.seed, self.log, self.finished = scenario, seed, log, finished
        self.current = 0
        """the episode being written (every lower one is done)."""
        self.begun = False
        self.waiting: dict[int, list[StepRecord]] = {}
        self.ended: dict[int, EpisodeMetrics] = {}

    def receive(self, kind: str, index: int, payload) -> None:
        if index != self.current:
            if kind == "step":
                self.waiting.setdefault(index, []).append(payload)
            else:
                self.ended[index] = payload
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
        """Write every waiting step, in episode order; the episodes that did not end stay unended."""
        for index in sorted(set(self.waiting) | set(self.ended)):
            if self.log is None:
                break
            if self.begun:
                self.log.abandon_episode()
            self.current, self.begun = index, False
            for record in self.waiting.pop(index, []):
                self._write(record)
            if index in self.ended:
                self._end(self.ended.pop(index), report=False)

    def _write(self, record: StepRecord) -> None:
        if self.log is None:
            return
        if not self.begun:
            self.log.begin_episode(self.scenario, self.seed + self.current, self.current)
            self.begun = True
        self.log.write_step(record)

    def _end(self, metrics: EpisodeMetrics, report: bool = True) -> None:
        if self.log is not None:
            if not self.begun:
                self.log.begin_episode(self.scenario, self.seed + self.current, self.current)
            self.log.end_episode(metrics)
        self.begun = False
        if report:
            self.finished(self.current, metrics)
        self.current += 1


def _evaluate_in_workers(
    policy: OnnxPolicy,
    scenario: Scenario,
    episodes: int,
    seed: int,
    workers: int,
    threads: int | None,
    log: EpisodeLogWriter | None,
    finished: Callable[[int, EpisodeMetrics], None],
) -> None:
    """Run the episodes in `workers` spawned processes that stream their steps to this one,
    which logs them (see `_InOrderLog`) and reports the episodes in order."""
    context = get_context("spawn")
    stop = context.Event()
    messages, sending = context.Pipe(duplex=False)
    init = (str(policy.path), 1 if threads is None else threads, policy.sha256, stop, (sending, context.Lock()),
            os.getpid())
    pool = ProcessPoolExecutor(workers, mp_context=context, initializer=_init_worker, initargs=init)
    writer = _InOrderLog(scenario, seed, log, finished)
    futures = []
    interrupted: list[int] = []
    previous = None
    if threading.current_thread() is threading.main_thread():
        # Ctrl-C becomes a flag checked between messages: one taken off the queue is always written.
        previous = signal.signal(signal.SIGINT, lambda signum, frame: interrupted.append(signum))
    try:
        futures = [pool.submit(_worker_episode, scenario, seed + k, k, log is not None) for k in range(episodes)]
        while writer.current < episodes:
            if interrupted:
                raise KeyboardInterrupt
            if messages.poll(0.1):
                writer.receive(*messages.recv())
            else:
                for future in futures:
                    if future.done() and future.exception() is not None:
                        raise future.exception()
        pool.shutdown()
    except BaseException:
        # Interrupted or failed: the workers stop within a step; what they sent is logged.
        stop.set()
        for future in futures:
            future.cancel()
        try:
            _drain(messages, futures, writer)
        finally:
            try:
                writer.flush_waiting()
            finally:
                pool.shutdown(wait=True, cancel_futures=True)
        raise
    finally:
        if previous is not None:
            signal.signal(signal.SIGINT, previous)
        messages.close()
        sending.close()


def _drain(messages, futures, writer: _InOrderLog, limit_s: float = 10.0) -> None:
    """Take what the workers still send until each has stopped (at most `limit_s`)."""
    deadline = time.monotonic() + limit_s
    while time.monotonic() < deadline:
        if messages.poll(0.05):
            writer.receive(*messages.recv())
        elif all(future.done() for future in futures):
            return
