"""A policy's results set against the TERL paper: docs/results.md and docs/results.png.

`write_report` takes the `ScenarioResult`s of `terl_rt.evaluation.evaluate.evaluate_policy` and writes a
markdown page (the policy, the command, the date; a row per preset beside the paper's
TERL row for its scale group; a row per scale group; which of the paper's goals are
met) and a figure in the manner of the paper's Fig. 3 (`terl_rt.paper.figures`).
`terl_rt.paper.comparison` shares the helpers below (group summaries and the wording
of intervals, run settings and caveats).
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import NamedTuple

from terl_rt.evaluation.episodes import ScenarioResult
from terl_rt.evaluation.stats import CI_METRICS, format_interval, mean_intervals
from terl_rt.paper.figures import plot_results, require_matplotlib
from terl_rt.paper.numbers import (
    ABLATION_TABLE,
    CC_TABLE,
    GOALS,
    REPORT_GROUPS,
    SCALE_GROUPS,
    SMALL_RELEASED,
    TERL,
    TERL_BY_GROUP,
    paper_group,
    scale_group,
)
from terl_rt.policy.contract import META_TRAINED_ON, META_TRAINING_STEPS
from terl_rt.sim.scenario import PAPER_SUITE, PUBLISHED_SMALL_SUITE

MARKDOWN_NAME = "results.md"
FIGURE_NAME = "results.png"
PAPER_EPISODES = 20
"""Episodes a scenario in the paper's evaluation."""
PAPER_MAX_STEPS = 1000
"""Step limit of the paper's evaluation episodes (world.md section 10)."""
REPORT_SUITE: tuple[str, ...] = PAPER_SUITE[:3] + PUBLISHED_SMALL_SUITE + PAPER_SUITE[3:]
"""The presets `terl-rt report` evaluates by default: the paper's 10, with the released
small-scale config after the table's small presets."""


class ReportPaths(NamedTuple):
    """The files `write_report` wrote."""

    markdown: Path
    figure: Path


@dataclass(frozen=True)
class GroupSummary:
    """This policy's mean over the evaluated presets of one scale group (each preset weighs the same)."""

    group: str
    """one of `terl_rt.paper.numbers.REPORT_GROUPS`: 'small', 'small (released config)',
    'medium', 'large' or 'CC'."""
    presets: tuple[str, ...]
    """the group's presets that were evaluated, in the order given."""
    success_rate: float
    travel_time_s_mean: float
    """s: mean of the presets' mean travel times (every episode as it ran)."""
    collision_ratio_mean: float
    ci95: dict = field(default_factory=dict)
    """95 % intervals of the means (terl_rt.evaluation.stats.mean_intervals), by
    terl_rt.evaluation.stats.CI_METRICS name -> (low, high); NaN without episodes."""
    travel_time_s_success_mean: float = math.nan
    """s: mean of the presets' mean travel times of their successful episodes."""
    travel_time_s_limit_mean: float = math.nan
    """s: mean of the presets' mean travel times, failures counted at the step limit."""

    def to_dict(self) -> dict:
        return {
            **asdict(self), "presets": list(self.presets),
            "ci95": {name: list(interval) for name, interval in self.ci95.items()},
        }


@dataclass(frozen=True)
class GoalCheck:
    """One of the paper's goals for one scale group, and whether this policy meets it."""

    group: str
    metric: str
    """'success rate', 'travel time' or 'collision ratio'."""
    value: float
    """this policy's group mean (travel time in s)."""
    goal: float
    """the bound: a minimum for the success rate, a maximum for the others."""
    met: bool

    def to_dict(self) -> dict:
        return asdict(self)


# --- numbers ------------------------------------------------------------------------


def group_summaries(results: Sequence[ScenarioResult]) -> list[GroupSummary]:
    """Per report group with at least one evaluated preset, in REPORT_GROUPS' order: the
    mean of the presets' success rates, mean travel times (s) and mean collision ratios."""
    summaries = []
    for group in REPORT_GROUPS:
        members = [r for r in results if scale_group(r.name) == group]
        if not members:
            continue
        summaries.append(GroupSummary(
            group=group,
            presets=tuple(r.name for r in members),
            success_rate=_mean(r.success_rate for r in members),
            travel_time_s_mean=_mean(r.travel_time_s_mean for r in members),
            collision_ratio_mean=_mean(r.collision_ratio_mean for r in members),
            ci95=(
                mean_intervals([r.per_episode for r in members], [r.limit_s for r in members])
                if all(r.per_episode for r in members) else dict.fromkeys(CI_METRICS, (math.nan, math.nan))
            ),
            travel_time_s_success_mean=_mean(r.travel_time_s_success_mean for r in members),
            travel_time_s_limit_mean=_mean(r.travel_time_s_limit_mean for r in members),
        ))
    return summaries


def goal_checks(results: Sequence[ScenarioResult]) -> list[GoalCheck]:
    """The paper's goals (`terl_rt.paper.numbers.GOALS`) for every evaluated report group (the
    released small config: small scale's): success rate at or above, travel time (s) and
    collision ratio at or under the bound.

    A short travel time counts only with the success goal met: episodes that end
    early because too few pursuers are left are not fast encirclements.
    """
    checks = []
    for summary in group_summaries(results):
        goal = GOALS[paper_group(summary.group)]
        succeeds = summary.success_rate >= goal.min_success_rate - 1e-9
        for metric, value, bound, met in (
            ("success rate", summary.success_rate, goal.min_success_rate, succeeds),
            ("travel time", summary.travel_time_s_mean, goal.max_travel_time_s,
             succeeds and summary.travel_time_s_mean <= goal.max_travel_time_s + 1e-9),
            ("collision ratio", summary.collision_ratio_mean, goal.max_collision_ratio,
             summary.collision_ratio_mean <= goal.max_collision_ratio + 1e-9),
        ):
            checks.append(GoalCheck(summary.group, metric, value, bound, met))
    return checks


def where_it_stands(results: Sequence[ScenarioResult]) -> str:
    """A short factual paragraph: per evaluated scale group, which of the paper's goals
    are met and which are missed, with the numbers; then what was not evaluated and
    whether the runs are comparable with the paper's (20 episodes, 1000 steps)."""
    summaries = {s.group: s for s in group_summaries(results)}
    checks = goal_checks(results)
    sentences = []
    for group, summary in summaries.items():
        own = [c for c in checks if c.group == group]
        met = [c for c in own if c.met]
        missed = [c for c in own if not c.met]
        where = f"{group_title(group)} ({', '.join(summary.presets)})"
        if not missed:
            sentences.append(f"{where} meets all three goals: {join_words(_shown(c) for c in own)}.")
        elif not met:
            sentences.append(f"{where} misses all three goals: {join_words(_shown(c) for c in own)}.")
        else:
            sentences.append(
                f"{where} meets {len(met)} of 3 goals, {join_words(_shown(c) for c in met)}, "
                f"and misses {join_words(_shown(c) for c in missed)}."
            )
    if checks:
        sentences.append(f"In all, {sum(c.met for c in checks)} of {len(checks)} goals are met.")
    else:
        sentences.append("No preset of the paper's scale groups was evaluated, so no goal is checked.")

    missing = [g for g in SCALE_GROUPS if g not in summaries]
    if checks and missing:
        sentences.append(f"Not evaluated: {join_words(group_title(g, lower=True) for g in missing)}.")
    unreported = [r.name for r in results if scale_group(r.name) is None]
    if unreported:
        sentences.append(f"The paper reports nothing for {', '.join(unreported)}; those rows are not compared.")
    note = comparability_note(results)
    if note:
        sentences.append(note)
    return " ".join(sentences)


def comparability_note(results: Sequence[ScenarioResult]) -> str:
    """A sentence saying the runs are indicative only where the paper's presets among them ran
    fewer episodes than the paper's 20 or another step limit than its 1000; empty otherwise.
    More episodes than the paper's only narrow the intervals, and a scenario the paper does not
    report (scale_group None: curriculum stages, the worlds past it) is compared with nothing."""
    compared = [r for r in results if scale_group(r.name) is not None]
    fewer = sorted({r.episodes for r in compared if r.episodes < PAPER_EPISODES})
    limits = sorted({r.max_steps for r in compared if r.max_steps != PAPER_MAX_STEPS})
    differences = []
    if fewer:
        differences.append(f"{join_words((str(e) for e in fewer), 'or')} {'episode' if fewer == [1] else 'episodes'} "
                           f"a scenario, fewer than the paper's {PAPER_EPISODES}")
    if limits:
        differences.append(f"a step limit of {join_words((str(s) for s in limits), 'or')}, not the paper's "
                           f"{PAPER_MAX_STEPS}")
    if not differences:
        return ""
    return f"These runs used {', and '.join(differences)}, so the comparison is indicative only."


def run_settings(results: Sequence[ScenarioResult]) -> str:
    """'20, episode k with seed 0 + k; step limit 1000 decision steps of 0.5 s': the
    episodes a scenario, seeds and step limits of `results`."""
    seeds = sorted({r.seed for r in results})
    return (
        f"{join_words((str(e) for e in sorted({r.episodes for r in results})), 'or')}, "
        f"episode k with seed {join_words((str(s) for s in seeds), 'or')} + k; step limit "
        f"{join_words((str(s) for s in sorted({r.max_steps for r in results})), 'or')} decision steps of 0.5 s"
    )


# --- markdown -----------------------------------------------------------------------


def render_markdown(
    results: Sequence[ScenarioResult],
    policy_info: Mapping,
    command: str,
    date: datetime,
    figure_name: str = FIGURE_NAME,
) -> str:
    """The text of results.md. `policy_info` as `terl_rt.policy.onnx_policy.policy_info` makes
    it: name, sha256, path and metadata (a dict of the ONNX metadata_props)."""
    metadata = policy_info.get("metadata") or {}
    released = any(scale_group(r.name) == SMALL_RELEASED for r in results)
    name = policy_info.get("name", "unknown policy")
    acting = results[0].acting
    lines = [
        f"# {shown_name(policy_info, results)} against the TERL paper",
        "",
        f"- policy: `{name}`" + (f" (`{policy_info['path']}`)" if policy_info.get("path") else ""),
        *([f"- acting: **{acting.label}** (docs/safety.md), not the paper's greedy rule"] if acting.label else []),
        f"- sha256: `{str(policy_info.get('sha256', ''))[:12]}`",
        f"- training steps: {training_steps_text(metadata.get(META_TRAINING_STEPS))}"
        + (f", trained on {metadata[META_TRAINED_ON]}" if metadata.get(META_TRAINED_ON) else ""),
        f"- command: `{command}`",
        f"- date: {date.astimezone(timezone.utc):%Y-%m-%d %H:%M} UTC",
        f"- episodes a scenario: {run_settings(results)}",
        "",
        f"![success rate, travel time and collision ratio against the number of pursuers]({figure_name})",
        "",
        "## Where it stands",
        "",
        where_it_stands(results),
        "",
        "The goals are the paper's TERL numbers (policy.md section 4): success rate 1.00 at small, "
        "medium and large scale and 0.80 on CC, collision ratio at most 0.03, and travel time at or "
        f"under {join_words(f'{GOALS[g].max_travel_time_s:.0f} s' for g in SCALE_GROUPS)} "
        f"({join_words(group_title(g, lower=True) for g in SCALE_GROUPS)})."
        + (f" The released small-scale config ({', '.join(PUBLISHED_SMALL_SUITE)}) is held to the "
           "small-scale goals." if released else ""),
        "",
        "## Per preset",
        "",
        "The paper reports one number per scale group, not per preset: the paper's TERL row for "
        "the preset's group stands beside each preset. Travel time is given three ways: mean ± "
        "standard deviation of every episode as it ran (what the goals check), the mean over the "
        "successful episodes, and the mean over every episode with each failure counted at the "
        "step limit. Brackets hold 95 % confidence intervals: exact (Clopper-Pearson) for the "
        "success rate, bootstrap over the episodes (fixed seed) for the means.",
        "",
        "| preset | group | episodes | success | travel time (s) | travel time, successes (s) "
        "| travel time, failures at limit (s) | collision ratio | paper TERL success | paper TERL travel time (s) "
        "| paper TERL collision ratio |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in results:
        group = scale_group(r.name)
        paper = _paper_cells(group)
        ci = r.ci95()
        lines.append(
            f"| {r.label} | {group or '—'} | {r.episodes} | {r.success_rate:.2f}{ci_text(ci, 'success_rate', 2)} "
            f"| {r.travel_time_s_mean:.1f} ± {r.travel_time_s_std:.1f}{ci_text(ci, 'travel_time_s', 1)} "
            f"| {r.travel_time_s_success_mean:.1f}{ci_text(ci, 'travel_time_s_success', 1)} "
            f"| {r.travel_time_s_limit_mean:.1f}{ci_text(ci, 'travel_time_s_limit', 1)} "
            f"| {r.collision_ratio_mean:.3f}{ci_text(ci, 'collision_ratio', 3)} | {paper} |"
        )

    lines += [
        "",
        "## Per scale group",
        "",
        "This policy's numbers are the mean over the group's evaluated presets, each preset "
        "weighing the same, with 95 % intervals (the success rate's exact, over the pooled episodes; "
        "the means' bootstrap, episodes resampled within each preset); the paper's are its TERL row "
        "for the group. Travel time: every episode as it ran (what the goals check), then over the "
        "successes, then with failures counted at the step limit.",
        "",
        "| group | presets | success | paper TERL | travel time (s) | travel time, successes (s) "
        "| travel time, failures at limit (s) | paper TERL | collision ratio | paper TERL |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for s in group_summaries(results):
        paper = TERL_BY_GROUP[paper_group(s.group)]
        lines.append(
            f"| {s.group} | {', '.join(s.presets)} | {s.success_rate:.2f}{ci_text(s.ci95, 'success_rate', 2)} "
            f"| {paper.success_rate:.2f} "
            f"| {s.travel_time_s_mean:.1f}{ci_text(s.ci95, 'travel_time_s', 1)} "
            f"| {s.travel_time_s_success_mean:.1f}{ci_text(s.ci95, 'travel_time_s_success', 1)} "
            f"| {s.travel_time_s_limit_mean:.1f}{ci_text(s.ci95, 'travel_time_s_limit', 1)} | {paper.travel_time_s:.2f} "
            f"| {s.collision_ratio_mean:.3f}{ci_text(s.ci95, 'collision_ratio', 3)} | {paper.collision_ratio:.2f} |"
        )

    cc = next((r for r in results if scale_group(r.name) == "CC"), None)
    lines += [
        "",
        "## The paper's CC comparison",
        "",
        "CC: 28 pursuers, 14 evaders. The paper's ablation table gives TERL on CC as "
        f"{ABLATION_TABLE[('CC', TERL)].success_rate:.2f} / {ABLATION_TABLE[('CC', TERL)].travel_time_s:.2f} s / "
        f"{ABLATION_TABLE[('CC', TERL)].collision_ratio:.2f}; the goals use the comparison row below.",
        "",
        "| method | success | travel time (s) | collision ratio |",
        "|---|---:|---:|---:|",
    ]
    if cc is not None:
        lines.append(
            f"| this policy ({cc.name}) | {cc.success_rate:.2f} | {cc.travel_time_s_mean:.1f} "
            f"| {cc.collision_ratio_mean:.3f} |"
        )
    for method, row in CC_TABLE.items():
        lines.append(f"| paper {method} | {row.success_rate:.2f} | {row.travel_time_s:.2f} | {row.collision_ratio:.2f} |")

    lines += [
        "",
        "## The paper's ablation",
        "",
        "| group | method | success | travel time (s) | collision ratio |",
        "|---|---|---:|---:|---:|",
    ]
    for (group, method), row in ABLATION_TABLE.items():
        lines.append(
            f"| {group} | {method} | {row.success_rate:.2f} | {row.travel_time_s:.2f} | {row.collision_ratio:.2f} |"
        )
    return "\n".join(lines) + "\n"


# --- page and figure --------------------------------------------------------------


def write_report(
    results: Sequence[ScenarioResult],
    policy_info: Mapping,
    out_dir: str | os.PathLike,
    command: str,
    date: datetime | None = None,
) -> ReportPaths:
    """Write `out_dir`/results.png and `out_dir`/results.md (the folder is made if missing).

    results: the evaluations, in the order the tables list them; policy_info: name,
    sha256, path and metadata, as `terl_rt.policy.onnx_policy.policy_info` gives them;
    command: the command line that produced them; date: when (default now, UTC).
    Raises `MatplotlibMissing` before writing anything when matplotlib is absent.
    """
    if not results:
        raise ValueError("write_report needs at least one ScenarioResult")
    require_matplotlib()
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    title = f"{shown_name(policy_info, results)} (sha256 {str(policy_info.get('sha256', ''))[:12]}) against the TERL paper"
    figure = plot_results(results, out_dir / FIGURE_NAME, title=title)
    markdown = out_dir / MARKDOWN_NAME
    markdown.write_text(render_markdown(results, policy_info, command, date or datetime.now(timezone.utc)))
    return ReportPaths(markdown=markdown, figure=figure)


# --- helpers ------------------------------------------------------------------------


def shown_name(policy_info: Mapping, results: Sequence[ScenarioResult]) -> str:
    """The policy's name as the page and the figure show it: with how it acted, in brackets,
    when that was not the paper's greedy rule (a shielded run is never taken for a plain one)."""
    label = results[0].acting.label if results else ""
    return policy_info.get("name", "policy") + (f" [{label}]" if label else "")


def ci_text(intervals: Mapping, name: str, digits: int) -> str:
    """' [low, high]' of intervals[name], or nothing when it is unknown (no episodes kept)."""
    interval = intervals.get(name)
    if interval is None or any(math.isnan(v) for v in interval):
        return ""
    return " " + format_interval(interval, digits)


def _mean(values) -> float:
    values = list(values)
    return math.fsum(values) / len(values)


def join_words(items, word: str = "and") -> str:
    """'a', 'a and b', 'a, b and c'."""
    items = list(items)
    if len(items) <= 1:
        return "".join(items)
    return f"{', '.join(items[:-1])} {word} {items[-1]}"


def group_title(group: str, lower: bool = False) -> str:
    """'Small scale', 'Small scale, released config', 'CC' (lowercase with `lower`)."""
    if group == "CC":
        return "CC"
    title = "small scale, released config" if group == SMALL_RELEASED else f"{group} scale"
    return title if lower else title.capitalize()


def _shown(check: GoalCheck) -> str:
    """'travel time 71.2 s > 63 s': enough digits that a miss never looks like the goal."""
    digits, unit = {"success rate": (2, ""), "travel time": (1, " s"), "collision ratio": (3, "")}[check.metric]
    if check.metric == "travel time" and not check.met and check.value <= check.goal + 1e-9:
        return f"travel time {check.value:.1f} s (within {check.goal:.0f} s, but counted only with the success goal met)"
    while digits < 6 and not check.met and float(f"{check.value:.{digits}f}") == check.goal:
        digits += 1
    if check.metric == "success rate":
        relation = "≥" if check.met else "<"
    else:
        relation = "≤" if check.met else ">"
    goal_digits = 0 if check.metric == "travel time" else 2
    return f"{check.metric} {check.value:.{digits}f}{unit} {relation} {check.goal:.{goal_digits}f}{unit}"


def _paper_cells(group: str | None) -> str:
    if group is None:
        return "— | — | —"
    paper = TERL_BY_GROUP[paper_group(group)]
    return f"{paper.success_rate:.2f} | {paper.travel_time_s:.2f} | {paper.collision_ratio:.2f}"


def training_steps_text(text: str | None) -> str:
    """The terl.training_steps metadata as '440,000', or why it is unknown."""
    if text is None:
        return "unknown (no terl.training_steps metadata)"
    try:
        return f"{int(text):,}"
    except ValueError:
        return text
