"""`python -m training grid`: recipes x seeds, each a run of its own, and their policies shipped."""

from __future__ import annotations

from pathlib import Path

import click

from terl_rt.command_line import address_option
from terl_rt.evaluation.backends import BACKENDS, RAY_INSTALL_HINT
from training.cli.options import seed_list
from training.config import ConfigError
from training.lab.card import DEFAULT_MACHINE


@click.command("grid")
@click.argument("recipes", nargs=-1, required=True, type=click.Path(path_type=Path), metavar="RECIPE.toml...")
@click.option("--seeds", required=True, callback=seed_list, metavar="S,S,...",
              help="Seeds of every recipe: 1,2,3 or 1-3.")
@click.option("--out", type=click.Path(path_type=Path), required=True, metavar="DIR",
              help="Folder of the grid: DIR/<method>/seed-<S>/ (the run) and DIR/<method>/seed-<S>.log; a "
                   "method is its recipe's file name without .toml.")
@click.option("--processes", type=click.IntRange(1, 1024), metavar="N",
              help="Cells run at once, one torch thread each [default: 1; with --backend ray: every cell, "
                   "as the cluster's CPUs allow].")
@click.option("--seeds-per-process", type=click.IntRange(1, 64), default=1, show_default=True, metavar="S",
              help="Seeds of a method trained together in one process (one batched update for all, "
                   "`run --seeds`), each still in DIR/<method>/seed-<S>/; a stack's log is "
                   "DIR/<method>/seeds-<S>-<S>....log.")
@click.option("--device", metavar="DEVICE",
              help="torch device of every cell's updates: cpu or cuda[:K] (default: the recipes', cpu).")
@click.option("--backend", type=click.Choice(BACKENDS), default="local", show_default=True,
              help="Where the cells run: local (processes of this machine) or ray (Ray tasks of one CPU: a "
                   "local Ray instance, or the cluster at --address, whose nodes see DIR and the recipes at "
                   "the same paths; pip install 'terl-rt[ray]').")
@address_option
@click.option("--ship", type=click.Path(path_type=Path), metavar="FOLDER",
              help="Once the cells have ended, write FOLDER/<method>-seed-<S>.onnx for every finished cell "
                   "(its best snapshot; terl.method and terl.seed in its metadata) and each method's card "
                   "FOLDER/<method>.md with its figure <method>-seeds.png.")
@click.option("--machine", default=DEFAULT_MACHINE, show_default=True, help="Where the cells train, in words (cards).")
@click.option("--stop-after", type=click.FloatRange(min=0, min_open=True), metavar="MINUTES",
              help="Stop the grid after MINUTES as SIGTERM would: the running cells write whole checkpoints "
                   "and no other starts (exit status 130); for a machine lent for a while, or a session's end.")
def grid_command(recipes: tuple[Path, ...], seeds: list[int], out: Path, processes: int | None,
                 seeds_per_process: int, device: str | None, backend: str, address: str | None, ship: Path | None,
                 machine: str, stop_after: float | None) -> int:
    """Run every recipe with every seed, each cell `python -m training run RECIPE --out
    DIR/<method>/seed-<S> --seed S --threads 1` in a process of its own, and (with --ship)
    ship their policies and one card per method.

    A line on stderr for each cell that starts or ends, with the counts. A cell that fails gives
    one `Error:` line naming its log; the others go on, and the exit status is 1. Ctrl-C or
    SIGTERM is passed on to the running cells, which write whole checkpoints (exit status 130).
    Run the same command again to go on: finished cells are skipped, cut-off ones resume. A
    cell that another run is training (a second grid over the same cells) is left to it, with
    a line saying so (exit status 75 if nothing failed or stopped).

    \b
    Examples:
      python -m training grid recipes/comparison/*.toml --seeds 1-3 --out runs/comparison \\
          --processes 16 --ship exported/comparison
      python -m training grid recipes/comparison/*.toml --seeds 1-3 --out /shared/comparison \\
          --backend ray --address auto --ship exported/comparison
      python -m training grid recipes/comparison/iqn.toml --seeds 4 --out runs/comparison
      python -m training grid recipes/terl-authors.toml --seeds 1-3 --seeds-per-process 3 --out runs/authors
    """
    from training.lab.grid import LocalProcesses, plan_grid, run_grid, stack_cells
    from training.lab.ship import ship_grid

    if address is not None and backend != "ray":
        raise ConfigError("--address names a Ray cluster; pass --backend ray with it")
    cells = stack_cells(plan_grid(recipes, seeds, out, device=device), seeds_per_process)
    if backend == "ray":
        try:
            from training.lab.grid_ray import RayCells
        except ModuleNotFoundError as error:
            if error.name != "ray" and not str(error.name).startswith("ray."):
                raise
            raise ConfigError(f"--backend ray needs Ray, which is not installed; install it with: {RAY_INSTALL_HINT}") from None
        runner = RayCells(address, cpus=processes)
        at_once = processes or len(cells)
    else:
        runner, at_once = LocalProcesses(), processes or 1
    note = lambda line: click.echo(line, err=True)  # noqa: E731
    note(f"grid of {len(recipes)} recipes x {len(seeds)} seeds in {out}: {len(cells)} "
         f"{'cells' if seeds_per_process == 1 else f'processes of up to {seeds_per_process} seeds'}, {at_once} at once "
         f"({backend})")
    outcome = run_grid(cells, runner, at_once, note, stop_after_s=None if stop_after is None else 60 * stop_after)
    note(f"{len(outcome.finished) + len(outcome.done)} cells finished, {len(outcome.failed)} failed, "
         f"{len(outcome.stopped)} stopped or not started"
         + (f", {len(outcome.elsewhere)} running in another process" if outcome.elsewhere else ""))
    if ship is not None:
        written = ship_grid(plan_grid(recipes, seeds, out, found_seeds=True), ship, machine)
        note(f"shipped {sum(path.suffix == '.onnx' for path in written)} policies and "
             f"{sum(path.suffix == '.md' for path in written)} cards into {ship}")
    return outcome.exit_status
