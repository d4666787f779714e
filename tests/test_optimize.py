"""`terl-rt optimize` (issue 40): variants of a policy are offered only when they decide as it does."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner
from onnx_models import write_test_policy

from terl_rt.cli.main import cli
from terl_rt.evaluation import optimize
from terl_rt.policy.onnx_policy import OnnxPolicy
from terl_rt.evaluation.optimize import VariantCheck, check_variant, record_observations
from terl_rt.sim.scenario import Scenario
from terl_rt.sim.world import World

pytest.importorskip("onnx")


@pytest.fixture(scope="module")
def policy(tmp_path_factory) -> OnnxPolicy:
    return OnnxPolicy(write_test_policy(tmp_path_factory.mktemp("optimize") / "linear.onnx", seed=0))


def test_recorded_observations_hold_the_deciding_pursuers_of_every_kept_step(policy):
    (recorded,) = record_observations(policy, [Scenario.preset("small-11")], seed=0, envs=2, steps=6, every=3)
    assert recorded.ego.shape == (2 * 2 * 11, 4)  # steps 0 and 3, 2 worlds of 11 pursuers, none collided yet


def test_a_variant_with_the_float_graphs_operators_is_not_offered(policy):
    same = OnnxPolicy(policy.path, model=policy.model)
    check = check_variant("copy", same, policy, [], [], 1, 0)
    assert check == VariantCheck("copy", False, "changed", check.detail)


def test_a_variant_that_decides_otherwise_is_not_offered(policy, tmp_path):
    # Other weights, and no target weights: other operators, other greedy actions.
    other = OnnxPolicy(write_test_policy(tmp_path / "other.onnx", seed=3, target_weights=False))
    recorded = record_observations(policy, [Scenario.preset("small-11")], seed=0, envs=1, steps=2, every=1)
    check = check_variant("other", other, policy, recorded, [], 1, 0)
    assert (check.passed, check.failed_check) == (False, "decisions") and check.agreement < 0.995


def test_optimize_writes_nothing_when_no_variant_passes(policy, tmp_path, monkeypatch):
    # A "fused" variant that is another policy (other weights, no target weights) decides otherwise.
    monkeypatch.setitem(optimize.VARIANTS, "fused", lambda source, target, recorded: write_test_policy(
        target, seed=3, target_weights=False))
    out = tmp_path / "fast.onnx"
    result = CliRunner().invoke(cli, ["optimize", str(policy.path), "-o", str(out), "--variant", "fused",
                                      "--scenario", "small-11", "--episodes", "1", "--json"])
    assert result.exit_code == 1, result.output
    (variant,) = json.loads(result.stdout)["variants"]
    assert (variant["name"], variant["passed"], variant["failed_check"]) == ("fused", False, "decisions")
    assert not out.exists()


def test_flops_count_every_matrix_product_of_a_row(policy):
    # The linear test policy: pooled [R, 23] @ W [23, 9], and evaders [R, E, 7] @ v [7, 1] for
    # the target weights: 2 * 23 * 9 + 2 * E * 7 FLOPs a row.
    from terl_rt.policy.flops import flops_per_row

    scenario = Scenario.preset("small-11")
    observation = World(scenario, num_envs=1, seed=0).reset().rows(np.arange(11))
    assert flops_per_row(policy, observation) == 2 * 23 * 9 + 2 * scenario.evader_slots * 7
