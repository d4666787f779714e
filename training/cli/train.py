"""`python -m training train`: one training run, a resume or a fine-tune."""

from __future__ import annotations

from pathlib import Path

import click

from training.cli.options import apply_overrides, config_options, resolve_config, set_threads
from training.config import NETWORK_FIELDS, ConfigError, changed_fields


@click.command("train")
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
    A shipped policy is made by its recipe instead: `python -m training run`.
    """
    from training.checkpoint import STATE_FILE, read_config
    from training.train import train

    if resume is not None:
        saved = read_config(resume)
        if options["config_file"] is not None:  # a fine-tune: the checkpoint's weights under a new config
            config = resolve_config(options)
            changed = changed_fields(saved, config, NETWORK_FIELDS)
            if changed:
                raise ConfigError(
                    f"{options['config_file']} describes another network than {resume} ("
                    + ", ".join(f"{name} {config.value(name)} against {saved.value(name)}" for name in changed)
                    + f"): a checkpoint continues only with the same {', '.join(NETWORK_FIELDS)}"
                )
        else:
            config = apply_overrides(saved, options)
        if options["model"] is not None and options["model"] != config.network.model:
            raise ConfigError(f"--model {options['model']} disagrees with the checkpoint (model '{config.network.model}')")
        out = out if out is not None else resume
    else:
        config = resolve_config(options)
        if out is None:
            raise ConfigError("give --out DIR (or --resume DIR)")
        if (out / STATE_FILE).exists():
            raise ConfigError(f"{out} holds a checkpoint; pass --resume {out} or pick another --out")
    set_threads(config.run.threads)
    counters = train(config, out, resume=resume, show_progress=not quiet)
    click.echo(
        f"{config.network.model}: {counters.env_step:,} environment steps, {counters.updates:,} updates, "
        f"{counters.episodes:,} episodes, {counters.wall_seconds:.0f} s; checkpoint and metrics.jsonl in {out}"
    )
