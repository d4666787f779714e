"""The matrix-product work of a policy: FLOPs a decision row, counted from a run of its graph.

Every MatMul and Gemm of the ONNX graph is counted at 2 x M x K x N multiply-adds (times
its broadcast batch dimensions), and every Attention op (opset 23, 3-D query, key and value
[B, L, H], H = heads x head size) at its two products, 2 x 2 x B x L x S x H for S keys,
with the shapes it meets on real observations: the
graph is run once with each product's operands as extra outputs. What a policy costs
depends on the observation's slots (P, E, O tokens), so the count is per scenario.
Needs the `onnx` package (the `optimize` extra) to add those outputs.
"""

from __future__ import annotations

import math

import numpy as np
import onnxruntime as ort

from terl_rt.policy.onnx_policy import OnnxPolicy, observation_inputs
from terl_rt.sim.observation import Observation

MATMUL_GFLOPS = 380.0
"""GFLOP/s: the fp32 matrix-multiply rate of the project's 2-core machine (issue 40), the
limit a policy's speed is set against."""


class OnnxMissing(ImportError):
    """Counting FLOPs (or optimising a policy) needs the onnx package; the message says how to install it."""


def _onnx():
    try:
        import onnx
    except ImportError as error:
        raise OnnxMissing("counting a policy's FLOPs needs onnx; install it with: pip install -e '.[optimize]'") from error
    return onnx


def flops_per_row(policy: OnnxPolicy, observation: Observation) -> float:
    """FLOPs of the policy's matrix products for one row of `observation` (leading shape
    [R], rows of one scenario): the graph run once on them, each MatMul / Gemm counted at
    2 x M x K x N and each Attention at its two products, summed and divided by R. Work a call does once, whatever its rows (the
    shipped graph's quantile embedding, about 0.26 MFLOP), is shared by its R rows."""
    onnx = _onnx()
    model = onnx.load_from_string(policy.model)
    weights = {tensor.name: tuple(tensor.dims) for tensor in model.graph.initializer}
    products = [node for node in model.graph.node if node.op_type in ("MatMul", "Gemm", "Attention")]
    shown = {output.name for output in model.graph.output}
    operands = [name for node in products for name in node.input[:2] if name not in weights and name not in shown]
    for name in dict.fromkeys(operands):
        model.graph.output.append(onnx.helper.make_empty_tensor_value_info(name))
    session = ort.InferenceSession(model.SerializeToString(), providers=["CPUExecutionProvider"])
    inputs, leading = observation_inputs(observation)
    if len(leading) != 1 or leading[0] < 1:
        raise ValueError(f"flops_per_row needs [R] rows with R >= 1, got leading shape {leading}")
    values = dict(zip([output.name for output in model.graph.output], session.run(None, inputs)))
    shapes = {**weights, **{name: values[name].shape for name in operands}, **{n: v.shape for n, v in inputs.items()}}
    total = 0.0
    for node in products:
        a, b = shapes[node.input[0]], shapes[node.input[1]]
        if node.op_type == "Gemm":
            attributes = {attribute.name: attribute.i for attribute in node.attribute}
            m, k = a[::-1] if attributes.get("transA") else a
            n = b[0] if attributes.get("transB") else b[1]
            total += 2.0 * m * k * n
        elif node.op_type == "Attention":  # query [B, L, H] times keys [B, S, H], then weights times values
            total += 4.0 * a[0] * a[1] * b[1] * a[2]
        else:
            batch = np.broadcast_shapes(a[:-2], b[:-2]) if len(a) > 2 or len(b) > 2 else ()
            total += 2.0 * math.prod(batch) * (a[-2] if len(a) > 1 else 1) * a[-1] * b[-1]
    return total / leading[0]
