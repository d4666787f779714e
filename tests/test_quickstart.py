"""The training quick start (experiments/quickstart): a config the trainer accepts, as the README runs it."""

from __future__ import annotations

from pathlib import Path

import pytest

pytest.importorskip("torch")

from training.config import Config  # noqa: E402

QUICKSTART = Path(__file__).resolve().parents[1] / "experiments" / "quickstart" / "small-15.json"


def test_the_quick_start_recipe_is_a_valid_config_checkpointing_every_10k_steps():
    config = Config.from_file(QUICKSTART)
    assert (config.model, config.hidden, config.layers, config.heads) == ("terl", 64, 2, 4)
    assert config.scenario == "small-15" and config.curriculum
    assert config.checkpoint_frequency == 10_000 and config.snapshot_preset == "small-15"
    assert config.total_steps == 200_000
