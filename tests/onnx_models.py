"""Tiny ONNX test policies built with onnx.helper (no torch), for the runtime's tests.

The test policy is linear, so a test can compute its outputs by hand
(`reference_outputs`):

- pooled features: ego [4] and, per group, the sum of its present tokens
  (mask true) -> [23] = 4 + 7 + 7 + 5;
- q_values [B, 9] = pooled @ W + b;
- target_weights [B, E] = softmax over the present evader slots of
  (evaders @ v), zero on padding slots (all zero when no evader is present).

Every dimension B, P, E, O is dynamic, so one file serves any scenario.
`write_broken_policy` writes variants that break one clause of the contract each;
`write_random_bytes` and `write_truncated_policy` write files that are not ONNX;
`random_observation` makes a well-formed observation of any leading shape.
Models use opset 17 and IR version 9, which onnxruntime >= 1.17 loads.
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

from terl_rt.sim.actions import PURSUER_ACCELERATIONS, PURSUER_ACTIONS, PURSUER_YAW_RATES, action_table
from terl_rt.sim.observation import Observation

OPSET = 17
IR_VERSION = 9
POOLED_FEATURES = 4 + 7 + 7 + 5
"""Width of the pooled feature vector the linear policy reads."""
MASKED_SCORE = -1.0e9
"""Score given to padding evader slots before the softmax."""

DEFECTS = {
    "wrong_input_name": "the 'evaders' input is called 'targets'",
    "extra_input": "an extra input 'memory' [B, 4] beside the contract's five",
    "wrong_input_dtype": "'mask' is float32 instead of bool",
    "wrong_input_rank": "'ego' is [B, 1, 4] instead of [B, 4]",
    "wrong_feature_dim": "'obstacles' has 6 features instead of 5",
    "fixed_batch_dim": "B is fixed to 1 on every input and output",
    "fixed_evader_dim": "E is fixed to 8 on 'evaders' and 'target_weights'",
    "eight_actions": "'q_values' is [B, 8]",
    "missing_q_values": "the Q-value output is called 'q'",
    "wrong_output_dtype": "'q_values' is float64",
    "missing_metadata": "no metadata_props at all",
    "wrong_contract_version": "'terl.contract' is '2'",
    "wrong_action_table": "'terl.pursuer_actions' lists the actions yaw-rate major",
    "missing_model_name": "'terl.model' is absent",
    "bad_hidden_size": "'terl.hidden' is 'big'",
}
"""Defects `write_broken_policy` can write, each breaking one clause of the contract."""


def contract_metadata(*, training_info: bool = True, model: str = "linear-test") -> dict[str, str]:
    """metadata_props of a contract-meeting test policy named `model`; `training_info=False`
    leaves out terl.training_steps and terl.trained_on (a warning, not a refusal)."""
    metadata = {
        "terl.contract": "1",
        "terl.model": model,
        "terl.hidden": str(POOLED_FEATURES),
        "terl.layers": "0",
        "terl.heads": "0",
        "terl.pursuer_actions": json.dumps(PURSUER_ACTIONS.tolist()),
    }
    if training_info:
        metadata["terl.training_steps"] = "0"
        metadata["terl.trained_on"] = "unit-test"
    return metadata


@dataclass(frozen=True)
class LinearWeights:
    """Parameters of the linear test policy."""

    w: np.ndarray
    """[F, A] float32, F pooled features, A actions."""
    b: np.ndarray
    """[A] float32."""
    v: np.ndarray
    """[7] float32 evader score weights."""

    @classmethod
    def from_seed(cls, seed: int) -> LinearWeights:
        rng = np.random.default_rng(seed)
        return cls(
            w=(0.1 * rng.standard_normal((POOLED_FEATURES, 9))).astype(np.float32),
            b=(0.1 * rng.standard_normal(9)).astype(np.float32),
            v=(0.1 * rng.standard_normal(7)).astype(np.float32),
        )


@dataclass(frozen=True)
class _ModelSpec:
    """Everything a test model varies; the defaults meet the contract."""

    weights: LinearWeights
    metadata: Mapping[str, str]
    target_weights: bool = True
    evaders_name: str = "evaders"
    q_name: str = "q_values"
    extra_input: bool = False
    mask_dtype: int = TensorProto.BOOL
    ego_rank3: bool = False
    obstacle_features: int = 5
    batch_dim: str | int = "B"
    evader_dim: str | int = "E"
    q_dtype: int = TensorProto.FLOAT


def _const(name: str, value) -> onnx.NodeProto:
    return helper.make_node("Constant", [], [name], value=numpy_helper.from_array(np.asarray(value), name))


def _build(spec: _ModelSpec) -> onnx.ModelProto:
    b, e = spec.batch_dim, spec.evader_dim
    ego_dims = [b, 1, 4] if spec.ego_rank3 else [b, 4]
    inputs = [
        helper.make_tensor_value_info("ego", TensorProto.FLOAT, ego_dims),
        helper.make_tensor_value_info("teammates", TensorProto.FLOAT, [b, "P", 7]),
        helper.make_tensor_value_info(spec.evaders_name, TensorProto.FLOAT, [b, e, 7]),
        helper.make_tensor_value_info("obstacles", TensorProto.FLOAT, [b, "O", spec.obstacle_features]),
        helper.make_tensor_value_info("mask", spec.mask_dtype, [b, "1+P+E+O"]),
    ]
    if spec.extra_input:
        inputs.append(helper.make_tensor_value_info("memory", TensorProto.FLOAT, [b, 4]))
    num_actions = spec.weights.w.shape[1]
    outputs = [helper.make_tensor_value_info(spec.q_name, spec.q_dtype, [b, num_actions])]
    if spec.target_weights:
        outputs.append(helper.make_tensor_value_info("target_weights", TensorProto.FLOAT, [b, e]))

    ev = spec.evaders_name
    nodes = [
        _const("one", np.array([1], np.int64)),
        _const("axis1", np.array([1], np.int64)),
        _const("last_axis", np.array([-1], np.int64)),
        _const("W", spec.weights.w),
        _const("bias", spec.weights.b),
        _const("v", spec.weights.v.reshape(7, 1)),
        _const("masked_score", np.array(MASKED_SCORE, np.float32)),
        helper.make_node("Cast", ["mask"], ["mask_f"], to=TensorProto.FLOAT),
        # Token counts P, E, O as [1] tensors, then the mask's slice bounds.
        helper.make_node("Shape", ["teammates"], ["P"], start=1, end=2),
        helper.make_node("Shape", [ev], ["E"], start=1, end=2),
        helper.make_node("Shape", ["obstacles"], ["O"], start=1, end=2),
        helper.make_node("Add", ["one", "P"], ["end_t"]),
        helper.make_node("Add", ["end_t", "E"], ["end_e"]),
        helper.make_node("Add", ["end_e", "O"], ["end_o"]),
        helper.make_node("Slice", ["mask_f", "one", "end_t", "axis1"], ["mask_t"]),
        helper.make_node("Slice", ["mask_f", "end_t", "end_e", "axis1"], ["mask_e"]),
        helper.make_node("Slice", ["mask_f", "end_e", "end_o", "axis1"], ["mask_o"]),
    ]
    if spec.ego_rank3:
        nodes.append(helper.make_node("Squeeze", ["ego", "axis1"], ["ego_flat"]))
    else:
        nodes.append(helper.make_node("Identity", ["ego"], ["ego_flat"]))
    pooled = ["ego_flat"]
    for group, group_mask in (("teammates", "mask_t"), (ev, "mask_e"), ("obstacles", "mask_o")):
        nodes += [
            helper.make_node("Unsqueeze", [group_mask, "last_axis"], [f"{group}_m3"]),
            helper.make_node("Mul", [group, f"{group}_m3"], [f"{group}_present"]),
            helper.make_node("ReduceSum", [f"{group}_present", "axis1"], [f"{group}_sum"], keepdims=0),
        ]
        pooled.append(f"{group}_sum")
    if spec.extra_input:
        # Use the extra input so no optimiser drops it: q gains sum(memory) * 0.
        nodes += [
            helper.make_node("ReduceSum", ["memory", "axis1"], ["memory_sum"], keepdims=1),
            _const("zero", np.array(0.0, np.float32)),
            helper.make_node("Mul", ["memory_sum", "zero"], ["memory_zero"]),
        ]
    nodes += [
        helper.make_node("Concat", pooled, ["pooled"], axis=1),
        helper.make_node("MatMul", ["pooled", "W"], ["q_lin"]),
        helper.make_node("Add", ["q_lin", "bias"], ["q_raw"] if not spec.extra_input else ["q_pre"]),
    ]
    if spec.extra_input:
        nodes.append(helper.make_node("Add", ["q_pre", "memory_zero"], ["q_raw"]))
    nodes.append(helper.make_node("Cast", ["q_raw"], [spec.q_name], to=spec.q_dtype))
    if spec.target_weights:
        nodes += [
            helper.make_node("MatMul", [ev, "v"], ["score3"]),
            helper.make_node("Squeeze", ["score3", "last_axis"], ["score"]),
            helper.make_node("Cast", ["mask_e"], ["present_e"], to=TensorProto.BOOL),
            helper.make_node("Where", ["present_e", "score", "masked_score"], ["score_masked"]),
            helper.make_node("Softmax", ["score_masked"], ["softmax"], axis=-1),
            # Zero on padding; an all-padding row (uniform softmax) becomes all zeros.
            helper.make_node("Mul", ["softmax", "mask_e"], ["target_weights"]),
        ]

    graph = helper.make_graph(nodes, "linear_test_policy", inputs, outputs)
    model = helper.make_model(
        graph, opset_imports=[helper.make_opsetid("", OPSET)], producer_name="terl-rt tests"
    )
    model.ir_version = IR_VERSION
    helper.set_model_props(model, dict(spec.metadata))
    onnx.checker.check_model(model, full_check=True)
    return model


def _save(model: onnx.ModelProto, path: str | os.PathLike) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    onnx.save_model(model, str(path))
    return path


def write_test_policy(
    path: str | os.PathLike,
    *,
    target_weights: bool = True,
    seed: int = 0,
    training_info: bool = True,
    model: str = "linear-test",
    metadata: Mapping[str, str] | None = None,
) -> Path:
    """Write the linear test policy (weights `LinearWeights.from_seed(seed)`) to `path`.

    It meets the contract; `target_weights=False` leaves that output out,
    `training_info=False` the training metadata (warnings only); `model` is its
    terl.model name (e.g. "iqn" to stand for a baseline); `metadata` adds keys (e.g.
    terl.method and terl.seed of a comparison's seed). Returns the path.
    """
    spec = _ModelSpec(
        weights=LinearWeights.from_seed(seed),
        metadata={**contract_metadata(training_info=training_info, model=model), **(metadata or {})},
        target_weights=target_weights,
    )
    return _save(_build(spec), path)


def write_constant_policy(
    path: str | os.PathLike, q_values, *, target_weights: bool = False
) -> Path:
    """Write a contract-meeting policy whose q_values are `q_values` [9] for every row
    (W = 0), e.g. with ties to pin down the argmax. Returns the path."""
    bias = np.asarray(q_values, np.float32).reshape(9)
    weights = LinearWeights(np.zeros((POOLED_FEATURES, 9), np.float32), bias, np.zeros(7, np.float32))
    spec = _ModelSpec(weights=weights, metadata=contract_metadata(), target_weights=target_weights)
    return _save(_build(spec), path)


def write_failing_policy(path: str | os.PathLike) -> Path:
    """Write a policy that meets the contract and loads, but whose q-values [B, 9] pass
    through a Reshape to [B * B, -1]: onnxruntime fails on any batch of 2 to 8 rows (9 B
    values cannot make B * B rows). Returns the path."""
    model = _build(_ModelSpec(weights=LinearWeights.from_seed(0), metadata=contract_metadata()))
    cast = next(node for node in model.graph.node if "q_values" in node.output)
    cast.output[0] = "q_any_batch"
    model.graph.node.extend([
        helper.make_node("Shape", ["ego"], ["rows"], start=0, end=1),
        helper.make_node("Mul", ["rows", "rows"], ["rows_squared"]),
        _const("rest", np.array([-1], np.int64)),
        helper.make_node("Concat", ["rows_squared", "rest"], ["squared_shape"], axis=0),
        helper.make_node("Reshape", ["q_any_batch", "squared_shape"], ["q_values"]),
    ])
    return _save(model, path)


def write_broken_policy(path: str | os.PathLike, defect: str) -> Path:
    """Write the linear test policy (seed 0) with one contract defect; see `DEFECTS`:

    wrong_input_name, extra_input, wrong_input_dtype, wrong_input_rank,
    wrong_feature_dim, fixed_batch_dim, fixed_evader_dim, eight_actions,
    missing_q_values, wrong_output_dtype, missing_metadata, wrong_contract_version,
    wrong_action_table, missing_model_name, bad_hidden_size.

    onnxruntime loads every one of them; only the contract check refuses them.
    """
    if defect not in DEFECTS:
        raise ValueError(f"unknown defect {defect!r}; known: {', '.join(DEFECTS)}")
    weights = LinearWeights.from_seed(0)
    metadata = contract_metadata()
    spec = _ModelSpec(weights=weights, metadata=metadata)
    if defect == "wrong_input_name":
        spec = replace(spec, evaders_name="targets")
    elif defect == "extra_input":
        spec = replace(spec, extra_input=True)
    elif defect == "wrong_input_dtype":
        spec = replace(spec, mask_dtype=TensorProto.FLOAT)
    elif defect == "wrong_input_rank":
        spec = replace(spec, ego_rank3=True)
    elif defect == "wrong_feature_dim":
        rng = np.random.default_rng(1)
        w = (0.1 * rng.standard_normal((POOLED_FEATURES + 1, 9))).astype(np.float32)
        spec = replace(spec, obstacle_features=6, weights=replace(weights, w=w))
    elif defect == "fixed_batch_dim":
        spec = replace(spec, batch_dim=1)
    elif defect == "fixed_evader_dim":
        spec = replace(spec, evader_dim=8)
    elif defect == "eight_actions":
        spec = replace(spec, weights=replace(weights, w=weights.w[:, :8].copy(), b=weights.b[:8].copy()))
    elif defect == "missing_q_values":
        spec = replace(spec, q_name="q")
    elif defect == "wrong_output_dtype":
        spec = replace(spec, q_dtype=TensorProto.DOUBLE)
    elif defect == "missing_metadata":
        spec = replace(spec, metadata={})
    elif defect == "wrong_contract_version":
        spec = replace(spec, metadata={**metadata, "terl.contract": "2"})
    elif defect == "wrong_action_table":
        yaw_major = action_table(PURSUER_YAW_RATES, PURSUER_ACCELERATIONS)[:, ::-1]
        spec = replace(spec, metadata={**metadata, "terl.pursuer_actions": json.dumps(yaw_major.tolist())})
    elif defect == "missing_model_name":
        spec = replace(spec, metadata={k: v for k, v in metadata.items() if k != "terl.model"})
    elif defect == "bad_hidden_size":
        spec = replace(spec, metadata={**metadata, "terl.hidden": "big"})
    return _save(_build(spec), path)


def write_random_bytes(path: str | os.PathLike, size: int = 4096, seed: int = 0) -> Path:
    """Write `size` random bytes to `path` (not an ONNX model). Returns the path."""
    path = Path(path)
    path.write_bytes(np.random.default_rng(seed).bytes(size))
    return path


def write_truncated_policy(path: str | os.PathLike, keep: float = 0.5) -> Path:
    """Write the test policy cut to its first `keep` fraction of bytes. Returns the path."""
    path = Path(path)
    write_test_policy(path)
    data = path.read_bytes()
    path.write_bytes(data[: int(len(data) * keep)])
    return path


def reference_outputs(inputs: Mapping[str, np.ndarray], seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """The linear test policy's (q_values [B, 9], target_weights [B, E]) by plain NumPy,
    for contract inputs with one leading axis B."""
    weights = LinearWeights.from_seed(seed)
    ego, mates, evaders, obstacles = (
        np.asarray(inputs[name], np.float64) for name in ("ego", "teammates", "evaders", "obstacles")
    )
    mask = np.asarray(inputs["mask"], bool)
    p, e = mates.shape[1], evaders.shape[1]
    mask_t, mask_e, mask_o = mask[:, 1 : 1 + p], mask[:, 1 + p : 1 + p + e], mask[:, 1 + p + e :]
    pooled = np.concatenate(
        [
            ego,
            (mates * mask_t[..., None]).sum(axis=1),
            (evaders * mask_e[..., None]).sum(axis=1),
            (obstacles * mask_o[..., None]).sum(axis=1),
        ],
        axis=1,
    )
    q_values = pooled @ weights.w + weights.b
    score = np.where(mask_e, evaders @ weights.v, -np.inf)
    target_weights = np.zeros_like(score)
    for row in range(len(score)):
        if mask_e[row].any():
            exp = np.exp(score[row] - score[row].max())
            target_weights[row] = exp / exp.sum()
    return q_values, target_weights


def random_observation(leading: tuple[int, ...] = (4,), *, num_evaders: int = 8, seed: int = 0) -> Observation:
    """A random but well-formed `Observation` with leading shape `leading`: P = O = 5,
    E = `num_evaders`, features ~ N(0, 1) float32, about 70 % of the slots present
    (ego always), pursuer_index counting the rows."""
    rng = np.random.default_rng(seed)

    def features(*shape: int) -> np.ndarray:
        return rng.standard_normal(leading + shape).astype(np.float32)

    mask = rng.random(leading + (1 + 5 + num_evaders + 5,)) < 0.7
    mask[..., 0] = True
    return Observation(
        ego=features(4),
        teammates=features(5, 7),
        evaders=features(num_evaders, 7),
        obstacles=features(5, 5),
        mask=mask,
        pursuer_index=np.arange(int(np.prod(leading)), dtype=np.int64).reshape(leading),
    )
