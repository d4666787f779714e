"""`python -m training run`: a recipe made into its policy."""

from __future__ import annotations

import hashlib
from pathlib import Path

import click

from training.cli.options import set_threads
from training.recipe import load_recipe, run_recipe


@click.command("run")
@click.argument("recipe", type=click.Path(path_type=Path), metavar="RECIPE.toml")
@click.option("--out", type=click.Path(path_type=Path), required=True, metavar="DIR",
              help="Folder of the run: a folder per segment (<k>-<name>/) and the exported policy.")
@click.option("--threads", type=click.IntRange(1, 256), metavar="T",
              help="torch intra-op threads of every segment (default: the recipe's, 1).")
@click.option("--seed", type=int, metavar="S",
              help="Seed of the run (default: the recipe's, 1): replaces every segment's run.seed, as "
                   "`train --seed` does; a cut-off run resumes with the seed it started with.")
@click.option("--quiet", is_flag=True, help="No progress line on stderr.")
def run_command(recipe: Path, out: Path, threads: int | None, seed: int | None, quiet: bool) -> None:
    """Make the policy a recipe (recipes/*.toml) describes: train its segments in order, each
    continuing the one before, and export the policy it ships into DIR.

    Run it again with the same DIR after a stop: finished segments are skipped and a cut-off
    one resumes from its last checkpoint.

    \b
    Examples:
      python -m training run recipes/terl.toml --out runs/terl
      python -m training run recipes/comparison/iqn.toml --out runs/iqn-seed-2 --seed 2
    """
    from training.train import train

    plan = load_recipe(recipe)
    set_threads(threads or plan.segments[0].config.run.threads)
    path = run_recipe(plan, out, train, threads=threads, seed=seed, show_progress=not quiet, note=click.echo)
    digest = hashlib.sha256(path.read_bytes()).hexdigest()
    click.echo(f"{path}: {plan.ships} by {recipe}; sha256 {digest}")
