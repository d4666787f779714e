"""`terl-rt scenarios`: the preset scenarios."""

from __future__ import annotations

import json

import click

from terl_rt.cli.options import json_option
from terl_rt.sim.scenario import PAPER_SUITE, PUBLISHED_SMALL_SUITE, Scenario


@click.command()
@json_option
def scenarios(as_json: bool) -> None:
    """List the preset scenarios: the paper's 10 evaluation presets (`--suite paper`),
    the 3 of the authors' released small-scale evaluation config (small-published-*,
    policy.md section 2) and the 5 training curriculum stages. Arena sizes in metres.

    \b
    Examples:
      terl-rt scenarios
      terl-rt scenarios --json        # each preset in the form --scenario-file reads
    """
    rows = [Scenario.preset(name).to_dict() for name in Scenario.presets()]
    if as_json:
        click.echo(json.dumps({
            "scenarios": rows, "paper_suite": list(PAPER_SUITE), "published_small_suite": list(PUBLISHED_SMALL_SUITE),
        }))
        return
    header = f"{'name':<19}{'pursuers':>9}{'evaders':>8}{'obstacles':>10}{'vortices':>9}{'arena':>11}{'E':>4}{'steps':>7}"
    click.echo(header)
    for row in rows:
        arena = "x".join(f"{v:g}" for v in row["arena"])
        click.echo(
            f"{row['name']:<19}{row['pursuers']:>9}{row['evaders']:>8}{row['obstacles']:>10}"
            f"{row['vortices']:>9}{arena:>11}{row['evader_slots']:>4}{row['max_steps']:>7}"
        )
