"""`python -m training plot` and `snapshots`: what a run's metrics.jsonl says."""

from __future__ import annotations

import json
from pathlib import Path

import click

from training.cli.options import output_option, run_folder


@click.command("plot")
@click.argument("run", type=click.Path(path_type=Path), metavar="RUN_DIR")
@output_option("FILE.png")
@click.option("--title", default="", help="Figure title.")
def plot_command(run: Path, output: Path, title: str) -> None:
    """Plot a run's training curves (success rate, return, collision ratio) as a PNG."""
    from training.curves import plot_curves
    from training.train import METRICS_FILE

    path = plot_curves(run / METRICS_FILE, output, title=title)
    click.echo(f"{path}: training curves of {run}")


@click.command("snapshots")
@run_folder()
@click.option("--json", "as_json", is_flag=True, help="Print the snapshot records as a JSON list instead.")
def snapshots_command(run: Path, as_json: bool) -> None:
    """Print every snapshot evaluation of a run so far (it may still be training): step, score,
    and success / travel time / collision ratio on the current stage and the snapshot preset."""
    from training.card import snapshot_table
    from training.curves import read_metrics
    from training.train import METRICS_FILE

    if not (run / METRICS_FILE).is_file():
        raise click.ClickException(f"{run}: no {METRICS_FILE} (not a training run folder)")
    snapshots = [r for r in read_metrics(run / METRICS_FILE) if r.get("kind") == "snapshot"]
    if as_json:
        click.echo(json.dumps(snapshots))
        return
    if not snapshots:
        click.echo(f"{run}: no snapshot yet")
        return
    preset = snapshots[-1]["evaluations"][-1]["scenario"]
    click.echo("\n".join(snapshot_table(snapshots, preset)))
