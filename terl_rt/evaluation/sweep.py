"""A sweep: several policies x scenarios x seeds, run as one batch, into one results table.

Every episode of the sweep is one spec of a single run (terl_rt.evaluation.runs), so a
backend with many workers (a Ray cluster) is kept busy across scenario and policy
boundaries; the results come back in the sweep's order (policy, then scenario, then
episode k with seed + k) whatever the backend. A row of the table is one policy on one
scenario: its `ScenarioResult`, whose `wall_s` is the time from the start of the sweep
until the row's last episode was reported.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from terl_rt.evaluation.episodes import Progress, ScenarioResult, scenario_result
from terl_rt.evaluation.runs import Backend, EpisodeSpec, run_episodes
from terl_rt.evaluation.stats import CI_METRICS, format_interval
from terl_rt.policy.onnx_policy import OnnxPolicy
from terl_rt.safety.acting import Acting
from terl_rt.sim.metrics import EpisodeMetrics
from terl_rt.sim.scenario import Scenario


@dataclass(frozen=True)
class SweepRow:
    """One policy on one scenario."""

    policy: str
    """the policy's name (metadata terl.model)."""
    policy_sha256: str
    policy_path: str
    result: ScenarioResult


@dataclass(frozen=True)
class Sweep:
    """The rows of a sweep in its order (policy, then scenario) and its wall-clock time."""

    rows: tuple[SweepRow, ...]
    wall_s: float
    """s: the whole sweep."""


def run_sweep(
    policies: Sequence[OnnxPolicy],
    scenarios: Sequence[Scenario],
    episodes: int,
    seed: int,
    backend: Backend,
    max_steps: int | None = None,
    progress: Progress | None = None,
    acting: Acting = Acting(),
) -> Sweep:
    """Evaluate every policy on every scenario, `episodes` episodes each (episode k with
    seed + k), as one run on `backend`, every policy acting by `acting` (its rows name it).
    max_steps overrides the scenarios' step limits; `progress` hears of each episode (its
    number in the sweep) in the sweep's order."""
    for policy in policies:
        acting.check(policy)
    if isinstance(episodes, bool) or not isinstance(episodes, int) or episodes < 1:
        raise ValueError(f"episodes must be a positive integer, got {episodes!r}")
    if not policies or not scenarios:
        raise ValueError("a sweep needs at least one policy and one scenario")
    if max_steps is not None:
        scenarios = [scenario.replace(max_steps=max_steps) for scenario in scenarios]
    groups = [(p, scenario) for p in range(len(policies)) for scenario in scenarios]
    specs = [EpisodeSpec(p, scenario, seed + k, k, acting) for p, scenario in groups for k in range(episodes)]
    per_episode: list[EpisodeMetrics] = []
    done_s: list[float] = []
    start = time.perf_counter()

    def finished(number: int, metrics: EpisodeMetrics) -> None:
        per_episode.append(metrics)
        if len(per_episode) % episodes == 0:
            done_s.append(time.perf_counter() - start)
        if progress is not None:
            progress(number, metrics)

    run_episodes(policies, specs, backend, None, finished)
    rows = tuple(
        SweepRow(
            policy=policies[p].name, policy_sha256=policies[p].sha256, policy_path=str(policies[p].path),
            result=scenario_result(scenario, seed, per_episode[g * episodes:(g + 1) * episodes], done_s[g], acting),
        )
        for g, (p, scenario) in enumerate(groups)
    )
    return Sweep(rows=rows, wall_s=time.perf_counter() - start)


TABLE_COLUMNS = (
    "policy", "policy_sha256", "policy_path", "scenario", "evader", "episodes", "seed", "max_steps",
    "success_rate", "success_rate_ci_low", "success_rate_ci_high",
    "travel_time_s_mean", "travel_time_s_std", "travel_time_s_ci_low", "travel_time_s_ci_high",
    "collision_ratio_mean", "collision_ratio_ci_low", "collision_ratio_ci_high",
    "steps_mean", "acting", "shield_overrides_per_decision",
)
"""Columns of the sweep's CSV table, one row per policy and scenario (95 % bootstrap intervals);
`acting` names rows that did not act greedily (empty for the paper's rule), the shield's
overrides a pursuer-step are empty without it."""


def table_rows(sweep: Sweep) -> list[dict]:
    """One flat dict per row, keyed by TABLE_COLUMNS."""
    rows = []
    for row in sweep.rows:
        result = row.result
        intervals = result.ci95()
        flat = {
            "policy": row.policy, "policy_sha256": row.policy_sha256, "policy_path": row.policy_path,
            "scenario": result.name, "evader": result.evader,
            "episodes": result.episodes, "seed": result.seed, "max_steps": result.max_steps,
            "success_rate": result.success_rate, "travel_time_s_mean": result.travel_time_s_mean,
            "travel_time_s_std": result.travel_time_s_std, "collision_ratio_mean": result.collision_ratio_mean,
            "steps_mean": result.steps_mean, "acting": result.acting.label,
            "shield_overrides_per_decision": result.shield_overrides_per_decision,
        }
        for name in CI_METRICS:
            flat[f"{name}_ci_low"], flat[f"{name}_ci_high"] = intervals[name]
        rows.append({column: flat[column] for column in TABLE_COLUMNS})
    return rows


def sweep_json(sweep: Sweep) -> dict:
    """The sweep as JSON: its wall time and per row the policy (name, sha256, path) and
    the scenario's results with every episode (`ScenarioResult.to_dict(per_episode=True)`)."""
    return {
        "wall_s": sweep.wall_s,
        "rows": [
            {"policy": {"name": row.policy, "sha256": row.policy_sha256, "path": row.policy_path},
             **row.result.to_dict(per_episode=True)}
            for row in sweep.rows
        ],
    }


def sweep_markdown(sweep: Sweep) -> str:
    """The table as markdown: a row per policy and scenario, means with 95 % bootstrap intervals."""
    lines = [
        "| policy | file | sha256 | scenario | episodes | success | travel time (s) | collision ratio | steps |",
        "|---|---|---|---|---:|---:|---:|---:|---:|",
    ]
    for row in sweep.rows:
        result = row.result
        ci = result.ci95()
        lines.append(
            f"| {row.policy}{f' [{result.acting.label}]' if result.acting.label else ''} | {Path(row.policy_path).name} "
            f"| `{row.policy_sha256[:12]}` | {result.label} "
            f"| {result.episodes} "
            f"| {result.success_rate:.2f} {format_interval(ci['success_rate'], 2)} "
            f"| {result.travel_time_s_mean:.1f} ± {result.travel_time_s_std:.1f} {format_interval(ci['travel_time_s'], 1)} "
            f"| {result.collision_ratio_mean:.3f} {format_interval(ci['collision_ratio'], 3)} "
            f"| {result.steps_mean:.1f} |"
        )
    return "\n".join(lines) + "\n"
