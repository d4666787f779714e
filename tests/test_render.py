"""Rendering logged episodes to PNG and GIF (terl_rt.logs.render)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
from onnx_models import write_test_policy
from PIL import Image
from tiny_worlds import capture_scenario

from terl_rt.evaluation.evaluate import evaluate_policy as evaluate
from terl_rt.logs.foxglove import COLORS
from terl_rt.logs.render import RenderError, render

STEPS = 8


@pytest.fixture(scope="module")
def log_path(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("render")
    policy = write_test_policy(folder / "linear.onnx")
    path = folder / "capture.mcap"
    evaluate(str(policy), capture_scenario(STEPS), episodes=1, seed=0, log_path=path)
    return path


def count_pixels_near(image: Image.Image, kind: str, tolerance: int = 12) -> int:
    target = np.array([round(255 * c) for c in COLORS[kind][:3]])
    pixels = np.asarray(image.convert("RGB")).astype(int)
    return int((np.abs(pixels - target).max(-1) <= tolerance).sum())


def test_png_is_the_final_frame(log_path, tmp_path):
    out = render(log_path, tmp_path / "final.png")
    with Image.open(out) as image:
        assert image.format == "PNG" and image.size == (640, 720)  # arena, axes (m) and legend
        # The encircled evader (green) and the free one (red) are both drawn.
        assert count_pixels_near(image, "evader_encircled") > 50
        assert count_pixels_near(image, "evader") > 20


def test_gif_has_one_frame_per_step(log_path, tmp_path):
    out = render(log_path, tmp_path / "episode.gif", fps=5)
    with Image.open(out) as image:
        assert image.format == "GIF" and image.n_frames == STEPS + 1
        assert image.info["duration"] == 200


def test_every_skips_steps_but_keeps_the_last(log_path, tmp_path):
    out = render(log_path, tmp_path / "sparse.gif", every=3)
    with Image.open(out) as image:
        assert image.n_frames == 4  # steps 0, 3, 6 and the last, 8


def test_size_sets_the_width(log_path, tmp_path):
    with Image.open(render(log_path, tmp_path / "small.png", size=320)) as image:
        assert image.width == 320


def test_unknown_format_is_refused(log_path, tmp_path):
    with pytest.raises(RenderError, match="unknown output format '.jpg'"):
        render(log_path, tmp_path / "frame.jpg")


def test_mp4_without_the_video_extra_names_the_install(log_path, tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "imageio", None)
    monkeypatch.setitem(sys.modules, "imageio.v2", None)
    with pytest.raises(RenderError, match=r"pip install -e '\.\[video\]'"):
        render(log_path, tmp_path / "episode.mp4")


def test_mp4_has_one_frame_per_step_with_the_video_extra(log_path, tmp_path):
    imageio = pytest.importorskip("imageio.v2", reason="the video extra (imageio, imageio-ffmpeg) is not installed")
    pytest.importorskip("imageio_ffmpeg", reason="the video extra's imageio-ffmpeg is not installed")
    out = render(log_path, tmp_path / "episode.mp4")
    reader = imageio.get_reader(out)
    try:
        assert reader.get_meta_data()["size"] == (640, 736)
        assert sum(1 for _ in reader) == STEPS + 1
    finally:
        reader.close()
