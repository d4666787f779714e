"""The `terl-rt` command group: logging, error handling, subcommands."""

from __future__ import annotations

import logging

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
from terl_rt.command_line import TerlGroup


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
