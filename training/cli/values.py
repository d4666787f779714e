"""`python -m training values`: how well networks' Q-values predict the returns that follow."""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path

import click

from terl_rt.sim.scenario import Scenario, ScenarioError


@click.command("values")
@click.argument("checkpoints", nargs=-1, required=True, type=click.Path(path_type=Path), metavar="CHECKPOINT_DIR...")
@click.option("--scenario", "preset", default="small-15", show_default=True, metavar="PRESET",
              help="Preset the greedy episodes run on.")
@click.option("--episodes", type=click.IntRange(min=1), default=4, show_default=True)
@click.option("--seed", type=int, default=0, show_default=True, help="Seed of the first world (one per episode).")
@click.option("--epsilon", type=click.FloatRange(0.0, 1.0), default=0.0, show_default=True,
              help="Probability of a random action per pursuer-step (0: greedy; training explores at its end_e, 0.05).")
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object per checkpoint instead.")
def values_command(
    checkpoints: tuple[Path, ...], preset: str, episodes: int, seed: int, epsilon: float, as_json: bool
) -> None:
    """Compare each network's Q-values with the returns that follow them: greedy episodes (or
    exploring ones, --epsilon), every pursuer-step's Q(s, a) against the discounted return of the
    rewards the network was taught (its config's reward transform). Values track the returns when
    the correlation is at least 0.5 and the mean |Q - return| under a tenth of the returns' range
    (training.lab.values.ValueCheck.tracks_returns); both in the taught units."""
    from training.checkpoint import load_network
    from training.lab.values import value_check

    try:
        scenario = Scenario.preset(preset)
    except ScenarioError as error:
        raise click.BadParameter(str(error), param_hint="--scenario") from error
    if not as_json:
        click.echo(
            "| checkpoint | pursuer-steps | Q(s, a) | return | Q - return: mean | median | mean abs "
            "| return range | correlation | tracks returns |"
        )
        click.echo("|---|---:|---:|---:|---:|---:|---:|---:|---:|---|")
    for source in checkpoints:
        try:
            model, config, _ = load_network(source)
        except (FileNotFoundError, ValueError) as error:
            raise click.ClickException(str(error)) from error
        check = value_check(model, config, scenario.replace(max_steps=config.run.eval_max_steps), episodes, seed, epsilon)
        if as_json:
            click.echo(json.dumps({"checkpoint": str(source), **asdict(check), "tracks_returns": check.tracks_returns}))
        else:
            correlation = "-" if check.correlation is None else f"{check.correlation:.2f}"
            click.echo(
                f"| {source} | {check.pursuer_steps:,} | {check.q_mean:.2f} | {check.return_mean:.2f} | "
                f"{check.gap_mean:.2f} | {check.gap_median:.2f} | {check.abs_gap_mean:.2f} | "
                f"{check.return_range:.2f} | {correlation} | {'yes' if check.tracks_returns else 'no'} |"
            )
