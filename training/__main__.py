"""Command line of the training package: `python -m training {train,export,plot,card,bench}` (click,
like `terl-rt`).

A thin layer: each subcommand resolves its options into a `Config` (or paths), sets
torch's threads, calls one library function and prints the result. Expected user
mistakes (bad config, missing file) print one `error:` line and exit with status 2.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import click
import torch

from training.card import CardError
from training.checkpoint import (
    STATE_FILE, average_snapshots, export_checkpoint, read_config, read_counters, shift_values,
)
from training.config import NETWORK_FIELDS, Config, ConfigError, changed_fields, packaged_configs
from training.curves import CurvesError
from training.export import read_metadata

USER_ERRORS = (ConfigError, CurvesError, CardError, FileNotFoundError, IsADirectoryError)
"""Exceptions that mean bad input rather than a bug."""

OVERRIDES = ("total_steps", "curriculum_steps", "learning_rate", "learning_starts", "num_envs", "threads", "seed",
             "device", "hidden", "layers", "heads")
"""Config fields a command-line option may replace."""


def config_options(command):
    """Options shared by train and bench: where the config comes from and what to override."""
    options = [
        click.option("--model", type=click.Choice(packaged_configs()),
                     help="Model to train; loads training/configs/MODEL.json unless --config is given."),
        click.option("--config", "config_file", type=click.Path(path_type=Path), metavar="FILE",
                     help="JSON config file (unknown keys are errors; missing keys take the defaults)."),
        click.option("--total-steps", type=int, metavar="K", help="Environment steps in all (config default: 7,000,000)."),
        click.option("--curriculum-steps", type=int, metavar="K",
                     help="Environment steps the curriculum is split over (default: --total-steps); to extend a "
                          "finished run, resume with a larger --total-steps and this set to its old length: the "
                          "extra steps stay in the last stage."),
        click.option("--learning-rate", type=float, metavar="LR",
                     help="Adam learning rate; with --resume it replaces the checkpoint's."),
        click.option("--learning-starts", type=int, metavar="K",
                     help="Environment steps before the first update (config default 3000); with --resume and no "
                          "saved replay buffer, the fewest steps that refill it first (it refills to the "
                          "transitions it held)."),
        click.option("--num-envs", type=int, metavar="B", help="Environments stepped together (default 8)."),
        click.option("--threads", type=int, metavar="T", help="torch intra-op threads (default 2)."),
        click.option("--seed", type=int, metavar="S",
                     help="Random seed (default 1); a resume continues the checkpoint's CPU generators instead, unless the config sets resume_reseeds (the CUDA one of --device cuda takes S anew)."),
        click.option("--device", metavar="DEV",
                     help="torch device of the networks and updates: cpu (default) or cuda; rollouts stay on the CPU."),
    ]
    for option in reversed(options):
        command = option(command)
    return command


def apply_overrides(config: Config, options: dict) -> Config:
    """Replace the fields given on the command line."""
    return config.replace(**{name: options[name] for name in OVERRIDES if options.get(name) is not None})


def resolve_config(options: dict) -> Config:
    """The config of a new run: --config, else the packaged one of --model, then overrides."""
    config_file, model = options.get("config_file"), options.get("model")
    if config_file is not None:
        config = Config.from_file(config_file)
        if model is not None and model != config.model:
            raise ConfigError(f"--model {model} disagrees with {config_file} (model '{config.model}')")
    elif model is not None:
        config = Config.for_model(model)
    else:
        raise ConfigError("give --model NAME or --config FILE")
    return apply_overrides(config, options)


def set_threads(count: int) -> None:
    """torch's intra-op threads (the training functions leave them to the caller)."""
    torch.set_num_threads(count)


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
def cli() -> None:
    """Train pursuer Q-networks (TERL, its baselines and ablations), export them as ONNX
    policies, plot and time runs."""


@cli.command("train")
@config_options
@click.option("--out", type=click.Path(path_type=Path), metavar="DIR",
              help="Output folder: metrics.jsonl, the checkpoint, replay.npz, best/ (default: the --resume folder).")
@click.option("--resume", type=click.Path(path_type=Path), metavar="DIR",
              help="Continue the checkpoint in DIR with its config (and its replay buffer when saved there); "
                   "with --config, fine-tune it under that config instead (same network; e.g. another "
                   "scenario, reward or learning rate).")
@click.option("--quiet", is_flag=True, help="No progress line on stderr.")
def train_command(out: Path | None, resume: Path | None, quiet: bool, **options) -> None:
    """Train a pursuer Q-network (IQN/DQN) on the curriculum.

    \b
    New run:   --model NAME | --config FILE, and --out DIR
    Continue:  --resume DIR (its config; the overrides below replace fields)
    Fine-tune: --resume DIR --config FILE --out NEW_DIR (the checkpoint's weights, optimizer
               and counters under FILE's settings, e.g. a larger team as the scenario)
    """
    from training.train import train

    if resume is not None:
        saved = read_config(resume)
        if options["config_file"] is not None:  # a fine-tune: the checkpoint's weights under a new config
            config = resolve_config(options)
            changed = changed_fields(saved, config, NETWORK_FIELDS)
            if changed:
                raise ConfigError(
                    f"{options['config_file']} describes another network than {resume} ("
                    + ", ".join(f"{name} {getattr(config, name)} against {getattr(saved, name)}" for name in changed)
                    + f"): a checkpoint continues only with the same {', '.join(NETWORK_FIELDS)}"
                )
        else:
            config = apply_overrides(saved, options)
        if options["model"] is not None and options["model"] != config.model:
            raise ConfigError(f"--model {options['model']} disagrees with the checkpoint (model '{config.model}')")
        out = out if out is not None else resume
    else:
        config = resolve_config(options)
        if out is None:
            raise ConfigError("give --out DIR (or --resume DIR)")
        if (out / STATE_FILE).exists():
            raise ConfigError(f"{out} holds a checkpoint; pass --resume {out} or pick another --out")
    set_threads(config.threads)
    counters = train(config, out, resume=resume, show_progress=not quiet)
    click.echo(
        f"{config.model}: {counters.env_step:,} environment steps, {counters.updates:,} updates, "
        f"{counters.episodes:,} episodes, {counters.wall_seconds:.0f} s; checkpoint and metrics.jsonl in {out}"
    )


@cli.command("export")
@click.argument("checkpoint", type=click.Path(path_type=Path), metavar="CHECKPOINT_DIR_OR_FILE")
@click.option("-o", "--output", type=click.Path(path_type=Path), required=True, metavar="FILE.onnx")
def export_command(checkpoint: Path, output: Path) -> None:
    """Export a checkpoint (a run folder, its best/ snapshot, or one of their files) as a
    contract-v1 ONNX policy, parity-checked against torch."""
    path = export_checkpoint(checkpoint, output)
    metadata = read_metadata(path)
    click.echo(
        f"{path}: {metadata['terl.model']} H={metadata['terl.hidden']} L={metadata['terl.layers']} "
        f"h={metadata['terl.heads']}, {metadata['terl.training_steps']} training steps on "
        f"{metadata['terl.trained_on']}; torch-onnxruntime parity checked"
    )


@cli.command("average")
@click.argument("snapshots", nargs=-1, required=True, type=click.Path(path_type=Path), metavar="SNAPSHOT_DIR...")
@click.option("-o", "--output", type=click.Path(path_type=Path), required=True, metavar="DIR",
              help="Folder for the averaged snapshot (export it with `python -m training export DIR`).")
def average_command(snapshots: tuple[Path, ...], output: Path) -> None:
    """Average the weights of several snapshots of one network (e.g. a run's kept snapshots,
    runs/x/snapshots/{425,430,435}000) into one snapshot: stochastic weight averaging, which
    smooths the step-to-step noise of a fine-tune. It takes the config and counters of the
    snapshot trained longest; exported, its metadata lists the snapshots averaged."""
    try:
        folder = average_snapshots(list(snapshots), output)
    except (ValueError, FileNotFoundError) as error:
        raise click.ClickException(str(error)) from error
    steps = ", ".join(str(read_counters(source).env_step) for source in snapshots)
    click.echo(f"{folder}: the mean of {len(snapshots)} snapshots (environment steps {steps})")


@cli.command("shift")
@click.argument("checkpoint", type=click.Path(path_type=Path), metavar="CHECKPOINT_DIR")
@click.option("--by", "offset", type=float, required=True, metavar="RETURN",
              help="Added to every Q-value (return units; e.g. -300).")
@click.option("-o", "--output", type=click.Path(path_type=Path), required=True, metavar="DIR",
              help="Folder for the shifted checkpoint (resume from it with --resume DIR --config ...).")
def shift_command(checkpoint: Path, offset: float, output: Path) -> None:
    """Copy a checkpoint with every Q-value of its online and target networks moved by RETURN
    (the output layer's bias): the greedy policy is unchanged, and a fine-tune whose returns lie
    far from the network's values (see `values`) starts near them instead of closing the gap one
    Bellman backup per target copy. The replay buffer is not copied."""
    if output.exists() and any(output.iterdir()):
        raise click.ClickException(f"{output}: not empty; choose a new folder for the shifted checkpoint")
    try:
        folder = shift_values(checkpoint, output, offset)
    except (ValueError, FileNotFoundError) as error:
        raise click.ClickException(str(error)) from error
    click.echo(f"{folder}: {checkpoint} with every Q-value moved by {offset:+g}")


@cli.command("values")
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
    exploring ones, --epsilon), every
    pursuer-step's Q(s, a) against the discounted return of the rewards the network was taught
    (its config's shaping and collision value). Q far above the returns, or uncorrelated with
    them, is a value function that has not caught up with its reward. Values track the returns
    when the correlation is at least 0.5 and the mean |Q - return| under a tenth of the returns'
    range (training.values.ValueCheck.tracks_returns); both are in the taught units (the config's
    reward_scale), so the verdict does not depend on the scale."""
    from dataclasses import asdict

    from terl_rt.sim.scenario import Scenario, ScenarioError
    from training.checkpoint import load_network
    from training.values import value_check

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
        check = value_check(model, config, scenario.replace(max_steps=config.eval_max_steps), episodes, seed, epsilon)
        if as_json:
            click.echo(json.dumps({"checkpoint": str(source), **asdict(check), "tracks_returns": check.tracks_returns}))
        else:
            correlation = "-" if check.correlation is None else f"{check.correlation:.2f}"
            click.echo(
                f"| {source} | {check.pursuer_steps:,} | {check.q_mean:.2f} | {check.return_mean:.2f} | "
                f"{check.gap_mean:.2f} | {check.gap_median:.2f} | {check.abs_gap_mean:.2f} | "
                f"{check.return_range:.2f} | {correlation} | {'yes' if check.tracks_returns else 'no'} |"
            )


@cli.command("plot")
@click.argument("run", type=click.Path(path_type=Path), metavar="RUN_DIR")
@click.option("-o", "--output", type=click.Path(path_type=Path), required=True, metavar="FILE.png")
@click.option("--title", default="", help="Figure title.")
def plot_command(run: Path, output: Path, title: str) -> None:
    """Plot a run's training curves (success rate, return, collision ratio) as a PNG."""
    from training.curves import plot_curves
    from training.train import METRICS_FILE

    path = plot_curves(run / METRICS_FILE, output, title=title)
    click.echo(f"{path}: training curves of {run}")


@cli.command("snapshots")
@click.argument("run", type=click.Path(path_type=Path, exists=True, file_okay=False), metavar="RUN_DIR")
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


@cli.command("card")
@click.argument("run", type=click.Path(path_type=Path), metavar="RUN_DIR")
@click.option("--onnx", required=True, metavar="FILE.onnx", help="The shipped policy the card is for, as it names it.")
@click.option("--config", "config_file", required=True, metavar="FILE", help="The config the run was started from.")
@click.option("--machine", default="one core of the 2-core CPU machine (one torch thread)", show_default=True,
              help="Where the run trained, in words.")
@click.option("--comparison", type=click.Path(path_type=Path), metavar="FILE.json",
              help="A comparison.json of `terl-rt report` (several policies) holding this model: its "
                   "per-group evaluation goes into the card.")
@click.option("-o", "--output", type=click.Path(path_type=Path), required=True, metavar="CARD.md")
def card_command(run: Path, onnx: str, config_file: str, machine: str, comparison: Path | None, output: Path) -> None:
    """Write the model card of the policy exported from RUN_DIR's best snapshot: body,
    size, training cost, every snapshot evaluation and (with --comparison) its evaluation
    on the paper's presets."""
    from training.card import model_card

    output.write_text(model_card(run, onnx, config_file, machine, comparison))
    click.echo(f"{output}: model card of {onnx}")


@cli.command("bench")
@config_options
@click.option("--hidden", type=int, metavar="H", help="Override the hidden width.")
@click.option("--layers", type=int, metavar="L", help="Override the transformer layers.")
@click.option("--heads", type=int, metavar="h", help="Override the attention heads.")
@click.option("--seconds", type=float, default=5.0, show_default=True, help="Seconds per measurement.")
def bench_command(seconds: float, **options) -> None:
    """Time rollouts (per curriculum stage) and updates; estimate a run's wall clock.
    Without --model or --config: TERL's packaged config."""
    from training.train import UPDATE_MODES, benchmark

    if options["config_file"] is None and options["model"] is None:
        options["model"] = "terl"
    config = resolve_config(options)
    set_threads(config.threads)
    result = benchmark(config, seconds=seconds)
    click.echo(
        f"{result.model} H={result.hidden} L={result.layers} h={result.heads}, "
        f"{result.num_envs} environments, {result.threads} torch threads, dropout {config.dropout}"
    )
    click.echo("rollout (collect + store, no learning), environment steps/s:")
    for name, rate in result.rollout_steps_per_second.items():
        click.echo(f"  {name:<14} {rate:10.1f}")
    click.echo(f"updates/s at batch {config.batch_size} (sample, forward, backward, Adam step), by the rows' scenario:")
    click.echo(f"  {'':<14}" + "".join(f"{mode:>14}" for mode in UPDATE_MODES))
    for name, rates in result.update_modes.items():
        click.echo(f"  {name:<14}" + "".join(f"{rates[mode]:14.2f}" for mode in UPDATE_MODES))
    mix = result.mix_updates_per_second
    click.echo(f"  {'mix of stages':<14}" + "".join(f"{mix[mode]:14.2f}" for mode in UPDATE_MODES))
    base = mix[UPDATE_MODES[0]]
    click.echo(
        "  against fp32 full over the mix: "
        + ", ".join(f"{mode} {mix[mode] / base:.2f}x" for mode in UPDATE_MODES[1:])
        + f"; the run uses {'bf16' if config.bf16 else 'fp32'} trimmed ({result.updates_per_second:.2f} updates/s)"
    )
    hours = result.estimated_hours
    click.echo(
        f"estimated wall clock of {config.total_steps:,} environment steps "
        f"({config.total_steps // config.train_frequency:,} updates): {hours:.1f} h ({hours / 24:.1f} days)"
    )


def main(argv: list[str] | None = None) -> int:
    """Run the command line on `argv` (default: sys.argv[1:]); returns the exit status."""
    try:
        cli.main(args=argv, prog_name="python -m training", standalone_mode=False)
    except click.ClickException as error:
        error.show()
        return error.exit_code
    except click.exceptions.Abort:
        click.echo("aborted", err=True)
        return 1
    except USER_ERRORS as error:
        click.echo(f"error: {' '.join(str(error).split())}", err=True)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
