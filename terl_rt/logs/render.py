"""Render a logged episode to an image or an animation (Pillow).

`.png` gives the final frame, `.gif` an animation (Pillow), `.mp4` a video (the
`video` extra: imageio with its ffmpeg). A frame shows the arena with a grid and its
axes labelled in metres, obstacles, vortex cores with their rotation (orange clockwise, blue counter-clockwise),
pursuers as triangles along their heading with short trails (grey with a cross once
collided), evaders (red; green with their encirclement circle once encircled), and
the step, time and counts in the title; the last frame adds the episode's metrics.
The legend draws each kind with the very marker of the map.

GIFs share one adaptive palette (GIF_COLORS colours drawn from the first, middle and
last frames) and let Pillow store only what changed between frames: about 7 times
smaller than frames quantised one by one (a 155-step small-15 episode at 640 px:
4.99 MB before, 0.72 MB after). `every` skips frames for smaller files still.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from terl_rt.extras import install_hint
from terl_rt.logs.foxglove import COLORS
from terl_rt.logs.reader import EpisodeLogReader, LoggedEpisode

FORMATS = (".png", ".gif", ".mp4")
"""Output suffixes `render` writes."""
SIZE_RANGE = (64, 4096)
"""px: the smallest and largest image width drawn (`render`, `draw_state`, PettingZoo's render_size)."""
GIF_MAX_FRAMES = 200
"""With `every=None`, GIFs keep at most this many frames (every frame is held in memory)."""
TRAIL_STEPS = 20
"""Steps (0.5 s each) of past positions drawn behind each robot."""
VIDEO_INSTALL = install_hint("video")

GIF_COLORS = 64
"""Colours of the palette all frames of a GIF share."""

_SUPERSAMPLE = 2
_HEADER_PX = 56
_LEGEND_PX = 34
_MARGIN_PX = 14
_AXIS_LEFT_PX = 30
"""room for the y tick labels left of the arena."""
_AXIS_BOTTOM_PX = 18
"""room for the x tick labels under the arena."""
_BACKGROUND = (255, 255, 255)
_SEA = (232, 241, 248)
_GRID = (214, 226, 236)
_INK = (40, 40, 40)


LEGEND = ("pursuer", "collided", "evader", "encircled", "obstacle", "vortex cw", "vortex ccw")
"""The legend's entries, in order; each is drawn with its marker on the map."""


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


def _fonts() -> tuple[ImageFont.ImageFont, ImageFont.ImageFont, ImageFont.ImageFont]:
    """The title's, the labels' and the robot ids' fonts, at the supersampled size."""
    return _font(15 * _SUPERSAMPLE), _font(12 * _SUPERSAMPLE), _font(10 * _SUPERSAMPLE)


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
    legend: tuple[tuple[str, ...], ...]
    """the legend's entries, row by row (as many rows as the width needs)."""

    @staticmethod
    def of(arena: tuple[float, float], size: int, ss: int, font: ImageFont.ImageFont) -> _Canvas:
        width_m, height_m = arena
        scale = (size - 2 * _MARGIN_PX - _AXIS_LEFT_PX) / width_m
        arena_px = height_m * scale
        width = int(math.ceil(size / 16) * 16)
        legend = _legend_rows(width, font, ss)
        height = _HEADER_PX + 2 * _MARGIN_PX + arena_px + _AXIS_BOTTOM_PX + _LEGEND_PX * len(legend)
        height = int(math.ceil(height / 16) * 16)  # video encoders want multiples of 16
        return _Canvas(width=width, height=height, scale=scale, arena_height_px=arena_px, ss=ss, legend=legend)

    def point(self, x: float, y: float) -> tuple[float, float]:
        return (
            self.ss * (_MARGIN_PX + _AXIS_LEFT_PX + x * self.scale),
            self.ss * (_HEADER_PX + _MARGIN_PX + self.arena_height_px - y * self.scale),
        )

    def length(self, metres: float, minimum_px: float = 0.0) -> float:
        return self.ss * max(metres * self.scale, minimum_px)


_SWATCH_PX = 7
"""half the width of a legend marker."""
_LEGEND_GAP_PX = 12
"""space between two legend entries."""


def _legend_entry_px(label: str, font: ImageFont.ImageFont, ss: int) -> float:
    """Width (final px) of one legend entry: its marker, then its label."""
    return 2.4 * _SWATCH_PX + font.getlength(label) / ss


def _legend_rows(width: int, font: ImageFont.ImageFont, ss: int) -> tuple[tuple[str, ...], ...]:
    """LEGEND split into rows that fit `width` px (one row at 640 px, two at 480)."""
    rows: list[tuple[str, ...]] = []
    row: list[str] = []
    x = float(_MARGIN_PX)
    for label in LEGEND:
        entry = _legend_entry_px(label, font, ss)
        if row and x + entry > width - _MARGIN_PX:
            rows.append(tuple(row))
            row, x = [], float(_MARGIN_PX)
        row.append(label)
        x += entry + _LEGEND_GAP_PX
    rows.append(tuple(row))
    return tuple(rows)


def _circle(draw: ImageDraw.ImageDraw, center: tuple[float, float], radius: float, **style) -> None:
    x, y = center
    draw.ellipse((x - radius, y - radius, x + radius, y + radius), **style)


def _draw_vortex(draw, canvas: _Canvas, x: float, y: float, clockwise: bool) -> None:
    cx, cy = canvas.point(x, y)
    _vortex_marker(draw, cx, cy, canvas.length(2.5, 7), canvas.length(0.5, 2.5), clockwise, canvas.ss)


def _vortex_marker(draw, cx: float, cy: float, ring: float, core: float, clockwise: bool, ss: int) -> None:
    """A vortex core at pixel (cx, cy): an open ring with an arrowhead, and a dot."""
    color = _rgb("vortex_clockwise" if clockwise else "vortex_counter")
    width = max(1, ss * 2)
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
    _circle(draw, (cx, cy), core, fill=color)


def _draw_pursuer(draw, canvas: _Canvas, x: float, y: float, theta: float, active: bool) -> None:
    cx, cy = canvas.point(x, y)
    _pursuer_marker(draw, cx, cy, canvas.length(1.6, 7), theta, active, canvas.ss)


def _pursuer_marker(draw, cx: float, cy: float, size: float, theta: float, active: bool, ss: int) -> None:
    """A pursuer at pixel (cx, cy): a triangle along its heading; greyed with a cross once collided."""
    # Heading in image coordinates: y flips, so the angle changes sign.
    ux, uy = math.cos(theta), -math.sin(theta)
    nose = (cx + size * ux, cy + size * uy)
    back = (cx - 0.7 * size * ux, cy - 0.7 * size * uy)
    left = (back[0] - 0.6 * size * uy, back[1] + 0.6 * size * ux)
    right = (back[0] + 0.6 * size * uy, back[1] - 0.6 * size * ux)
    if active:
        draw.polygon([nose, left, right], fill=_rgb("pursuer"), outline=_rgb("pursuer", 0.5), width=ss)
    else:
        grey = _rgb("pursuer_collided")
        draw.polygon([nose, left, right], fill=_blend(grey, _SEA, 0.4), outline=grey, width=ss)
        arm = 0.8 * size
        draw.line((cx - arm, cy - arm, cx + arm, cy + arm), fill=_INK, width=ss * 2)
        draw.line((cx - arm, cy + arm, cx + arm, cy - arm), fill=_INK, width=ss * 2)


def _evader_marker(draw, cx: float, cy: float, radius: float, ring: float | None, ss: int) -> None:
    """An evader at pixel (cx, cy): red; green inside its encirclement ring (`ring` px) once encircled."""
    if ring is None:
        _circle(draw, (cx, cy), radius, fill=_rgb("evader"), outline=_rgb("evader", 0.6), width=ss)
    else:
        green = _rgb("evader_encircled")
        _circle(draw, (cx, cy), ring, outline=green, width=ss * 2)
        _circle(draw, (cx, cy), radius, fill=green, outline=_rgb("evader_encircled", 0.6), width=ss)


def axis_ticks(length_m: float) -> list[float]:
    """Tick positions (m) along an arena side of `length_m` metres: every 20 m up to 200 m,
    every 50 m beyond, from 0; the far end too when it is at least half a step past the last."""
    step = 20.0 if length_m <= 200 else 50.0
    ticks = list(np.arange(0.0, length_m + 1e-9, step))
    if length_m - ticks[-1] >= step / 2:
        ticks.append(float(length_m))
    return [float(t) for t in ticks]


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

    # Arena, with a grid at the axes' ticks (m).
    x0, y1 = canvas.point(0.0, 0.0)
    x1, y0 = canvas.point(width_m, height_m)
    draw.rectangle((x0, y0, x1, y1), fill=_SEA)
    x_ticks, y_ticks = axis_ticks(width_m), axis_ticks(height_m)
    for metres in x_ticks[1:-1]:
        gx, _ = canvas.point(metres, 0.0)
        draw.line((gx, y0, gx, y1), fill=_GRID, width=ss)
    for metres in y_ticks[1:-1]:
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
    ring = canvas.length(params.d_encircle)
    title_font, small_font, id_font = fonts
    for (x, y), active in zip(state["evader_xy"].tolist(), state["evader_active"].tolist()):
        _evader_marker(draw, *canvas.point(x, y), radius, None if active else ring, ss)
    for (x, y), theta, active in zip(
        state["pursuer_xy"].tolist(), state["pursuer_theta"].tolist(), state["pursuer_active"].tolist()
    ):
        _draw_pursuer(draw, canvas, x, y, theta, active)
    # Ids, as replay and the logs' events name the robots: pursuer i, evader "e" j.
    offset = canvas.length(1.6, 7)
    for group, prefix, kind in (("pursuer_xy", "", "pursuer"), ("evader_xy", "e", "evader")):
        for i, (x, y) in enumerate(state[group].tolist()):
            cx, cy = canvas.point(x, y)
            draw.text((cx + 0.8 * offset, cy - 0.8 * offset), f"{prefix}{i}", fill=_rgb(kind, 0.55), font=id_font,
                      anchor="ld", stroke_width=ss, stroke_fill=_SEA)

    # Title, axes and legend, on bands that hide robots far outside the arena.
    draw.rectangle((0, 0, image.width, (_HEADER_PX + 2) * ss), fill=_BACKGROUND)
    draw.rectangle((0, y1 + 2 * ss, image.width, image.height), fill=_BACKGROUND)
    draw.rectangle((0, 0, x0 - 2 * ss, image.height), fill=_BACKGROUND)
    draw.rectangle((x0, y0, x1, y1), outline=_INK, width=2 * ss)
    tick = 4 * ss
    for metres in x_ticks:
        gx, _ = canvas.point(metres, 0.0)
        draw.line((gx, y1, gx, y1 + tick), fill=_INK, width=ss)
        last_tick = metres == x_ticks[-1]
        label = f"{metres:g}" + (" m" if last_tick else "")
        draw.text((gx + (3 * ss if last_tick else 0), y1 + tick + ss), label, fill=_INK, font=small_font,
                  anchor="ra" if last_tick else "ma")
    for metres in y_ticks:
        _, gy = canvas.point(0.0, metres)
        draw.line((x0 - tick, gy, x0, gy), fill=_INK, width=ss)
        draw.text((x0 - tick - 2 * ss, gy), f"{metres:g}", fill=_INK, font=small_font, anchor="rm")
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

    # Legend: each kind drawn with the map's own marker, in as many rows as the width needs.
    swatch = _SWATCH_PX * ss
    for row_index, row in enumerate(canvas.legend):
        legend_y = (canvas.height - _LEGEND_PX * (len(canvas.legend) - row_index - 0.5)) * ss
        x = _MARGIN_PX * ss
        for label in row:
            cx = x + swatch
            if label == "pursuer":
                _pursuer_marker(draw, cx, legend_y, swatch, 0.0, True, ss)
            elif label == "collided":
                _pursuer_marker(draw, cx, legend_y, swatch, 0.0, False, ss)
            elif label == "evader":
                _evader_marker(draw, cx, legend_y, 0.6 * swatch, None, ss)
            elif label == "encircled":
                _evader_marker(draw, cx, legend_y, 0.45 * swatch, swatch, ss)
            elif label == "obstacle":
                _circle(draw, (cx, legend_y), 0.7 * swatch, fill=_rgb("obstacle"))
            else:
                _vortex_marker(draw, cx, legend_y, 0.9 * swatch, 0.25 * swatch, label == "vortex cw", ss)
            draw.text((x + 2.4 * swatch, legend_y), label, fill=_INK, font=small_font, anchor="lm")
            x += (_legend_entry_px(label, small_font, ss) + _LEGEND_GAP_PX) * ss
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
    fonts = _fonts()
    canvas = _Canvas.of(episode.scenario.arena, size, _SUPERSAMPLE, fonts[1])
    return _draw_frame(states, t, episode, canvas, fonts, final=final)


def _shared_palette(samples: list[Image.Image]) -> Image.Image:
    """An adaptive GIF_COLORS-colour palette (median cut) of the sample frames, stacked."""
    width, height = samples[0].size
    sheet = Image.new("RGB", (width, height * len(samples)))
    for i, image in enumerate(samples):
        sheet.paste(image, (0, i * height))
    return sheet.quantize(colors=GIF_COLORS, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE)


def _frame_steps(last: int, every: int) -> list[int]:
    steps = list(range(0, last + 1, every))
    if steps[-1] != last:
        steps.append(last)
    return steps


def render(
    log: str | os.PathLike | EpisodeLogReader,
    out: str | os.PathLike,
    episode: int = 0,
    fps: float = 10.0,
    every: int | None = None,
    size: int = 640,
) -> Path:
    """Render episode `episode` (file order) of `log` (a path, or the log opened) to `out`.

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

    reader = log if isinstance(log, EpisodeLogReader) else EpisodeLogReader(log)
    entry = reader.episode(episode)
    states = [step.state for step in reader.steps(episode)]
    if not states:
        why = f"; {reader.problem}" if reader.problem else ""
        raise RenderError(f"{reader.path}: episode {episode} has no complete step to draw{why}")
    last = len(states) - 1
    fonts = _fonts()
    canvas = _Canvas.of(entry.scenario.arena, size, _SUPERSAMPLE, fonts[1])

    def frame(t: int) -> Image.Image:
        return _draw_frame(states, t, entry, canvas, fonts, final=t == last)

    if suffix == ".png":
        frame(last).save(out)
        return out
    if every is None:
        every = max(1, math.ceil((last + 1) / GIF_MAX_FRAMES)) if suffix == ".gif" else 1
    steps = _frame_steps(last, every)
    if suffix == ".gif":
        rgb = [frame(t) for t in steps]
        palette = _shared_palette([rgb[0], rgb[len(rgb) // 2], rgb[-1]])
        frames = [image.quantize(palette=palette, dither=Image.Dither.NONE) for image in rgb]
        duration = [int(round(1000 / fps))] * len(frames)
        duration[-1] = max(duration[-1], 1500)  # linger on the outcome
        # One palette for every frame lets Pillow store each frame as its change from the last.
        frames[0].save(out, save_all=True, append_images=frames[1:], duration=duration, loop=0, optimize=True)
        return out
    try:
        writer = imageio.get_writer(out, fps=fps, codec="libx264", quality=7, macro_block_size=16)
    except Exception as error:  # imageio without a usable ffmpeg backend
        raise RenderError(f"cannot write .mp4 ({error}); install the video extra: {VIDEO_INSTALL}") from None
    with writer:
        for t in steps:
            writer.append_data(np.asarray(frame(t)))
    return out
