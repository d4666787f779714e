"""Risk-aware acting (terl_rt.safety.risk) and the contract's optional output quantiles."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest
from click.testing import CliRunner
from onnx_models import random_observation, write_test_policy

from terl_rt.cli.main import cli
from terl_rt.policy.onnx_policy import OnnxPolicy, PolicyOutput, check_contract
from terl_rt.policy.shipped import open_policy
from terl_rt.safety.acting import Acting
from terl_rt.safety.risk import Risk
from terl_rt.sim.params import WorldParams


def test_cvar_keeps_the_lowest_alpha_share_of_32_quantiles():
    assert (Risk.parse("cvar:0.25").kept(32), Risk.parse("cvar:1").kept(32), Risk.parse("cvar:0.01").kept(32)) == (8, 32, 1)
    # Quantiles 0..31 of one action, shuffled: CVaR at 0.25 is the mean of 0..7, 3.5.
    quantiles = np.zeros((1, 32, 9), np.float32)
    quantiles[0, :, 4] = np.random.default_rng(0).permutation(32)
    assert Risk(0.25).values(quantiles)[0, 4] == pytest.approx(3.5)


@pytest.mark.parametrize("text", ["cvar", "cvar:", "cvar:0", "cvar:1.5", "cvar:nan", "var:0.5", "cvar:x"])
def test_a_risk_that_does_not_parse_is_refused_in_one_line(text):
    with pytest.raises(ValueError, match="^risk: ") as error:
        Risk.parse(text)
    assert "\n" not in str(error.value)


@dataclass
class TwoActions:
    """A policy whose action 0 has the better mean and action 1 the better lower tail."""

    name = "two-actions"
    path = "<two-actions>"
    has_quantiles = True

    def evaluate(self, observation, quantiles: bool = False) -> PolicyOutput:
        rows = len(observation.ego)
        values = np.full((rows, 32, 9), -100.0, np.float32)
        values[:, :, 0] = np.linspace(-40.0, 60.0, 32)  # mean 10, worst quarter about -28
        values[:, :, 1] = 5.0  # mean 5, no spread
        return PolicyOutput(q_values=values.mean(axis=1), target_weights=None, actions=np.zeros(rows, np.int64),
                            quantiles=values if quantiles else None)


def test_cvar_acting_prefers_the_action_of_the_better_lower_tail():
    observation = random_observation((3,))
    greedy = Acting().act(TwoActions(), observation, WorldParams())
    careful = Acting(risk=Risk(0.25)).act(TwoActions(), observation, WorldParams())
    assert greedy.actions.tolist() == [0, 0, 0] and careful.actions.tolist() == [1, 1, 1]
    assert careful.overridden is None  # no shield, no override


def test_shipped_policy_gives_quantiles_whose_mean_is_its_q_values_unchanged():
    policy = open_policy("terl")
    observation = random_observation((6,), num_evaders=8)
    plain, asked = policy.evaluate(observation), policy.evaluate(observation, quantiles=True)
    assert policy.has_quantiles and asked.quantiles.shape == (6, 32, 9) and plain.quantiles is None
    assert np.array_equal(plain.q_values, asked.q_values)  # bit for bit
    np.testing.assert_allclose(asked.quantiles.mean(axis=1), asked.q_values, atol=1e-3)
    assert any(c.name == "output 'quantiles'" and c.status == "pass" for c in policy.report.checks)


def test_a_policy_without_quantiles_still_loads_and_refuses_risk_in_one_line(tmp_path):
    path = write_test_policy(tmp_path / "linear.onnx")
    policy = OnnxPolicy(path)
    assert not policy.has_quantiles
    assert any(c.detail == "absent (optional)" and "quantiles" in c.name for c in check_contract(path).checks)
    with pytest.raises(ValueError, match="has no quantiles output"):
        policy.evaluate(random_observation((2,)), quantiles=True)
    out = CliRunner().invoke(cli, ["eval", "--policy", str(path), "--episodes", "1", "--risk", "cvar:0.25"])
    assert out.exit_code == 2 and out.output.count("\n") == 1 and "has no quantiles output" in out.output


def test_eval_risk_reaches_the_results():
    out = CliRunner().invoke(cli, ["eval", "--scenario", "small-11", "--episodes", "1", "--max-steps", "5",
                                   "--risk", "cvar:0.5", "--json"])
    assert out.exit_code == 0, out.output
    assert '"risk": "cvar:0.5"' in out.output and '"label": "cvar:0.5"' in out.output
