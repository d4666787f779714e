"""`terl-rt optimize POLICY -o OUT`: the fastest variant of a policy that decides as it does."""

from __future__ import annotations

import json

import click

from terl_rt.cli.options import (
    BadInput,
    episodes_option,
    json_option,
    open_policy,
    resolve_scenarios,
    scenarios_option,
    seed_option,
    suite_option,
    threads_option,
)
from terl_rt.cli.outputs import check_output, force_option
from terl_rt.files import atomic_output
from terl_rt.policy.flops import OnnxMissing
from terl_rt.evaluation.optimize import DECISION_AGREEMENT, VARIANTS, optimize_policy


@click.command("optimize")
@click.argument("policy_path", metavar="POLICY")
@click.option("-o", "--out", required=True, metavar="FILE", help="Where to write the fastest variant that passes.")
@click.option(
    "--variant", "variants", type=click.Choice(list(VARIANTS)), multiple=True, default=tuple(VARIANTS),
    show_default=True, help="Variants to try (repeat for several).",
)
@scenarios_option
@suite_option
@episodes_option
@seed_option
@threads_option
@force_option
@json_option
@click.pass_context
def optimize_command(ctx, policy_path, out, variants, scenario_names, suite, episodes, seed, threads, force,
                     as_json) -> None:
    """Try onnxruntime's transformer fusions and int8 quantisation (dynamic, and static
    calibrated on recorded observations) on POLICY. Each variant is checked against the
    float graph: rows decided alike whatever rows share a call, the same greedy action on
    at least 99.5 % of observations recorded in the policy's own episodes, each
    scenario's success rate inside the float's exact 95 % interval (--episodes each, the
    paper suite unless --scenario or --suite), and a call at least 1.1x faster. The fastest variant that
    passes is written to --out; a variant that fails is not offered (exit status 1 when
    none passes).

    \b
    Examples:
      terl-rt optimize exported/terl.onnx -o runs/terl-fast.onnx
      terl-rt optimize my.onnx -o fast.onnx --scenario small-15 --episodes 20 --json
    """
    policy = open_policy(policy_path, threads=threads or 1)
    target = check_output(out, "--out", [("policy", policy_path)], force)
    scenarios = resolve_scenarios(scenario_names, None, suite or (None if scenario_names else "paper"))
    try:
        checks = optimize_policy(policy, scenarios, episodes, seed, variants, threads=threads or 1)
    except OnnxMissing as error:
        raise BadInput(str(error)) from None
    passed = sorted((check for check in checks if check.passed), key=lambda check: -check.speedup)
    if as_json:
        click.echo(json.dumps({
            "policy": policy.name, "scenarios": [scenario.name for scenario in scenarios], "episodes": episodes,
            "decision_agreement": DECISION_AGREEMENT, "written": passed[0].name if passed else None,
            "variants": [{"name": c.name, "passed": c.passed, "failed_check": c.failed_check, "detail": c.detail,
                          "agreement": c.agreement, "speedup": c.speedup} for c in checks],
        }))
    else:
        for check in checks:
            verdict = "passes" if check.passed else f"fails '{check.failed_check}'"
            click.echo(f"{check.name:<14}{verdict:<22}{check.detail}")
        click.echo(f"writing {passed[0].name} to {target}" if passed else "no variant passed its checks; nothing written")
    if not passed:
        ctx.exit(1)
    with atomic_output(target, replace=force) as staging:  # after the results are printed
        staging.write_bytes(passed[0].model)
