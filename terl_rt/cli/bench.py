"""`terl-rt bench ...`: speed benchmarks."""

from __future__ import annotations

import json
import sys

import click

from terl_rt.cli.options import (
    MAX_WORKERS,
    BadInput,
    IntRange,
    evaluation_run_options,
    json_option,
    open_policy,
    policy_option,
    progressbar,
    resolve_scenarios,
    scenario_option,
    scenarios_option,
    seed_option,
    stdout_kept_for_json,
    threads_option,
)
from terl_rt.evaluation.backends import RayMissing
from terl_rt.safety.acting import Acting
from terl_rt.safety.risk import Risk
from terl_rt.safety.shield import Shield
from terl_rt.evaluation.play import BATCH_ENVS
from terl_rt.evaluation.speed import (
    POLICY_BATCHES,
    acting_costs,
    SCALING_PURSUERS,
    SIM_WARMUP,
    backend_speeds,
    policies_side_by_side,
    policy_latencies,
    scaling_scenario,
    simulator_speed,
)

steps_option = click.option(
    "--steps", type=IntRange(min=1, max=10_000_000), default=500, show_default=True, help="Timed steps."
)
envs_option = click.option(
    "--envs", "num_envs", type=IntRange(min=1, max=4096), default=1, show_default=True,
    help="Environments stepped together (a batch).",
)


@click.group()
def bench() -> None:
    """Speed benchmarks (timings for reports, never pass/fail).

    \b
    Examples:
      terl-rt bench sim --scenario large-80 --envs 16
      terl-rt bench policy --threads 1
      terl-rt bench shield --scenario large-80 --steps 50
    """


@bench.command("sim")
@scenario_option
@steps_option
@envs_option
@seed_option
@json_option
def sim(scenario, steps: int, num_envs: int, seed: int, as_json: bool) -> None:
    """Simulator speed: environment steps per second and ms per step, with random
    pursuer actions and the paper's APF evaders (observations included).

    \b
    Examples:
      terl-rt bench sim
      terl-rt bench sim --scenario large-80 --envs 16 --steps 200 --json
    """
    # A large batch of a large world takes minutes a step: say what comes, then show it coming.
    click.echo(
        f"placing {num_envs} world(s) of {scenario.name} ({scenario.pursuers} pursuers each), then "
        f"{SIM_WARMUP} untimed and {steps} timed batch steps", err=True,
    )
    with progressbar(
        length=SIM_WARMUP + steps, label="bench sim", file=sys.stderr, show_pos=True, show_eta=True,
    ) as bar:
        result = simulator_speed(scenario, steps, num_envs=num_envs, seed=seed, progress=bar.update)
    if as_json:
        click.echo(json.dumps(result.to_dict()))
        return
    click.echo(
        f"{result.scenario}: {result.pursuers} pursuers, {result.evaders} evaders, {result.num_envs} env(s), "
        f"{result.steps} steps\n"
        f"  {result.env_steps_per_s:,.0f} env-steps/s, {result.ms_per_step:.3f} ms per step"
    )


@bench.command("scaling")
@steps_option
@json_option
def scaling(steps: int, as_json: bool) -> None:
    """How the cost of one step grows with the team: large-80's world with 15, 80, 200
    and 400 pursuers (evaders a quarter of that, arena grown to keep the density).

    \b
    Examples:
      terl-rt bench scaling
      terl-rt bench scaling --steps 50 --json
    """
    rows = []
    with progressbar(SCALING_PURSUERS, label="scaling", file=sys.stderr) as counts:
        for pursuers in counts:
            rows.append(simulator_speed(scaling_scenario(pursuers), steps).to_dict())
    if as_json:
        click.echo(json.dumps({"rows": rows}))
        return
    click.echo(f"{'pursuers':>9}{'evaders':>9}{'ms/step':>10}{'steps/s':>10}{'us/pursuer':>12}")
    for row in rows:
        per = 1e3 * row["ms_per_step"] / row["pursuers"]
        click.echo(f"{row['pursuers']:>9}{row['evaders']:>9}{row['ms_per_step']:>10.3f}{row['env_steps_per_s']:>10.0f}{per:>12.1f}")


@bench.command("policy")
@policy_option
@scenario_option
@click.option(
    "--batch", "batches", type=IntRange(min=1, max=100_000), multiple=True, default=POLICY_BATCHES,
    show_default=True, help="Rows of a call to time (repeat for several): 1 is one robot's controller.",
)
@click.option("--calls", type=IntRange(min=1, max=100_000), default=100, show_default=True,
              help="Timed calls at each batch size.")
@seed_option
@threads_option
@json_option
def policy_command(policy_path, scenario, batches, calls: int, seed: int, threads, as_json: bool) -> None:
    """Policy latency: p50 and p99 of one call at each --batch (rows of real observations
    of --scenario), per pursuer, and the matrix-product rate it reaches as a share of the
    machine's fp32 matmul rate (380 GFLOP/s on 2 threads; the FLOPs need onnx).

    \b
    Examples:
      terl-rt bench policy
      terl-rt bench policy --policy my.onnx --scenario large-80 --threads 1
    """
    policy = open_policy(policy_path, threads=threads)
    rows = policy_latencies(policy, scenario, batches, calls, seed=seed)
    if as_json:
        click.echo(json.dumps({"threads": threads, "rows": [row.to_dict() for row in rows]}))
        return
    click.echo(
        f"{policy.name} on {scenario.name}, threads {threads or 'default'}, {calls} calls a batch size"
        + ("" if rows[0].mflop_per_row else " (FLOPs need onnx: pip install -e '.[optimize]')")
    )
    click.echo(f"{'batch':>6}{'p50 (ms)':>10}{'p99 (ms)':>10}{'us/pursuer':>12}{'MFLOP/row':>11}{'GFLOP/s':>9}"
               f"{'of matmul':>11}")
    for row in rows:
        rate = "" if row.gflops is None else (
            f"{row.mflop_per_row:>11.2f}{row.gflops:>9.1f}{100 * row.matmul_share:>10.0f}%"
        )
        click.echo(f"{row.batch:>6}{row.ms_p50:>10.3f}{row.ms_p99:>10.3f}{row.us_per_pursuer:>12.1f}{rate}")


@bench.command("policies")
@click.argument("policy_paths", nargs=-1, required=True, metavar="POLICY.onnx...")
@scenarios_option
@click.option("--rounds", type=IntRange(min=1, max=1000), default=6, show_default=True,
              help="Times each policy is called on all the rows.")
@seed_option
@threads_option
@json_option
def policies_command(policy_paths, scenario_names, rounds: int, seed: int, threads, as_json: bool) -> None:
    """Policy files side by side: CPU time a row of each on the same rows, recorded along
    the first one's own episodes (4 worlds, every 20th of 400 steps, so padding as
    evaluation meets it), the files called in turn; and whether each gives the first one's
    outputs bit for bit. The ratio is the first file's CPU time over each file's.

    \b
    Examples:
      terl-rt bench policies exported/terl.onnx runs/terl-again.onnx --scenario large-80 --threads 1
      terl-rt bench policies old.onnx new.onnx --scenario small-15 --scenario medium-48 --json
    """
    if len(policy_paths) < 2:
        raise BadInput("give at least two policy files to compare")
    policies = [open_policy(path, threads=threads) for path in policy_paths]
    results = [policies_side_by_side(policies, scenario, rounds=rounds, seed=seed)
               for scenario in resolve_scenarios(scenario_names, None, None)]
    if as_json:
        click.echo(json.dumps({"threads": threads, "rounds": rounds, "scenarios": [r.to_dict() for r in results]}))
        return
    click.echo(f"CPU a row, threads {threads or 'default'}, {rounds} rounds; ratio: the first file's CPU over each one's")
    for result in results:
        click.echo(f"{result.scenario}: {result.rows} rows, {100 * result.valid_tokens:.0f} % of their tokens valid")
        for path, us, ratio, same in zip(result.policies, result.us_per_row, result.speedups, result.same_outputs):
            click.echo(f"  {us:>8.1f} us/row {ratio:>6.2f}x  {'same outputs' if same else 'OTHER OUTPUTS':<13}  {path}")


@bench.command("eval")
@evaluation_run_options
@click.option(
    "--workers", type=IntRange(min=1, max=MAX_WORKERS), default=2, show_default=True,
    help="Local worker processes, each running batches.",
)
@click.option(
    "--envs", "env_counts", type=IntRange(min=1, max=4096), multiple=True, default=(1, BATCH_ENVS),
    show_default=True, help="Episodes a batch runs at once, to time in turn (1: each episode alone, as before batching).",
)
@click.option(
    "--repeat", type=IntRange(min=1, max=100), default=1, show_default=True,
    help="Rounds over the batch sizes; each one's best round counts.",
)
@json_option
def eval_command(policy_path, scenario_names, suite, episodes, seed, max_steps, workers, env_counts, repeat,
                 as_json) -> None:
    """Evaluation speed by batch size, side by side: the same evaluation (scenario by
    scenario, as `terl-rt eval` runs it, on the local backend) with each --envs in turn,
    --repeat rounds, so all see the same load. Prints the best round's time, episodes per
    second, each one's speed-up over the first --envs, the CPU time of the run (this process
    and its workers; on a loaded machine the better measure of the work) and its ratio, and
    whether every episode came out the same. Every worker runs its policy on one onnxruntime
    thread.

    \b
    Examples:
      terl-rt bench eval --scenario small-15 --workers 1
      terl-rt bench eval --suite paper --episodes 20 --workers 2 --envs 1 --envs 20
    """
    policy = open_policy(policy_path, threads=1)
    scenarios = resolve_scenarios(scenario_names, None, suite)
    rows = backend_speeds(policy, scenarios, episodes, seed, workers, backends=("local",), repeat=repeat,
                          max_steps=max_steps, envs=env_counts)
    identical = _echo_speeds(policy, scenarios, episodes, seed, max_steps, repeat, rows, as_json, f", {workers} worker(s)")
    if as_json:
        return
    click.echo(f"{'envs':>6}{'episodes':>10}{'run (s)':>10}{'episodes/s':>12}{'speed-up':>10}{'CPU (s)':>10}"
               f"{'CPU ratio':>11}")
    for row in rows:
        click.echo(f"{row.envs:>6}{row.episodes:>10}{row.run_s:>10.1f}{row.episodes_per_s:>12.2f}"
                   f"{rows[0].run_s / row.run_s:>9.2f}x{row.cpu_s:>10.1f}{rows[0].cpu_s / row.cpu_s:>10.2f}x")
    click.echo(f"every episode the same at every batch size: {'yes' if identical else 'NO'}")


@bench.command("shield")
@policy_option
@scenario_option
@click.option("--steps", type=IntRange(min=1, max=100_000), default=50, show_default=True, help="Timed batch steps.")
@click.option(
    "--envs", "num_envs", type=IntRange(min=1, max=4096), default=BATCH_ENVS, show_default=True,
    help="Environments stepped together (an evaluation's batch).",
)
@click.option(
    "--risk", "risks", multiple=True, metavar="cvar:ALPHA",
    help="Also time risk-aware acting at this measure, alone and under the shield (repeat for several).",
)
@click.option("--repeat", type=IntRange(min=1, max=100), default=1, show_default=True,
              help="Rounds over the rules; each one's least CPU time counts.")
@seed_option
@json_option
def shield_command(policy_path, scenario, steps: int, num_envs: int, risks, repeat: int, seed: int,
                   as_json: bool) -> None:
    """CPU time per evaluation step with and without the shield (docs/safety.md): the same
    batched steps as `terl-rt eval` takes (policy on one onnxruntime thread, the rule, the
    simulator), greedy first, then under the shield with its defaults, then each --risk alone
    and shielded; prints ms of CPU a batch step and each rule's ratio to the greedy one.

    \b
    Examples:
      terl-rt bench shield --scenario large-80 --steps 50
      terl-rt bench shield --scenario large-80 --risk cvar:0.25 --repeat 3 --json
    """
    try:
        measures = [Risk.parse(text) for text in risks]
    except ValueError as error:
        raise BadInput(str(error)) from None
    policy = open_policy(policy_path, threads=1)
    actings = [Acting(), Acting(Shield())] + [Acting(shield, risk) for risk in measures for shield in (None, Shield())]
    for acting in actings:
        try:
            acting.check(policy)
        except ValueError as error:
            raise BadInput(str(error)) from None
    rows = acting_costs(policy, scenario, actings, steps, num_envs, seed, repeat)
    if as_json:
        click.echo(json.dumps({"policy": policy.name, "scenario": scenario.name, "envs": num_envs, "seed": seed,
                               "repeat": repeat, "rows": [row.to_dict() for row in rows]}))
        return
    click.echo(f"{policy.name} on {scenario.name}: {num_envs} environments, {steps} steps, best of {repeat}")
    click.echo(f"{'acting':<36}{'decisions':>10}{'CPU ms/step':>13}{'ratio':>8}")
    for row in rows:
        click.echo(f"{row.acting or 'greedy (the paper)':<36}{row.decisions:>10}{row.cpu_ms_per_step:>13.1f}{row.ratio:>8.2f}")


@bench.command("backends")
@evaluation_run_options
@click.option(
    "--workers", "worker_counts", type=IntRange(min=1, max=MAX_WORKERS), multiple=True, default=(1, 2),
    show_default=True, help="Worker counts to time (repeat for several).",
)
@click.option(
    "--repeat", type=IntRange(min=1, max=100), default=1, show_default=True,
    help="Rounds of local then Ray runs; each backend's best round counts.",
)
@json_option
def backends_command(policy_path, scenario_names, suite, episodes, seed, max_steps, worker_counts, repeat,
                     as_json) -> None:
    """Evaluation speed of the local and the Ray backend: for each worker count, the same
    evaluation (scenario by scenario, as `terl-rt eval` and `report` run it) on the local
    backend and on a local Ray instance with that many CPUs, in turn, --repeat rounds, so
    both see the same load on the machine. Prints episodes per second of the best round,
    the time to start Ray (not in the run time), Ray's run time over the local one, and
    whether every episode came out the same. Every worker runs its policy on one
    onnxruntime thread (a local run in this process too). Needs Ray: pip install 'terl-rt[ray]'.

    \b
    Examples:
      terl-rt bench backends --scenario small-15 --episodes 10 --workers 1 --workers 2 --repeat 3
      terl-rt bench backends --suite paper --episodes 4 --workers 2 --repeat 2
    """
    policy = open_policy(policy_path, threads=1)
    scenarios = resolve_scenarios(scenario_names, None, suite)
    rows = []
    with stdout_kept_for_json(as_json), progressbar(worker_counts, label="backends", file=sys.stderr) as counts:
        for workers in counts:
            try:
                rows += backend_speeds(policy, scenarios, episodes, seed, workers, repeat=repeat, max_steps=max_steps)
            except RayMissing as error:
                raise BadInput(str(error)) from None
    identical = _echo_speeds(policy, scenarios, episodes, seed, max_steps, repeat, rows, as_json)
    if as_json:
        return
    click.echo(f"{'backend':<9}{'workers':>8}{'episodes':>10}{'start (s)':>11}{'run (s)':>10}{'episodes/s':>12}{'ray/local':>11}")
    for local, ray in zip(rows[::2], rows[1::2]):
        for row in (local, ray):
            ratio = f"{row.run_s / local.run_s:.2f}" if row is ray else ""
            click.echo(f"{row.backend:<9}{row.workers:>8}{row.episodes:>10}{row.start_s:>11.1f}{row.run_s:>10.1f}"
                       f"{row.episodes_per_s:>12.2f}{ratio:>11}")
    click.echo(f"every episode the same on every backend and worker count: {'yes' if identical else 'NO'}")


def _echo_speeds(policy, scenarios, episodes: int, seed: int, max_steps, repeat: int, rows, as_json: bool,
                 setting: str = "") -> bool:
    """Print the JSON object of timed evaluations `rows` (BackendSpeed), or the heading line of
    their table (`setting` added to it); returns whether every row gave the same episodes."""
    identical = all(row.per_episode == rows[0].per_episode for row in rows)
    if as_json:
        click.echo(json.dumps({
            "policy": policy.name, "scenarios": [scenario.name for scenario in scenarios], "episodes": episodes,
            "seed": seed, "max_steps": max_steps, "repeat": repeat, "rows": [row.to_dict() for row in rows],
            "identical": identical,
        }))
    else:
        click.echo(
            f"{policy.name} on {', '.join(scenario.name for scenario in scenarios)}: {episodes} episodes each, "
            f"seed {seed}{setting}" + (f", step limit {max_steps}" if max_steps else "") + f", best of {repeat}"
        )
    return identical
