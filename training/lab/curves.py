"""Training curves from a run's metrics.jsonl: success rate, return and collision ratio against environment steps."""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any


class CurvesError(ValueError):
    """A metrics log that cannot be plotted, or no matplotlib; the message says which."""


def read_metrics(path: str | Path) -> list[dict[str, Any]]:
    """The records of a metrics.jsonl file (one JSON object a line), in order."""
    path = Path(path)
    records = []
    for number, line in enumerate(path.read_text().splitlines(), start=1):
        if not line.strip():
            continue
        try:
            records.append(json.loads(line))
        except json.JSONDecodeError as error:
            raise CurvesError(f"{path}:{number}: not a JSON object ({error})") from None
    return records


def _pyplot() -> Any:
    """matplotlib.pyplot on the Agg backend; CurvesError without matplotlib."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        raise CurvesError("plotting needs matplotlib: pip install -e '.[report]'") from None
    return plt


def plot_seed_curves(runs: dict[str, list[dict[str, Any]]], out_path: str | Path, title: str = "",
                     star_best: bool = True) -> Path:
    """Write a PNG of several runs' curves in one figure, a colour a run (e.g. a method's seeds).

    `runs`: label -> the run's metrics records in order (every segment's metrics.jsonl, one after
    the other). Top: success rate of the recent episodes (exploring); bottom: success rate of the
    snapshot evaluations on the snapshot preset (the selection's episodes), the best starred where
    `star_best` (a run that ships its last model draws no star: no snapshot was chosen).
    x axis: environment steps. A run without records keeps its label in the legend.
    """
    plt = _pyplot()
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
    for index, (label, records) in enumerate(runs.items()):
        colour = f"C{index % 10}"
        train = [r for r in records if r.get("kind") == "train" and r.get("success_rate") is not None]
        top.plot([r["env_step"] for r in train], [r["success_rate"] for r in train], color=colour, label=label)
        shown = [r for r in records if r.get("kind") == "snapshot" and len(r["evaluations"]) > 1]
        bottom.plot([r["env_step"] for r in shown], [r["evaluations"][1]["success_rate"] for r in shown], "x-",
                    color=colour, linewidth=0.8)
        best = [r for r in shown if r.get("best")]
        if star_best and best:
            bottom.plot([best[-1]["env_step"]], [best[-1]["evaluations"][1]["success_rate"]], "*", markersize=12,
                        color=colour)
    preset = next((r["evaluations"][1]["scenario"] for records in runs.values() for r in records
                   if r.get("kind") == "snapshot" and len(r["evaluations"]) > 1), "the snapshot preset")
    top.set_ylabel("success, recent episodes")
    bottom.set_ylabel(f"success, snapshots on {preset}")
    bottom.set_xlabel("environment steps")
    for axis in (top, bottom):
        axis.set_ylim(-0.05, 1.05)
        axis.grid(alpha=0.3)
    top.legend(loc="upper left")
    return save_figure(fig, out_path, title)


def plot_snapshot_curves(curves: dict[str, list[dict[str, Any]]], out_path: str | Path, title: str = "",
                         stages: Sequence[dict[str, Any]] = ()) -> Path:
    """Write a PNG of learning curves of kept snapshots, a column a preset and a colour a run.

    `curves`: label -> the run's curve points (`training.lab.snapshot_curves.with_interval`: step,
    scenario, success rate with its exact interval, collision ratio). Top row: success rate, its
    95 % interval as error bars; bottom row: collision ratio. x axis: environment steps (the
    runs' points at one step drawn a little apart, left to right in `curves`' order).
    `stages`: the runs' curriculum stage starts (metrics.jsonl "stage" records), dashed lines.
    """
    plt = _pyplot()
    from matplotlib.ticker import EngFormatter

    presets = list(dict.fromkeys(point["scenario"] for points in curves.values() for point in points))
    if not presets:
        raise CurvesError("no snapshot evaluation to plot")
    fig, axes = plt.subplots(2, len(presets), figsize=(4 * len(presets), 6), sharex=True, squeeze=False)
    # Runs' points at one step (seeds evaluated together) are drawn `apart`, their bars side by side.
    every_step = [point["env_step"] for points in curves.values() for point in points]
    apart = 0.006 * ((max(every_step) - min(every_step)) or max(every_step))
    for column, preset in enumerate(presets):
        success, collisions = axes[0][column], axes[1][column]
        for index, (label, points) in enumerate(curves.items()):
            shown = [point for point in points if point["scenario"] == preset]
            steps = [point["env_step"] + apart * (index - (len(curves) - 1) / 2) for point in shown]
            rates = [point["success_rate"] for point in shown]
            below = [rate - point["success_low"] for rate, point in zip(rates, shown)]
            above = [point["success_high"] - rate for rate, point in zip(rates, shown)]
            success.errorbar(steps, rates, yerr=[below, above], fmt="o-", color=f"C{index % 10}", capsize=2,
                             linewidth=1, markersize=3, label=label)
            collisions.plot(steps, [point["collision_ratio_mean"] for point in shown], "o-", color=f"C{index % 10}",
                            linewidth=1, markersize=3)
        episodes = sorted({point["episodes"] for points in curves.values() for point in points
                           if point["scenario"] == preset})
        success.set_title(f"{preset} ({'/'.join(map(str, episodes))} episodes)")
        collisions.set_xlabel("environment steps")
        collisions.xaxis.set_major_formatter(EngFormatter())  # 500 k, 1 M
        for axis in (success, collisions):
            axis.set_ylim(-0.05, 1.05)
            axis.grid(alpha=0.3)
        mark_stages((success, collisions), stages)
    axes[0][0].set_ylabel("success (exact 95 % interval)")
    axes[1][0].set_ylabel("collision ratio")
    axes[0][0].legend(loc="upper left", fontsize=8)
    return save_figure(fig, out_path, title)


def stage_starts(metrics_paths: list[Path]) -> list[dict[str, Any]]:
    """The curriculum stage starts ("stage" records: env_step, stage) in the runs' metrics.jsonl,
    each (step, stage) once, in step order: seeds of one schedule share them."""
    starts = {(record["env_step"], record["stage"])
              for path in metrics_paths for record in read_metrics(path) if record.get("kind") == "stage"}
    return [{"env_step": step, "stage": stage} for step, stage in sorted(starts)]


def mark_stages(axes: Sequence[Any], stages: Sequence[dict[str, Any]]) -> None:
    """Dashed vertical lines at the stage starts ("stage" records) on `axes` (sharing x), each
    stage named at the top of the first, whose y axis runs to 1."""
    for stage in stages:
        for axis in axes:
            axis.axvline(stage["env_step"], color="grey", linestyle="--", linewidth=0.8)
        axes[0].annotate(stage["stage"].replace("curriculum-", "stage "), (stage["env_step"], 1.0),
                         fontsize=7, rotation=90, va="top", ha="right", color="grey")


def plot_curves(metrics_path: str | Path, out_path: str | Path, title: str = "") -> Path:
    """Write a PNG of the training curves of a run.

    Top: success rate of the recent episodes (line) and of the
    snapshot evaluations (points; one series for the current stage, one for the snapshot
    preset; the best snapshot starred); middle: mean per-pursuer return of the recent
    episodes; bottom: their collision ratio (where logged) and the snapshots'. Curriculum stage starts are dashed vertical lines,
    resumes dotted ones (the replay buffer starts empty there). x axis: environment steps.
    """
    plt = _pyplot()
    records = read_metrics(metrics_path)
    train = [r for r in records if r.get("kind") == "train" and r.get("success_rate") is not None]
    snapshots = [r for r in records if r.get("kind") == "snapshot"]
    stages = [r for r in records if r.get("kind") == "stage"]
    resumes = [r for r in records if r.get("kind") == "resume"]
    if not train:
        raise CurvesError(f"{metrics_path}: no training record with finished episodes yet")

    fig, (top, middle, bottom) = plt.subplots(3, 1, figsize=(8, 8), sharex=True)
    steps = [r["env_step"] for r in train]
    top.plot(steps, [r["success_rate"] for r in train], label="recent episodes (exploring)")
    for index in (0, 1):  # a snapshot's evaluations: the current stage, then the snapshot preset
        shown = [r for r in snapshots if len(r["evaluations"]) > index]
        if not shown:
            continue
        snapshot_steps = [r["env_step"] for r in shown]
        label = "snapshot: current stage" if index == 0 else f"snapshot: {shown[-1]['evaluations'][1]['scenario']}"
        top.plot(snapshot_steps, [r["evaluations"][index]["success_rate"] for r in shown], "x",
                 color=f"C{index + 2}", label=label)
        bottom.plot(snapshot_steps, [r["evaluations"][index]["collision_ratio_mean"] for r in shown], "x",
                    color=f"C{index + 2}")
    best = [r for r in snapshots if r.get("best")]
    if best:
        chosen = best[-1]
        success = sum(e["success_rate"] for e in chosen["evaluations"]) / len(chosen["evaluations"])
        top.plot([chosen["env_step"]], [success], "*", markersize=12, color="black", label="best snapshot")
    top.set_ylabel("success rate")
    top.set_ylim(-0.05, 1.05)
    top.legend(loc="center left")
    middle.plot(steps, [r["mean_return"] for r in train])
    middle.set_ylabel("return per pursuer")
    bottom.plot(steps, [r.get("collision_ratio", float("nan")) for r in train], color="C0")
    bottom.set_ylabel("collision ratio")
    bottom.set_xlabel("environment steps")
    for axis in (top, middle, bottom):
        axis.grid(alpha=0.3)
        for resume in resumes:
            axis.axvline(resume["env_step"], color="grey", linestyle=":", linewidth=0.8)
    mark_stages((top, middle, bottom), stages)
    return save_figure(fig, out_path, title)


def save_figure(fig: Any, out_path: str | Path, title: str = "") -> Path:
    """Title `fig` (when given), write it as a PNG at `out_path`, close it; returns the path."""
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    out_path = Path(out_path)
    fig.savefig(out_path, dpi=110)
    _pyplot().close(fig)
    return out_path
