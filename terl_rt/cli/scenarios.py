"""`terl-rt scenarios`: the preset scenarios."""

from __future__ import annotations

import json

import click

from terl_rt.cli.options import json_option
from terl_rt.sim.evader import DEFAULT_EVADER, EVADERS
from terl_rt.sim.scenario import PAPER_SUITE, PUBLISHED_SMALL_SUITE, Scenario


@click.command()
@click.argument("name", required=False, metavar="[NAME]")
@click.option("--evaders", "list_evaders", is_flag=True, help="List the evaders a scenario (or --evader) can name instead.")
@json_option
def scenarios(name: str | None, list_evaders: bool, as_json: bool) -> None:
    """List the preset scenarios: the paper's 10 evaluation presets (`--suite paper`),
    the 3 of the authors' released small-scale evaluation config (small-published-*,
    policy.md section 2) and the 5 training curriculum stages. Arena sizes in metres.
    With NAME, that preset alone; with NAME and --json, it as a scenario file that
    --scenario-file reads (docs/world.md section 12): a start for one of your own.
    With --evaders, the evaders by name (one a line, the default first), which a
    scenario's `evader` field and --evader of eval, report and sweep choose from.

    \b
    Examples:
      terl-rt scenarios
      terl-rt scenarios --json        # every preset, and the suites
      terl-rt scenarios --json small-15 > my_world.json && terl-rt eval --scenario-file my_world.json
      terl-rt scenarios --evaders     # then: terl-rt eval --evader widest-gap
    """
    if list_evaders:
        if name is not None:
            raise click.UsageError("--evaders lists every evader; pass no NAME with it")
        if as_json:
            rows = [{"name": kind.name, "summary": kind.summary} for kind in EVADERS.values()]
            click.echo(json.dumps({"evaders": rows, "default": DEFAULT_EVADER}))
        else:
            width = max(map(len, EVADERS)) + 2
            for kind in EVADERS.values():
                click.echo(f"{kind.name:<{width}}{kind.summary}")
        return
    if name is not None and as_json:
        click.echo(json.dumps(Scenario.preset(name).to_dict(), indent=2))
        return
    rows = [Scenario.preset(each).to_dict() for each in ([name] if name else Scenario.presets())]
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
