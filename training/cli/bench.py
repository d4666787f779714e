"""`python -m training bench`: how fast the loop's two halves run here, for one seed and for seeds trained together."""

from __future__ import annotations

import json

import click

from training.cli.options import config_options, resolve_config, seed_list, set_threads


@click.command("bench")
@config_options
@click.option("--hidden", type=int, metavar="H", help="Override the hidden width.")
@click.option("--layers", type=int, metavar="L", help="Override the transformer layers.")
@click.option("--heads", type=int, metavar="h", help="Override the attention heads.")
@click.option("--stacks", "stacks", default="1-4", show_default=True, callback=seed_list, metavar="S,S,...",
              help="Seeds trained together to time, as counts: 1-4 times 1, 2, 3 and 4 seeds a process.")
@click.option("--seconds", type=float, default=5.0, show_default=True, help="Seconds per measurement.")
@click.option("--json", "as_json", is_flag=True, help="Print the figures as one JSON object instead.")
def bench_command(seconds: float, stacks: list[int], as_json: bool, **options) -> None:
    """Time rollouts (per curriculum stage) and updates: the one-seed update of main 7725bd1
    beside S seeds trained together in one process, for each S of --stacks, on the same batches;
    with each update's aten calls, GFLOP and share of this machine's matrix-product rate
    (measured first). Times are CPU seconds of this process, so load elsewhere does not count.
    Without --model or --config: TERL with the shipped settings.

    \b
    Example:
      python -m training bench --stacks 1-4 --seconds 5 --json > bench.json
    """
    from training.lab.throughput import benchmark

    config = resolve_config(options, default_model="terl")
    set_threads(config.run.threads)
    result = benchmark(config, seeds=stacks, seconds=seconds)
    if as_json:
        click.echo(json.dumps(result.to_dict(), indent=2))
        return
    click.echo(
        f"{result.model} H={result.hidden} L={result.layers} h={result.heads}, {result.num_envs} environments, "
        f"{result.threads} torch threads, dropout {config.network.dropout}, {result.device}; CPU {result.cpu_capability}, "
        f"float32 matrix products {result.matmul_gflops:.1f} GFLOP/s"
    )
    click.echo("rollout (collect + store, no learning), environment steps per CPU second:")
    for name, rate in result.rollout_steps_per_second.items():
        click.echo(f"  {name:<14} {rate:10.1f}")
    base = result.updates[0]
    click.echo(f"updates at batch {config.learner.batch_size} over the run's mix of stages (sample, forward, backward, Adam):")
    click.echo(f"  {'':<20}{'updates/s a seed':>17}{'seed-updates/s':>16}{'vs one seed':>13}{'aten calls':>12}"
               f"{'GFLOP':>8}{'matmul share':>14}{'h a seed':>10}")
    for speed in result.updates:
        click.echo(
            f"  {speed.name:<20}{speed.updates_per_second:17.2f}{speed.seed_updates_per_second:16.2f}"
            f"{speed.seed_updates_per_second / base.seed_updates_per_second:12.2f}x{speed.aten_calls:12,.0f}"
            f"{speed.gflop:8.2f}{speed.matmul_share:13.0%}{result.estimated_hours[speed.name]:10.1f}"
        )
    click.echo(f"(h a seed: CPU hours of {config.schedule.total_steps:,} environment steps, rollouts and updates, "
               "for one seed of the variant)")
