"""Export a trained Q-network as one ONNX policy (policy.md section 3, contract version 1).

The graph is traced in eval mode with the legacy TorchScript exporter (opset 23):
inputs ego/teammates/evaders/obstacles float32 and mask bool with dynamic B, P, E
and O; outputs q_values [B, 9] (mean of the quantiles at the fixed fractions
(k + 0.5) / 32, folded into the graph), for models with target selection
target_weights [B, E], and for models with a distributional (IQN) head those quantiles
themselves, [B, 32, 9] (contract revision 1.1). `export_onnx` checks the file with
onnx.checker and then compares it with the torch model by `check_parity`. `reexport_onnx`
writes an exported policy again from the weights inside it, with this exporter's graph;
`with_quantiles` gives an older file the quantiles output and changes nothing else.
"""

from __future__ import annotations

import functools
import hashlib
import json
import warnings
from collections.abc import Iterator, Mapping
from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort
import torch
from torch import nn

from terl_rt.files import atomic_output
from terl_rt.policy.contract import (
    CONTRACT_VERSION,
    INPUT_NAMES,
    INPUTS,
    META_CONTRACT,
    META_HEADS,
    META_HIDDEN,
    META_LAYERS,
    META_MODEL,
    META_PURSUER_ACTIONS,
    NUM_QUANTILES,
    OUTPUTS,
)
from terl_rt.sim.actions import PURSUER_ACTIONS
from terl_rt.sim.scenario import PAPER_SUITE, Scenario
from terl_rt.sim.simulator import Simulator
from training.networks.encoders import QNetwork, fixed_fractions
from training.onnx_weights import network_from_onnx

OPSET = 23
"""ONNX opset the policies are written with: 23 for the `Attention` op the transformer
layers export as (training/networks/terl.py), which onnxruntime runs on CPU from 1.23 on."""
META_REEXPORTED_FROM = "terl.reexported_from"
"""Metadata key of a re-exported policy: the sha256 of the file its weights came from."""
PARITY_TOLERANCE = 1e-4
"""Largest torch-onnxruntime difference `check_parity` accepts, relative to the output's
largest magnitude when that is above 1 (float32 round-off grows with the values: a
trained policy's Q-values are in the hundreds)."""


class ParityError(RuntimeError):
    """The exported graph and the torch model disagree beyond the tolerance."""


def contract_outputs(
    model: QNetwork,
    ego: torch.Tensor,
    teammates: torch.Tensor,
    evaders: torch.Tensor,
    obstacles: torch.Tensor,
    mask: torch.Tensor,
) -> tuple[torch.Tensor, ...]:
    """The model's contract outputs, in `output_names` order: q_values [B, 9] (the mean of the
    quantiles at the fixed fractions, as `QNetwork.policy_outputs`), target_weights [B, E] with
    target selection, and the quantiles [B, K, 9] themselves with a distributional head."""
    output = model(ego, teammates, evaders, obstacles, mask, fixed_fractions(device=ego.device))
    outputs = (output.quantiles.mean(dim=1),)
    if output.target_weights is not None:
        outputs += (output.target_weights,)
    return outputs + (output.quantiles,) if model.distributional else outputs


class _ContractGraph(nn.Module):
    """The traced function: the five contract inputs -> q_values [B, 9] (, target_weights [B, E])
    (, quantiles [B, K, 9])."""

    def __init__(self, model: QNetwork) -> None:
        super().__init__()
        self.model = model

    def forward(
        self,
        ego: torch.Tensor,
        teammates: torch.Tensor,
        evaders: torch.Tensor,
        obstacles: torch.Tensor,
        mask: torch.Tensor,
    ) -> tuple[torch.Tensor, ...]:
        return contract_outputs(self.model, ego, teammates, evaders, obstacles, mask)


def output_names(model: QNetwork) -> tuple[str, ...]:
    """The contract's outputs the model has: q_values, plus target_weights with target
    selection, plus quantiles with a distributional head."""
    has = {"q_values": True, "target_weights": model.has_target_selection, "quantiles": model.distributional}
    return tuple(spec.name for spec in OUTPUTS if has[spec.name])


def contract_metadata(model: QNetwork) -> dict[str, str]:
    """The metadata_props every policy carries: contract, model name, sizes, action table (JSON)."""
    config = model.config
    return {
        META_CONTRACT: CONTRACT_VERSION,
        META_MODEL: config["name"],
        META_HIDDEN: str(config["hidden"]),
        META_LAYERS: str(config["layers"]),
        META_HEADS: str(config["heads"]),
        # [9, 2] rows of (acceleration m/s^2, yaw rate rad/s), index = action id.
        META_PURSUER_ACTIONS: json.dumps(PURSUER_ACTIONS.tolist()),
    }


def merged_metadata(model: QNetwork, extra: Mapping[str, str]) -> dict[str, str]:
    """Contract metadata plus the caller's keys; a caller may not override a contract key."""
    metadata = contract_metadata(model)
    for key, value in extra.items():
        if not isinstance(key, str) or not isinstance(value, str):
            raise TypeError(f"metadata must map str to str; got {key!r}: {value!r}")
        if key in metadata and metadata[key] != value:
            raise ValueError(
                f"metadata '{key}' is set by the exporter to '{metadata[key]}'; got '{value}'"
            )
        metadata[key] = value
    return metadata


def example_inputs(
    batch: int,
    teammates: int,
    evaders: int,
    obstacles: int,
    *,
    seed: int = 0,
    partial_mask: bool = False,
) -> dict[str, torch.Tensor]:
    """Random contract inputs by name: ego [B, 4], teammates [B, P, 7], evaders [B, E, 7],
    obstacles [B, O, 5] float32 (values of metre and m/s scale), mask [B, 1 + P + E + O] bool.

    With `partial_mask`, slots are present at random, row 1 (if any) has no evader and
    row 2 (if any) only its ego; otherwise every slot is present.
    """
    generator = torch.Generator().manual_seed(seed)
    width = 1 + teammates + evaders + obstacles
    mask = torch.ones(batch, width, dtype=torch.bool)
    if partial_mask:
        mask = torch.rand(batch, width, generator=generator) < 0.6
        mask[1:2, 1 + teammates : 1 + teammates + evaders] = False
        mask[2:3] = False
        mask[:, 0] = True
    return {
        "ego": 5.0 * torch.randn(batch, 4, generator=generator),
        "teammates": 5.0 * torch.randn(batch, teammates, 7, generator=generator),
        "evaders": 5.0 * torch.randn(batch, evaders, 7, generator=generator),
        "obstacles": 5.0 * torch.randn(batch, obstacles, 5, generator=generator),
        "mask": mask,
    }


def _dynamic_axes(model: QNetwork) -> dict[str, dict[int, str]]:
    """The contract's named (dynamic) dimensions of every input and of the model's outputs."""
    names = set(INPUT_NAMES) | set(output_names(model))
    return {
        spec.name: {axis: dim for axis, dim in enumerate(spec.dims) if isinstance(dim, str)}
        for spec in INPUTS + OUTPUTS
        if spec.name in names
    }


def _trace_to_onnx(model: QNetwork, path: Path, opset: int) -> None:
    """Trace the eval-mode model on an example whose P, E, O differ from the usual sizes."""
    # P=3, E=6, O=4 and a partial mask: sizes baked in by mistake would show in the parity check.
    inputs = example_inputs(3, 3, 6, 4, partial_mask=True)
    device = next(model.parameters()).device
    args = tuple(inputs[name].to(device) for name in INPUT_NAMES)
    with warnings.catch_warnings():
        # The legacy exporter announces its own deprecation; its output is what we check.
        warnings.filterwarnings("ignore", message=".*legacy TorchScript", category=DeprecationWarning)
        warnings.filterwarnings("ignore", category=DeprecationWarning, module=r"torch\.onnx")
        # It also says opset 23 is past the 20 it knows: the ops whose schemas changed from 21
        # to 23 only gained element types (int4, float8); onnx.checker and check_parity verify.
        warnings.filterwarnings("ignore", message="Exporting to ONNX opset version 23")
        torch.onnx.export(
            _ContractGraph(model),
            args,
            str(path),
            dynamo=False,
            input_names=list(INPUT_NAMES),
            output_names=list(output_names(model)),
            dynamic_axes=_dynamic_axes(model),
            opset_version=opset,
            do_constant_folding=True,
        )


def _write_metadata(path: Path, metadata: Mapping[str, str]) -> None:
    """Replace the file's metadata_props by `metadata`, check the model and save it."""
    proto = onnx.load(str(path))
    del proto.metadata_props[:]
    for key, value in sorted(metadata.items()):
        entry = proto.metadata_props.add()
        entry.key, entry.value = key, value
    onnx.checker.check_model(proto, full_check=True)
    onnx.save(proto, str(path))


def export_onnx(
    model: QNetwork,
    path: str | Path,
    metadata: Mapping[str, str],
    *,
    opset: int = OPSET,
) -> Path:
    """Write `model` as one contract-v1 ONNX policy at `path` and return the path.

    Args:
        model: any registry network; its train/eval mode is restored afterwards.
        path: output file (.onnx); parent folders are created.
        metadata: extra metadata_props, str -> str (e.g. `terl.training_steps`,
            `terl.trained_on`); the contract keys are written by the exporter.
        opset: ONNX opset.

    Raises:
        ParityError: onnxruntime and torch differ beyond PARITY_TOLERANCE (see
            `check_parity`); nothing is left at `path` then (an earlier file there stays).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    props = merged_metadata(model, metadata)
    was_training = model.training
    model.eval()
    try:
        with atomic_output(path, replace=True) as partial:  # published at `path` once it passes
            with torch.no_grad():
                _trace_to_onnx(model, partial, opset)
            _write_metadata(partial, props)
            check_parity(model, partial)
    finally:
        model.train(was_training)
    return path


def reexport_onnx(source: str | Path, path: str | Path, metadata: dict[str, str] | None = None) -> Path:
    """Write the policy at `source` again at `path`, with this exporter's graph, and return the path.

    The network is rebuilt from the weights in the source graph (training.onnx_weights) and
    checked to compute what the source does (`check_parity` against the source file) before
    `export_onnx` writes and checks the new file; the source's metadata is kept, with
    META_REEXPORTED_FROM and the caller's `metadata` (str -> str) added over it.

    Raises:
        WeightsNotFound: the source graph lacks a parameter of its network.
        ParityError: the rebuilt network differs from the source file or from the new one.
    """
    source = Path(source)
    model, kept = network_from_onnx(source)
    check_parity(model, source)
    kept[META_REEXPORTED_FROM] = hashlib.sha256(source.read_bytes()).hexdigest()
    return export_onnx(model, path, {**kept, **(metadata or {})})


def with_quantiles(source: str | Path, path: str | Path) -> Path:
    """Write the policy at `source` again at `path` with the optional output quantiles [B, K, 9]
    (contract revision 1.1), its graph otherwise untouched, and return the path.

    The quantiles are the tensor the graph's q_values already average (an Identity of the
    ReduceMean's input), so q_values stay what they were, bit for bit, which is checked on
    `parity_cases` against the source file; the quantiles are checked against the network
    rebuilt from the file's weights (`check_parity`). Metadata is kept as it is.

    Raises:
        ValueError: the source has quantiles already, or its network has no distributional
            head (dqn), or its q_values are not the mean of a [B, K, 9] tensor.
        ParityError: q_values changed, or the quantiles differ from the network's.
    """
    source, path = Path(source), Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    model, _ = network_from_onnx(source)
    if not model.distributional:
        raise ValueError(f"{source}: a {model.config['name']} network has no quantiles (no distributional head)")
    proto = onnx.load(str(source))
    graph = proto.graph
    if any(output.name == "quantiles" for output in graph.output):
        raise ValueError(f"{source}: has the quantiles output already")
    mean = next(node for node in graph.node if "q_values" in node.output)
    if mean.op_type != "ReduceMean":
        raise ValueError(f"{source}: q_values come from a {mean.op_type} node, not the mean of the quantiles")
    graph.node.append(onnx.helper.make_node("Identity", [mean.input[0]], ["quantiles"], name="quantiles"))
    dims = ["B", NUM_QUANTILES, len(PURSUER_ACTIONS)]
    graph.output.append(onnx.helper.make_tensor_value_info("quantiles", onnx.TensorProto.FLOAT, dims))
    onnx.checker.check_model(proto, full_check=True)
    with atomic_output(path, replace=True) as partial:  # published at `path` once it passes
        onnx.save(proto, str(partial))
        before = ort.InferenceSession(str(source), providers=["CPUExecutionProvider"])
        after = ort.InferenceSession(str(partial), providers=["CPUExecutionProvider"])
        for case, inputs in parity_cases((8, 14, 20)):
            feed = {name: tensor.numpy() for name, tensor in inputs.items()}
            if not np.array_equal(before.run(["q_values"], feed)[0], after.run(["q_values"], feed)[0]):
                raise ParityError(f"{case}: q_values of {partial} differ from those of {source}")
        check_parity(model, partial)
    return path


def read_metadata(path: str | Path) -> dict[str, str]:
    """metadata_props of an ONNX file as a dict."""
    proto = onnx.load(str(path), load_external_data=False)
    return {entry.key: entry.value for entry in proto.metadata_props}


@functools.cache
def simulated_inputs(evader_slots: int, steps: int = 20) -> tuple[str, dict[str, torch.Tensor]] | None:
    """Real observations: the active pursuers of the first paper preset with `evader_slots`
    evader slots, after `steps` random steps from seed 0. None if no preset has that E.

    Made once a process (a stack of seeds exports each seed with the same cases): every call
    returns the same tensors, which no caller may change."""
    names = [name for name in PAPER_SUITE if Scenario.preset(name).evader_slots == evader_slots]
    if not names:
        return None
    simulator = Simulator(Scenario.preset(names[0]), seed=0)
    observation = simulator.reset()
    rng = np.random.default_rng(0)
    for _ in range(steps):
        if simulator.done:
            break
        observation, _ = simulator.step(rng.integers(0, 9, simulator.scenario.pursuers))
    arrays = observation.as_inputs()
    return names[0], {name: torch.from_numpy(arrays[name].copy()) for name in INPUT_NAMES}


def parity_cases(evader_slots: tuple[int, ...]) -> Iterator[tuple[str, dict[str, torch.Tensor]]]:
    """Inputs `check_parity` compares on: per E, all slots present (P = O = 5), a
    partial mask with other P and O (4 and 6), and real observations of a paper
    preset with that E when there is one. Yields (description, inputs)."""
    for index, evaders in enumerate(evader_slots):
        yield f"E={evaders} all present", example_inputs(4, 5, evaders, 5, seed=2 * index)
        yield f"E={evaders} partial mask, P=4, O=6", example_inputs(
            5, 4, evaders, 6, seed=2 * index + 1, partial_mask=True
        )
        simulated = simulated_inputs(evaders)
        if simulated is not None:
            yield f"E={evaders} observations of {simulated[0]}", simulated[1]


def check_parity(
    model: QNetwork,
    path: str | Path,
    *,
    evader_slots: tuple[int, ...] = (8, 14, 20),
    tolerance: float = PARITY_TOLERANCE,
) -> float:
    """Compare the eval-mode torch model with onnxruntime on the file at `path`.

    Runs every case of `parity_cases` and compares q_values [B, 9] and, where the
    model has them, target_weights [B, E] and quantiles [B, K, 9] (a file exported before
    contract revision 1.1 may lack the quantiles). Returns the largest difference, each relative
    to its output's largest magnitude when that is above 1 (see PARITY_TOLERANCE).

    Raises:
        ParityError: a difference above `tolerance`, a missing or extra output, or
            a non-finite value; the message names the case and output.
    """
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    names = output_names(model)
    got_names = tuple(output.name for output in session.get_outputs())
    if got_names not in (names, tuple(name for name in names if name != "quantiles")):  # older files lack them
        raise ParityError(f"{path}: expected outputs {names}, got {got_names}")
    names = got_names
    device = next(model.parameters()).device
    was_training = model.training
    model.eval()
    worst = 0.0
    try:
        for case, inputs in parity_cases(evader_slots):
            with torch.no_grad():
                expected = contract_outputs(model, *(inputs[n].to(device) for n in INPUT_NAMES))
            feed = {name: tensor.numpy() for name, tensor in inputs.items()}
            for name, want, got in zip(names, expected, session.run(list(names), feed)):
                worst = max(worst, _compare(f"{case}, {name}", want.cpu().numpy(), got, tolerance))
    finally:
        model.train(was_training)
    return worst


def _compare(label: str, expected: np.ndarray, got: np.ndarray, tolerance: float) -> float:
    """Largest |expected - got| / max(1, max |expected|); raises ParityError on shape
    mismatch, NaN or excess difference."""
    if expected.shape != got.shape:
        raise ParityError(f"{label}: torch shape {expected.shape}, onnxruntime shape {got.shape}")
    if not np.isfinite(got).all():
        raise ParityError(f"{label}: onnxruntime returned non-finite values")
    if not expected.size:
        return 0.0
    scale = max(1.0, float(np.abs(expected).max()))
    difference = float(np.abs(expected - got).max()) / scale
    if not difference <= tolerance:
        raise ParityError(
            f"{label}: max |torch - onnxruntime| = {difference * scale:.3g} "
            f"(relative to max |torch| = {scale:.3g}: {difference:.3g} > {tolerance:g}); "
            "the exported graph computes something else (sizes baked in at trace time?)"
        )
    return difference
