"""`python -m training run`: a recipe made into its policy."""

from __future__ import annotations

import hashlib
from pathlib import Path

import click

from training.cli.options import seed_list, set_threads
from training.config import ConfigError


@click.command("run")
@click.argument("recipe", type=click.Path(path_type=Path), metavar="RECIPE.toml")
@click.option("--out", type=click.Path(path_type=Path), required=True, metavar="DIR",
              help="Folder of the run: a folder per segment (<k>-<name>/) and the exported policy.")
@click.option("--threads", type=click.IntRange(1, 256), metavar="T",
              help="torch intra-op threads of every segment (default: the recipe's, 1).")
@click.option("--seed", type=int, metavar="S",
              help="Seed of the run (default: the recipe's, 1): replaces every segment's run.seed, as "
                   "`train --seed` does; a cut-off run resumes with the seed it started with.")
@click.option("--seeds", callback=lambda ctx, param, value: None if value is None else seed_list(ctx, param, value),
              metavar="S,S,...", help="Train several seeds together in this process (one batched update for "
              "all: 1,2,3 or 1-3), each in DIR/seed-<S>/ as one seed's run lays out DIR; not with --seed.")
@click.option("--device", metavar="DEVICE",
              help="torch device of the updates of every segment: cpu or cuda[:K] (default: the recipe's, cpu); "
                   "rollouts stay on the CPU.")
@click.option("--segments", type=click.IntRange(min=1), metavar="K",
              help="Train the first K segments only (nothing is exported unless K covers the recipe).")
@click.option("--start", metavar="START",
              help="What a recipe with from_step (recipes/scale-fine-tune.toml) continues: a checkpoint folder, a "
                   "snapshot folder or an exported .onnx policy; with --seeds, \"{seed}\" in it stands for each "
                   "seed's number. Its network and step carry into the run (laid down in DIR/0-start/).")
@click.option("--quiet", is_flag=True, help="No progress line on stderr.")
def run_command(recipe: Path, out: Path, threads: int | None, seed: int | None, seeds: list[int] | None,
                device: str | None, segments: int | None, start: str | None, quiet: bool) -> None:
    """Make the policy a recipe (recipes/*.toml) describes: train its segments in order, each
    continuing the one before, and export the policy it ships into DIR.

    Run it again with the same DIR after a stop: finished segments are skipped and a cut-off
    one resumes from its last checkpoint.

    \b
    Examples:
      python -m training run recipes/terl.toml --out runs/terl
      python -m training run recipes/comparison/iqn.toml --out runs/iqn-seed-2 --seed 2
      python -m training run recipes/terl-paper.toml --out runs/paper --seeds 1-3 --segments 1
      python -m training run recipes/scale-fine-tune.toml --start runs/paper/seed-1/1-curriculum --out runs/ft
      python -m training run recipes/scale-fine-tune.toml --seeds 1-3 --out runs/ft3 \\
          --start 'exported/comparison/terl-authors-seed-{seed}.onnx'
    """
    from training.lab.recipe import load_recipe, run_recipe
    from training.train import train_seeds

    if seed is not None and seeds is not None:
        raise ConfigError("give --seed S (one seed, in DIR) or --seeds S,S,... (several, in DIR/seed-<S>), not both")
    plan = load_recipe(recipe)
    set_threads(threads or plan.segments[0].config.run.threads)
    paths = run_recipe(plan, out, train_seeds, threads=threads, seed=seed, seeds=seeds, device=device,
                       segments=segments, show_progress=not quiet, note=click.echo, start=start)
    for path in paths:
        digest = hashlib.sha256(path.read_bytes()).hexdigest()
        click.echo(f"{path}: {plan.ships} by {recipe}; sha256 {digest}")
    if not paths:
        click.echo(f"segments 1-{segments} of {recipe} trained in {out} (nothing exported: the recipe has "
                   f"{len(plan.segments)} segments)")
