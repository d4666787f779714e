"""Several policies set against the paper's comparison: docs/comparison.md, .png and .json.

The paper compares TERL with IQN, DQN and MEAN (its Fig. 3 and the CC table, Table III)
and with its ablations w/o RE and w/o TS (Table IV); policy.md section 4 holds its
numbers and claims. `write_comparison` takes one `MethodRun` a policy (its evaluations
on the same scenarios) and writes:

- a figure in the form of Fig. 3 (`terl_rt.paper.figures.plot_comparison`);
- Table III: every method on CC beside the paper's numbers;
- Table IV: TERL, w/o RE and w/o TS per scale group beside the paper's ablation;
- every method per scale group;
- the paper's claims (`terl_rt.paper.claims`), each checked on the measured group
  means (`claim_checks`);
- the same as JSON, for scripts.

Every measured number has its 95 % bootstrap interval (`terl_rt.evaluation.stats`): group
means resample the episodes within each preset (`report.group_summaries`).
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import NamedTuple

from terl_rt.evaluation.episodes import ScenarioResult
from terl_rt.paper.claims import ClaimCheck, check_claims, claim_metrics
from terl_rt.paper.figures import plot_comparison, require_matplotlib
from terl_rt.paper.numbers import (
    ABLATION_TABLE,
    ABLATIONS,
    CC_TABLE,
    PAPER_METHODS,
    REPORT_GROUPS,
    TERL,
    PaperResult,
    paper_group,
)
from terl_rt.paper.report import (
    GroupSummary,
    ci_text,
    comparability_note,
    group_summaries,
    join_words,
    run_settings,
    training_steps_text,
)
from terl_rt.policy.contract import META_TRAINING_STEPS

MARKDOWN_NAME = "comparison.md"
FIGURE_NAME = "comparison.png"
JSON_NAME = "comparison.json"

class ComparisonError(ValueError):
    """Policies that cannot be compared side by side; the message names them."""


class ComparisonPaths(NamedTuple):
    """The files `write_comparison` wrote."""

    markdown: Path
    figure: Path
    json: Path


@dataclass(frozen=True)
class MethodRun:
    """One policy's evaluations in a comparison."""

    method: str
    """the paper's name of its model (`method_name`): TERL, IQN, DQN, MEAN, w/o RE, w/o TS,
    or the model's own name for a model the paper does not have."""
    policy: Mapping
    """name, sha256, path and metadata, as `terl_rt.policy.onnx_policy.policy_info` gives them."""
    results: tuple[ScenarioResult, ...]
    """its evaluations, one a scenario."""


DEFAULT_TERL = "terl"
"""The model (recipe stem) that stands for the paper's TERL unless a report names another."""


def method_name(model: str, terl: str = DEFAULT_TERL) -> str:
    """The paper's name of a model or recipe stem (`terl.model` or `terl.method` metadata:
    terl -> TERL, terl-no-re -> w/o RE, ...); a model the paper does not have keeps its own
    name. `terl`: the stem that stands for TERL (`terl-rt report --terl`); where that is
    another, the stem "terl" keeps its own name."""
    if model == terl:
        return TERL
    if model == DEFAULT_TERL:
        return model
    return PAPER_METHODS.get(model, model)


def check_methods(policies: Sequence[tuple[str, str]]) -> None:
    """Raise ComparisonError when two of the (method, policy path) pairs are one method."""
    seen: dict[str, str] = {}
    for method, path in policies:
        if method in seen:
            raise ComparisonError(
                f"{seen[method]} and {path} are both method {method!r}; compare one policy a method"
            )
        seen[method] = path


def paper_order(method: str) -> int:
    """Sort key of a method: its place in the paper's order (TERL, IQN, DQN, MEAN, w/o RE,
    w/o TS); methods the paper does not have come after them (a stable sort keeps their order)."""
    order = list(PAPER_METHODS.values())
    return order.index(method) if method in order else len(order)


# --- tables -------------------------------------------------------------------------


@dataclass(frozen=True)
class TableRow:
    """One method's mean over the presets of one report group, beside the paper's row."""

    method: str
    measured: GroupSummary
    """its group mean with 95 % intervals (`report.group_summaries`)."""
    paper: PaperResult | None
    """the paper's row for this method and group in the table at hand; None where it has none."""

    def to_dict(self) -> dict:
        return {
            "method": self.method, **self.measured.to_dict(),
            "paper": None if self.paper is None else asdict(self.paper),
        }


def method_groups(runs: Sequence[MethodRun]) -> dict[str, dict[str, GroupSummary]]:
    """method -> report group -> its group summary, for every group the method was evaluated on."""
    return {run.method: {s.group: s for s in group_summaries(run.results)} for run in runs}


def table_iii(runs: Sequence[MethodRun]) -> list[TableRow]:
    """CC (cc-28): every method evaluated on it, beside the paper's CC comparison (w/o RE
    and w/o TS: its ablation table, the only one that has them on CC)."""
    rows = []
    for method, groups in method_groups(runs).items():
        if "CC" in groups:
            paper = CC_TABLE.get(method) or ABLATION_TABLE.get(("CC", method))
            rows.append(TableRow(method, groups["CC"], paper))
    return rows


def table_iv(runs: Sequence[MethodRun]) -> list[TableRow]:
    """TERL, w/o RE and w/o TS per report group, beside the paper's ablation table (the
    released small config beside its small-scale rows)."""
    by_method = method_groups(runs)
    return [
        TableRow(method, by_method[method][group], ABLATION_TABLE.get((paper_group(group), method)))
        for group in REPORT_GROUPS
        for method in (TERL, *ABLATIONS)
        if group in by_method.get(method, {})
    ]


# --- claims -------------------------------------------------------------------------


def claim_checks(groups: Mapping[str, Mapping[str, GroupSummary]]) -> list[ClaimCheck]:
    """Check every claim of CLAIMS on `groups` (method -> report group -> summary, as
    `method_groups` gives them) and on the paper's own tables."""
    return check_claims({
        (method, group): (claim_metrics(s.success_rate, s.travel_time_s_mean, s.collision_ratio_mean), s.ci95)
        for method, by_group in groups.items()
        for group, s in by_group.items()
    })


# --- markdown and JSON ----------------------------------------------------------------


def render_comparison_markdown(
    runs: Sequence[MethodRun],
    command: str,
    date: datetime,
    figure_name: str = FIGURE_NAME,
) -> str:
    """The text of comparison.md for `runs` (in the order given)."""
    results = [r for run in runs for r in run.results]
    groups = method_groups(runs)
    lines = [
        f"# {join_words(run.method for run in runs)} against the paper's comparison",
        "",
        f"- command: `{command}`",
        f"- date: {date.astimezone(timezone.utc):%Y-%m-%d %H:%M} UTC",
        f"- episodes a scenario: {run_settings(results)}",
        "",
        "| method | model | policy | sha256 | training steps |",
        "|---|---|---|---|---:|",
    ]
    for run in runs:
        metadata = run.policy.get("metadata") or {}
        lines.append(
            f"| {run.method} | {run.policy.get('name', '')} | `{run.policy.get('path', '')}` "
            f"| `{str(run.policy.get('sha256', ''))[:12]}` | {training_steps_text(metadata.get(META_TRAINING_STEPS))} |"
        )
    note = comparability_note(results)
    cc_ablation = ABLATION_TABLE[("CC", TERL)]
    lines += [
        "",
        f"![success rate, travel time and collision ratio against the number of pursuers, one line a method]"
        f"({figure_name})",
        "",
        "The figure follows the paper's Fig. 3: each point is a preset's mean with its 95 % "
        "confidence interval (bootstrap over the episodes, fixed seed) as error bars; solid lines "
        "join the paper's presets, dotted lines the released small-scale config's, stars are CC. "
        "Where two methods' intervals overlap, these episodes cannot tell them apart.",
        "",
        "## Claims",
        "",
        "Each claim of the paper (policy.md section 4) is checked by the criterion beside it on "
        "the group means (each preset of a group weighing the same). *reproduces*: every comparison "
        "of the criterion holds on the means; *does not reproduce*: one fails; *not measured*: a "
        "method or group it needs was not evaluated. *clear*: the 95 % intervals give the verdict "
        "too (every comparison holds between them, or a failing one fails between them), so it "
        "stands clear of the episodes' noise; *no*: it rests on differences within the intervals, "
        "which more episodes could overturn. *paper*: the same criterion on the paper's own tables; Fig. 3's numbers "
        "(IQN, DQN and MEAN below CC) are not in its tables." + (f" {note}" if note else ""),
        "",
        "| claim | criterion | measured (95 % interval) | clear | paper | verdict |",
        "|---|---|---|---|---|---|",
    ]
    for check in claim_checks(groups):
        clear = "—" if check.clear is None else "yes" if check.clear else "no"
        lines.append(
            f"| {check.claim} | {check.criterion} | {check.measured} | {clear} | {check.in_paper} "
            f"| **{check.verdict}** |"
        )

    lines += [
        "",
        "## Table III: CC (cc-28)",
        "",
        "28 pursuers, 14 evaders. Beside each method, the paper's CC comparison; w/o RE and w/o TS "
        "are in its ablation table only, whose TERL row for CC reads "
        f"{cc_ablation.success_rate:.2f} / {cc_ablation.travel_time_s:.2f} s / {cc_ablation.collision_ratio:.2f}.",
        "",
    ]
    lines += _table(table_iii(runs), with_group=False) or ["cc-28 was not evaluated."]
    lines += [
        "",
        "## Table IV: ablation per scale group",
        "",
        "TERL without relation extraction (w/o RE) and without target selection (w/o TS), beside "
        "the paper's ablation table; the released small-scale config stands beside its small-scale rows.",
        "",
    ]
    lines += _table(table_iv(runs), with_group=True) or ["Neither TERL nor an ablation was evaluated."]
    lines += [
        "",
        "## Every method per scale group",
        "",
        "| group | method | presets | success | travel time (s) | collision ratio |",
        "|---|---|---|---:|---:|---:|",
    ]
    for group in REPORT_GROUPS:
        for method, by_group in groups.items():
            if group in by_group:
                s = by_group[group]
                lines.append(f"| {group} | {method} | {', '.join(s.presets)} | {_measured_cells(s)} |")
    return "\n".join(lines) + "\n"


def comparison_dict(runs: Sequence[MethodRun], command: str, date: datetime) -> dict:
    """comparison.json: per method its policy, every scenario (with every episode) and
    group; the rows of Tables III and IV with the paper's; the claims."""
    return {
        "command": command,
        "date": date.astimezone(timezone.utc).isoformat(),
        "methods": [
            {
                "method": run.method,
                "policy": dict(run.policy),
                "scenarios": [result.to_dict(per_episode=True) for result in run.results],
                "groups": [summary.to_dict() for summary in group_summaries(run.results)],
            }
            for run in runs
        ],
        "table_iii": [row.to_dict() for row in table_iii(runs)],
        "table_iv": [row.to_dict() for row in table_iv(runs)],
        "claims": [check.to_dict() for check in claim_checks(method_groups(runs))],
    }


def write_comparison(
    runs: Sequence[MethodRun],
    out_dir: str | os.PathLike,
    command: str,
    date: datetime | None = None,
) -> ComparisonPaths:
    """Write `out_dir`/comparison.png, comparison.md and comparison.json (the folder is made
    if missing), the methods in the paper's order (`paper_order`).

    runs: one a policy, each method once (ComparisonError otherwise), at least two;
    command: the command line that produced them; date: when (default now, UTC).
    Raises `figures.MatplotlibMissing` before writing anything when matplotlib is absent.
    """
    if len(runs) < 2:
        raise ValueError("write_comparison needs at least two MethodRuns; one policy is write_report's")
    check_methods([(run.method, str(run.policy.get("path", ""))) for run in runs])
    require_matplotlib()
    runs = sorted(runs, key=lambda run: paper_order(run.method))
    date = date or datetime.now(timezone.utc)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    figure = plot_comparison(
        {run.method: run.results for run in runs}, out_dir / FIGURE_NAME,
        title=f"{join_words(run.method for run in runs)}: means with 95 % confidence intervals",
    )
    markdown = out_dir / MARKDOWN_NAME
    markdown.write_text(render_comparison_markdown(runs, command, date))
    data = out_dir / JSON_NAME
    data.write_text(json.dumps(comparison_dict(runs, command, date), indent=1) + "\n")
    return ComparisonPaths(markdown=markdown, figure=figure, json=data)


# --- helpers ------------------------------------------------------------------------


def _table(rows: Sequence[TableRow], with_group: bool) -> list[str]:
    """Markdown lines of a table of `rows` (measured, then the paper's), or [] for none."""
    if not rows:
        return []
    first = "| group | method |" if with_group else "| method |"
    lines = [
        f"{first} success | travel time (s) | collision ratio | paper success | paper travel time (s) "
        "| paper collision ratio |",
        "|---" * (2 if with_group else 1) + "|---:|---:|---:|---:|---:|---:|",
    ]
    for row in rows:
        start = f"| {row.measured.group} | {row.method} |" if with_group else f"| {row.method} |"
        paper = "— | — | —" if row.paper is None else _paper_cells(row.paper)
        lines.append(f"{start} {_measured_cells(row.measured)} | {paper} |")
    return lines


def _measured_cells(summary: GroupSummary) -> str:
    return (
        f"{summary.success_rate:.2f}{ci_text(summary.ci95, 'success_rate', 2)} "
        f"| {summary.travel_time_s_mean:.1f}{ci_text(summary.ci95, 'travel_time_s', 1)} "
        f"| {summary.collision_ratio_mean:.3f}{ci_text(summary.ci95, 'collision_ratio', 3)}"
    )


def _paper_cells(row: PaperResult) -> str:
    return f"{row.success_rate:.2f} | {row.travel_time_s:.2f} | {row.collision_ratio:.2f}"
