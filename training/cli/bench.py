"""`python -m training bench`: how fast the loop's two halves run here."""

from __future__ import annotations

import click

from training.cli.options import config_options, resolve_config, set_threads


@click.command("bench")
@config_options
@click.option("--hidden", type=int, metavar="H", help="Override the hidden width.")
@click.option("--layers", type=int, metavar="L", help="Override the transformer layers.")
@click.option("--heads", type=int, metavar="h", help="Override the attention heads.")
@click.option("--seconds", type=float, default=5.0, show_default=True, help="Seconds per measurement.")
def bench_command(seconds: float, **options) -> None:
    """Time rollouts (per curriculum stage) and updates; estimate a run's wall clock.
    Without --model or --config: TERL with the shipped settings."""
    from training.throughput import UPDATE_MODES, benchmark

    config = resolve_config(options, default_model="terl")
    set_threads(config.run.threads)
    result = benchmark(config, seconds=seconds)
    click.echo(
        f"{result.model} H={result.hidden} L={result.layers} h={result.heads}, "
        f"{result.num_envs} environments, {result.threads} torch threads, dropout {config.network.dropout}"
    )
    click.echo("rollout (collect + store, no learning), environment steps/s:")
    for name, rate in result.rollout_steps_per_second.items():
        click.echo(f"  {name:<14} {rate:10.1f}")
    click.echo(
        f"updates/s at batch {config.learner.batch_size} (sample, forward, backward, Adam step), by the rows' scenario:"
    )
    click.echo(f"  {'':<14}" + "".join(f"{mode:>14}" for mode in UPDATE_MODES))
    for name, rates in result.update_modes.items():
        click.echo(f"  {name:<14}" + "".join(f"{rates[mode]:14.2f}" for mode in UPDATE_MODES))
    mix = result.mix_updates_per_second
    click.echo(f"  {'mix of stages':<14}" + "".join(f"{mix[mode]:14.2f}" for mode in UPDATE_MODES))
    base = mix[UPDATE_MODES[0]]
    click.echo(
        "  against fp32 full (untrimmed rows; the transformer skips padded tokens either way) over the mix: "
        + ", ".join(f"{mode} {mix[mode] / base:.2f}x" for mode in UPDATE_MODES[1:])
        + f"; the run uses {'bf16' if config.learner.bf16 else 'fp32'} trimmed ({result.updates_per_second:.2f} updates/s)"
    )
    hours = result.estimated_hours
    steps = config.schedule.total_steps
    click.echo(
        f"estimated wall clock of {steps:,} environment steps "
        f"({steps // config.learner.train_frequency:,} updates): {hours:.1f} h ({hours / 24:.1f} days)"
    )
