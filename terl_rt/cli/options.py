"""Options shared by several terl-rt subcommands, defined once."""

from __future__ import annotations

import click

from terl_rt.scenario import Scenario, ScenarioError


def _scenario(ctx: click.Context, param: click.Parameter, value: str | None) -> Scenario | None:
    if value is None:
        return None
    try:
        return Scenario.preset(value)
    except ScenarioError as err:
        raise click.BadParameter(str(err), ctx=ctx, param=param) from None


scenario_option = click.option(
    "--scenario", "scenario", default="small-15", show_default=True, callback=_scenario,
    help="Preset scenario name (see `terl-rt scenarios`).",
)
seed_option = click.option(
    "--seed", type=int, default=0, show_default=True, help="Random seed of the episodes."
)
json_option = click.option(
    "--json", "as_json", is_flag=True, help="Print one JSON object instead of a table."
)
