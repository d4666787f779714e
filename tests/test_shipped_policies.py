"""Every policy shipped in exported/ loads, meets the ONNX contract and has its model card."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from terl_rt import Scenario, Simulator
from terl_rt.policy.onnx_policy import OnnxPolicy, check_contract

EXPORTED = Path(__file__).resolve().parent.parent / "exported"
SHIPPED = sorted(EXPORTED.rglob("*.onnx"))
"""The default policy (exported/terl.onnx) and the equal-budget comparison (exported/comparison/)."""
IDS = [str(path.relative_to(EXPORTED)) for path in SHIPPED]


@pytest.mark.parametrize("path", SHIPPED, ids=IDS)
def test_shipped_policy_meets_the_contract(path):
    report = check_contract(path, strict=True)
    assert report.ok
    assert "terl.training_steps" in report.metadata and "terl.trained_on" in report.metadata


def grid_seed(path: Path) -> tuple[str, str] | None:
    """(method, seed) of a grid's policy, <method>-seed-<S>.onnx (python -m training grid --ship); else None."""
    found = re.fullmatch(r"(.+)-seed-(\d+)", path.stem)
    return (found.group(1), found.group(2)) if found else None


@pytest.mark.parametrize("path", SHIPPED, ids=IDS)
def test_shipped_policy_has_a_model_card(path):
    seed = grid_seed(path)
    card = path.with_name(f"{seed[0]}.md") if seed else path.with_suffix(".md")  # a grid's card: one per method
    assert card.is_file(), f"{path.name} ships without {card.name}"


@pytest.mark.parametrize("path", SHIPPED, ids=IDS)
def test_shipped_policy_acts_on_every_evader_slot_count(path):
    policy = OnnxPolicy(path, threads=1)
    for name in ("small-15", "medium-48", "large-80", "cc-28"):
        observation = Simulator(Scenario.preset(name), seed=0).reset()
        actions = policy.act(observation)
        assert actions.shape == (len(observation.ego),)
        assert np.all((actions >= 0) & (actions < 9))


@pytest.mark.parametrize("path", SHIPPED, ids=IDS)
def test_shipped_policy_is_named_by_its_model_or_its_grid_method_and_seed(path):
    """exported/[comparison/]<model>.onnx names its model (terl.model); a grid's <method>-seed-<S>.onnx
    is tagged with its method and seed, by which the report and the comparison name it (terl.method,
    terl.seed): a method's network may be another's (terl-authors trains the terl network)."""
    policy = OnnxPolicy(path, threads=1)
    seed = grid_seed(path)
    if seed:
        assert (policy.metadata.get("terl.method"), policy.metadata.get("terl.seed")) == seed
    else:
        assert policy.name == path.stem
