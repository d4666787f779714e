"""The files of a comparison over training seeds: docs/comparison.md (the aggregates, the
claims, Tables III and IV beside the paper's, each seed against the paper's goals), comparison.png (the paper's Fig. 3 as bars,
`terl_rt.paper.seed_figure`), comparison.json (every episode and every statistic) and
comparison-marl-eval.json (every episode in marl-eval's format, `terl_rt.paper.marl_eval`),
from the `SeedRun`s and `SeedStatistics` of `terl_rt.paper.seed_comparison`.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Sequence
from datetime import datetime, timezone
from pathlib import Path
from typing import NamedTuple

from terl_rt.evaluation.stats import format_interval
from terl_rt.paper import seed_stats
from terl_rt.paper.comparison import DEFAULT_TERL
from terl_rt.paper.figures import require_matplotlib
from terl_rt.paper.marl_eval import marl_eval_dict
from terl_rt.paper.numbers import ABLATION_TABLE, ABLATIONS, CC_TABLE, REPORT_GROUPS, TERL, paper_group
from terl_rt.paper.report import comparability_note, join_words, run_settings, training_steps_text
from terl_rt.paper.seed_comparison import (
    AGGREGATES,
    BEYOND_PURSUERS,
    METRICS,
    SEED_GROUPS,
    Aggregate,
    SeedRun,
    SeedStatistics,
    check_seeds,
    method_runs,
    method_stem,
    seed_statistics,
)
from terl_rt.paper.seed_figure import plot_seed_comparison
from terl_rt.paper.seed_goals import seed_goals, seed_goals_markdown
from terl_rt.policy.contract import META_TRAINING_STEPS

MARKDOWN_NAME = "comparison.md"
FIGURE_NAME = "comparison.png"
JSON_NAME = "comparison.json"
MARL_EVAL_NAME = "comparison-marl-eval.json"
OUTPUT_NAMES = (FIGURE_NAME, MARKDOWN_NAME, JSON_NAME, MARL_EVAL_NAME)
"""What `write_seed_comparison` writes, in the order it is published."""


class SeedComparisonPaths(NamedTuple):
    """The files `write_seed_comparison` wrote."""

    markdown: Path
    figure: Path
    json: Path
    marl_eval: Path


_CELL = {"success_rate": (2, ""), "travel_time_s": (1, ""), "travel_time_s_limit": (1, ""), "collision_ratio": (3, "")}
"""metric -> (decimals, unit) in the tables."""


EXACT_MARK = " †"
"""Marks a success rate whose interval is the exact one over its episodes (`Aggregate.success_exact`)."""
EXACT_NOTE = ("† the success rate's exact (Clopper-Pearson) interval over every episode of the cell: with one "
              "seed, or every episode alike, the bootstrap has nothing to draw again.")
"""What EXACT_MARK means, said under the figure's description where a cell holds one."""


def _cell(row: Aggregate, aggregate: str, metric: str) -> str:
    digits, _ = _CELL[metric]
    value, interval = row.values[aggregate][metric], row.ci95[aggregate][metric]
    if math.isnan(value):
        return "—"
    exact = EXACT_MARK if metric == "success_rate" and row.success_exact else ""
    return f"{value:.{digits}f} {format_interval(interval, digits)}{exact}"


def _paper_row(method: str, group: str) -> str:
    """The paper's success / travel time / collision ratio cells for (method, group), or dashes."""
    paper = CC_TABLE.get(method) if group == "CC" and method in CC_TABLE else None
    paper = paper or ABLATION_TABLE.get((paper_group(group), method))
    if paper is None:
        return "— | — | —"
    return f"{paper.success_rate:.2f} | {paper.travel_time_s:.2f} | {paper.collision_ratio:.2f}"


def terl_stand_in(terl_runs: Sequence[SeedRun]) -> list[str]:
    """The line that says which method stands for TERL (`terl-rt report --terl`), none where
    it is the paper's own (terl) or TERL was not evaluated."""
    stems = sorted({method_stem(run.policy.get("metadata") or {}) for run in terl_runs} - {DEFAULT_TERL})
    if not stems:
        return []
    return [f"- TERL: method {join_words(stems)} (`--terl`), the one the claims are judged on"]


def render_seed_markdown(
    runs: Sequence[SeedRun], stats: SeedStatistics, command: str, date: datetime, figure_name: str = FIGURE_NAME,
) -> str:
    """The text of comparison.md for `runs` and their `seed_statistics`."""
    by_method = method_runs(runs)
    rows = stats.aggregates
    results = [r for run in runs for r in run.results]
    seeds_text = join_words(f"{method} {len(seed_runs)}" for method, seed_runs in by_method.items())
    lines = [
        f"# {join_words(by_method)} against the paper's comparison, over training seeds",
        "",
        f"- command: `{command}`",
        f"- date: {date.astimezone(timezone.utc):%Y-%m-%d %H:%M} UTC",
        f"- seeds: {seeds_text}",
        *terl_stand_in(by_method.get(TERL, ())),
        f"- episodes a scenario and seed: {run_settings(results)}",
        "",
        "| method | seed | model | policy | sha256 | training steps |",
        "|---|---:|---|---|---|---:|",
    ]
    for method, seed_runs in by_method.items():
        for run in seed_runs:
            metadata = run.policy.get("metadata") or {}
            lines.append(
                f"| {method} | {'—' if run.seed is None else run.seed} | {run.policy.get('name', '')} "
                f"| `{run.policy.get('path', '')}` | `{str(run.policy.get('sha256', ''))[:12]}` "
                f"| {training_steps_text(metadata.get(META_TRAINING_STEPS))} |"
            )
    note = comparability_note(results)
    lines += [
        "",
        f"![success rate, travel time and collision ratio per scale group, one bar a method]({figure_name})",
        "",
        "The figure follows the paper's Fig. 3: one panel a metric, the scale groups along the x axis, "
        "one bar a method: its mean over seeds (each seed's mean over its episodes of each preset, every "
        "(seed, preset) weighing the same), the dot its interquartile mean, the error bars the mean's 95 % "
        "stratified bootstrap interval (seeds drawn again within each preset, then each drawn seed's "
        "episodes; 2,000 resamples, fixed seed), as rliable recommends (Agarwal et al. 2021). A method "
        "that never learned on some seed keeps that seed: it is part of the method's reliability."
        + (f" {EXACT_NOTE}" if any(row.success_exact for row in rows) else ""),
        "",
        "## Claims",
        "",
        "Each claim of the paper (policy.md section 4) is checked by the criterion beside it on the means "
        "over seeds. *reproduces* / *does not reproduce*: the means and the 95 % intervals give that "
        "verdict alike; *cannot tell*: the intervals overlap where the criterion compares them, so more "
        "seeds or episodes could overturn it; *not measured*: a method or group it needs was not "
        "evaluated. *paper*: the same criterion on the paper's own tables." + (f" {note}" if note else ""),
        "",
        "| claim | criterion | measured: mean over seeds (95 % interval) | paper | verdict |",
        "|---|---|---|---|---|",
    ]
    for check in stats.claims:
        lines.append(f"| {check.claim} | {check.criterion} | {check.measured} | {check.in_paper} | **{check.verdict}** |")
    for title, intro, wanted in (
        ("Table III: CC (cc-28)", "28 pursuers, 14 evaders, beside the paper's CC comparison (w/o RE and w/o "
         "TS: its ablation table's CC rows).", lambda row: row.group == "CC"),
        ("Table IV: ablation per scale group", "TERL, w/o RE and w/o TS beside the paper's ablation table (the "
         "released small config beside its small-scale rows).",
         lambda row: row.method in (TERL, *ABLATIONS) and row.group in REPORT_GROUPS),
    ):
        chosen = [row for row in rows if wanted(row)]
        lines += ["", f"## {title}", "", intro, ""]
        if not chosen:
            lines.append("Not evaluated.")
            continue
        lines += [
            "| group | method | seeds | success | travel time (s) | collision ratio | paper success "
            "| paper travel time (s) | paper collision ratio |",
            "|---|---|---:|---:|---:|---:|---:|---:|---:|",
        ]
        for row in chosen:
            lines.append(
                f"| {row.group} | {row.method} | {row.seeds} | {_cell(row, 'mean', 'success_rate')} "
                f"| {_cell(row, 'mean', 'travel_time_s')} | {_cell(row, 'mean', 'collision_ratio')} "
                f"| {_paper_row(row.method, row.group)} |"
            )
    lines += [
        "",
        "## Every method per scale group",
        "",
        "Mean and interquartile mean (IQM) over seeds with their 95 % stratified bootstrap intervals. "
        "Travel time: every episode as it ran; *at limit*: each failure counted at the step limit. "
        f"Groups past 80 pursuers ({join_words(str(n) for n in BEYOND_PURSUERS)}) are `terl-rt bench "
        "scaling`'s worlds: large-80's grown, evaders a quarter of the pursuers, the same density.",
        "",
        "| group | method | seeds | presets | success: mean | success: IQM | travel time (s): mean "
        "| travel time at limit (s): mean | collision ratio: mean | collision ratio: IQM |",
        "|---|---|---:|---|---:|---:|---:|---:|---:|---:|",
    ]
    for row in rows:
        lines.append(
            f"| {row.group} | {row.method} | {row.seeds} | {', '.join(row.presets)} "
            f"| {_cell(row, 'mean', 'success_rate')} | {_cell(row, 'iqm', 'success_rate')} "
            f"| {_cell(row, 'mean', 'travel_time_s')} | {_cell(row, 'mean', 'travel_time_s_limit')} "
            f"| {_cell(row, 'mean', 'collision_ratio')} | {_cell(row, 'iqm', 'collision_ratio')} |"
        )
    lines += ["", *seed_goals_markdown(seed_goals(runs))]
    better = stats.improvements
    lines += [
        "",
        "## Probability that TERL does better",
        "",
        "P(TERL > method): the chance that a TERL seed's mean on a preset beats the method's (a tie counts "
        "one half), averaged over the group's presets (rliable's probability of improvement), with its 95 % "
        "stratified bootstrap interval. 0.5: no difference; above: TERL better.",
        "",
    ]
    if not better:
        lines.append("TERL was not evaluated beside another method.")
    else:
        lines += ["| group | method | higher success | shorter travel time | fewer collisions |", "|---|---|---:|---:|---:|"]
        for improvement in better:
            cells = " | ".join(
                f"{improvement.probability[m]:.2f} {format_interval(improvement.ci95[m], 2)}"
                for m in ("success_rate", "travel_time_s", "collision_ratio")
            )
            lines.append(f"| {improvement.group} | {improvement.method} | {cells} |")
    return "\n".join(lines) + "\n"


def seed_comparison_dict(runs: Sequence[SeedRun], stats: SeedStatistics, command: str, date: datetime) -> dict:
    """comparison.json: every seed's policy and scenarios (with every episode), and the
    aggregates, P(TERL better) and claims of `stats` (`seed_statistics(runs)`)."""
    return {
        "command": command,
        "date": date.astimezone(timezone.utc).isoformat(),
        "statistics": {
            "aggregates": list(AGGREGATES), "metrics": list(METRICS), "confidence": seed_stats.CONFIDENCE,
            "bootstrap": "stratified: seeds resampled within each preset, then episodes within each drawn seed",
            "resamples": seed_stats.RESAMPLES, "bootstrap_seed": seed_stats.BOOTSTRAP_SEED,
        },
        "runs": [
            {"method": run.method, "seed": run.seed, "policy": dict(run.policy),
             "scenarios": [result.to_dict(per_episode=True) for result in run.results]}
            for seed_runs in method_runs(runs).values() for run in seed_runs
        ],
        "aggregates": [row.to_dict() for row in stats.aggregates],
        "seeds": [standing.to_dict() for standing in seed_goals(runs)],
        "improvements": [row.to_dict() for row in stats.improvements],
        "claims": [check.to_dict() for check in stats.claims],
    }


def write_seed_comparison(
    runs: Sequence[SeedRun], out_dir: str | os.PathLike, command: str, date: datetime | None = None,
    stats: SeedStatistics | None = None,
) -> SeedComparisonPaths:
    """Write OUTPUT_NAMES into `out_dir` (made if missing). runs: one a policy, each
    (method, seed) once (ComparisonError otherwise), all on the same scenarios; command:
    the command line that produced them; date: when (default now, UTC); stats: their
    `seed_statistics`, computed here when not given. Raises `figures.MatplotlibMissing`
    before writing anything when matplotlib is absent."""
    if not runs:
        raise ValueError("write_seed_comparison needs at least one SeedRun")
    check_seeds([(run.method, run.seed, str(run.policy.get("path", ""))) for run in runs])
    require_matplotlib()
    date = date or datetime.now(timezone.utc)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    stats = stats or seed_statistics(runs)
    figure = plot_seed_comparison(
        stats.aggregates, SEED_GROUPS, out_dir / FIGURE_NAME,
        title=f"{join_words(method_runs(runs))}: mean over seeds with 95 % stratified bootstrap intervals",
    )
    markdown = out_dir / MARKDOWN_NAME
    markdown.write_text(render_seed_markdown(runs, stats, command, date))
    data = out_dir / JSON_NAME
    data.write_text(json.dumps(seed_comparison_dict(runs, stats, command, date), indent=1) + "\n")
    marl_eval = out_dir / MARL_EVAL_NAME
    marl_eval.write_text(json.dumps(marl_eval_dict(
        [(run.method, run_name(run), run.policy, run.results) for run in runs]), indent=1) + "\n")
    return SeedComparisonPaths(markdown=markdown, figure=figure, json=data, marl_eval=marl_eval)


def run_name(run: SeedRun) -> str:
    """The run's key in the marl-eval export: its seed, or its file's stem without one."""
    return str(run.seed) if run.seed is not None else Path(str(run.policy.get("path", "policy"))).stem

