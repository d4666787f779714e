"""`terl_rt.evaluate`: the one call that evaluates a policy. It opens what the evaluation
needs (the policy from a path or a shipped policy's name, the backend, the episode log),
runs each scenario's episodes (`episodes.run_scenario`: episode k with seed + k, batched,
the same results on every backend), writing every step to the sinks of `log`
(terl_rt.logs.sink), and closes what it opened.

    import terl_rt
    evaluation = terl_rt.evaluate("terl", "small-15", episodes=20, seed=0)
    print(evaluation.result.success_rate, evaluation.result.per_episode[0])
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from contextlib import AbstractContextManager, ExitStack, nullcontext
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from terl_rt.evaluation.backends import open_backend
from terl_rt.evaluation.episodes import Progress, ScenarioResult, run_scenario
from terl_rt.evaluation.play import BATCH_ENVS
from terl_rt.evaluation.pool import LocalBackend
from terl_rt.evaluation.runs import Backend
from terl_rt.logs.held import episode_log
from terl_rt.logs.sink import StepSink, StepSinks
from terl_rt.logs.writer import EpisodeLogWriter
from terl_rt.policy.onnx_policy import OnnxPolicy, policy_info
from terl_rt.policy.protocol import Policy, as_policy
from terl_rt.policy.shipped import open_policy
from terl_rt.safety.acting import Acting
from terl_rt.safety.risk import Risk
from terl_rt.safety.shield import Shield
from terl_rt.sim.observation import Observation
from terl_rt.sim.scenario import Scenario

LogTarget = str | os.PathLike | StepSink
"""Where `evaluate` writes every step: an MCAP file's path (the log opened there) or a sink."""
ScenarioProgress = Callable[[Scenario, int], AbstractContextManager[Progress]]
"""(scenario, episodes) -> a context around that scenario's evaluation, whose value is
called after each of its episodes with the episode's index and metrics (a progress bar)."""


@dataclass(frozen=True)
class Evaluation:
    """What `evaluate` gives: the policy evaluated and its results, one a scenario."""

    policy: dict[str, Any]
    """`policy_info` of the policy: name, sha256, path, metadata."""
    acting: Acting
    """how the policy acted (greedy, risk-aware, shielded): `acting.label` names the rows."""
    seed: int
    """episode k of every scenario ran with seed + k."""
    results: tuple[ScenarioResult, ...]
    """per scenario, in the order given: every episode's metrics and their aggregates."""
    log_path: Path | None
    """the MCAP episode log written (given as a path or an EpisodeLogWriter), None without one."""
    logged_episodes: int
    """episodes in the log (0 without one)."""

    @property
    def result(self) -> ScenarioResult:
        """The result of the only scenario; ValueError with several (read `results`)."""
        if len(self.results) != 1:
            raise ValueError(f"{len(self.results)} scenarios were evaluated: read `results`")
        return self.results[0]


def evaluate(
    policy: Policy | Callable[[Observation], Any] | str | os.PathLike | None = None,
    scenario: Scenario | str | Sequence[Scenario | str] = "small-15",
    episodes: int = 20,
    seed: int = 0,
    *,
    max_steps: int | None = None,
    log: LogTarget | Sequence[LogTarget] | None = None,
    replace_log: bool = True,
    workers: int | None = None,
    backend: Backend | str = "local",
    address: str | None = None,
    threads: int | None = None,
    envs: int = BATCH_ENVS,
    progress: ScenarioProgress | None = None,
    shield: Shield | bool | None = None,
    risk: Risk | str | None = None,
) -> Evaluation:
    """Evaluate `policy` on `episodes` episodes of each scenario, episode k with seed + k.

    policy: an ONNX file's path, a shipped policy's name (`terl`, `iqn-seed-1`, ...;
    `terl_rt.policy.shipped`), None for the default policy, a `Policy` (an OnnxPolicy,
    training's TorchPolicy) or a function of observation rows [R] to R action indices
    (`CallablePolicy`). scenario: a Scenario or a preset's name, or several. max_steps:
    every scenario's step limit (decision steps of 0.5 s) instead of its own.
    log: where every step goes, in episode order (terl_rt.logs.sink): an MCAP file's path
    (published at the first step; an existing file is replaced only with `replace_log`, else
    FileExistsError), or a StepSink the caller opened and closes (an EpisodeLogWriter to
    append to, a terl_rt.logs.live.LiveSink, one of your own), or a list of them, each
    getting every step (one MCAP log at most).
    backend: "local" or "ray" (`open_backend` with `workers`, `address`, `threads` and
    `envs`, closed at the end), or an open Backend (the caller closes it; then workers and
    envs are the backend's). threads: onnxruntime intra-op threads of a policy opened here
    and of each worker's. A policy that is no ONNX file runs in this process only (one local
    worker). progress: a context a scenario (`ScenarioProgress`), told of each episode.
    shield: True (the default `Shield`) or a Shield puts the policy under the shield
    (terl_rt.safety.shield; docs/safety.md). risk: "cvar:ALPHA" or a Risk acts on the CVaR of
    the policy's quantiles instead of their mean (ValueError for a policy without them).
    """
    acting = Acting.of(shield, risk)
    if isinstance(episodes, bool) or not isinstance(episodes, int) or episodes < 1:
        raise ValueError(f"episodes must be a positive integer, got {episodes!r}")
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or workers < 1):
        raise ValueError(f"workers must be a positive integer, got {workers!r}")
    if not isinstance(backend, str) and (workers not in (None, 1) or envs != BATCH_ENVS):
        raise ValueError("pass workers and envs to the backend, not to evaluate as well")
    scenarios = [_scenario(each, max_steps) for each in _as_list(scenario)]
    targets = _log_targets(log)
    if policy is None or isinstance(policy, (str, os.PathLike)):
        policy = open_policy(policy, threads=threads)
    policy = as_policy(policy)
    acting.check(policy)
    if not isinstance(policy, OnnxPolicy) and not _in_process(backend, workers):
        raise ValueError(f"policy {policy.name} is no ONNX file: it runs in this process only "
                         "(the local backend with one worker)")
    with ExitStack() as opened:
        if isinstance(backend, str):
            backend = opened.enter_context(open_backend(backend, workers, address, threads, envs))
        sinks = [
            opened.enter_context(EpisodeLogWriter(Path(target), policy_info(policy), staged=True, replace=replace_log))
            if isinstance(target, (str, os.PathLike)) else target
            for target in targets
        ]
        sink = None if not sinks else sinks[0] if len(sinks) == 1 else StepSinks(sinks)
        written = episode_log(sink)
        results = []
        for each in scenarios:
            with progress(each, episodes) if progress is not None else nullcontext(None) as on_episode:
                results.append(run_scenario(policy, each, episodes, seed, backend, sink, on_episode, acting))
    return Evaluation(policy_info(policy), acting, seed, tuple(results), None if written is None else written.path,
                      0 if written is None else written.episodes_written)


def evaluate_policy(
    policy: Policy | str | os.PathLike,
    scenario: Scenario,
    episodes: int,
    seed: int,
    max_steps: int | None = None,
    workers: int = 1,
    log_path: LogTarget | Sequence[LogTarget] | None = None,
    progress: Progress | None = None,
    threads: int | None = None,
    backend: Backend | None = None,
    envs: int = BATCH_ENVS,
) -> ScenarioResult:
    """`terl_rt.evaluate` on one scenario, its result: the arguments are evaluate's
    (`log_path` its `log`, `progress` called after each episode with its index and metrics)."""
    per_scenario = None if progress is None else (lambda scenario, count: nullcontext(progress))
    return evaluate(policy, scenario, episodes, seed, max_steps=max_steps, log=log_path, workers=workers,
                    threads=threads, backend=backend or "local", envs=envs, progress=per_scenario).result


def _in_process(backend: Backend | str, workers: int | None) -> bool:
    """Whether the episodes run in this process: the local backend with one worker."""
    if isinstance(backend, str):
        return backend == "local" and workers in (None, 1)
    return isinstance(backend, LocalBackend) and backend.workers == 1


def _log_targets(log: LogTarget | Sequence[LogTarget] | None) -> list[LogTarget]:
    """The targets of `evaluate`'s `log` as a list (None: none); TypeError for anything but
    paths and sinks."""
    if log is None:
        return []
    targets = [log] if isinstance(log, (str, os.PathLike, StepSink)) or not isinstance(log, Sequence) else list(log)
    for target in targets:
        if not isinstance(target, (str, os.PathLike, StepSink)):
            raise TypeError(f"log takes an MCAP file's path, a StepSink (terl_rt.logs.sink) or a list of them, "
                            f"got {type(target).__name__}")
    return targets


def _as_list(scenario: Scenario | str | Sequence[Scenario | str]) -> list[Scenario | str]:
    """One scenario or several, as a list."""
    return [scenario] if isinstance(scenario, (Scenario, str)) else list(scenario)


def _scenario(scenario: Scenario | str, max_steps: int | None) -> Scenario:
    """A Scenario (a preset's by name) with `max_steps` in force where given."""
    scenario = Scenario.preset(scenario) if isinstance(scenario, str) else scenario
    return scenario if max_steps is None else scenario.replace(max_steps=max_steps)
