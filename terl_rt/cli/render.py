"""`terl-rt render`: draw an episode of an MCAP log to .png, .gif or .mp4."""

from __future__ import annotations

import click

from terl_rt.logs.render import FORMATS, render


@click.command("render")
@click.argument("log", type=str)
@click.option("--episode", type=click.IntRange(min=0), default=0, show_default=True,
              help="Episode of the log, by its position in the file (0-based).")
@click.option("-o", "--output", "output", type=str, required=True, metavar="OUT",
              help=f"Output file; its suffix picks the format ({', '.join(FORMATS)}; .png = final frame).")
@click.option("--fps", type=click.FloatRange(min=0, min_open=True), default=10.0, show_default=True,
              help="Frames per second of an animation.")
@click.option("--every", type=click.IntRange(min=1), default=None,
              help="Draw every K-th step (0.5 s each) [default: 1; a .gif keeps at most 200 frames].")
@click.option("--size", type=click.IntRange(min=64), default=640, show_default=True, help="Image width in px.")
def render_command(log: str, episode: int, output: str, fps: float, every: int | None, size: int) -> None:
    """Render an episode: arena, obstacles, vortex cores with their rotation, pursuers
    with heading and trails, evaders (green once encircled), step and metrics in the title."""
    path = render(log, output, episode=episode, fps=fps, every=every, size=size)
    click.echo(f"wrote {path}")
