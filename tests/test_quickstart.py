"""The training quick start docs/train.md runs: the first segment of recipes/terl-paper.toml."""

from __future__ import annotations

from pathlib import Path

import pytest

pytest.importorskip("torch")

from training.lab.recipe import load_recipe  # noqa: E402

RECIPE = Path(__file__).resolve().parents[1] / "recipes" / "terl-paper.toml"


def test_the_quick_start_is_the_small_terl_on_the_curriculum_with_checkpoints_and_snapshots():
    first = load_recipe(RECIPE).segments[0].config
    network, schedule, run = first.network, first.schedule, first.run
    assert (network.model, network.hidden, network.layers, network.heads) == ("terl", 64, 2, 4)
    assert schedule.curriculum and schedule.total_steps == 200_000 and schedule.train_max_steps == 500
    assert run.checkpoint_frequency <= 20_000 and run.snapshot_frequency and run.snapshot_preset == "small-15"
