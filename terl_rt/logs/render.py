"""Render a logged episode to an image or an animation (Pillow).

`.png` gives the final frame, `.gif` an animation (Pillow), `.mp4` a video (the
`video` extra: imageio with its ffmpeg). A frame shows the arena with a 20 m grid,
obstacles, vortex cores with their rotation (orange clockwise, blue counter-clockwise),
pursuers as triangles along their heading with short trails (grey with a cross once
collided), evaders (red; green with their encirclement circle once encircled), and
the step, time and counts in the title; the last frame adds the episode's metrics.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from terl_rt.logs.foxglove import COLORS
from terl_rt.logs.reader import EpisodeLogReader, LoggedEpisode

FORMATS = (".png", ".gif", ".mp4")
"""Output suffixes `render` writes."""
GIF_MAX_FRAMES = 200
"""With `every=None`, GIFs keep at most this many frames (every frame is held in memory)."""
TRAIL_STEPS = 20
"""Steps (0.5 s each) of past positions drawn behind each robot."""
VIDEO_INSTALL = "pip install -e '.[video]' (from the terl-rt checkout)"

_SUPERSAMPLE = 2
_HEADER_PX = 56
_LEGEND_PX = 30
_MARGIN_PX = 14
_BACKGROUND = (255, 255, 255)
_SEA = (232, 241, 248)
_GRID = (214, 226, 236)
_INK = (40, 40, 40)


class RenderError(ValueError):
    """A render request that cannot be met (output format, missing extra, empty episode)."""


def _rgb(kind: str, scale: float = 1.0) -> tuple[int, int, int]:
    r, g, b, _ = COLORS[kind]
    return tuple(int(round(255 * min(1.0, c * scale))) for c in (r, g, b))


def _blend(color: tuple[int, int, int], toward: tuple[int, int, int], amount: float) -> tuple[int, int, int]:
    return tuple(int(round(c + (t - c) * amount)) for c, t in zip(color, toward))


def _font(size: int) -> ImageFont.ImageFont:
    try:
        return ImageFont.load_default(size=size)
    except TypeError:  # Pillow < 10.1 has only the fixed bitmap font
        return ImageFont.load_default()


@dataclass(frozen=True)
class _Canvas:
    """Pixel geometry of a frame: world (m) to image (px), y up in the world, down in the image."""

    width: int
    height: int
    scale: float
    """px per m."""
    arena_height_px: float
    ss: int
    """supersampling factor: drawing is done at ss times the final size."""

    @staticmethod
    def of(arena: tuple[float, float], size: int, ss: int) -> _Canvas:
        width_m, height_m = arena
        scale = (size - 2 * _MARGIN_PX) / width_m
        arena_px = height_m * scale
        height = _HEADER_PX + 2 * _MARGIN_PX + arena_px + _LEGEND_PX
        height = int(math.ceil(height / 16) * 16)  # video encoders want multiples of 16
        return _Canvas(width=int(math.ceil(size / 16) * 16), height=height, scale=scale, arena_height_px=arena_px, ss=ss)

    def point(self, x: float, y: float) -> tuple[float, float]:
        return (
            self.ss * (_MARGIN_PX + x * self.scale),
            self.ss * (_HEADER_PX + _MARGIN_PX + self.arena_height_px - y * self.scale),
        )

    def length(self, metres: float, minimum_px: float = 0.0) -> float:
        return self.ss * max(metres * self.scale, minimum_px)


def _circle(draw: ImageDraw.ImageDraw, center: tuple[float, float], radius: float, **style) -> None:
    x, y = center
    draw.ellipse((x - radius, y - radius, x + radius, y + radius), **style)


def _draw_vortex(draw, canvas: _Canvas, x: float, y: float, clockwise: bool) -> None:
    color = _rgb("vortex_clockwise" if clockwise else "vortex_counter")
    cx, cy = canvas.point(x, y)
    ring = canvas.length(2.5, 7)
    width = max(1, canvas.ss * 2)
    # An open ring with an arrowhead at the end that points the way the water turns.
    # Image angles run clockwise (y down): a clockwise arc ends at 300 deg going forward.
    start, end = (20.0, 320.0)
    draw.arc((cx - ring, cy - ring, cx + ring, cy + ring), start, end, fill=color, width=width)
    tip_angle = math.radians(end if clockwise else start)
    tip = (cx + ring * math.cos(tip_angle), cy + ring * math.sin(tip_angle))
    # Tangent in image coordinates: increasing image angle is clockwise on screen.
    direction = tip_angle + (math.pi / 2 if clockwise else -math.pi / 2)
    head = ring * 0.75
    left = (tip[0] - head * math.cos(direction - 0.5), tip[1] - head * math.sin(direction - 0.5))
    right = (tip[0] - head * math.cos(direction + 0.5), tip[1] - head * math.sin(direction + 0.5))
    draw.polygon([tip, left, right], fill=color)
    _circle(draw, (cx, cy), canvas.length(0.5, 2.5), fill=color)


def _draw_pursuer(draw, canvas: _Canvas, x: float, y: float, theta: float, active: bool) -> None:
    cx, cy = canvas.point(x, y)
    size = canvas.length(1.6, 7)
    # Heading in image coordinates: y flips, so the angle changes sign.
    ux, uy = math.cos(theta), -math.sin(theta)
    nose = (cx + size * ux, cy + size * uy)
    back = (cx - 0.7 * size * ux, cy - 0.7 * size * uy)
    left = (back[0] - 0.6 * size * uy, back[1] + 0.6 * size * ux)
    right = (back[0] + 0.6 * size * uy, back[1] - 0.6 * size * ux)
    if active:
        draw.polygon([nose, left, right], fill=_rgb("pursuer"), outline=_rgb("pursuer", 0.5), width=canvas.ss)
    else:
        grey = _rgb("pursuer_collided")
        draw.polygon([nose, left, right], fill=_blend(grey, _SEA, 0.4), outline=grey, width=canvas.ss)
        arm = 0.8 * size
        draw.line((cx - arm, cy - arm, cx + arm, cy + arm), fill=_INK, width=canvas.ss * 2)
        draw.line((cx - arm, cy + arm, cx + arm, cy - arm), fill=_INK, width=canvas.ss * 2)


def _draw_frame(
    states: list[dict[str, np.ndarray]],
    t: int,
    entry: LoggedEpisode,
    canvas: _Canvas,
    fonts: tuple,
    final: bool,
) -> Image.Image:
    scenario, params = entry.scenario, entry.scenario.params
    ss = canvas.ss
    image = Image.new("RGB", (canvas.width * ss, canvas.height * ss), _BACKGROUND)
    draw = ImageDraw.Draw(image)
    state = states[t]
    width_m, height_m = scenario.arena

    # Arena, with a 20 m grid for scale.
    x0, y1 = canvas.point(0.0, 0.0)
    x1, y0 = canvas.point(width_m, height_m)
    draw.rectangle((x0, y0, x1, y1), fill=_SEA)
    for metres in np.arange(20.0, max(width_m, height_m), 20.0):
        if metres < width_m:
            gx, _ = canvas.point(metres, 0.0)
            draw.line((gx, y0, gx, y1), fill=_GRID, width=ss)
        if metres < height_m:
            _, gy = canvas.point(0.0, metres)
            draw.line((x0, gy, x1, gy), fill=_GRID, width=ss)
    draw.rectangle((x0, y0, x1, y1), outline=_INK, width=2 * ss)

    for (x, y), clockwise in zip(state["vortex_xy"].tolist(), state["vortex_clockwise"].tolist()):
        _draw_vortex(draw, canvas, x, y, clockwise)
    for (x, y), radius in zip(state["obstacle_xy"].tolist(), state["obstacle_r"].tolist()):
        _circle(draw, canvas.point(x, y), canvas.length(radius, 2.5), fill=_rgb("obstacle"))

    # Trails: the last TRAIL_STEPS positions, fading into the sea.
    first = max(0, t - TRAIL_STEPS)
    for group, kind in (("pursuer_xy", "pursuer"), ("evader_xy", "evader")):
        track = np.stack([states[k][group] for k in range(first, t + 1)])  # [T, K, 2]
        light = _blend(_rgb(kind), _SEA, 0.55)
        for robot in range(track.shape[1]):
            points = [canvas.point(x, y) for x, y in track[:, robot].tolist()]
            if len(points) > 1:
                draw.line(points, fill=light, width=ss * 2, joint="curve")

    radius = canvas.length(params.robot_radius, 4)
    for (x, y), active in zip(state["evader_xy"].tolist(), state["evader_active"].tolist()):
        center = canvas.point(x, y)
        if active:
            _circle(draw, center, radius, fill=_rgb("evader"), outline=_rgb("evader", 0.6), width=ss)
        else:
            green = _rgb("evader_encircled")
            _circle(draw, center, canvas.length(params.d_encircle), outline=green, width=ss * 2)
            _circle(draw, center, radius, fill=green, outline=_rgb("evader_encircled", 0.6), width=ss)
    for (x, y), theta, active in zip(
        state["pursuer_xy"].tolist(), state["pursuer_theta"].tolist(), state["pursuer_active"].tolist()
    ):
        _draw_pursuer(draw, canvas, x, y, theta, active)

    # Title and legend, on bands that hide robots far outside the arena.
    draw.rectangle((0, 0, image.width, (_HEADER_PX + 2) * ss), fill=_BACKGROUND)
    draw.rectangle((0, (canvas.height - _LEGEND_PX) * ss, image.width, image.height), fill=_BACKGROUND)
    title_font, small_font = fonts
    step_s = params.dt * params.substeps
    last = len(states) - 1
    encircled = int((~state["evader_active"]).sum())
    collided = int((~state["pursuer_active"]).sum())
    line1 = (
        f"{scenario.name}  ·  episode {entry.number} (seed {entry.seed})  ·  "
        f"step {t}/{last}  ·  {t * step_s:.1f} s"
    )
    line2 = f"encircled {encircled}/{len(state['evader_active'])}  ·  collided {collided}/{len(state['pursuer_active'])}"
    if final:
        if entry.metrics is None:
            line2 += "  ·  log cut off here: episode incomplete"
        else:
            m = entry.metrics
            outcome = "SUCCESS" if m.success else "not all encircled"
            line2 += f"  ·  {outcome}, travel time {m.travel_time_s:.1f} s, collision ratio {m.collision_ratio:.2f}"
    draw.text((_MARGIN_PX * ss, 8 * ss), line1, fill=_INK, font=title_font)
    draw.text((_MARGIN_PX * ss, 32 * ss), line2, fill=_INK, font=small_font)

    legend_y = (canvas.height - _LEGEND_PX / 2) * ss
    x = _MARGIN_PX * ss
    swatch = 6 * ss
    for label, color in (
        ("pursuer", _rgb("pursuer")),
        ("collided", _rgb("pursuer_collided")),
        ("evader", _rgb("evader")),
        ("encircled", _rgb("evader_encircled")),
        ("obstacle", _rgb("obstacle")),
        ("vortex cw", _rgb("vortex_clockwise")),
        ("vortex ccw", _rgb("vortex_counter")),
    ):
        _circle(draw, (x + swatch, legend_y), swatch, fill=color)
        draw.text((x + 2.6 * swatch, legend_y), label, fill=_INK, font=small_font, anchor="lm")
        x += 2.6 * swatch + draw.textlength(label, font=small_font) + 14 * ss
    if ss > 1:
        image = image.resize((canvas.width, canvas.height), Image.Resampling.LANCZOS)
    return image


def draw_state(
    states: list[dict[str, np.ndarray]], t: int, episode, size: int = 640, final: bool = False
) -> Image.Image:
    """Draw step `t` of `states` (`Simulator.state()` dicts, one per step, step 0 first)
    as `render` draws a logged one. `episode` needs `scenario`, `number`, `seed` and
    `metrics` (an EpisodeMetrics or None), as a LoggedEpisode has: what
    terl_rt.envs draws its frames with."""
    canvas = _Canvas.of(episode.scenario.arena, size, _SUPERSAMPLE)
    fonts = (_font(15 * _SUPERSAMPLE), _font(12 * _SUPERSAMPLE))
    return _draw_frame(states, t, episode, canvas, fonts, final=final)


def _frame_steps(last: int, every: int) -> list[int]:
    steps = list(range(0, last + 1, every))
    if steps[-1] != last:
        steps.append(last)
    return steps


def render(
    path: str | os.PathLike,
    out: str | os.PathLike,
    episode: int = 0,
    fps: float = 10.0,
    every: int | None = None,
    size: int = 640,
) -> Path:
    """Render episode `episode` (file order) of the log at `path` to `out`.

    The suffix of `out` picks the format: .png (final frame), .gif or .mp4 (one frame
    every `every` steps, `fps` frames per second; every=None: 1, or as many as keep a
    GIF within GIF_MAX_FRAMES). size: image width in px. Returns the output path.
    Raises RenderError for another suffix, a missing video extra or an empty episode.
    """
    out = Path(out)
    suffix = out.suffix.lower()
    if suffix not in FORMATS:
        raise RenderError(f"{out}: unknown output format {suffix or '(none)'!r}; use one of {', '.join(FORMATS)}")
    if not (fps > 0 and math.isfinite(fps)):
        raise RenderError(f"fps must be a positive number, got {fps}")
    if every is not None and every < 1:
        raise RenderError(f"every must be >= 1, got {every}")
    if size < 64:
        raise RenderError(f"size must be at least 64 px, got {size}")
    if suffix == ".mp4":
        try:
            import imageio.v2 as imageio  # the optional `video` extra
        except ImportError:
            raise RenderError(f"writing .mp4 needs the video extra: {VIDEO_INSTALL}") from None

    reader = EpisodeLogReader(path)
    entry = reader.episode(episode)
    states = [step.state for step in reader.steps(episode)]
    if not states:
        raise RenderError(f"{path}: episode {episode} has no complete step to draw")
    last = len(states) - 1
    canvas = _Canvas.of(entry.scenario.arena, size, _SUPERSAMPLE)
    fonts = (_font(15 * _SUPERSAMPLE), _font(12 * _SUPERSAMPLE))

    def frame(t: int) -> Image.Image:
        return _draw_frame(states, t, entry, canvas, fonts, final=t == last)

    if suffix == ".png":
        frame(last).save(out)
        return out
    if every is None:
        every = max(1, math.ceil((last + 1) / GIF_MAX_FRAMES)) if suffix == ".gif" else 1
    steps = _frame_steps(last, every)
    if suffix == ".gif":
        frames = [
            frame(t).quantize(colors=128, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE) for t in steps
        ]
        duration = [int(round(1000 / fps))] * len(frames)
        duration[-1] = max(duration[-1], 1500)  # linger on the outcome
        frames[0].save(out, save_all=True, append_images=frames[1:], duration=duration, loop=0, optimize=False)
        return out
    try:
        writer = imageio.get_writer(out, fps=fps, codec="libx264", quality=7, macro_block_size=16)
    except Exception as error:  # imageio without a usable ffmpeg backend
        raise RenderError(f"cannot write .mp4 ({error}); install the video extra: {VIDEO_INSTALL}") from None
    with writer:
        for t in steps:
            writer.append_data(np.asarray(frame(t)))
    return out
