"""`terl-rt eval`: evaluate a policy on scenarios (success rate, travel time, collisions)."""

from __future__ import annotations

import json
from pathlib import Path

import click

from terl_rt.cli.options import (
    episodes_option,
    evaluate_with_progress,
    json_option,
    log_option,
    max_steps_option,
    open_policy,
    policy_json,
    policy_option,
    resolve_scenarios,
    scenario_file_option,
    scenarios_option,
    seed_option,
    suite_option,
    threads_option,
    workers_option,
)
from terl_rt.cli.outputs import check_output, force_option
from terl_rt.evaluation.episodes import ScenarioResult
from terl_rt.logs.writer import EpisodeLogWriter
from terl_rt.policy.onnx_policy import policy_info

HEADER = (
    f"{'scenario':<14}{'episodes':>9}{'success':>9}{'travel time (s)':>18}"
    f"{'collision':>11}{'steps':>9}{'wall (s)':>10}"
)


def _row(result: ScenarioResult) -> str:
    travel = f"{result.travel_time_s_mean:.1f} ± {result.travel_time_s_std:.1f}"
    return (
        f"{result.name:<14}{result.episodes:>9}{result.success_rate:>9.2f}{travel:>18}"
        f"{result.collision_ratio_mean:>11.3f}{result.steps_mean:>9.1f}{result.wall_s:>10.1f}"
    )


@click.command("eval")
@policy_option
@scenarios_option
@scenario_file_option
@suite_option
@episodes_option
@seed_option
@max_steps_option
@workers_option
@log_option
@json_option
@threads_option
@force_option
def eval_command(
    policy_path, scenario_names, scenario_file, suite, episodes, seed, max_steps, workers, log_path, as_json, threads,
    force,
) -> None:
    """Evaluate a policy: success rate, travel time (s, mean ± std), collision ratio,
    steps and wall time per scenario. Episode k of a scenario runs with seed + k, so
    any episode can be run again alone. A progress bar goes to stderr. An existing
    --log file is replaced only with --force (and never when it is the policy or
    scenario file), at the first step."""
    if log_path:
        check_output(log_path, "--log", [("--policy", policy_path), ("--scenario-file", scenario_file)], force)
    scenarios = resolve_scenarios(scenario_names, scenario_file, suite)
    policy = open_policy(policy_path, threads=threads if workers == 1 else None)
    if log_path:  # the default policy too
        check_output(log_path, "--log", [("--policy", policy.path)], force)
    info = policy_info(policy)
    log = EpisodeLogWriter(Path(log_path), info, staged=True) if log_path else None
    try:
        results = evaluate_with_progress(
            policy, scenarios, episodes, seed, max_steps=max_steps, workers=workers, log=log, threads=threads,
        )
    finally:
        if log is not None:
            log.close()

    if as_json:
        click.echo(json.dumps({
            "policy": policy_json(info),
            "scenarios": [result.to_dict() for result in results],
        }))
        return
    click.echo(f"policy {policy.name} ({policy.path}, sha256 {policy.sha256[:12]}), seed {seed}")
    click.echo(HEADER)
    for result in results:
        click.echo(_row(result))
    if log is not None:
        click.echo(f"log: {log.path} ({log.episodes_written} episodes)")
