"""Evaluations in the raw-data JSON format of InstaDeep's marl-eval (Gorsane et al. 2022),
the tools MARL researchers aggregate and plot results with.

marl-eval reads environment -> task -> algorithm -> run -> {"step_<i>": {"step_count":
int, metric: [one value an evaluation episode], ...}, "absolute_metrics": {metric:
[...]}}. Here the environment is "terl-rt", a task a scenario (preset), an algorithm a
method by its recipe stem (terl, iqn, dqn, mean, terl-no-re, terl-no-ts), a run a
training seed. A shipped policy is evaluated once, after training: one logging step,
"step_1", whose step_count is its training steps (terl.training_steps, 0 where unknown),
and its episodes are also the run's absolute metrics (the final policy's evaluation).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

from terl_rt.evaluation.episodes import ScenarioResult
from terl_rt.evaluation.stats import travel_times
from terl_rt.paper.numbers import PAPER_METHODS
from terl_rt.paper.seed_comparison import method_stem
from terl_rt.policy.contract import META_TRAINING_STEPS

ENVIRONMENT = "terl-rt"
STEP = "step_1"
ABSOLUTE = "absolute_metrics"
METRICS = ("success", "travel_time_s", "collision_ratio", "return")
"""Per-episode metrics of the export: success (1.0 or 0.0), travel time (s) as run,
collision ratio and the team's return (left out where an episode has none)."""

_STEMS = {paper: stem for stem, paper in PAPER_METHODS.items()}
"""The paper's method name -> its recipe stem."""

Entry = tuple[str, str, Mapping, Sequence[ScenarioResult]]
"""(method, run name, policy info, evaluations): one trained policy's results."""


def algorithm_name(method: str, metadata: Mapping[str, str]) -> str:
    """A method's name in the export: the recipe stem its policy's metadata names
    (`method_stem`), else the stem of the paper's name (TERL -> terl, w/o RE -> terl-no-re),
    or the name itself for a method the paper does not have."""
    return method_stem(metadata) or _STEMS.get(method, method)


def episode_lists(result: ScenarioResult, with_return: bool) -> dict[str, list[float]]:
    """metric -> [K] values of `result`'s episodes (METRICS; "return" only `with_return`)."""
    episodes = result.per_episode
    lists = {
        "success": [float(m.success) for m in episodes],
        "travel_time_s": [float(t) for t in travel_times(episodes, result.limit_s)["travel_time_s"]],
        "collision_ratio": [float(m.collision_ratio) for m in episodes],
    }
    if with_return:
        lists["return"] = [float(m.team_return) for m in episodes]
    return lists


def marl_eval_dict(entries: Sequence[Entry]) -> dict:
    """The marl-eval JSON of `entries`; "return" is exported only when every episode of
    every entry has one, so every run carries the same metrics (marl-eval requires it)."""
    with_return = all(m.team_return is not None for _, _, _, results in entries for r in results for m in r.per_episode)
    tasks: dict[str, dict] = {}
    for method, run, policy, results in entries:
        metadata = policy.get("metadata") or {}
        steps = metadata.get(META_TRAINING_STEPS, "0")
        step_count = int(steps) if str(steps).isdigit() else 0
        for result in results:
            lists = episode_lists(result, with_return)
            tasks.setdefault(result.name, {}).setdefault(algorithm_name(method, metadata), {})[run] = {
                STEP: {"step_count": step_count, **lists},
                ABSOLUTE: {name: list(values) for name, values in lists.items()},
            }
    return {ENVIRONMENT: tasks}
