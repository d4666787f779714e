"""`python -m training card`: the model card of a shipped policy."""

from __future__ import annotations

from pathlib import Path

import click

from training.cli.options import output_option
from training.lab.card import DEFAULT_MACHINE


@click.command("card")
@click.argument("run", type=click.Path(path_type=Path), metavar="RUN_DIR")
@click.option("--onnx", type=click.Path(path_type=Path, exists=True, dir_okay=False), required=True,
              metavar="FILE.onnx", help="The shipped policy the card is for (its sha256 goes into the card).")
@click.option("--recipe", type=click.Path(path_type=Path, exists=True, dir_okay=False), required=True,
              metavar="RECIPE.toml", help="The recipe that made it (recipes/*.toml).")
@click.option("--machine", default=DEFAULT_MACHINE, show_default=True,
              help="Where the run trained, in words.")
@click.option("--comparison", type=click.Path(path_type=Path), metavar="FILE.json",
              help="A comparison.json of `terl-rt report` (several policies) holding this model: its "
                   "per-group evaluation goes into the card.")
@output_option("CARD.md")
def card_command(run: Path, onnx: Path, recipe: Path, machine: str, comparison: Path | None, output: Path) -> None:
    """Write the model card of the policy exported from RUN_DIR's best snapshot: its recipe and
    the sha256 of its weights, body, size, training cost, every snapshot evaluation and (with
    --comparison) its evaluation on the paper's presets."""
    from training.lab.card import model_card

    output.write_text(model_card(run, onnx, recipe, machine, comparison))
    click.echo(f"{output}: model card of {onnx}")
