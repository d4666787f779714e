"""A policy's inputs from an observation: the contract's arrays (terl_rt.policy.contract),
float32, their widths and finiteness checked, with the leading axes of the rows kept."""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from terl_rt.policy.contract import INPUTS
from terl_rt.sim.observation import Observation

_FEATURES = {spec.name: spec.dims[-1] for spec in INPUTS if spec.name != "mask"}
"""Feature width of each token group (ego, teammates, evaders, obstacles)."""


def _row_label(flat_row: int, leading: tuple[int, ...]) -> str:
    if not leading:
        return "the single row"
    if len(leading) == 1:
        return f"row {flat_row}"
    return f"row {tuple(int(i) for i in np.unravel_index(flat_row, leading))}"


def _features(name: str, value) -> np.ndarray:
    array = np.asarray(value)
    if array.dtype.kind not in "biuf":
        raise ValueError(f"{name} has dtype {array.dtype}; the contract needs float32 features")
    return array.astype(np.float32, copy=False)


def _check_finite(name: str, array: np.ndarray, leading: tuple[int, ...]) -> None:
    finite = np.isfinite(array)
    if finite.all():
        return
    rows = math.prod(leading)
    flat_row = int(np.flatnonzero(~finite.reshape(rows, -1).all(axis=1))[0])
    row = array.reshape((rows,) + array.shape[len(leading):])[flat_row]
    inner = tuple(int(i) for i in np.argwhere(~np.isfinite(row))[0])
    # Position inside the row: the feature for ego, slot and feature for token groups.
    where = f"feature {inner[0]}" if len(inner) == 1 else f"slot {inner[0]}, feature {inner[1]}"
    raise ValueError(
        f"{name} has a non-finite value ({row[inner]}) in {_row_label(flat_row, leading)} ({where}); "
        "the observation must be finite everywhere, padding included"
    )


def observation_inputs(
    observation: Observation | Mapping[str, np.ndarray],
) -> tuple[dict[str, np.ndarray], tuple[int, ...]]:
    """Check an observation and return the contract inputs with their leading shape.

    `observation` is an `Observation` or a mapping with its `as_inputs()` keys, with
    any leading shape `...`: ego [..., 4], teammates [..., P, 7], evaders [..., E, 7],
    obstacles [..., O, 5] (numbers, converted to float32, all finite) and mask
    [..., 1 + P + E + O] bool. Raises ValueError naming the group at fault.
    """
    values = observation.as_inputs() if isinstance(observation, Observation) else observation
    missing = [spec.name for spec in INPUTS if spec.name not in values]
    if missing:
        raise ValueError(f"observation lacks {', '.join(missing)}")

    inputs = {name: _features(name, values[name]) for name in _FEATURES}
    ego = inputs["ego"]
    if ego.ndim < 1 or ego.shape[-1] != _FEATURES["ego"]:
        raise ValueError(f"ego has shape {ego.shape}, expected [..., {_FEATURES['ego']}]")
    leading = ego.shape[:-1]
    for name in ("teammates", "evaders", "obstacles"):
        array, width = inputs[name], _FEATURES[name]
        if array.ndim < 2 or array.shape[-1] != width:
            raise ValueError(f"{name} has shape {array.shape}, expected [..., slots, {width}]")
        if array.shape[:-2] != leading:
            raise ValueError(
                f"{name} has leading shape {array.shape[:-2]} but ego has {leading}; "
                "every group needs the same rows"
            )

    mask = np.asarray(values["mask"])
    if mask.dtype != np.bool_:
        raise ValueError(f"mask has dtype {mask.dtype}, the contract says bool (true = present)")
    tokens = 1 + sum(inputs[name].shape[-2] for name in ("teammates", "evaders", "obstacles"))
    if mask.shape != leading + (tokens,):
        raise ValueError(
            f"mask has shape {mask.shape}, expected {leading + (tokens,)}: "
            "[..., 1 + P + E + O] with P, E, O the slots of teammates, evaders, obstacles"
        )
    inputs["mask"] = mask

    if math.prod(leading) > 0:
        for name in _FEATURES:
            _check_finite(name, inputs[name], leading)
    return inputs, leading
