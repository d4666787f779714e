"""Each seed of a comparison against the paper's goals, as `terl-rt report` judges one policy.

A comparison over seeds aggregates each method's seeds; a user who ships one seed needs each
seed's own standing too: per scale group its success rate (with the exact interval over the
group's episodes), travel time and collision ratio, the paper's goals it meets
(`terl_rt.paper.report.goal_checks`: 15 with the released small config, 12 without), and
its successes in each world past 80 pursuers.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from terl_rt.evaluation.stats import format_interval
from terl_rt.paper.report import GoalCheck, GroupSummary, goal_checks, group_summaries
from terl_rt.paper.seed_comparison import BEYOND_PURSUERS, SeedRun, beyond_group, group_of, method_runs

TABLE_GROUPS = ("small", "small (released config)", "medium", "large", "CC")
"""The paper's scale groups, in the table's column order (`terl_rt.paper.numbers.REPORT_GROUPS`)."""


@dataclass(frozen=True)
class SeedGoals:
    """One seed's standing: its group summaries, the goals checked on them, and beyond the paper
    each world's successes and collision ratio."""

    method: str
    seed: int | None
    groups: tuple[GroupSummary, ...]
    goals: tuple[GoalCheck, ...]
    beyond: tuple[tuple[str, int, int, float], ...]
    """(group, successes, episodes, mean collision ratio) of each world past 80 pursuers evaluated."""

    @property
    def met(self) -> int:
        return sum(check.met for check in self.goals)

    def to_dict(self) -> dict:
        return {
            "method": self.method, "seed": self.seed, "goals_met": self.met, "goals": len(self.goals),
            "groups": [summary.to_dict() for summary in self.groups],
            "checks": [check.to_dict() for check in self.goals],
            "beyond": [{"group": group, "successes": won, "episodes": episodes, "collision_ratio": collision}
                       for group, won, episodes, collision in self.beyond],
        }


def seed_goals(runs: Sequence[SeedRun]) -> list[SeedGoals]:
    """Each run's SeedGoals, methods in the comparison's order, seeds in theirs."""
    standings = []
    for method, seed_runs in method_runs(runs).items():
        for run in seed_runs:
            beyond = {group_of(result.name): result for result in run.results}
            standings.append(SeedGoals(
                method=method, seed=run.seed, groups=tuple(group_summaries(run.results)),
                goals=tuple(goal_checks(run.results)),
                beyond=tuple(
                    (group, round(result.success_rate * result.episodes), result.episodes, result.collision_ratio_mean)
                    for group, result in ((beyond_group(n), beyond.get(beyond_group(n))) for n in BEYOND_PURSUERS)
                    if result is not None
                ),
            ))
    return standings


def seed_goals_markdown(standings: Sequence[SeedGoals]) -> list[str]:
    """The comparison page's section "Each seed against the paper's goals" (lines)."""
    groups = [g for g in TABLE_GROUPS if any(s.group == g for standing in standings for s in standing.groups)]
    beyond = [b[0] for b in standings[0].beyond] if standings else []
    lines = [
        "## Each seed against the paper's goals",
        "",
        "Each seed's policy alone, as `terl-rt report` judges one policy: per scale group the success "
        "rate with its exact (Clopper-Pearson) interval over the group's episodes, the travel time (s, "
        "every episode as it ran) and the collision ratio, means over the group's presets; the paper's "
        "TERL goals it meets (success 1.00 at small, medium and large scale and 0.80 on CC, travel time "
        "within 46, 64, 63 and 227 s, collision ratio at most 0.03; the released small config held to "
        "small scale's); beyond 80 pursuers, the episodes it encircled every evader in and the "
        "collision ratio.",
        "",
        "| method | seed | " + " | ".join(groups + beyond) + " | goals met |",
        "|---|---:|" + "---|" * (len(groups) + len(beyond)) + "---:|",
    ]
    for standing in standings:
        by_group = {summary.group: summary for summary in standing.groups}
        cells = [_group_cell(by_group.get(group)) for group in groups]
        won = {group: (successes, episodes, collision) for group, successes, episodes, collision in standing.beyond}
        cells += [f"{won[g][0]}/{won[g][1]}, {won[g][2]:.3f}" if g in won else "—" for g in beyond]
        seed = "—" if standing.seed is None else str(standing.seed)
        lines.append(f"| {standing.method} | {seed} | " + " | ".join(cells) + f" | {standing.met} of {len(standing.goals)} |")
    return lines


def _group_cell(summary: GroupSummary | None) -> str:
    """"1.00 [0.99, 1.00], 44.4 s, 0.016": success (exact interval), travel time, collision ratio."""
    if summary is None:
        return "—"
    return (f"{summary.success_rate:.2f} {format_interval(summary.ci95['success_rate'], 2)}, "
            f"{summary.travel_time_s_mean:.1f} s, {summary.collision_ratio_mean:.3f}")
