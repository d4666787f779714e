"""`terl-rt render`: draw an episode of an MCAP log to .png, .gif or .mp4."""

from __future__ import annotations

from pathlib import Path

import click

from terl_rt.cli.options import IntRange
from terl_rt.cli.outputs import check_output, force_option
from terl_rt.files import atomic_output
from terl_rt.logs.reader import EpisodeLogReader
from terl_rt.logs.render import FORMATS, SIZE_RANGE, RenderError, render


@click.command("render")
@click.argument("log", type=str)
@click.option("--episode", type=IntRange(min=0), default=0, show_default=True,
              help="Episode of the log, by its position in the file (0-based).")
@click.option("-o", "--output", "output", type=str, required=True, metavar="OUT",
              help=f"Output file; its suffix picks the format ({', '.join(FORMATS)}; .png = final frame).")
@click.option("--fps", type=click.FloatRange(min=0.1, max=120.0), default=10.0, show_default=True,
              help="Frames per second of an animation.")
@click.option("--every", type=IntRange(min=1), default=None,
              help="Draw every K-th step (0.5 s each) [default: 1; a .gif keeps at most 200 frames].")
@click.option("--size", type=IntRange(min=SIZE_RANGE[0], max=SIZE_RANGE[1]), default=640, show_default=True, help="Image width in px.")
@force_option
def render_command(log: str, episode: int, output: str, fps: float, every: int | None, size: int, force: bool) -> None:
    """Render an episode: arena, obstacles, vortex cores with their rotation, pursuers
    with heading and trails, evaders (green once encircled), step and metrics in the title.
    An existing OUT is replaced only with --force (never the LOG itself), once the image is complete.
    A log that was cut off or is damaged is drawn up to its last complete step, with a note saying so.

    \b
    Examples:
      terl-rt render run.mcap -o final.png                      # the last frame
      terl-rt render run.mcap --episode 2 -o episode.gif --every 2
      terl-rt render run.mcap -o episode.mp4 --fps 20 --size 960  # needs terl-rt[video]
    """
    if Path(output).suffix.lower() not in FORMATS:
        raise RenderError(f"{output}: unknown output format {Path(output).suffix or '(none)'!r}; use one of {', '.join(FORMATS)}")
    out = check_output(output, "-o", [("LOG", log)], force)
    reader = EpisodeLogReader(log)
    with atomic_output(out, replace=force) as staging:
        render(reader, staging, episode=episode, fps=fps, every=every, size=size)
    click.echo(f"wrote {out}")
    if reader.problem:  # cut off or damaged: drawn up to its last complete step, as replay notes
        click.echo(f"note: {reader.problem}", err=True)
