"""The exported-policy contract, version 1 (policy.md section 3): the one home of its
input and output names, feature widths, metadata keys and version, and of the plain
description of a model's tensors (`TensorInfo`) that its checks (terl_rt.policy.checks) read.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

from terl_rt.sim.actions import NUM_PURSUER_ACTIONS
from terl_rt.sim.observation import (  # the observation layout is the simulator's; the contract names it
    EGO_FEATURES, EVADER_FEATURES, INPUT_NAMES, OBSTACLE_FEATURES, TEAMMATE_FEATURES,
)

if TYPE_CHECKING:
    from terl_rt.policy.checks import ContractReport

CONTRACT_VERSION = "1"
"""The contract version this runtime reads. Revision 1.1 added the optional output
`quantiles`; files with it keep `terl.contract` "1" (runtimes before it warn of an extra
output and ignore it), files without it keep working (docs/policy.md)."""
NUM_QUANTILES = 32
"""K: the fixed quantile fractions tau_k = (k + 0.5) / K of the `quantiles` output and of
`q_values`, their mean."""

META_CONTRACT = "terl.contract"
"""Metadata key: contract version, "1"."""
META_MODEL = "terl.model"
"""Metadata key: model name (the network family, e.g. "terl", "iqn", "dqn")."""
META_HIDDEN = "terl.hidden"
"""Metadata key: hidden size H, a positive integer."""
META_LAYERS = "terl.layers"
"""Metadata key: transformer layers L, an integer >= 0 (0 for bodies without one)."""
META_HEADS = "terl.heads"
"""Metadata key: attention heads h, an integer >= 0 (0 for bodies without attention)."""
META_PURSUER_ACTIONS = "terl.pursuer_actions"
"""Metadata key: JSON list of 9 [acceleration m/s^2, yaw rate rad/s] pairs."""
META_TRAINING_STEPS = "terl.training_steps"
"""Metadata key (reported, optional): environment steps trained, an integer >= 0."""
META_TRAINED_ON = "terl.trained_on"
"""Metadata key (reported, optional): the scenario set trained on."""
META_TRAINING_CONFIG = "terl.training_config"
"""Metadata key (reported, optional): JSON of the training config (its "seed": the training seed)."""
META_METHOD = "terl.method"
"""Metadata key (reported, optional): the recipe stem of a comparison's method (terl, iqn,
dqn, mean, terl-no-re, terl-no-ts); files exported/comparison/<method>-seed-<S>.onnx."""
META_SEED = "terl.seed"
"""Metadata key (reported, optional): the training seed of a comparison's policy, an integer."""

ACTION_TABLE_TOLERANCE = 1e-6
"""Largest difference allowed between the model's action table and PURSUER_ACTIONS."""

# ONNX tensor element types as onnxruntime names them, in numpy spelling.
_ORT_DTYPES = {
    "tensor(float)": "float32",
    "tensor(double)": "float64",
    "tensor(float16)": "float16",
    "tensor(bfloat16)": "bfloat16",
    "tensor(bool)": "bool",
    "tensor(int8)": "int8",
    "tensor(int16)": "int16",
    "tensor(int32)": "int32",
    "tensor(int64)": "int64",
    "tensor(uint8)": "uint8",
    "tensor(uint16)": "uint16",
    "tensor(uint32)": "uint32",
    "tensor(uint64)": "uint64",
    "tensor(string)": "string",
}


class ContractError(ValueError):
    """A model breaks the exported-policy contract; the message says how.

    `report` holds the full `ContractReport` when the error came from one.
    """

    report: ContractReport | None = None


class ContractWarning(UserWarning):
    """A model meets the contract but leaves out something worth reporting."""


@dataclass(frozen=True)
class TensorSpec:
    """What the contract asks of one input or output.

    `dims` gives one entry per axis: a string names a dimension that must be
    dynamic (B, P, E, O, ...), an integer a dimension that must be exactly that.
    """

    name: str
    dtype: str
    dims: tuple[str | int, ...]
    required: bool = True


INPUTS = (
    TensorSpec("ego", "float32", ("B", EGO_FEATURES)),
    TensorSpec("teammates", "float32", ("B", "P", TEAMMATE_FEATURES)),
    TensorSpec("evaders", "float32", ("B", "E", EVADER_FEATURES)),
    TensorSpec("obstacles", "float32", ("B", "O", OBSTACLE_FEATURES)),
    TensorSpec("mask", "bool", ("B", "1+P+E+O")),
)
"""Contract inputs, in the order of `Observation.as_inputs()` (INPUT_NAMES)."""

OUTPUTS = (
    TensorSpec("q_values", "float32", ("B", NUM_PURSUER_ACTIONS)),
    TensorSpec("target_weights", "float32", ("B", "E"), required=False),
    TensorSpec("quantiles", "float32", ("B", NUM_QUANTILES, NUM_PURSUER_ACTIONS), required=False),
)
"""Contract outputs; target_weights only for models with target selection, quantiles
[B, K, 9] (each action's return at the fractions tau_k, q_values their mean) only for
models with a distributional (IQN) head that export them (contract revision 1.1)."""


@dataclass(frozen=True)
class TensorInfo:
    """One model input or output as the model declares it.

    `shape` has one entry per axis: an int for a fixed size, a string for a
    named dynamic dimension, None for an unnamed dynamic one; `shape` is None
    when the model does not declare the rank.
    """

    name: str
    dtype: str
    shape: tuple[int | str | None, ...] | None

    @classmethod
    def from_node_arg(cls, arg) -> TensorInfo:
        """From an onnxruntime NodeArg (`session.get_inputs()[i]`)."""
        dtype = _ORT_DTYPES.get(arg.type, arg.type)
        shape = None if arg.shape is None else tuple(arg.shape)
        return cls(arg.name, dtype, shape)

    def describe(self) -> str:
        """e.g. "float32 [B, E, 7]"."""
        if self.shape is None:
            return f"{self.dtype} [rank unknown]"
        dims = ", ".join("?" if dim is None else str(dim) for dim in self.shape)
        return f"{self.dtype} [{dims}]"
