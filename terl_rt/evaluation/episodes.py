"""Evaluate a policy on a scenario: success rate, travel time, collision ratio (world.md section 10).

Episode k of an evaluation with seed s is the episode of `Simulator(scenario, seed=s + k)`,
bit for bit, so any episode can be run again alone (terl_rt.evaluation.play runs one).
The episodes run in batches, each batch's together in one World with one policy call a
step for all their deciding pursuers (terl_rt.evaluation.play.batch_steps). Where the
batches run is a backend (terl_rt.evaluation.backends): this process, worker processes
(`workers > 1`) or Ray tasks; results and logs are the same on each, in episode order,
whatever the number of workers or the batch size (terl_rt.evaluation.runs).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass

from terl_rt.evaluation.runs import Backend, EpisodeSpec, run_episodes
from terl_rt.evaluation.stats import episode_intervals, travel_times
from terl_rt.logs.sink import StepSink
from terl_rt.policy.protocol import Policy
from terl_rt.safety.acting import Acting
from terl_rt.sim.evader import DEFAULT_EVADER
from terl_rt.sim.metrics import EpisodeMetrics, summarize
from terl_rt.sim.scenario import Scenario, scenario_label

RESULTS_SCHEMA = 3
"""Version of the per-episode result fields (`ScenarioResult.episode_rows`, `eval --json`
and `--csv`): 2 added `return`, 3 what the collided pursuers touched (`collisions_teammate`,
`collisions_evader`, `collisions_obstacle`)."""

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
    step_s: float = 0.5
    """s: the decision step (params.dt x params.substeps); the step limit lasts max_steps x step_s."""
    acting: Acting = Acting()
    """how the policy acted: greedy (the paper's rule), risk-aware or shielded (terl_rt.safety);
    `acting.label` names a row that did not act greedily."""

    @property
    def collisions_touched(self) -> dict[str, int] | None:
        """Collided pursuers over every episode by what they touched ({"teammate", "evader",
        "obstacle"}: one that touched two kinds counts under each); None where an episode did not record it."""
        touched = [m.collisions_touched for m in self.per_episode]
        if not touched or any(kinds is None for kinds in touched):
            return None
        return {kind: sum(kinds[kind] for kinds in touched) for kind in touched[0]}

    @property
    def shield_overrides_per_decision(self) -> float | None:
        """The shield's overrides per pursuer-step over every episode; None for a run without it."""
        if self.acting.shield is None:
            return None
        decisions = sum(m.decisions or 0 for m in self.per_episode)
        return sum(m.shield_overrides or 0 for m in self.per_episode) / decisions if decisions else float("nan")
    evader: str = DEFAULT_EVADER
    """the evaders' behaviour (`Scenario.evader`, a name of terl_rt.sim.evader.EVADERS)."""

    @property
    def label(self) -> str:
        """The scenario's name, with the evader where it is not the default: "small-15/still"."""
        return scenario_label(self.name, self.evader)

    @property
    def limit_s(self) -> float:
        """s: the step limit as a time, what a failed episode counts in `travel_time_s_limit_mean`."""
        return self.max_steps * self.step_s

    @property
    def travel_time_s_success_mean(self) -> float:
        """s: mean travel time of the successful episodes (nan without one)."""
        times = travel_times(self.per_episode, self.limit_s)["travel_time_s_success"]
        return float(times.mean()) if times.size else float("nan")

    @property
    def travel_time_s_limit_mean(self) -> float:
        """s: mean travel time of every episode, each failure counted at the step limit (nan without episodes)."""
        times = travel_times(self.per_episode, self.limit_s)["travel_time_s_limit"]
        return float(times.mean()) if times.size else float("nan")

    def ci95(self) -> dict[str, tuple[float, float]]:
        """95 % intervals over the episodes (terl_rt.evaluation.stats.episode_intervals): the
        success rate's exact (Clopper-Pearson) one, bootstrap ones (fixed seed) of the mean
        travel times (s: as run, of successes, failures at the limit) and collision ratio."""
        return episode_intervals(self.per_episode, self.limit_s)

    def episode_rows(self) -> list[dict]:
        """One row per episode (fields of RESULTS_SCHEMA): index, seed, outcome (success,
        too_few_pursuers or step_limit), steps, travel time, collisions (pursuers) and how
        many of them touched a teammate, an evader, an obstacle, collision ratio, captures (evaders encircled) and return (every pursuer's reward
        summed over the episode); under the shield also its overrides and the pursuer-steps
        decided."""
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
                "collisions_teammate": m.collisions_teammate,
                "collisions_evader": m.collisions_evader,
                "collisions_obstacle": m.collisions_obstacle,
                "captures": m.evaders_encircled,
                "return": m.team_return,
                **({} if m.shield_overrides is None else {"shield_overrides": m.shield_overrides,
                                                          "decisions": m.decisions}),
            }
            for k, m in enumerate(self.per_episode)
        ]

    def to_dict(self, per_episode: bool = False) -> dict:
        """The JSON row of `terl-rt eval --json`; `per_episode` adds every episode's row
        (`episode_rows`). A row that did not act greedily says how it acted ("acting": the
        shield's parameters and the risk measure, with the shield's overrides a pursuer-step)."""
        row = {
            "name": self.name,
            "evader": self.evader,
            "episodes": self.episodes,
            "seed": self.seed,
            "max_steps": self.max_steps,
            "success_rate": self.success_rate,
            "travel_time_s_mean": self.travel_time_s_mean,
            "travel_time_s_std": self.travel_time_s_std,
            "travel_time_s_success_mean": _number(self.travel_time_s_success_mean),
            "travel_time_s_limit_mean": _number(self.travel_time_s_limit_mean),
            "limit_s": self.limit_s,
            "collision_ratio_mean": self.collision_ratio_mean,
            "collisions_touched": self.collisions_touched,
            "steps_mean": self.steps_mean,
            "ci95": {name: [_number(bound) for bound in interval] for name, interval in self.ci95().items()},
            "wall_s": self.wall_s,
        }
        if not self.acting.plain:
            row["acting"] = {**self.acting.to_dict(), "label": self.acting.label,
                             "shield_overrides_per_decision": _number(self.shield_overrides_per_decision)
                             if self.acting.shield is not None else None}
        if per_episode:
            row["per_episode"] = self.episode_rows()
        return row


def _number(value: float) -> float | None:
    """`value` for JSON: None where it is NaN (a mean over no episode), which JSON cannot hold."""
    return None if math.isnan(value) else value


def episode_outcome(metrics: EpisodeMetrics, max_steps: int) -> str:
    """How an episode ended: "success" (every evader encircled), "too_few_pursuers"
    (fewer than 3 left) or "step_limit"."""
    if metrics.success:
        return "success"
    return "step_limit" if metrics.steps >= max_steps else "too_few_pursuers"


def run_scenario(
    policy: Policy, scenario: Scenario, episodes: int, seed: int, backend: Backend,
    log: StepSink | None = None, progress: Progress | None = None, acting: Acting = Acting(),
) -> ScenarioResult:
    """`episodes` episodes of `scenario` (its step limit in force) on `backend`, episode k
    with seed + k, acting by `acting`; every step written to `log` (a sink) and every episode reported
    to `progress` in episode order as it finishes. Opens nothing: the caller owns the policy,
    backend and log."""
    specs = [EpisodeSpec(0, scenario, seed + k, k, acting) for k in range(episodes)]
    start = time.perf_counter()
    per_episode: list[EpisodeMetrics] = []

    def finished(index: int, metrics: EpisodeMetrics) -> None:
        per_episode.append(metrics)
        if progress is not None:
            progress(index, metrics)

    run_episodes([policy], specs, backend, log, finished)
    return scenario_result(scenario, seed, per_episode, time.perf_counter() - start, acting)


def scenario_result(scenario: Scenario, seed: int, per_episode: Sequence[EpisodeMetrics], wall_s: float,
                    acting: Acting = Acting()) -> ScenarioResult:
    """The ScenarioResult of `per_episode`, episode k run with seed + k acting by `acting`; wall_s in s."""
    return ScenarioResult(
        name=scenario.name, episodes=len(per_episode), seed=seed, max_steps=scenario.max_steps,
        **asdict(summarize(per_episode)), wall_s=wall_s, per_episode=tuple(per_episode),
        step_s=scenario.params.dt * scenario.params.substeps, acting=acting, evader=scenario.evader,
    )
