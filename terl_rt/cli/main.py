"""The `terl-rt` command group: logging, error handling, subcommands."""

from __future__ import annotations

import logging
import signal

import click

import terl_rt
from terl_rt.cli.bench import bench
from terl_rt.cli.eval import eval_command
from terl_rt.cli.info import info
from terl_rt.cli.layout import layout_command
from terl_rt.cli.optimize import optimize_command
from terl_rt.cli.render import render_command
from terl_rt.cli.replay import replay
from terl_rt.cli.report import report_command
from terl_rt.cli.scenarios import scenarios
from terl_rt.cli.sweep import sweep_command
from terl_rt.evaluation.runs import BackendError, Stopped
from terl_rt.logs.format import EpisodeLogError
from terl_rt.logs.render import RenderError
from terl_rt.policy.contract import ContractError
from terl_rt.sim.scenario import ScenarioError

USER_ERRORS = (
    ScenarioError, ContractError, EpisodeLogError, RenderError, OSError, MemoryError, BackendError,
)
"""Exceptions that mean bad input or a machine that cannot do what was asked (a missing,
unreadable or unwritable file, a full disk, too little memory, a Ray cluster that cannot
be reached): one line on stderr and exit status 2 (traceback with --debug)."""


class TerlGroup(click.Group):
    """A click group that turns expected user mistakes (`user_errors`) into a one-line error, exit 2."""

    user_errors: tuple[type[BaseException], ...] = USER_ERRORS
    """What counts as a user mistake; a group of another package extends it."""

    def invoke(self, ctx: click.Context):
        try:
            return super().invoke(ctx)
        except click.UsageError as err:
            # A bad option value or an unknown option: one line naming the command's help.
            if ctx.obj and ctx.obj.get("debug"):
                raise
            where = f" (see {err.ctx.command_path} -h)" if err.ctx is not None else ""
            click.echo(f"Error: {one_line(click.ClickException(err.format_message()))}{where}", err=True)
            ctx.exit(2)
        except KeyboardInterrupt as err:
            # Ctrl-C, or SIGTERM or SIGHUP during a run with workers (Stopped): what was run
            # is written; the status a process ended by that signal would have.
            if ctx.obj and ctx.obj.get("debug"):
                raise
            click.echo(f"Error: {one_line(err) if isinstance(err, Stopped) else 'stopped by SIGINT'}", err=True)
            ctx.exit(128 + getattr(err, "signum", signal.SIGINT))
        except self.user_errors as err:
            if ctx.obj and ctx.obj.get("debug"):
                raise
            click.echo(f"Error: {one_line(err)}", err=True)
            ctx.exit(2)


MAX_ERROR_CHARS = 600
"""An error line longer than this is cut (a message never echoes a huge value)."""


def one_line(err: BaseException) -> str:
    """The message of `err` on one line, at most MAX_ERROR_CHARS long."""
    if isinstance(err, MemoryError):
        text = f"not enough memory for this run ({str(err) or 'MemoryError'})"
    elif isinstance(err, OSError) and err.strerror and not isinstance(err, (FileNotFoundError, IsADirectoryError)):
        where = f"{err.filename}: " if err.filename else ""
        text = f"{where}{err.strerror}" if where else f"{err.strerror} ({type(err).__name__}, errno {err.errno})"
    else:
        text = str(err) or type(err).__name__
    text = " ".join(text.split())
    return text if len(text) <= MAX_ERROR_CHARS else text[: MAX_ERROR_CHARS - 3] + "..."


@click.group(cls=TerlGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.option("--debug", is_flag=True, help="Show full tracebacks and debug logging.")
@click.option("-v", "--verbose", count=True, help="More log output (-v info, -vv debug).")
@click.version_option(terl_rt.__version__, prog_name="terl-rt")
@click.pass_context
def cli(ctx: click.Context, debug: bool, verbose: int) -> None:
    """terl-rt: simulate, evaluate and inspect TERL multi-target encirclement policies.

    The world is the TERL paper's: pursuer robots encircle faster evaders in a 2-D sea
    with obstacles and vortex currents. Every subcommand has its own --help.

    \b
    Examples:
      terl-rt eval                       # the shipped TERL policy on small-15
      terl-rt eval --episodes 5 --log run.mcap && terl-rt render run.mcap -o final.png
      terl-rt scenarios                  # the presets
      python -m terl_rt --version        # where the terl-rt script is not on PATH
    """
    level = logging.DEBUG if debug or verbose > 1 else logging.INFO if verbose else logging.WARNING
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s")
    ctx.ensure_object(dict)["debug"] = debug


cli.add_command(bench)
cli.add_command(eval_command)
cli.add_command(info)
cli.add_command(layout_command)
cli.add_command(optimize_command)
cli.add_command(render_command)
cli.add_command(replay)
cli.add_command(report_command)
cli.add_command(scenarios)
cli.add_command(sweep_command)
