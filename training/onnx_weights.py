"""A network rebuilt from the weights inside an exported ONNX policy, for policies whose
torch checkpoint is not shipped: re-exported, such a policy gets the current exporter's graph.

The exporter (training/export.py, any version so far) leaves every parameter in the graph
as an initializer in one of three forms, which `network_from_onnx` reads back:

- under its own name, prefixed "model." (biases, LayerNorm weights, weights of 2-D Gemms);
- transposed, under a generated name, as the weight input of a MatMul whose output the
  layer's bias is added to: the parameter is "<layer>.weight" of that bias's "<layer>.bias";
- a row of the type embedding, constant-folded, under a generated name, added to the
  output of the entity encoder of that type (ego 0, teammate 1, evader 2, obstacle 3).

A parameter equal to another one (fresh LayerNorm weights) is the output of an Identity
of that one's initializer.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import onnx
import torch
from onnx import numpy_helper

from terl_rt.policy.contract import META_HEADS, META_HIDDEN, META_LAYERS, META_MODEL
from training.networks import build_network
from training.networks.encoders import QNetwork

PREFIX = "model."
"""What the exporter's traced wrapper puts before every parameter name."""
ENCODER_TYPES = {"ego": 0, "teammate": 1, "evader": 2, "obstacle": 3}
"""Entity encoder name -> its row of the type embedding (training/networks/terl.py)."""
TYPE_EMBEDDING = "relations.type_embedding.weight"


class WeightsNotFound(ValueError):
    """The ONNX graph does not hold every parameter of the network its metadata names."""


def _consumers(graph: onnx.GraphProto) -> dict[str, list[onnx.NodeProto]]:
    """Tensor name -> the nodes that read it."""
    readers: dict[str, list[onnx.NodeProto]] = {}
    for node in graph.node:
        for name in node.input:
            readers.setdefault(name, []).append(node)
    return readers


def _encoder_type(graph: onnx.GraphProto, tensor: str) -> int | None:
    """The type row index when `tensor` is an entity encoder's output (Relu of its
    LayerNormalization), else None."""
    producers = {output: node for node in graph.node for output in node.output}
    relu = producers.get(tensor)
    if relu is None or relu.op_type != "Relu":
        return None
    norm = producers.get(relu.input[0])
    if norm is None or norm.op_type != "LayerNormalization":
        return None
    for kind, row in ENCODER_TYPES.items():
        if norm.input[1] == f"{PREFIX}relations.encoders.{kind}.1.weight":
            return row
    return None


def _read_weights(graph: onnx.GraphProto, parameters: dict[str, torch.Tensor]) -> dict[str, np.ndarray]:
    """Parameter name -> value found in `graph`, by the three forms of the module docstring."""
    values = {init.name: numpy_helper.to_array(init) for init in graph.initializer}
    readers = _consumers(graph)
    found: dict[str, np.ndarray] = {}
    type_rows: dict[int, np.ndarray] = {}
    for name, value in values.items():
        if name.startswith(PREFIX):
            found[name[len(PREFIX):]] = value
            continue
        for node in readers.get(name, []):
            if node.op_type == "MatMul" and node.input[1] == name:
                for add in readers.get(node.output[0], []):
                    bias = next((i for i in add.input if i.startswith(PREFIX) and i.endswith(".bias")), None)
                    if add.op_type == "Add" and bias is not None:
                        found[bias[len(PREFIX):-len("bias")] + "weight"] = value.T
            elif node.op_type == "Add":
                other = node.input[0] if node.input[1] == name else node.input[1]
                row = _encoder_type(graph, other)
                if row is not None:
                    type_rows[row] = value
    for node in graph.node:  # parameters equal to another one are exported as its Identity
        if node.op_type == "Identity" and node.input[0] in values and node.output[0].startswith(PREFIX):
            found[node.output[0][len(PREFIX):]] = values[node.input[0]]
    if TYPE_EMBEDDING in parameters and len(type_rows) == len(ENCODER_TYPES):
        found[TYPE_EMBEDDING] = np.stack([type_rows[row] for row in sorted(type_rows)])
    return found


def network_from_onnx(path: str | Path) -> tuple[QNetwork, dict[str, str]]:
    """The eval-mode network of the ONNX policy at `path` (built from its metadata's model,
    hidden, layers and heads) with the graph's weights, and the file's metadata_props.

    Raises:
        WeightsNotFound: a parameter is missing from the graph or has another shape.
    """
    proto = onnx.load(str(path))
    metadata = {entry.key: entry.value for entry in proto.metadata_props}
    try:
        model = build_network(metadata[META_MODEL], int(metadata[META_HIDDEN]), int(metadata[META_LAYERS]),
                              int(metadata[META_HEADS]))
    except KeyError as error:
        raise WeightsNotFound(f"{path}: metadata has no {error.args[0]}: not a contract-v1 policy") from None
    parameters = dict(model.named_parameters())
    found = _read_weights(proto.graph, parameters)
    missing = [name for name in parameters if name not in found]
    if missing:
        raise WeightsNotFound(f"{path}: no weights in the graph for {', '.join(missing)}")
    wrong = [f"{name} {list(found[name].shape)} (expected {list(p.shape)})" for name, p in parameters.items()
             if tuple(found[name].shape) != tuple(p.shape)]
    if wrong:
        raise WeightsNotFound(f"{path}: weights of another shape: {', '.join(wrong)}")
    with torch.no_grad():
        for name, parameter in parameters.items():
            parameter.copy_(torch.from_numpy(np.array(found[name], dtype=np.float32)))
    return model.eval(), metadata
