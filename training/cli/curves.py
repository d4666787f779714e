"""`python -m training plot` and `snapshots`: what a run's metrics.jsonl says."""

from __future__ import annotations

import json
from pathlib import Path

import click

from training.cli.options import output_option, run_folder, set_threads


@click.command("plot")
@click.argument("run", type=click.Path(path_type=Path), metavar="RUN_DIR")
@output_option("FILE.png")
@click.option("--title", default="", help="Figure title.")
def plot_command(run: Path, output: Path, title: str) -> None:
    """Plot a run's training curves (success rate, return, collision ratio) as a PNG."""
    from training.lab.curves import plot_curves
    from training.seed_state import METRICS_FILE

    path = plot_curves(run / METRICS_FILE, output, title=title)
    click.echo(f"{path}: training curves of {run}")


@click.command("snapshots")
@run_folder()
@click.option("--json", "as_json", is_flag=True, help="Print the snapshot records as a JSON list instead.")
def snapshots_command(run: Path, as_json: bool) -> None:
    """Print every snapshot evaluation of a run so far (it may still be training): step, score,
    and success / travel time / collision ratio on the current stage and the snapshot preset."""
    from training.lab.card import snapshot_table
    from training.lab.curves import read_metrics
    from training.seed_state import METRICS_FILE

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


@click.command("curve")
@click.argument("runs", nargs=-1, required=True, type=click.Path(path_type=Path, exists=True, file_okay=False),
                metavar="RUN_DIR...")
@click.option("--scenario", "presets", multiple=True, default=("small-15", "large-80", "cc-28"), show_default=True,
              metavar="PRESET", help="Preset to evaluate every kept snapshot on (repeat for more).")
@click.option("--episodes", type=click.IntRange(min=1), default=10, show_default=True)
@click.option("--seed", type=int, default=6000, show_default=True, help="Seed of the first episode (episode k: seed + k).")
@click.option("--max-steps", type=click.IntRange(min=1), default=1000, show_default=True,
              help="Steps before an episode is cut off (a failure).")
@click.option("--threads", type=click.IntRange(min=1), default=1, show_default=True, help="torch intra-op threads.")
@output_option("FILE.png", "Also plot the curves into this PNG.", required=False)
@click.option("--title", default="", help="Figure title.")
@click.option("--pick", default=None, metavar="PRESET",
              help="Also pick each run's snapshot by PRESET alone (evaluated too if no --scenario names it): the "
                   "most successes there, then the lowest collision ratio, then the latest step; its folder is "
                   "what `python -m training export` takes. A rule beside the last model that sees no larger team.")
@click.option("--json", "as_json", is_flag=True,
              help="Print every point as one JSON list instead of a table (with --pick, each point's \"picked\").")
def curve_command(runs: tuple[Path, ...], presets: tuple[str, ...], episodes: int, seed: int, max_steps: int,
                  threads: int, output: Path | None, title: str, pick: str | None, as_json: bool) -> None:
    """Learning curves of runs' kept snapshots (RUN_DIR/snapshots/<step>/, `keep_snapshots`):
    each network evaluated greedy on every --scenario, as the run's snapshots are (in-process,
    episode k with seed --seed + k). Each evaluation is stored beside its network
    (snapshots/<step>/evaluations.json) and the run's own snapshot evaluations (metrics.jsonl)
    are read back, so a second call evaluates only new snapshots or presets. Prints a table
    (success with its exact 95 % interval, collision ratio; --json for scripts); -o plots a
    column a preset, a colour a run, the curriculum's stage starts dashed.

    \b
    Examples (the authors' protocol, issue 53):
      python -m training curve runs/authors/terl-authors/seed-{1,2,3}/1-curriculum -o curves.png
      # each seed's snapshot by small-15 alone, exported under a method name of its own:
      python -m training curve runs/authors/terl-authors/seed-1/1-curriculum --pick small-15
      python -m training export runs/authors/terl-authors/seed-1/1-curriculum/snapshots/STEP \\
        --method terl-authors-small -o runs/three/terl-authors-small-seed-1.onnx
    """
    from terl_rt.sim.scenario import Scenario, ScenarioError
    from training.lab.curves import plot_snapshot_curves, stage_starts
    from training.lab.snapshot_curves import picked_snapshot, run_seed, snapshot_curve, with_interval
    from training.seed_state import METRICS_FILE, snapshot_folder

    if pick is not None and pick not in presets:
        presets = (*presets, pick)
    for preset in presets:
        try:
            Scenario.preset(preset)
        except ScenarioError as error:
            raise click.BadParameter(str(error), param_hint="--scenario") from error
    set_threads(threads)
    trained_seeds = [run_seed(run) for run in runs]
    labels = ([f"seed {trained}" for trained in trained_seeds] if len(set(trained_seeds)) == len(runs)
              else [str(run) for run in runs])
    curves = {
        label: [with_interval(point) for point in snapshot_curve(
            run, presets, episodes, seed, max_steps, announce=lambda text: click.echo(text, err=True))]
        for label, run in zip(labels, runs)
    }
    picks = {label: picked_snapshot(points, pick) for label, points in curves.items()} if pick is not None else {}
    if as_json:
        click.echo(json.dumps([{"run": label, **point, **({"picked": point is picks[label]} if picks else {})}
                               for label, points in curves.items() for point in points]))
    else:
        click.echo("| run | step | preset | success [95 % interval] | travel time | collision ratio |")
        click.echo("|---|---:|---|---|---:|---:|")
        for label, points in curves.items():
            for point in points:
                click.echo(
                    f"| {label} | {point['env_step']:,} | {point['scenario']} | {point['success_rate']:.2f} "
                    f"[{point['success_low']:.2f}, {point['success_high']:.2f}] | {point['travel_time_s_mean']:.1f} s | "
                    f"{point['collision_ratio_mean']:.3f} |"
                )
        for label, run in zip(labels, runs) if picks else ():
            step = picks[label]["env_step"]
            click.echo(f"picked by {pick}: {label} at {step:,} ({snapshot_folder(run, step)})")
    if output is not None:
        stages = stage_starts([run / METRICS_FILE for run in runs])
        click.echo(f"{plot_snapshot_curves(curves, output, title, stages)}: learning curves of {len(runs)} runs", err=True)
