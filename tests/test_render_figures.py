"""Renders a researcher can put in a paper: axes in metres, a legend of the map's markers, small GIFs."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from terl_rt import Scenario
from terl_rt.evaluation.evaluate import evaluate_policy
from terl_rt.logs import render as render_module
from terl_rt.logs.render import LEGEND, axis_ticks, render
from terl_rt.policy.onnx_policy import OnnxPolicy

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def episode_log(tmp_path_factory) -> Path:
    """40 steps of small-15 with the shipped policy: robots move, trails grow."""
    path = tmp_path_factory.mktemp("render") / "small.mcap"
    evaluate_policy(OnnxPolicy(ROOT / "exported" / "terl.onnx"), Scenario.preset("small-15"), 1, 0,
                    max_steps=40, log_path=path)
    return path


def test_axis_ticks_are_metres_along_each_side():
    assert axis_ticks(120.0) == [0.0, 20.0, 40.0, 60.0, 80.0, 100.0, 120.0]
    assert axis_ticks(220.0) == [0.0, 50.0, 100.0, 150.0, 200.0]
    assert axis_ticks(125.0) == [0.0, 20.0, 40.0, 60.0, 80.0, 100.0, 120.0]
    assert axis_ticks(140.0)[-1] == 140.0


def test_frames_have_tick_labels_left_of_and_under_the_arena(episode_log, tmp_path):
    out = render(episode_log, tmp_path / "last.png", size=480)
    image = np.asarray(Image.open(out).convert("L"))
    canvas = render_module._Canvas.of((120.0, 120.0), 480, 1, render_module._fonts()[1])
    x0, y_bottom = canvas.point(0.0, 0.0)
    left_band = image[int(canvas.point(0, 120)[1]):int(y_bottom), : int(x0) - 2]
    under_band = image[int(y_bottom) + 6 : int(y_bottom) + 18, int(x0):]
    assert (left_band < 120).sum() > 50, "no y tick labels"
    assert (under_band < 120).sum() > 50, "no x tick labels"


def test_the_legend_names_every_kind_of_marker():
    assert LEGEND == ("pursuer", "collided", "evader", "encircled", "obstacle", "vortex cw", "vortex ccw")


def test_gifs_share_one_palette_and_are_small(episode_log, tmp_path):
    out = render(episode_log, tmp_path / "ep.gif", size=480)
    with Image.open(out) as gif:
        assert gif.n_frames == 41
        palette = gif.getpalette()
        sizes = set()
        for k in range(gif.n_frames):
            gif.seek(k)
            sizes.add(gif.size)
        assert len(palette) <= 3 * 256
    assert len(sizes) == 1
    # Quantising frame by frame (the old way) made this episode ~6x larger.
    assert out.stat().st_size < 41 * 25_000, out.stat().st_size


def test_every_skips_frames_for_smaller_files(episode_log, tmp_path):
    full = render(episode_log, tmp_path / "full.gif", size=320)
    skipped = render(episode_log, tmp_path / "skip.gif", size=320, every=4)
    with Image.open(skipped) as gif:
        assert gif.n_frames == 11
    assert skipped.stat().st_size < full.stat().st_size / 2


@pytest.mark.parametrize("size", [480, 640, 1024])
def test_the_legend_fits_the_width_in_as_many_rows_as_it_needs(size):
    font = render_module._fonts()[1]
    ss = render_module._SUPERSAMPLE
    rows = render_module._legend_rows(size, font, ss)
    assert tuple(label for row in rows for label in row) == LEGEND
    for row in rows:
        width = sum(render_module._legend_entry_px(label, font, ss) + render_module._LEGEND_GAP_PX for label in row)
        assert render_module._MARGIN_PX + width - render_module._LEGEND_GAP_PX <= size - render_module._MARGIN_PX
    assert len(rows) == (2 if size == 480 else 1)

