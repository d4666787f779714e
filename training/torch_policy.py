"""A torch Q-network behind the policy interface that terl_rt.evaluation runs: training's
snapshots are measured by the same evaluator, on the same episodes (episode k with seed + k),
as `terl-rt eval` measures an exported ONNX policy.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path

import numpy as np
import torch

from terl_rt.policy.contract import INPUT_NAMES
from terl_rt.policy.inputs import observation_inputs
from terl_rt.policy.onnx_policy import PolicyOutput
from terl_rt.sim.observation import Observation
from training.networks import QNetwork


def network_device(model: QNetwork) -> torch.device:
    """The device of a network's weights."""
    return next(model.parameters()).device


def as_tensors(arrays: Mapping[str, np.ndarray], device: torch.device | str = "cpu") -> tuple[torch.Tensor, ...]:
    """Observation arrays as torch tensors on `device` (no copy on the CPU), in the network's call order."""
    return tuple(torch.from_numpy(np.asarray(arrays[key])).to(device, non_blocking=True) for key in INPUT_NAMES)


class TorchPolicy:
    """`model` (eval mode, no gradients) answering as OnnxPolicy does: `evaluate` gives the
    Q-values [..., 9], target weights [..., E] (None for bodies without target selection) and
    greedy actions [...] of observations with any leading shape `...`."""

    def __init__(self, model: QNetwork, path: str = "<torch network>") -> None:
        self.model = model
        self.path = Path(path)
        """What error messages call the policy (it has no file)."""

    @property
    def name(self) -> str:
        """The network's registry name (as an exported file's `terl.model`)."""
        return self.model.model_name

    def evaluate(self, observation: Observation | Mapping[str, np.ndarray]) -> PolicyOutput:
        """One forward of every row of `observation` (checked as OnnxPolicy checks it)."""
        inputs, leading = observation_inputs(observation)
        rows = math.prod(leading)
        flat = {name: np.ascontiguousarray(array.reshape((rows,) + array.shape[len(leading):])) for name, array in inputs.items()}
        self.model.eval()
        with torch.inference_mode():
            q_values, target_weights = self.model.policy_outputs(*as_tensors(flat, network_device(self.model)))
        q_values = q_values.float().cpu().numpy()
        weights = None if target_weights is None else target_weights.float().cpu().numpy().reshape(leading + (-1,))
        return PolicyOutput(
            q_values=q_values.reshape(leading + q_values.shape[1:]),
            target_weights=weights,
            actions=q_values.argmax(axis=-1).astype(np.int64).reshape(leading),
        )

    def act(self, observation: Observation | Mapping[str, np.ndarray]) -> np.ndarray:
        """Greedy pursuer actions [...] int64."""
        return self.evaluate(observation).actions
