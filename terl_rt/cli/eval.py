"""`terl-rt eval`: evaluate a policy on scenarios (success rate, travel time, collisions)."""

from __future__ import annotations

import csv
import json
from contextlib import ExitStack
from pathlib import Path

import click

import terl_rt
from terl_rt.cli.live import live_option, open_live
from terl_rt.cli.options import (
    acting_of,
    episodes_option,
    evaluate_with_progress,
    json_option,
    log_option,
    open_policy,
    policy_json,
    policy_option,
    policy_threads,
    resolve_scenarios,
    run_options,
    scenario_file_option,
    scenarios_option,
    stdout_kept_for_json,
    suite_option,
)
from terl_rt.cli.outputs import check_output, force_option
from terl_rt.evaluation.episodes import RESULTS_SCHEMA, ScenarioResult
from terl_rt.evaluation.stats import format_interval
from terl_rt.files import atomic_output
from terl_rt.policy.contract import META_CONTRACT, META_TRAINING_STEPS

TABLE_WIDTH = 100
"""Columns of the table at most; every episode, and travel time with failures counted at
the step limit, are in --json and --csv."""
HEADER = (
    f"{'scenario':<14}{'episodes':>9} {'success [95 % CI]':<18}{'travel, successes (s)':<22}"
    f"{'collision ratio':<20}{'steps':>7}{'wall (s)':>9}"
)
"""Success rate with its exact (Clopper-Pearson) interval; mean travel time over the
successful episodes and mean collision ratio, each with its bootstrap interval."""

CSV_COLUMNS = (
    "scenario", "evader", "episode", "seed", "outcome", "success", "steps", "travel_time_s", "collisions",
    "collisions_teammate", "collisions_evader", "collisions_obstacle", "collision_ratio", "captures", "return", "max_steps", "policy", "policy_sha256", "acting", "shield_overrides",
    "decisions", "terl_rt", "schema",
)
"""Columns of `terl-rt eval --csv`, one row per episode: `acting` names a run that did not act
greedily (`terl_rt.safety.acting.Acting.label`, empty for the paper's greedy rule), the
shield's two are empty without it."""


def _row(result: ScenarioResult) -> str:
    """The table's row of `result`, in HEADER's columns."""
    ci = result.ci95()
    success = f"{result.success_rate:.2f} {format_interval(ci['success_rate'], 2)}"
    travel = f"{result.travel_time_s_success_mean:.1f} {format_interval(ci['travel_time_s_success'], 1)}"
    collision = f"{result.collision_ratio_mean:.3f} {format_interval(ci['collision_ratio'], 3)}"
    return (
        f"{result.label:<14}{result.episodes:>9} {success:<18}{travel:<22}{collision:<20}"
        f"{result.steps_mean:>7.1f}{result.wall_s:>9.1f}"
    )


def terl_rt_version() -> str:
    """The running terl-rt's version (`terl_rt.__version__`)."""
    return terl_rt.__version__


def policy_version(info: dict) -> dict:
    """What identifies the policy's version: name, sha256, path, its contract version and
    the training steps recorded in its metadata."""
    metadata = info.get("metadata", {})
    return {
        **policy_json(info),
        "contract": metadata.get(META_CONTRACT),
        "training_steps": metadata.get(META_TRAINING_STEPS),
    }


def write_csv(path: Path, results: list[ScenarioResult], info: dict) -> None:
    """One row per episode of every scenario (CSV_COLUMNS)."""
    version = terl_rt_version()
    with open(path, "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=CSV_COLUMNS)
        writer.writeheader()
        for result in results:
            for row in result.episode_rows():
                writer.writerow({
                    "scenario": result.name, "evader": result.evader, **{k: v for k, v in row.items() if k in CSV_COLUMNS},
                    "max_steps": result.max_steps, "policy": info["name"], "policy_sha256": info["sha256"],
                    "acting": result.acting.label, "terl_rt": version, "schema": RESULTS_SCHEMA,
                })


@click.command("eval")
@policy_option
@scenarios_option
@scenario_file_option
@suite_option
@episodes_option
@run_options
@log_option
@live_option("Serve every step live, as it is taken,")
@json_option
@click.option(
    "--csv", "csv_path", type=str, default=None, metavar="FILE.csv",
    help="Also write one row per episode (seed, outcome, steps, collisions, captures, return) to this CSV file.",
)
@force_option
def eval_command(
    policy_path, scenario_names, scenario_file, suite, evader, episodes, seed, max_steps, workers, backend, address,
    log_path, live, as_json, csv_path, threads, shield, shield_margin, shield_horizon, risk, force,
) -> None:
    """Evaluate a policy: success rate, travel time (s) over the successful episodes,
    collision ratio, steps and wall time per scenario, with 95 % confidence intervals over
    the episodes (exact for the success rate, bootstrap with a fixed seed for the means),
    in a table of 100 columns. Episode k of a scenario runs with seed + k, so any episode
    can be run again alone. A progress bar with an ETA goes to stderr. --json prints
    every episode too (seed, outcome, steps, collisions and what they touched, captures, return), the step
    limit, the terl-rt and policy versions and the results' schema version. An existing --log or --csv file is replaced only
    with --force (and never when it is the policy or scenario file); the log at the
    first step. With --backend ray the episodes are Ray tasks (the policy reaches the
    workers through Ray's object store); their steps stream back to the log as they are
    taken, and an episode whose worker dies is run again elsewhere, counted once.
    --shield and --risk change how the policy acts (docs/safety.md); the table's first line,
    the JSON ("acting") and the CSV name such a run, and a shielded one counts its overrides.
    --live serves the steps to Foxglove while the run goes on, in episode order as the log
    holds them (with --workers too); a slow or lost viewer never holds the run back.

    \b
    Examples:
      terl-rt eval                                     # the shipped policy on small-15, 20 episodes
      terl-rt eval --scenario large-80 --shield        # under the shield, its defaults
      terl-rt eval --scenario large-80 --shield --risk cvar:0.25
      terl-rt eval --policy my.onnx --scenario medium-48 --episodes 50 --seed 100
      terl-rt eval --suite paper --workers 2 --csv episodes.csv
      terl-rt eval --episodes 5 --log run.mcap         # then: terl-rt replay run.mcap
      terl-rt eval --suite paper --live                # watch in Foxglove: ws://127.0.0.1:8765
      terl-rt eval --scenario-file my-world.json --json
      terl-rt eval --scenario large-80 --evader widest-gap   # rows: large-80/widest-gap
    """
    inputs = [("--policy", policy_path), ("--scenario-file", scenario_file)]
    if log_path is not None:
        check_output(log_path, "--log", inputs, force)
    if csv_path is not None:
        check_output(csv_path, "--csv", inputs + [("--log", log_path)], force)
    scenarios = resolve_scenarios(scenario_names, scenario_file, suite, evader)
    acting = acting_of(shield, shield_margin, shield_horizon, risk)
    policy = open_policy(policy_path, threads=policy_threads(backend, workers, threads))
    for option, path in (("--log", log_path), ("--csv", csv_path)):
        if path is not None:  # the default policy too
            check_output(path, option, [("--policy", policy.path)], force)
    with ExitStack() as live_view, stdout_kept_for_json(as_json):  # until the backend (Ray) has shut down
        sinks = [log_path] if log_path is not None else []
        if live is not None:
            sinks.append(live_view.enter_context(open_live(live)))
        evaluation = evaluate_with_progress(
            policy, scenarios, episodes, seed, max_steps=max_steps, log=sinks, replace_log=force, workers=workers,
            backend=backend, address=address, threads=threads, acting=acting,
        )
    results, info = list(evaluation.results), evaluation.policy

    # The results reach the terminal before any file is written: a full disk cannot lose them.
    if as_json:
        click.echo(json.dumps({
            "terl_rt": terl_rt_version(),
            "schema": RESULTS_SCHEMA,
            "policy": policy_version(info),
            "acting": {**acting.to_dict(), "label": acting.label},
            "seed": seed,
            "scenarios": [result.to_dict(per_episode=True) for result in results],
        }))
    else:
        acted = f" [{acting.label}]" if acting.label else ""
        click.echo(f"policy {policy.name}{acted} ({policy.path}, sha256 {policy.sha256[:12]}), seed {seed}")
        click.echo(HEADER)
        for result in results:
            click.echo(_row(result))
        touched = [(result.label, result.collisions_touched) for result in results if result.collisions_touched]
        if any(sum(kinds.values()) for _, kinds in touched):
            click.echo("collided pursuers touched (teammate / evader / obstacle): " + ", ".join(
                f"{label} {kinds['teammate']} / {kinds['evader']} / {kinds['obstacle']}" for label, kinds in touched))
        if acting.shield is not None:
            click.echo("shield overrides a pursuer-step: " + ", ".join(
                f"{result.name} {result.shield_overrides_per_decision:.4f}" for result in results))
    if csv_path is not None:
        with atomic_output(csv_path, replace=force) as staging:
            write_csv(staging, results, info)
    if as_json:
        return
    if evaluation.log_path is not None:
        click.echo(f"log: {evaluation.log_path} ({evaluation.logged_episodes} episodes)")
    if csv_path is not None:
        click.echo(f"csv: {csv_path} ({sum(r.episodes for r in results)} episodes)")
