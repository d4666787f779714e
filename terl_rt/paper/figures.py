"""The paper's Fig. 3, drawn for one policy (`plot_results`) or several (`plot_comparison`):
success rate, travel time (s) and collision ratio against the number of pursuers N, every
point with its 95 % interval as error bars.

matplotlib draws them; it is an optional extra (`pip install 'terl-rt[report]'`), imported
only when a figure is drawn: `require_matplotlib` says so before a long evaluation.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from pathlib import Path

from terl_rt.evaluation.episodes import ScenarioResult
from terl_rt.extras import install_hint
from terl_rt.paper.numbers import PRESET_GROUPS, SCALE_GROUPS, SMALL_RELEASED, TERL_BY_GROUP, scale_group
from terl_rt.sim.scenario import PRESETS

INSTALL_HINT = install_hint("report")


class MatplotlibMissing(ImportError):
    """matplotlib, needed for the figure, is not installed; the message says how to install it."""



def require_matplotlib() -> None:
    """Raise `MatplotlibMissing` (with the install command) unless matplotlib imports;
    check this before a long evaluation whose figure needs it."""
    agg_figure_classes()


def plot_results(results: Sequence[ScenarioResult], path: str | os.PathLike, title: str = "") -> Path:
    """Draw the three panels of the paper's Fig. 3 into a PNG at `path`: success rate,
    travel time (s, failures counted at the step limit) and collision ratio against the
    number of pursuers N, each of this policy's points with its 95 % interval as error bars
    (`INTERVAL_LEGEND`).

    This policy's small, medium and large presets are one line with markers, the released
    small config's (small-published-*) a dotted line with hollow diamonds; the paper's
    TERL row of each group is a dashed line over the group's N with hollow squares;
    cc-28 (N = 28) is a star, filled for this policy, hollow for the paper.
    """
    figure_class, canvas_class = agg_figure_classes()
    ours = _by_pursuers(r for r in results if scale_group(r.name) in ("small", "medium", "large"))
    released = _by_pursuers(r for r in results if scale_group(r.name) == SMALL_RELEASED)
    cc = [(PRESETS[r.name].pursuers, r) for r in results if scale_group(r.name) == "CC"]
    group_pursuers = {
        group: [PRESETS[name].pursuers for name, g in PRESET_GROUPS.items() if g == group] for group in SCALE_GROUPS
    }
    panels = (
        ("success rate", "success_rate", "success_rate", "success_rate"),
        (TRAVEL_PANEL, "travel_time_s_limit_mean", "travel_time_s", "travel_time_s_limit"),
        ("collision ratio", "collision_ratio_mean", "collision_ratio", "collision_ratio"),
    )

    figure = figure_class(figsize=(15.0, 4.6), dpi=110)
    canvas_class(figure)
    axes = figure.subplots(1, 3)
    for ax, (label, ours_field, paper_field, ci_name) in zip(axes, panels):
        # The paper's TERL numbers: one value per scale group, drawn across the group's N.
        for index, group in enumerate(("small", "medium", "large")):
            xs = group_pursuers[group]
            value = getattr(TERL_BY_GROUP[group], paper_field)
            ax.hlines(value, min(xs) - 2, max(xs) + 2, colors="C1", linestyles="dashed",
                      label="paper TERL (per scale group)" if index == 0 else None)
            ax.plot(xs, [value] * len(xs), "s", color="C1", markerfacecolor="none")
        ax.plot(group_pursuers["CC"], [getattr(TERL_BY_GROUP["CC"], paper_field)], "*", color="C3",
                markerfacecolor="none", markersize=13, label="paper TERL, CC")
        for series, fmt, color, series_label, style in (
            (ours, "o-", "C0", "this policy", {}),
            (released, "D:", "C4", "this policy, released small config", {"markerfacecolor": "none"}),
            (cc, "*", "C2", "this policy, cc-28", {"markersize": 13}),
        ):
            if series:
                ys, bars = interval_bars([r for _, r in series], ours_field, ci_name)
                ax.errorbar([n for n, _ in series], ys, yerr=bars, fmt=fmt, color=color, capsize=3,
                            label=series_label, **style)
        ax.set_title(label)
        ax.set_xlabel("pursuers N")
        ax.grid(True, alpha=0.3)
        if ours_field == "success_rate":
            ax.set_ylim(-0.05, 1.05)
        elif ours_field == "travel_time_s_limit_mean":
            ax.set_ylim(bottom=0.0)
        else:
            # Collision ratios are mostly a few hundredths: zoom in, but never below 0.05.
            values = [getattr(r, ours_field) for r in results if scale_group(r.name) is not None]
            top = max([0.05, *(1.15 * v for v in values), *(1.15 * p.collision_ratio for p in TERL_BY_GROUP.values())])
            ax.set_ylim(-0.04 * top, top)
    handles, labels = axes[0].get_legend_handles_labels()
    _legend(figure, axes[0], handles, labels, title)
    path = Path(path)
    figure.savefig(path, format="png")
    return path


TRAVEL_PANEL = "travel time (s), failures at the step limit"
INTERVAL_LEGEND = "bars: 95 % intervals (success rate: exact, Clopper-Pearson; means: bootstrap over episodes)"
"""What the figures' error bars are, in their legend."""


def interval_bars(results: Sequence[ScenarioResult], value_field: str, ci_name: str) -> tuple[list, list]:
    """The points (`value_field` of each result) and their asymmetric error bars [below,
    above] from the 95 % interval `ci_name` of `ScenarioResult.ci95` (0 where unknown)."""
    ys = [getattr(r, value_field) for r in results]
    intervals = [r.ci95()[ci_name] for r in results]
    below = [max(y - low, 0.0) if not math.isnan(low) else 0.0 for y, (low, _) in zip(ys, intervals)]
    above = [max(high - y, 0.0) if not math.isnan(high) else 0.0 for y, (_, high) in zip(ys, intervals)]
    return ys, [below, above]


def _legend(figure, ax, handles: list, labels: list, title: str) -> None:
    """The figure's legend below the panels, with what the error bars are as its last entry."""
    (bars,) = ax.plot([], [], "|", color="0.45", markersize=12)
    figure.legend([*handles, bars], [*labels, INTERVAL_LEGEND], loc="lower center", ncol=min(len(labels) + 1, 4),
                  frameon=False)
    if title:
        figure.suptitle(title)
    figure.subplots_adjust(left=0.05, right=0.98, bottom=0.26, top=0.85, wspace=0.25)


METHOD_SHIFT_N = 0.5
"""Pursuers: how far apart along N `plot_comparison` draws the methods' points, so that
their error bars do not hide each other."""


def plot_comparison(
    results_by_method: Mapping[str, Sequence[ScenarioResult]],
    path: str | os.PathLike,
    title: str = "",
) -> Path:
    """Draw the paper's Fig. 3 for several methods into a PNG at `path`: success rate,
    travel time (s) and collision ratio against the number of pursuers N, one colour per
    method (in the mapping's order), every point a preset's mean with its 95 % interval
    (`ScenarioResult.ci95`, `INTERVAL_LEGEND`) as error bars.

    A method's small, medium and large presets are one solid line with dots, the released
    small config's (small-published-*) a dotted line with hollow diamonds, cc-28 a star;
    presets the paper does not report are left out. Each method is shifted by
    METHOD_SHIFT_N pursuers from the one before.
    """
    figure_class, canvas_class = agg_figure_classes()
    kinds = (
        ("paper's presets", ("small", "medium", "large"), "o-", {}),
        ("released small config", (SMALL_RELEASED,), "D:", {"markerfacecolor": "none"}),
        ("cc-28", ("CC",), "*", {"markersize": 13}),
    )
    panels = (
        ("success rate", "success_rate", "success_rate"),
        (TRAVEL_PANEL, "travel_time_s_limit_mean", "travel_time_s_limit"),
        ("collision ratio", "collision_ratio_mean", "collision_ratio"),
    )

    figure = figure_class(figsize=(15.0, 4.8), dpi=110)
    canvas_class(figure)
    axes = figure.subplots(1, 3)
    drawn_kinds = set()
    for index, (method, results) in enumerate(results_by_method.items()):
        color = f"C{index % 10}"
        shift = (index - (len(results_by_method) - 1) / 2) * METHOD_SHIFT_N
        label = method
        for kind, groups, fmt, style in kinds:
            points = _by_pursuers(r for r in results if scale_group(r.name) in groups)
            if not points:
                continue
            drawn_kinds.add(kind)
            for ax, (_, value_field, ci_name) in zip(axes, panels):
                ys, bars = interval_bars([r for _, r in points], value_field, ci_name)
                ax.errorbar([n + shift for n, _ in points], ys, yerr=bars, fmt=fmt, color=color,
                            capsize=3, label=label if ax is axes[0] else None, **style)
            label = None  # one legend entry a method
    # The line styles in grey, for the legend, after the methods.
    handles, labels = axes[0].get_legend_handles_labels()
    for kind, _, fmt, style in kinds:
        if kind in drawn_kinds:
            (line,) = axes[0].plot([], [], fmt, color="0.45", **style)
            handles.append(line)
            labels.append(kind)
    for ax, (label, value_field, _) in zip(axes, panels):
        ax.set_title(label)
        ax.set_xlabel("pursuers N")
        ax.grid(True, alpha=0.3)
        if value_field == "success_rate":
            ax.set_ylim(-0.05, 1.05)
        else:
            top = ax.get_ylim()[1]
            ax.set_ylim(-0.04 * top, top)  # points at 0 stay visible
    _legend(figure, axes[0], handles, labels, title)
    path = Path(path)
    figure.savefig(path, format="png")
    return path


def _by_pursuers(results) -> list[tuple[int, ScenarioResult]]:
    """(pursuers N, result) of preset results, by N."""
    return sorted(((PRESETS[r.name].pursuers, r) for r in results), key=lambda pair: pair[0])


def agg_figure_classes():
    """(Figure, FigureCanvasAgg), imported here so matplotlib stays optional."""
    try:
        import matplotlib  # noqa: F401  (fails first, even when submodules are cached)
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
    except ImportError as error:
        raise MatplotlibMissing(
            f"the report's figure needs matplotlib, which is not installed; install it with: {INSTALL_HINT}"
        ) from error
    return Figure, FigureCanvasAgg
