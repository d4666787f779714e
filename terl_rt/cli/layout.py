"""`terl-rt layout`: write the Foxglove layout shipped with terl-rt, for opening logs."""

from __future__ import annotations

import importlib.resources

import click

from terl_rt.cli.outputs import check_output, force_option
from terl_rt.files import atomic_output

LAYOUT = ("terl_rt.logs", "foxglove-layout.json")
"""(package, resource) of the Foxglove layout installed with terl-rt."""


def layout_bytes() -> bytes:
    """The shipped Foxglove layout (JSON): a 3-D view of /world from above, plots of
    /rewards and /target_weights, and the /events messages."""
    package, resource = LAYOUT
    return importlib.resources.files(package).joinpath(resource).read_bytes()


@click.command("layout")
@click.option("-o", "--output", "output", type=str, default="terl-foxglove-layout.json", show_default=True,
              metavar="FILE", help="Where to write the layout (JSON).")
@force_option
def layout_command(output: str, force: bool) -> None:
    """Write the Foxglove layout that shows a terl-rt log: the 3-D scene (/world) seen
    from above, plots of the rewards and target weights, and the events.

    In Foxglove, open the log (File > Open local file), then Layouts > Import from file
    and pick FILE.

    \b
    Examples:
      terl-rt layout                       # ./terl-foxglove-layout.json
      terl-rt layout -o ~/layouts/terl.json --force
    """
    out = check_output(output, "-o", (), force)
    with atomic_output(out, replace=force) as staging:
        staging.write_bytes(layout_bytes())
    click.echo(f"wrote {out}")
