"""Options shared by `python -m training` subcommands, defined once, and how they make a config."""

from __future__ import annotations

from pathlib import Path

import click

from training.config import MODELS, Config, ConfigError, DataConfig, RunConfig, ScheduleConfig

OVERRIDES = ("total_steps", "curriculum_steps", "learning_rate", "learning_starts", "num_envs", "threads", "seed",
             "device", "hidden", "layers", "heads")
"""Config fields a command-line option may replace."""


def config_options(command):
    """Options of train and bench: where the config comes from and what to override."""
    schedule, data, run = ScheduleConfig(), DataConfig(), RunConfig()  # the defaults, unchecked: no torch for --help
    options = [
        click.option("--model", type=click.Choice(sorted(MODELS)),
                     help="Network to train with the shipped settings (the comparison's recipe: only the body "
                          "changes); --config gives a file instead."),
        click.option("--config", "config_file", type=click.Path(path_type=Path), metavar="FILE",
                     help="JSON config file, by part or flat (unknown keys are errors; missing keys take the defaults)."),
        click.option("--total-steps", type=int, metavar="K",
                     help=f"Environment steps in all (default {schedule.total_steps:,})."),
        click.option("--curriculum-steps", type=int, metavar="K",
                     help="Environment steps the curriculum is split over (default: --total-steps); to extend a "
                          "finished run, resume with a larger --total-steps and this set to its old length: the "
                          "extra steps stay in the last stage."),
        click.option("--learning-rate", type=float, metavar="LR",
                     help="Adam learning rate; with --resume it replaces the checkpoint's."),
        click.option("--learning-starts", type=int, metavar="K",
                     help=f"Environment steps before the first update (default {data.learning_starts}); with "
                          "--resume and no saved replay buffer, the fewest steps that refill it first (it refills "
                          "to the transitions it held)."),
        click.option("--num-envs", type=int, metavar="B",
                     help=f"Environments stepped together (default {schedule.num_envs})."),
        click.option("--threads", type=int, metavar="T", help=f"torch intra-op threads (default {run.threads})."),
        click.option("--seed", type=int, metavar="S",
                     help=f"Random seed (default {run.seed}); a resume continues the checkpoint's CPU "
                          "generators instead (the CUDA one of --device cuda takes S anew)."),
        click.option("--device", metavar="DEV",
                     help="torch device of the networks and updates: cpu (default) or cuda; rollouts stay on the CPU."),
    ]
    for option in reversed(options):
        command = option(command)
    return command


def apply_overrides(config: Config, options: dict) -> Config:
    """Replace the fields given on the command line."""
    return config.replace(**{name: options[name] for name in OVERRIDES if options.get(name) is not None})


def resolve_config(options: dict, default_model: str | None = None) -> Config:
    """The config of a new run: --config, else the defaults with --model's body (or
    `default_model`'s), then the overrides."""
    config_file, model = options.get("config_file"), options.get("model") or default_model
    if config_file is not None:
        config = Config.from_file(config_file)
        if options.get("model") is not None and options["model"] != config.network.model:
            raise ConfigError(f"--model {options['model']} disagrees with {config_file} (model '{config.network.model}')")
    elif model is not None:
        config = Config.for_model(model)
    else:
        raise ConfigError("give --model NAME or --config FILE")
    return apply_overrides(config, options)


def set_threads(count: int) -> None:
    """torch's intra-op threads (the training functions leave them to the caller)."""
    import torch  # here, not above: a subcommand's --help does not import torch

    torch.set_num_threads(count)


def run_folder(name: str = "RUN_DIR"):
    """The argument naming a training run's folder (it must exist)."""
    return click.argument("run", type=click.Path(path_type=Path, exists=True, file_okay=False), metavar=name)


def output_option(metavar: str, help_text: str | None = None, required: bool = True):
    """-o/--output (required unless told)."""
    return click.option("-o", "--output", type=click.Path(path_type=Path), required=required, metavar=metavar,
                        help=help_text)


def seed_list(ctx: click.Context, param: click.Parameter, value: str) -> list[int]:
    """--seeds as whole numbers: "1,2,3" or a range "1-3" (or both: "1-3,7")."""
    seeds: list[int] = []
    for part in value.split(","):
        first, _, last = part.strip().partition("-")
        try:
            span = range(int(first), int(last or first) + 1)
        except ValueError:
            span = range(0)
        if not span:
            raise click.BadParameter(f"expected seeds as 1,2,3 or 1-3, got {value!r}")
        seeds.extend(span)
    return seeds
