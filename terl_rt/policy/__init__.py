"""Policies: the ONNX contract (`contract`: names, feature dims, metadata keys, version
and the checks of a model against them), ONNX policies through onnxruntime
(`onnx_policy`) and a policy inside one's own controller (`embed`).

This file imports nothing, so that `terl_rt.policy.contract` loads without onnxruntime.
"""
