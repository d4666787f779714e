"""The `python -m training` command group: error handling and the subcommands, one module each
(as terl_rt/cli): the same one-line `Error:` for a user's mistake, exit status 2."""

from __future__ import annotations

import click

from terl_rt.command_line import TerlGroup
from training.cli.bench import bench_command
from training.cli.card import card_command
from training.cli.curves import curve_command, plot_command, snapshots_command
from training.cli.export import export_command
from training.cli.grid import grid_command
from training.cli.run import run_command
from training.cli.train import train_command
from training.cli.values import values_command
from training.config import ConfigError
from training.lab.card import CardError
from training.lab.curves import CurvesError
from training.run_lock import RUN_HELD, RunFolderHeld
from training.stops import TrainingStopped


class TrainingGroup(TerlGroup):
    """terl-rt's group, with training's own user mistakes (a bad config or recipe, a card or
    curves file it cannot read) as one-line errors too."""

    user_errors = TerlGroup.user_errors + (ConfigError, CurvesError, CardError)


@click.group(cls=TrainingGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.option("--debug", is_flag=True, help="Show full tracebacks of user errors.")
@click.pass_context
def cli(ctx: click.Context, debug: bool) -> None:
    """Train pursuer Q-networks (TERL, its baselines and ablations), make the shipped policies
    from their recipes (recipes/*.toml), export them as ONNX policies, write their cards, plot
    and time runs. Every subcommand has its own --help."""
    ctx.ensure_object(dict)["debug"] = debug


for command in (run_command, grid_command, train_command, export_command, card_command, snapshots_command, curve_command,
                plot_command, values_command, bench_command):
    cli.add_command(command)


def main(argv: list[str] | None = None) -> int:
    """Run the command line on `argv` (default: sys.argv[1:]); returns the exit status."""
    try:
        status = cli.main(args=argv, prog_name="python -m training", standalone_mode=False)
    except click.ClickException as error:
        error.show()
        return error.exit_code
    except click.exceptions.Abort:
        click.echo("Aborted!", err=True)
        return 1
    except TrainingStopped as stop:  # Ctrl-C or SIGTERM: the checkpoint is written, the run can go on
        click.echo(f"Stopped: {stop}", err=True)
        return 130
    except RunFolderHeld as held:  # another run trains in this folder: nothing was written
        click.echo(f"Error: {held}", err=True)
        return RUN_HELD
    return status if isinstance(status, int) else 0
