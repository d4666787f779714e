"""Training curves from a run's metrics.jsonl: success rate, return and collision ratio against environment steps."""

from __future__ import annotations

import json
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


def plot_curves(metrics_path: str | Path, out_path: str | Path, title: str = "") -> Path:
    """Write a PNG of the training curves of a run.

    Top: success rate of the recent episodes (line) and of the
    snapshot evaluations (points; one series for the current stage, one for the snapshot
    preset; the best snapshot starred); middle: mean per-pursuer return of the recent
    episodes; bottom: their collision ratio (where logged) and the snapshots'. Curriculum stage starts are dashed vertical lines,
    resumes dotted ones (the replay buffer starts empty there). x axis: environment steps.
    """
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        raise CurvesError("plotting needs matplotlib: pip install -e '.[report]'") from None

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
        for stage in stages:
            axis.axvline(stage["env_step"], color="grey", linestyle="--", linewidth=0.8)
        for resume in resumes:
            axis.axvline(resume["env_step"], color="grey", linestyle=":", linewidth=0.8)
    for stage in stages:
        top.annotate(stage["stage"].replace("curriculum-", "stage "), (stage["env_step"], 1.0),
                     fontsize=7, rotation=90, va="top", ha="right", color="grey")
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    out_path = Path(out_path)
    fig.savefig(out_path, dpi=110)
    plt.close(fig)
    return out_path
