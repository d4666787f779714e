"""Loading exported policies, the contract check, and acting (policy.md section 3)."""

from __future__ import annotations

import dataclasses
import re
import hashlib
import subprocess
import sys
from pathlib import Path

import numpy as np
import onnxruntime as ort
import pytest
from onnx_models import (
    DEFECTS,
    random_observation,
    reference_outputs,
    write_broken_policy,
    write_constant_policy,
    write_random_bytes,
    write_test_policy,
    write_truncated_policy,
)

from terl_rt.policy.onnx_policy import (
    ContractError,
    OnnxPolicy,
    PolicyOutput,
    action_to_control,
    check_contract,
    open_session,
)

REPO_ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def policy_path(tmp_path_factory) -> Path:
    return write_test_policy(tmp_path_factory.mktemp("policy") / "linear.onnx")


@pytest.fixture(scope="module")
def policy(policy_path) -> OnnxPolicy:
    return OnnxPolicy(policy_path)


def flat_inputs(observation, num_rows: int) -> dict[str, np.ndarray]:
    """Contract inputs with the leading dims flattened to [num_rows]."""
    return {
        name: array.reshape((num_rows,) + array.shape[observation.ego.ndim - 1 :])
        for name, array in observation.as_inputs().items()
    }


# --- the contract ------------------------------------------------------------


def test_test_policy_meets_contract(policy_path):
    report = check_contract(policy_path)
    assert report.ok
    assert not report.warnings
    assert report.has_target_weights
    assert "[fail]" not in report.format()


def test_check_contract_accepts_an_open_session(policy_path):
    assert check_contract(open_session(policy_path), strict=True).ok


def test_missing_training_info_is_a_warning_not_a_refusal(tmp_path):
    path = write_test_policy(tmp_path / "p.onnx", training_info=False)
    report = check_contract(path, strict=True)
    assert report.ok
    warned = " ".join(check.detail for check in report.warnings)
    assert "terl.training_steps" in warned and "terl.trained_on" in warned
    assert OnnxPolicy(path).name == "linear-test"


REFUSALS = {
    "wrong_input_name": "missing input 'evaders'",
    "extra_input": "unexpected input(s) 'memory'",
    "wrong_input_dtype": "input 'mask' has dtype float32, the contract says bool",
    "wrong_input_rank": "input 'ego' has rank 3",
    "wrong_feature_dim": "input 'obstacles' has 6 features on axis 2, the contract says 5",
    "fixed_batch_dim": "dimension B of 'ego' is fixed to 1; the contract needs it dynamic",
    "fixed_evader_dim": "dimension E of 'evaders' is fixed to 8; the contract needs it dynamic",
    "eight_actions": "output 'q_values' has 8 actions, the contract says 9",
    "missing_q_values": "missing output 'q_values'",
    "wrong_output_dtype": "output 'q_values' has dtype float64, the contract says float32",
    "missing_metadata": "metadata 'terl.contract' is missing",
    "wrong_contract_version": "metadata 'terl.contract' is '2', this runtime reads contract 1",
    "wrong_action_table": (
        "metadata 'terl.pursuer_actions' differs from the runtime's pursuer action table at action 1"
    ),
    "missing_model_name": "metadata 'terl.model' is missing",
    "bad_hidden_size": "metadata 'terl.hidden' is 'big', the contract needs an integer",
}


def test_every_documented_defect_has_a_refusal_test():
    assert set(REFUSALS) == set(DEFECTS)


@pytest.mark.parametrize("defect", sorted(REFUSALS))
def test_contract_refuses_defect_with_its_message(tmp_path, defect):
    path = write_broken_policy(tmp_path / f"{defect}.onnx", defect)
    report = check_contract(path)
    assert not report.ok
    assert report.failures[0].detail.startswith(REFUSALS[defect])
    with pytest.raises(ContractError, match="^" + re.escape(REFUSALS[defect])):
        check_contract(path, strict=True)
    with pytest.raises(ContractError, match=re.escape(REFUSALS[defect])):
        OnnxPolicy(path)


def test_strict_refusal_carries_the_full_report(tmp_path):
    path = write_broken_policy(tmp_path / "b.onnx", "fixed_batch_dim")
    with pytest.raises(ContractError) as caught:
        check_contract(path, strict=True)
    assert "more contract problem(s)" in str(caught.value)
    assert len(caught.value.report.failures) > 1


def test_unknown_defect_is_rejected_by_the_builder(tmp_path):
    with pytest.raises(ValueError, match="unknown defect"):
        write_broken_policy(tmp_path / "x.onnx", "no_such_defect")


# --- loading ---------------------------------------------------------------------


def test_missing_file_raises_file_not_found_naming_the_path(tmp_path):
    path = tmp_path / "absent.onnx"
    with pytest.raises(FileNotFoundError, match="absent.onnx"):
        OnnxPolicy(path)
    with pytest.raises(FileNotFoundError, match="absent.onnx"):
        check_contract(path)


@pytest.mark.parametrize("writer", [write_random_bytes, write_truncated_policy], ids=["random", "truncated"])
def test_unreadable_file_raises_contract_error(tmp_path, writer):
    path = writer(tmp_path / "bad.onnx")
    with pytest.raises(ContractError, match="bad.onnx is not a readable ONNX model"):
        OnnxPolicy(path)


def test_empty_file_raises_contract_error(tmp_path):
    path = tmp_path / "empty.onnx"
    path.write_bytes(b"")
    with pytest.raises(ContractError, match="not a readable ONNX model"):
        OnnxPolicy(path)


def test_policy_properties(policy, policy_path):
    assert policy.path == policy_path
    assert policy.name == "linear-test"
    assert policy.metadata["terl.contract"] == "1"
    assert policy.has_target_weights
    assert policy.sha256 == hashlib.sha256(policy_path.read_bytes()).hexdigest()


@pytest.mark.parametrize("threads", [1, 2])
def test_threads_option_is_accepted_and_does_not_change_outputs(policy, policy_path, threads):
    observation = random_observation((16,), seed=3)
    threaded = OnnxPolicy(policy_path, threads=threads).evaluate(observation)
    np.testing.assert_array_equal(threaded.q_values, policy.evaluate(observation).q_values)


@pytest.mark.parametrize("threads", [0, -1, 1.5, True])
def test_invalid_threads_are_rejected(policy_path, threads):
    with pytest.raises(ValueError, match="threads"):
        OnnxPolicy(policy_path, threads=threads)


# --- acting ------------------------------------------------------------------------


def test_act_on_rows_is_argmax_of_reference_q_values(policy):
    observation = random_observation((7,), seed=1)
    q_values, target_weights = reference_outputs(observation.as_inputs())
    output = policy.evaluate(observation)
    assert output.q_values.shape == (7, 9) and output.q_values.dtype == np.float32
    np.testing.assert_allclose(output.q_values, q_values, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(output.target_weights, target_weights, rtol=1e-5, atol=1e-6)
    assert output.actions.dtype == np.int64
    np.testing.assert_array_equal(policy.act(observation), np.argmax(q_values, axis=-1))


def test_act_on_batched_leading_dims_matches_flat_rows(policy):
    observation = random_observation((3, 4), num_evaders=14, seed=2)
    output = policy.evaluate(observation)
    flat = policy.evaluate(flat_inputs(observation, 12))
    assert output.q_values.shape == (3, 4, 9)
    assert output.target_weights.shape == (3, 4, 14)
    assert output.actions.shape == (3, 4)
    np.testing.assert_array_equal(output.q_values.reshape(12, 9), flat.q_values)
    np.testing.assert_array_equal(output.actions.reshape(12), flat.actions)


def test_single_observation_without_leading_dims(policy):
    batch = random_observation((1,), seed=4)
    single = {name: array[0] for name, array in batch.as_inputs().items()}
    output = policy.evaluate(single)
    assert output.q_values.shape == (9,) and output.actions.shape == ()
    np.testing.assert_array_equal(output.q_values, policy.evaluate(batch).q_values[0])


def test_all_rows_go_to_onnxruntime_in_one_call(policy, monkeypatch):
    calls = []
    run = ort.InferenceSession.run

    def counting_run(self, *args, **kwargs):
        calls.append(args[1]["ego"].shape)
        return run(self, *args, **kwargs)

    monkeypatch.setattr(ort.InferenceSession, "run", counting_run)
    policy.act(random_observation((5, 6)))
    assert calls == [(30, 4)]


@pytest.mark.parametrize("num_evaders", [8, 14, 20])
def test_one_model_serves_every_evader_count(policy, num_evaders):
    observation = random_observation((6,), num_evaders=num_evaders, seed=num_evaders)
    q_values, target_weights = reference_outputs(observation.as_inputs())
    output = policy.evaluate(observation)
    assert output.target_weights.shape == (6, num_evaders)
    np.testing.assert_allclose(output.q_values, q_values, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(output.target_weights, target_weights, rtol=1e-5, atol=1e-6)


def test_target_weights_are_zero_on_padding_and_sum_to_one(policy):
    observation = random_observation((20,), num_evaders=8, seed=5)
    present = observation.mask[:, 6:14]
    weights = policy.evaluate(observation).target_weights
    assert np.all(weights[~present] == 0.0)
    rows_with_evaders = present.any(axis=1)
    np.testing.assert_allclose(weights[rows_with_evaders].sum(axis=1), 1.0, rtol=1e-5)


def test_policy_without_target_selection_returns_none(tmp_path):
    policy = OnnxPolicy(write_test_policy(tmp_path / "p.onnx", target_weights=False))
    assert not policy.has_target_weights
    assert policy.evaluate(random_observation((3,))).target_weights is None


def test_ties_resolve_to_the_first_action(tmp_path):
    # q = [0, 1, 3, 3, 0, 3, 2, 2, 3] for every row: the maximum 3 first appears at 2.
    path = write_constant_policy(tmp_path / "ties.onnx", [0, 1, 3, 3, 0, 3, 2, 2, 3])
    actions = OnnxPolicy(path).act(random_observation((4,)))
    np.testing.assert_array_equal(actions, [2, 2, 2, 2])


@pytest.mark.parametrize("leading", [(0,), (0, 3), (2, 0)])
def test_empty_observation_gives_empty_outputs_without_running(policy, monkeypatch, leading):
    def must_not_run(*args, **kwargs):
        raise AssertionError("onnxruntime was called for an empty observation")

    monkeypatch.setattr(ort.InferenceSession, "run", must_not_run)
    output = policy.evaluate(random_observation(leading, num_evaders=8))
    assert output.q_values.shape == leading + (9,) and output.q_values.dtype == np.float32
    assert output.target_weights.shape == leading + (8,)
    assert output.actions.shape == leading and output.actions.dtype == np.int64


def test_same_observation_gives_identical_outputs(policy):
    observation = random_observation((64,), num_evaders=20, seed=6)
    first, second = policy.evaluate(observation), policy.evaluate(observation)
    np.testing.assert_array_equal(first.q_values, second.q_values)
    np.testing.assert_array_equal(first.target_weights, second.target_weights)
    np.testing.assert_array_equal(first.actions, second.actions)


def test_float64_and_integer_features_are_converted(policy):
    observation = random_observation((3,), seed=7)
    widened = dataclasses.replace(
        observation,
        ego=observation.ego.astype(np.float64),
        obstacles=np.zeros(observation.obstacles.shape, np.int64),
    )
    converted = dataclasses.replace(observation, obstacles=np.zeros(observation.obstacles.shape, np.float32))
    np.testing.assert_array_equal(policy.evaluate(widened).q_values, policy.evaluate(converted).q_values)


# --- observation checks ----------------------------------------------------------


@pytest.mark.parametrize("group", ["ego", "teammates", "evaders", "obstacles"])
@pytest.mark.parametrize("bad_value", [np.nan, np.inf])
def test_non_finite_feature_is_refused_naming_group_and_row(policy, group, bad_value):
    observation = random_observation((2, 3), seed=8)
    array = getattr(observation, group).copy()
    array[1, 2, ..., 0] = bad_value
    with pytest.raises(ValueError, match=rf"^{group} has a non-finite value .* row \(1, 2\)"):
        policy.act(dataclasses.replace(observation, **{group: array}))


def test_non_finite_value_on_flat_rows_names_the_row(policy):
    observation = random_observation((5,), seed=9)
    evaders = observation.evaders.copy()
    evaders[3, 6, 4] = np.nan
    with pytest.raises(ValueError, match=r"evaders .* row 3 \(slot 6, feature 4\)"):
        policy.act(dataclasses.replace(observation, evaders=evaders))


def _with(observation, **changes):
    return dataclasses.replace(observation, **changes)


BAD_SHAPES = {
    "teammate rows differ": (lambda o: _with(o, teammates=o.teammates[:3]), "teammates has leading shape"),
    "evader features": (
        lambda o: _with(o, evaders=o.evaders[..., :6]),
        r"evaders has shape .* expected \[\.\.\., slots, 7\]",
    ),
    "ego features": (lambda o: _with(o, ego=o.ego[..., :3]), "ego has shape"),
    "mask too short": (lambda o: _with(o, mask=o.mask[..., :-1]), r"mask has shape .* 1 \+ P \+ E \+ O"),
    "mask rows differ": (lambda o: _with(o, mask=o.mask[:2]), "mask has shape"),
    "mask not bool": (
        lambda o: _with(o, mask=o.mask.astype(np.int64)),
        "mask has dtype int64, the contract says bool",
    ),
    "string features": (lambda o: _with(o, ego=o.ego.astype(str)), "ego has dtype"),
}


@pytest.mark.parametrize("case", sorted(BAD_SHAPES))
def test_inconsistent_observation_is_refused(policy, case):
    change, message = BAD_SHAPES[case]
    with pytest.raises(ValueError, match=message):
        policy.act(change(random_observation((4,), seed=10)))


def test_observation_missing_a_group_is_refused(policy):
    inputs = random_observation((2,)).as_inputs()
    del inputs["obstacles"]
    with pytest.raises(ValueError, match="observation lacks obstacles"):
        policy.act(inputs)


# --- controls ---------------------------------------------------------------------


def test_action_to_control_follows_the_pursuer_table():
    # index = i_a * 3 + i_w with a in (-0.4, 0, 0.4) m/s^2 and w in (-pi/6, 0, pi/6) rad/s.
    controls = action_to_control(np.array([0, 4, 5, 8, 6]))
    expected = [[-0.4, -np.pi / 6], [0.0, 0.0], [0.0, np.pi / 6], [0.4, np.pi / 6], [0.4, -np.pi / 6]]
    np.testing.assert_allclose(controls, expected)


def test_action_to_control_keeps_leading_dims():
    actions = np.arange(9).reshape(3, 3)
    controls = OnnxPolicy.action_to_control(actions)
    assert controls.shape == (3, 3, 2)
    np.testing.assert_allclose(controls[2, 1], [0.4, 0.0])


@pytest.mark.parametrize("actions", [[9], [-1], [0.0]])
def test_action_to_control_rejects_bad_indices(actions):
    with pytest.raises(ValueError, match="actions"):
        action_to_control(np.array(actions))


# --- dependencies -------------------------------------------------------------------


def test_importing_the_policy_module_loads_neither_torch_nor_onnx():
    code = (
        "import sys, terl_rt.policy.onnx_policy, terl_rt.policy.contract; "
        "print(sorted(m for m in ('torch', 'onnx') if m in sys.modules))"
    )
    result = subprocess.run(
        [sys.executable, "-c", code], cwd=REPO_ROOT, capture_output=True, text=True, check=True
    )
    assert result.stdout.strip() == "[]"


def test_first_non_finite_names_the_output_its_row_and_the_value():
    # Row 1 of q_values holds inf; target_weights' NaN comes later in the order checked.
    output = PolicyOutput(q_values=np.array([[0.0, 1.0], [2.0, np.inf]], np.float32),
                          target_weights=np.array([[np.nan], [0.0]], np.float32), actions=np.array([1, 0]))
    assert output.first_non_finite() == ("q_values", 1, np.inf)
    name, row, value = dataclasses.replace(output, q_values=np.zeros((2, 2), np.float32)).first_non_finite()
    assert (name, row, np.isnan(value)) == ("target_weights", 0, True)
    assert dataclasses.replace(output, target_weights=None, q_values=np.zeros((2, 2))).first_non_finite() is None
