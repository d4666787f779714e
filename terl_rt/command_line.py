"""What terl-rt's command line and `python -m training`'s share, defined once where both may
import it (training never imports terl_rt.cli): the click group that turns a user's mistake
into one `Error:` line, and the options both take."""

from __future__ import annotations

import signal

import click

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


address_option = click.option(
    "--address", type=str, default=None, metavar="ADDR",
    help="The Ray cluster to join with --backend ray: HOST:PORT of its head (what `ray start --head` "
    "prints) or auto (RAY_ADDRESS, or the cluster this machine belongs to) [default: start a local "
    "Ray instance].",
)
