"""The checks of the exported-policy contract (terl_rt.policy.contract, policy.md section 3).

One function per property, in the style of Gymnasium's env checker: each takes the
part of the model it looks at, returns a one-line description when the property
holds, and raises `ContractError` (a refusal) or `ContractWarning` (worth telling,
not a refusal) with a message that names the problem and its likely cause.
`check_model` runs them all and collects a `ContractReport`.

The checks read plain descriptions (`TensorInfo`, a metadata dict), so they need
neither onnx nor an onnxruntime session; `terl_rt.policy.onnx_policy.check_contract`
builds those descriptions from a session.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from terl_rt.policy.contract import (
    ACTION_TABLE_TOLERANCE,
    CONTRACT_VERSION,
    INPUTS,
    META_CONTRACT,
    META_HEADS,
    META_HIDDEN,
    META_LAYERS,
    META_MODEL,
    META_PURSUER_ACTIONS,
    META_TRAINED_ON,
    META_TRAINING_STEPS,
    OUTPUTS,
    ContractError,
    ContractWarning,
    TensorInfo,
    TensorSpec,
)
from terl_rt.sim.actions import NUM_PURSUER_ACTIONS, PURSUER_ACTIONS

PASS, WARN, FAIL = "pass", "warn", "fail"
"""The status of a `Check`: the property holds, is worth telling, or refuses the model."""


@dataclass(frozen=True)
class Check:
    """One property of the contract and how the model fared on it."""

    name: str
    """What was checked, e.g. "input 'mask' dtype"."""
    status: str
    """"pass", "warn" or "fail" (a refusal)."""
    detail: str
    """What was found; for warn and fail, the problem and its likely cause."""


@dataclass(frozen=True)
class ContractReport:
    """Every contract check run on one model, with what the model declares."""

    checks: tuple[Check, ...]
    inputs: tuple[TensorInfo, ...]
    outputs: tuple[TensorInfo, ...]
    metadata: Mapping[str, str] = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        """True when no check refused the model (warnings allowed)."""
        return not self.failures

    @property
    def failures(self) -> tuple[Check, ...]:
        return tuple(check for check in self.checks if check.status == FAIL)

    @property
    def warnings(self) -> tuple[Check, ...]:
        return tuple(check for check in self.checks if check.status == WARN)

    @property
    def has_target_weights(self) -> bool:
        return any(info.name == "target_weights" for info in self.outputs)

    @property
    def has_quantiles(self) -> bool:
        """The model gives the optional `quantiles` output (contract revision 1.1)."""
        return any(info.name == "quantiles" for info in self.outputs)

    def raise_for_refusal(self) -> None:
        """Raise ContractError with the first refusal's message, if any."""
        failures = self.failures
        if not failures:
            return
        message = failures[0].detail
        if len(failures) > 1:
            message += f" (and {len(failures) - 1} more contract problem(s))"
        error = ContractError(message)
        error.report = self
        raise error

    def format(self) -> str:
        """One line per check, e.g. "[pass] input 'ego': float32 [B, 4]"."""
        return "\n".join(f"[{check.status}] {check.name}: {check.detail}" for check in self.checks)


# --- metadata ---------------------------------------------------------------


def _require_metadata(metadata: Mapping[str, str], key: str) -> str:
    if key not in metadata:
        raise ContractError(
            f"metadata '{key}' is missing; the exporter did not write the contract "
            "metadata_props, or this is not a terl policy"
        )
    return metadata[key]


def _quoted(text: str) -> str:
    """A metadata value as an error message shows it: its first 80 characters, quoted and
    escaped (repr), so a line break or control character in it keeps the message on one line."""
    return repr(text[:80])


def check_contract_version(metadata: Mapping[str, str]) -> str:
    """`terl.contract` is "1"."""
    version = _require_metadata(metadata, META_CONTRACT).strip()
    if version != CONTRACT_VERSION:
        raise ContractError(
            f"metadata '{META_CONTRACT}' is {_quoted(version)}, this runtime reads contract "
            f"{CONTRACT_VERSION}; use a runtime for that contract or re-export the policy"
        )
    return version


def check_model_name(metadata: Mapping[str, str]) -> str:
    """`terl.model` is a non-empty name."""
    name = _require_metadata(metadata, META_MODEL).strip()
    if not name:
        raise ContractError(f"metadata '{META_MODEL}' is empty; the exporter must name the model")
    return name


def check_size(metadata: Mapping[str, str], key: str, minimum: int) -> str:
    """An architecture size (`terl.hidden`, `terl.layers`, `terl.heads`) is an integer >= minimum."""
    text = _require_metadata(metadata, key)
    try:
        value = int(text)
    except ValueError:
        raise ContractError(f"metadata '{key}' is {_quoted(text)}, the contract needs an integer") from None
    if value < minimum:
        raise ContractError(f"metadata '{key}' is {value}, the contract needs at least {minimum}")
    return str(value)


def check_action_table(metadata: Mapping[str, str]) -> str:
    """`terl.pursuer_actions` equals PURSUER_ACTIONS within ACTION_TABLE_TOLERANCE."""
    text = _require_metadata(metadata, META_PURSUER_ACTIONS)
    try:
        table = np.asarray(json.loads(text), dtype=np.float64)
    except (json.JSONDecodeError, TypeError, ValueError, RecursionError):
        raise ContractError(
            f"metadata '{META_PURSUER_ACTIONS}' is not a JSON list of "
            f"{NUM_PURSUER_ACTIONS} [acceleration, yaw rate] pairs: {_quoted(text)}"
        ) from None
    if table.shape != PURSUER_ACTIONS.shape:
        raise ContractError(
            f"metadata '{META_PURSUER_ACTIONS}' has shape {list(table.shape)}, the contract "
            f"says {list(PURSUER_ACTIONS.shape)} ({NUM_PURSUER_ACTIONS} [acceleration, yaw rate] pairs)"
        )
    differs = np.abs(table - PURSUER_ACTIONS) > ACTION_TABLE_TOLERANCE
    if not np.all(np.isfinite(table)) or differs.any():
        index = int(np.flatnonzero(~np.isfinite(table).all(-1) | differs.any(-1))[0])
        raise ContractError(
            f"metadata '{META_PURSUER_ACTIONS}' differs from the runtime's pursuer action table "
            f"at action {index}: model {table[index].tolist()}, runtime "
            f"{PURSUER_ACTIONS[index].tolist()} (m/s^2, rad/s); the model was trained with "
            "another action order or units, so its action indices would mean other controls"
        )
    return f"{NUM_PURSUER_ACTIONS} actions, matches world.md section 2"


def check_training_steps(metadata: Mapping[str, str]) -> str:
    """`terl.training_steps` is reported when present (warning if absent or malformed)."""
    if META_TRAINING_STEPS not in metadata:
        raise ContractWarning(f"metadata '{META_TRAINING_STEPS}' is missing; training length unknown")
    text = metadata[META_TRAINING_STEPS]
    try:
        steps = int(text)
    except ValueError:
        raise ContractWarning(f"metadata '{META_TRAINING_STEPS}' is {_quoted(text)}, expected an integer") from None
    if steps < 0:
        raise ContractWarning(f"metadata '{META_TRAINING_STEPS}' is {steps}, expected >= 0")
    return str(steps)


def check_trained_on(metadata: Mapping[str, str]) -> str:
    """`terl.trained_on` is reported when present (warning if absent or empty)."""
    text = metadata.get(META_TRAINED_ON, "").strip()
    if not text:
        raise ContractWarning(f"metadata '{META_TRAINED_ON}' is missing; training scenarios unknown")
    return text


# --- inputs and outputs ------------------------------------------------------


def check_present(infos: Mapping[str, TensorInfo], spec: TensorSpec, kind: str) -> str:
    """The model has the input or output `spec.name`."""
    if spec.name not in infos:
        found = ", ".join(repr(name) for name in infos) or "none"
        raise ContractError(
            f"missing {kind} '{spec.name}'; the model's {kind}s are {found} "
            "(renamed at export, or an older export?)"
        )
    return infos[spec.name].describe()


def check_dtype(info: TensorInfo, spec: TensorSpec, kind: str) -> str:
    """The element type is the contract's (float32, or bool for the mask)."""
    if info.dtype != spec.dtype:
        raise ContractError(
            f"{kind} '{info.name}' has dtype {info.dtype}, the contract says {spec.dtype}"
            + (" (cast in the exported graph)" if spec.dtype == "bool" else " (export in float32)")
        )
    return info.dtype


def check_rank(info: TensorInfo, spec: TensorSpec, kind: str) -> str:
    """The rank is the contract's, e.g. 3 for [B, E, 7]."""
    expected = "[" + ", ".join(str(dim) for dim in spec.dims) + "]"
    if info.shape is None:
        raise ContractError(
            f"{kind} '{info.name}' declares no shape, the contract says {expected}; "
            "export with shape information"
        )
    if len(info.shape) != len(spec.dims):
        raise ContractError(
            f"{kind} '{info.name}' has rank {len(info.shape)} {info.describe()}, "
            f"the contract says rank {len(spec.dims)} {expected}"
        )
    return f"rank {len(spec.dims)}"


def check_fixed_dims(info: TensorInfo, spec: TensorSpec, kind: str) -> str:
    """Dimensions the contract fixes (features, actions) have that size."""
    for axis, (dim, want) in enumerate(zip(info.shape, spec.dims)):
        if not isinstance(want, int):
            continue
        if isinstance(dim, int) and dim != want:
            if spec.name in ("q_values", "quantiles") and axis == len(spec.dims) - 1:
                raise ContractError(
                    f"output '{spec.name}' has {dim} actions, the contract says {want} "
                    "(one per entry of the pursuer action table)"
                )
            if spec.name == "quantiles":
                raise ContractError(
                    f"output 'quantiles' has {dim} quantile fractions, the contract says {want} "
                    "(tau_k = (k + 0.5) / K, K = 32)"
                )
            raise ContractError(
                f"{kind} '{info.name}' has {dim} features on axis {axis}, the contract says "
                f"{want}; the model was built for another observation layout"
            )
        if not isinstance(dim, int):
            raise ContractWarning(
                f"{kind} '{info.name}' leaves axis {axis} dynamic where the contract says {want}; "
                "it will be checked when the policy runs"
            )
    return "sizes match"


def check_dynamic_dims(info: TensorInfo, spec: TensorSpec, kind: str) -> str:
    """Dimensions the contract calls dynamic (B, P, E, O) are not fixed integers."""
    for dim, want in zip(info.shape, spec.dims):
        if isinstance(want, str) and isinstance(dim, int):
            raise ContractError(
                f"dimension {want} of '{info.name}' is fixed to {dim}; the contract needs it "
                "dynamic (export it as a dynamic axis)"
            )
    return "dynamic: " + ", ".join(str(want) for want in spec.dims if isinstance(want, str))


def check_no_extra_inputs(inputs: Mapping[str, TensorInfo]) -> str:
    """The model asks for no input beyond the contract's five."""
    extra = [name for name in inputs if name not in {spec.name for spec in INPUTS}]
    if extra:
        raise ContractError(
            f"unexpected input(s) {', '.join(repr(name) for name in extra)}; the contract "
            f"feeds exactly {', '.join(spec.name for spec in INPUTS)}"
        )
    return "none"


def check_no_extra_outputs(outputs: Mapping[str, TensorInfo]) -> str:
    """Outputs beyond q_values and target_weights are ignored (warning)."""
    extra = [name for name in outputs if name not in {spec.name for spec in OUTPUTS}]
    if extra:
        raise ContractWarning(
            f"extra output(s) {', '.join(repr(name) for name in extra)} are not part of the "
            "contract and are ignored"
        )
    return "none"


# --- the whole contract ------------------------------------------------------


def _run(checks: list[Check], name: str, check: Callable[..., str], *args) -> bool:
    """Run one check, record it; True unless it refused."""
    try:
        detail = check(*args)
    except ContractError as error:
        checks.append(Check(name, FAIL, str(error)))
        return False
    except ContractWarning as warning:
        checks.append(Check(name, WARN, str(warning)))
        return True
    checks.append(Check(name, PASS, detail))
    return True


def _check_tensor(checks: list[Check], infos: Mapping[str, TensorInfo], spec: TensorSpec, kind: str) -> None:
    label = f"{kind} '{spec.name}'"
    if not spec.required and spec.name not in infos:
        checks.append(Check(label, PASS, "absent (optional)"))
        return
    if not _run(checks, label, check_present, infos, spec, kind):
        return
    info = infos[spec.name]
    _run(checks, f"{label} dtype", check_dtype, info, spec, kind)
    if _run(checks, f"{label} rank", check_rank, info, spec, kind):
        _run(checks, f"{label} sizes", check_fixed_dims, info, spec, kind)
        _run(checks, f"{label} dynamic dims", check_dynamic_dims, info, spec, kind)


def check_model(
    inputs: Sequence[TensorInfo],
    outputs: Sequence[TensorInfo],
    metadata: Mapping[str, str],
) -> ContractReport:
    """Run every contract check on a model's declared inputs, outputs and metadata_props."""
    checks: list[Check] = []
    # The version first: a model for another contract explains every later failure.
    _run(checks, "metadata contract version", check_contract_version, metadata)

    input_infos = {info.name: info for info in inputs}
    output_infos = {info.name: info for info in outputs}
    for spec in INPUTS:
        _check_tensor(checks, input_infos, spec, "input")
    _run(checks, "extra inputs", check_no_extra_inputs, input_infos)
    for spec in OUTPUTS:
        _check_tensor(checks, output_infos, spec, "output")
    _run(checks, "extra outputs", check_no_extra_outputs, output_infos)

    _run(checks, "metadata model name", check_model_name, metadata)
    _run(checks, "metadata hidden size", check_size, metadata, META_HIDDEN, 1)
    _run(checks, "metadata layers", check_size, metadata, META_LAYERS, 0)
    _run(checks, "metadata heads", check_size, metadata, META_HEADS, 0)
    _run(checks, "metadata pursuer action table", check_action_table, metadata)
    _run(checks, "metadata training steps", check_training_steps, metadata)
    _run(checks, "metadata trained on", check_trained_on, metadata)
    return ContractReport(tuple(checks), tuple(inputs), tuple(outputs), dict(metadata))
