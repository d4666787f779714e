"""Learning curves of a run's kept snapshots: `python -m training curve`.

A run with `keep_snapshots` keeps the network of every snapshot in RUN/snapshots/<step>/. A
curve evaluates each of them greedy on presets the run itself did not (its snapshots see the
current stage and one preset), as its snapshots were evaluated (`training.seed_state.greedy_evaluation`:
the network in-process, episode k with seed `seed` + k, truncated after `max_steps`). Each
evaluation is stored beside its network (snapshots/<step>/evaluations.json), so a later call
evaluates only new snapshots or presets; one the run made itself (a "snapshot" record of its
metrics.jsonl with the same preset, episodes, first seed and step limit) is read from there.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

from terl_rt.evaluation.stats import success_interval
from terl_rt.files import atomic_output
from terl_rt.sim.scenario import Scenario
from training.checkpoint import STATE_FILE, load_network, read_config
from training.lab.curves import CurvesError, read_metrics
from training.seed_state import METRICS_FILE, SNAPSHOTS_FOLDER, greedy_evaluation

EVALUATIONS_FILE = "evaluations.json"
"""A kept snapshot's stored evaluations, beside its network: a JSON list of records."""
KEYS = {"scenario", "episodes", "seed", "max_steps", "success_rate", "travel_time_s_mean", "collision_ratio_mean"}
"""What every evaluation record holds: what it evaluated, and what a curve shows of it."""


def kept_snapshots(run: Path) -> list[tuple[int, Path]]:
    """(environment step, folder) of every whole snapshot a run kept (its state.json written), by step."""
    folder = run / SNAPSHOTS_FOLDER
    if not folder.is_dir():
        raise CurvesError(f"{run}: no {SNAPSHOTS_FOLDER}/ (the run kept no snapshot: keep_snapshots)")
    kept = sorted((int(path.name), path) for path in folder.iterdir()
                  if path.name.isdigit() and (path / STATE_FILE).is_file())
    if not kept:
        raise CurvesError(f"{folder}: no whole snapshot yet")
    return kept


def same_evaluation(record: dict[str, Any], scenario: str, episodes: int, seed: int, max_steps: int) -> bool:
    """Whether an evaluation record is of `scenario`'s `episodes` episodes from `seed`, cut at `max_steps`."""
    return (record["scenario"], record["episodes"], record["seed"], record["max_steps"]) == (
        scenario, episodes, seed, max_steps)


def run_seed(run: Path) -> int:
    """The seed of a run, as its first kept snapshot's config says."""
    return read_config(kept_snapshots(run)[0][1]).run.seed


def recorded_evaluations(run: Path, max_steps: int) -> dict[int, list[dict[str, Any]]]:
    """The evaluations the run made at its snapshots (metrics.jsonl), by environment step, each
    with the run's step limit (`max_steps`, its config's eval_max_steps) as "max_steps"."""
    if not (run / METRICS_FILE).is_file():
        return {}
    return {
        record["env_step"]: [{**evaluation, "max_steps": max_steps} for evaluation in record["evaluations"]]
        for record in read_metrics(run / METRICS_FILE) if record.get("kind") == "snapshot"
    }


def read_stored(folder: Path) -> list[dict[str, Any]]:
    """A snapshot folder's stored evaluations ([] when there are none)."""
    path = folder / EVALUATIONS_FILE
    if not path.is_file():
        return []
    try:
        stored = json.loads(path.read_text())
    except json.JSONDecodeError as error:
        raise CurvesError(f"{path}: not JSON ({error}); delete it to evaluate again") from None
    if not isinstance(stored, list) or not all(isinstance(record, dict) and KEYS <= record.keys() for record in stored):
        raise CurvesError(f"{path}: not a list of evaluations (each with {', '.join(sorted(KEYS))}); "
                          "delete it to evaluate again")
    return stored


def snapshot_curve(
    run: Path, presets: Sequence[str], episodes: int, seed: int, max_steps: int,
    announce: Callable[[str], None] = lambda text: None,
) -> list[dict[str, Any]]:
    """Every kept snapshot of `run` on every preset of `presets`: records of "env_step",
    "scenario", "episodes", "seed", "max_steps", success rate, travel time (s), collision ratio
    and steps, by step then preset. What is neither stored nor recorded is evaluated (a line to
    `announce` before each) and stored."""
    scenarios = [Scenario.preset(name) for name in presets]
    kept = kept_snapshots(run)
    recorded = recorded_evaluations(run, read_config(kept[0][1]).run.eval_max_steps)
    points = []
    for step, folder in kept:
        stored = read_stored(folder)
        for scenario in scenarios:
            known = [record for record in stored + recorded.get(step, [])
                     if same_evaluation(record, scenario.name, episodes, seed, max_steps)]
            if known:
                evaluation = known[0]
            else:
                announce(f"{folder}: {episodes} episodes of {scenario.name}")
                model, config, _ = load_network(folder)
                settings = replace(config.run, snapshot_episodes=episodes, eval_seed=seed, eval_max_steps=max_steps)
                evaluation = {**greedy_evaluation(model, scenario, settings), "max_steps": max_steps}
                stored.append(evaluation)
                with atomic_output(folder / EVALUATIONS_FILE, replace=True) as temporary:  # whole, or the old list
                    temporary.write_text(json.dumps(stored, indent=1) + "\n")
            points.append({"env_step": step, **evaluation})
    return points


def with_interval(point: dict[str, Any]) -> dict[str, Any]:
    """A curve point with the exact 95 % interval of its success rate ("success_low", "success_high")."""
    successes = round(point["success_rate"] * point["episodes"])
    low, high = success_interval(successes, point["episodes"])
    return {**point, "success_low": low, "success_high": high}


def picked_snapshot(points: Sequence[dict[str, Any]], preset: str) -> dict[str, Any]:
    """The point of one run's curve (`points`, from `snapshot_curve`) whose snapshot a rule that
    sees `preset` alone ships: the most successes there, then the lowest collision ratio, then the
    latest step. Raises CurvesError when no point is of `preset`."""
    candidates = [point for point in points if point["scenario"] == preset]
    if not candidates:
        raise CurvesError(f"no snapshot evaluated on {preset}")
    return max(candidates, key=lambda point: (point["success_rate"], -point["collision_ratio_mean"], point["env_step"]))
