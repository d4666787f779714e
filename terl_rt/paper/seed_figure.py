"""The paper's Fig. 3 over training seeds: one panel a metric, the scale groups along the
x axis, one bar a method (its mean over seeds), the interquartile mean as a dot and the
mean's 95 % stratified bootstrap interval as error bars (the aggregates of
`terl_rt.paper.seed_comparison`, drawn for `seed_comparison_files`).

matplotlib draws it (the `report` extra), imported only when a figure is drawn.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Protocol

from terl_rt.paper.figures import TRAVEL_PANEL, agg_figure_classes

PANELS = (("success rate", "success_rate"), (TRAVEL_PANEL, "travel_time_s_limit"), ("collision ratio", "collision_ratio"))
"""(title, metric) of each panel, as the single-seed figures draw them."""
BAR_SPAN = 0.8
"""Width of one group's bars together, in units of the gap between groups."""
LEGEND = "bars: mean over seeds; dots: interquartile mean; error bars: 95 % stratified bootstrap interval (seeds, then episodes)"
"""What the figure's marks are, in its legend."""


class AggregateRow(Protocol):
    """What a bar is drawn from: one method on one scale group over its seeds
    (`terl_rt.paper.seed_comparison.Aggregate`)."""

    method: str
    group: str
    values: dict
    """aggregate ('mean', 'iqm') -> metric -> value."""
    ci95: dict
    """aggregate -> metric -> (low, high)."""


def group_label(group: str) -> str:
    """A scale group's label under its bars, broken over two lines where it is long."""
    return group.replace(" (released config)", "\n(released)").replace(" pursuers", "\npursuers")


def plot_seed_comparison(
    rows: Sequence[AggregateRow], groups: Sequence[str], path: str | os.PathLike, title: str = "",
) -> Path:
    """Draw `rows` (one a method and scale group) into a PNG at `path`: the groups of
    `groups` that have a row, in that order, along the x axis; the methods in the order
    they first appear in `rows`, one colour each."""
    figure_class, canvas_class = agg_figure_classes()
    shown = [g for g in groups if any(row.group == g for row in rows)]
    methods = list(dict.fromkeys(row.method for row in rows))
    width = BAR_SPAN / max(len(methods), 1)
    figure = figure_class(figsize=(max(15.0, 2.5 * len(shown)), 5.0), dpi=110)
    canvas_class(figure)
    axes = figure.subplots(1, 3)
    for ax, (title_text, metric) in zip(axes, PANELS):
        for index, method in enumerate(methods):
            own = {row.group: row for row in rows if row.method == method}
            xs = [x for x, g in enumerate(shown) if g in own]
            picked = [own[g] for g in shown if g in own]
            means = [row.values["mean"][metric] for row in picked]
            below = [max(m - row.ci95["mean"][metric][0], 0.0) for m, row in zip(means, picked)]
            above = [max(row.ci95["mean"][metric][1] - m, 0.0) for m, row in zip(means, picked)]
            offset = (index - (len(methods) - 1) / 2) * width
            ax.bar([x + offset for x in xs], means, width, yerr=[below, above], capsize=2, color=f"C{index % 10}",
                   label=method, error_kw={"elinewidth": 1})
            ax.plot([x + offset for x in xs], [row.values["iqm"][metric] for row in picked], "o", color="black",
                    markersize=3)
        paper_groups = sum(1 for g in shown if not g.endswith(" pursuers"))
        if 0 < paper_groups < len(shown):
            ax.axvline(paper_groups - 0.5, color="0.5", linestyle=":")
            ax.text(paper_groups - 0.4, 0.98, "beyond the paper", transform=ax.get_xaxis_transform(), va="top",
                    fontsize=8, color="0.4", zorder=5,
                    bbox={"facecolor": "white", "edgecolor": "none", "alpha": 0.85, "pad": 1.5})  # over tall bars
        ax.set_xticks(range(len(shown)), [group_label(g) for g in shown], fontsize=8)
        ax.set_title(title_text)
        ax.grid(True, axis="y", alpha=0.3)
        if metric == "success_rate":
            ax.set_ylim(0.0, 1.05)
    handles, labels = axes[0].get_legend_handles_labels()
    (bars,) = axes[0].plot([], [], "|", color="0.3", markersize=12)
    figure.legend([*handles, bars], [*labels, LEGEND], loc="lower center", ncol=min(len(labels) + 1, 7), frameon=False,
                  fontsize=8)
    if title:
        figure.suptitle(title)
    figure.subplots_adjust(left=0.04, right=0.99, bottom=0.22, top=0.88, wspace=0.18)
    path = Path(path)
    figure.savefig(path, format="png")
    return path
