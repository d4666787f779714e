"""--live of `terl-rt eval` and `terl-rt replay`: where the live view is served, and its server
opened and announced on stderr (terl_rt.logs.live)."""

from __future__ import annotations

import logging

import click

from terl_rt.cli.options import BadInput
from terl_rt.logs.live import DEFAULT_HOST, DEFAULT_PORT, LIVE_INSTALL, LiveMissing, LiveSink, parse_address

DEFAULT_ADDRESS = f"{DEFAULT_HOST}:{DEFAULT_PORT}"
"""What --live alone serves on: this machine only, Foxglove's default port."""


def _address(ctx: click.Context, param: click.Parameter, value: str | None) -> tuple[str, int] | None:
    if value is None:
        return None
    try:
        return parse_address(value)
    except ValueError as error:
        raise click.BadParameter(str(error)) from None


def live_option(what: str):
    """--live [HOST:PORT], as (host, port) or None; `what` begins its help (what is served)."""
    return click.option(
        "--live", "live", is_flag=False, flag_value=DEFAULT_ADDRESS, default=None, metavar="[HOST:PORT]",
        callback=_address,
        help=f"{what} to Foxglove over its WebSocket protocol, on the log's topics (the layout of `terl-rt "
        f"layout`), at HOST:PORT [alone: {DEFAULT_ADDRESS}, this machine only; port 0: any free one]. "
        f"Needs {LIVE_INSTALL}.",
    )


def open_live(address: tuple[str, int]) -> LiveSink:
    """The live view's server at `address` (host, port), its address announced on stderr;
    a missing Foxglove SDK is BadInput (a port taken is a LiveServerError: one line too)."""
    if not logging.getLogger().isEnabledFor(logging.INFO):
        # The SDK logs a viewer gone without the closing handshake (a closed tab) as an ERROR:
        # the viewer's business, not the run's, so it shows with -v only.
        logging.getLogger("foxglove").setLevel(logging.CRITICAL)
    try:
        sink = LiveSink(*address)
    except LiveMissing as error:
        raise BadInput(str(error)) from None
    click.echo(f"live: {sink.url} (Foxglove: Open connection > Foxglove WebSocket, or {sink.app_url}); "
               "Ctrl-C stops", err=True)
    return sink
