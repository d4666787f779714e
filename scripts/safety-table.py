"""The tables of docs/safety.md ("Measured") from scripts/safety-measurement.sh's sweeps.

    python scripts/safety-table.py [OUT]         # OUT default runs/safety; markdown on stdout

OUT/<policy>/<rule>/<worlds>/sweep.json, as the measurement script writes them (OUT/held-out/ is
left to a call of its own); what is not
there yet is left out (a run still going). Per policy and rule and scale group (the paper
suite's small, medium, large and CC; 160, 240 and 400 pursuers): success with its exact 95 %
interval, travel time (s, every episode as it ran) and collision ratio with their 95 %
bootstrap intervals (`terl_rt.evaluation.stats.mean_intervals`: every preset of a group
weighs the same), the shield's overrides a pursuer-step, the travel time against the same
episodes run greedily (a ratio of the two means, with a bootstrap interval over the paired
episodes) and what the collided pursuers touched. Then the issue's goals for the default
under each rule: collision ratio at most 0.03 everywhere, success 1.00 at small, medium and
large scale and at least 0.95 on CC, travel times within the paper's, at most 10 % slower than greedy.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from terl_rt.evaluation.stats import BOOTSTRAP_RESAMPLES, BOOTSTRAP_SEED, format_interval, mean_intervals
from terl_rt.paper.numbers import GOALS
from terl_rt.paper.seed_comparison import SEED_GROUPS, group_of
from terl_rt.sim.metrics import EpisodeMetrics

WORLDS = ("paper", "scale-160", "scale-240", "scale-400")
"""The sweeps of one policy and rule, in the measurement script's order."""
GROUPS = tuple(group for group in SEED_GROUPS if group != "small (released config)")
"""The groups of the table: the paper suite's four, then the three beyond it."""
DEFAULT = "terl"
"""The folder of the shipped default (exported/terl.onnx)."""
HELD_OUT = "held-out"
"""OUT/held-out/: the same layout on held-out episodes, a measurement of its own (its table: OUT/held-out as OUT)."""
MAX_COLLISION_RATIO = 0.03
MIN_CC_SUCCESS = 0.95
MAX_SLOWDOWN = 1.10
"""The issue's goals for the shielded default (docs/safety.md, "Goals")."""


def episode_metrics(row: dict) -> EpisodeMetrics:
    """One episode of a sweep's JSON (`ScenarioResult.episode_rows`) as EpisodeMetrics."""
    return EpisodeMetrics(
        success=row["success"], steps=row["steps"], travel_time_s=row["travel_time_s"],
        collision_ratio=row["collision_ratio"], evaders_encircled=row["captures"],
        pursuers_collided=row["collisions"], team_return=row["return"],
        shield_overrides=row.get("shield_overrides"), decisions=row.get("decisions"),
        collisions_teammate=row["collisions_teammate"], collisions_evader=row["collisions_evader"],
        collisions_obstacle=row["collisions_obstacle"],
    )


def check_acting(rule: str, acting: dict, path: Path) -> None:
    """Refuse a sweep whose acting is not its folder's rule (plain, shield, cvar-A, shield-cvar-A)."""
    risk = rule.removeprefix("shield").removeprefix("-")
    expected_risk = f"cvar:{risk.removeprefix('cvar-')}" if risk.startswith("cvar-") else None
    if (acting.get("shield") is not None) != rule.startswith("shield") or acting.get("risk") != expected_risk:
        raise SystemExit(f"{path}: acted as {acting.get('label') or 'greedy'!r}, which is not its folder's rule {rule!r}")


def read_rule(folder: Path) -> dict[str, list[tuple[list[EpisodeMetrics], float]]]:
    """group -> [(episodes, step limit in s)] a preset, from the finished sweeps of one policy and rule."""
    groups: dict[str, list[tuple[list[EpisodeMetrics], float]]] = {}
    for worlds in WORLDS:
        path = folder / worlds / "sweep.json"
        if not path.is_file():
            continue
        sweep = json.loads(path.read_text())
        check_acting(folder.name, sweep["acting"], path)
        for row in sweep["rows"]:
            group = group_of(row["name"])
            if group in GROUPS:
                groups.setdefault(group, []).append(([episode_metrics(e) for e in row["per_episode"]], row["limit_s"]))
    return groups


def travel_ratio(rule: list[tuple[list[EpisodeMetrics], float]], plain: list[tuple[list[EpisodeMetrics], float]]) -> tuple[float, tuple[float, float]]:
    """The group's mean travel time under a rule over the greedy one on the same episodes, and
    its 95 % bootstrap interval (episodes drawn again within each preset, the same draw for both)."""
    rng = np.random.default_rng(BOOTSTRAP_SEED)
    ours = np.zeros(BOOTSTRAP_RESAMPLES)
    theirs = np.zeros(BOOTSTRAP_RESAMPLES)
    point = [0.0, 0.0]
    for (episodes, _), (greedy, _) in zip(rule, plain):
        a = np.array([m.travel_time_s for m in episodes])
        b = np.array([m.travel_time_s for m in greedy])
        draw = rng.integers(0, a.size, size=(BOOTSTRAP_RESAMPLES, a.size))
        ours += a[draw].mean(axis=1)
        theirs += b[draw].mean(axis=1)
        point[0] += a.mean()
        point[1] += b.mean()
    low, high = np.quantile(ours / theirs, [0.025, 0.975])
    return point[0] / point[1], (float(low), float(high))


def summary(presets: list[tuple[list[EpisodeMetrics], float]]) -> dict:
    """The group's means over its presets (each weighing the same) and their intervals."""
    ci = mean_intervals([episodes for episodes, _ in presets], [limit for _, limit in presets])
    decided = sum(m.decisions or 0 for episodes, _ in presets for m in episodes)
    overrides = sum(m.shield_overrides or 0 for episodes, _ in presets for m in episodes)
    touched = [sum(getattr(m, f"collisions_{kind}") for episodes, _ in presets for m in episodes)
               for kind in ("teammate", "evader", "obstacle")]
    return {
        "episodes": sum(len(episodes) for episodes, _ in presets),
        "success": float(np.mean([np.mean([m.success for m in e]) for e, _ in presets])),
        "travel": float(np.mean([np.mean([m.travel_time_s for m in e]) for e, _ in presets])),
        "collision": float(np.mean([np.mean([m.collision_ratio for m in e]) for e, _ in presets])),
        "ci": ci, "overrides": overrides / decided if decided else None, "touched": touched,
    }


def goals_met(group: str, s: dict, ratio: float | None) -> list[str]:
    """The issue's goals this group misses under a rule (empty: all met)."""
    missed = []
    if s["collision"] > MAX_COLLISION_RATIO + 1e-9:
        missed.append(f"collision ratio {s['collision']:.3f}")
    paper = GOALS.get(group)
    need = MIN_CC_SUCCESS if group == "CC" else 1.0
    if s["success"] < need - 1e-9:
        missed.append(f"success {s['success']:.3f}")
    if paper is not None and s["travel"] > paper.max_travel_time_s + 1e-9:
        missed.append(f"travel time {s['travel']:.1f} s")
    if ratio is not None and ratio > MAX_SLOWDOWN + 1e-9:
        missed.append(f"{ratio:.2f} x greedy's travel time")
    return missed


def policy_table(out: Path, policy: str) -> list[str]:
    """The full table of one policy: a row a rule and group, and the goals each rule misses."""
    folder = out / policy
    rules = sorted((p.name for p in folder.iterdir() if p.is_dir()), key=lambda r: (r != "plain", "shield" in r, r))
    read = {rule: read_rule(folder / rule) for rule in rules}
    plain = read.get("plain", {})
    lines = [
        f"#### {policy}", "",
        "| acting | group | episodes | success | travel time (s) | vs greedy | collision ratio | touched: teammate / evader / obstacle | overrides / pursuer-step |",
        "|---|---|---:|---|---|---|---|---|---:|",
    ]
    verdicts = []
    for rule in rules:
        missed_all = []
        for group in GROUPS:
            presets = read[rule].get(group)
            if not presets:
                continue
            s = summary(presets)
            ratio = None
            vs = "—"
            if rule != "plain" and group in plain and len(plain[group]) == len(presets):
                ratio, interval = travel_ratio(presets, plain[group])
                vs = f"{ratio:.2f} {format_interval(interval, 2)}"
            ci = s["ci"]
            overrides = "—" if s["overrides"] is None else f"{s['overrides']:.4f}"
            lines.append(
                f"| {rule} | {group} | {s['episodes']} | {s['success']:.2f} {format_interval(ci['success_rate'], 2)} "
                f"| {s['travel']:.1f} {format_interval(ci['travel_time_s'], 1)} | {vs} "
                f"| {s['collision']:.3f} {format_interval(ci['collision_ratio'], 3)} "
                f"| {' / '.join(str(t) for t in s['touched'])} "
                f"| {overrides} |"
            )
            missed_all += [f"{group}: {m}" for m in goals_met(group, s, ratio)]
        if not read[rule]:
            verdicts.append(f"- {rule}: not measured yet")
            continue
        complete = all(group in read[rule] for group in GROUPS)
        verdicts.append(f"- {rule}: " + (
            ("meets every goal" if not missed_all else "misses " + "; ".join(missed_all))
            + ("" if complete else " (not every group measured yet)")))
    return lines + ["", "Goals (issue 75) under each rule:", "", *verdicts, ""]


def main(out: Path) -> None:
    policies = sorted((p.name for p in out.iterdir() if p.is_dir() and p.name != HELD_OUT), key=lambda p: (p != DEFAULT, p))
    for policy in policies:
        print("\n".join(policy_table(out, policy)))


if __name__ == "__main__":
    main(Path(sys.argv[1] if len(sys.argv) > 1 else "runs/safety"))
