"""Exported ONNX policies: load one, check it against the contract, act with it.

The contract (policy.md section 3) is checked in `terl_rt.policy.contract`; this module
opens the file with onnxruntime, refuses models that break the contract, checks
observations before they reach the model, and runs the rows in calls of at most CALL_ROWS.
"""

from __future__ import annotations

import errno
import hashlib
import logging
import math
import os
import re
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import onnxruntime as ort

from terl_rt.policy.checks import ContractReport, check_model
from terl_rt.policy.contract import META_MODEL, NUM_QUANTILES, ContractError, TensorInfo
from terl_rt.policy.inputs import observation_inputs
from terl_rt.sim.actions import NUM_PURSUER_ACTIONS, PURSUER_ACTIONS
from terl_rt.sim.observation import Observation

__all__ = [
    "ContractError",
    "ContractReport",
    "OnnxPolicy",
    "PolicyOutput",
    "PolicyRunError",
    "action_to_control",
    "check_contract",
    "describe_session",
    "observation_inputs",
    "open_session",
    "policy_info",
    "session_options",
]

logger = logging.getLogger(__name__)


# --- opening a model ---------------------------------------------------------


MAX_POLICY_BYTES = 2**31 - 1
"""bytes: the largest ONNX file (one protobuf message) onnxruntime can read."""


def _read_policy_file(path: Path) -> bytes:
    """The file's bytes; FileNotFoundError / IsADirectoryError name the path."""
    if not path.exists():
        raise FileNotFoundError(errno.ENOENT, "no policy file at this path", str(path))
    if path.is_dir():
        raise IsADirectoryError(errno.EISDIR, "expected an ONNX policy file, got a directory", str(path))
    if not path.is_file():
        raise ContractError(f"{path}: not a regular file (a device or a pipe), not an ONNX policy")
    size = path.stat().st_size
    if size > MAX_POLICY_BYTES:
        raise ContractError(
            f"{path}: {size:,} bytes, larger than any ONNX policy can be ({MAX_POLICY_BYTES:,} bytes, protobuf's limit)"
        )
    return path.read_bytes()


def _check_threads(threads: int | None) -> None:
    if threads is None:
        return
    if isinstance(threads, bool) or not isinstance(threads, int) or threads < 1:
        raise ValueError(f"threads must be a positive integer or None, got {threads!r}")


def session_options(threads: int | None = None) -> ort.SessionOptions:
    """Deterministic CPU session options: `threads` intra-op threads (None: onnxruntime's
    default), one inter-op thread, sequential execution, and threads that sleep between calls."""
    _check_threads(threads)
    options = ort.SessionOptions()
    if threads is not None:
        options.intra_op_num_threads = threads
    # onnxruntime's threads spin after each call by default, burning a core while the simulator
    # steps between calls (docs/benchmarks.md, "onnxruntime's threads between calls").
    options.add_session_config_entry("session.intra_op.allow_spinning", "0")
    options.inter_op_num_threads = 1
    options.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    options.use_deterministic_compute = True
    # Fatal only: a failure while running is raised (PolicyRunError) as one line, not also logged.
    options.log_severity_level = 4
    return options


THREAD_STACK_BYTES = 8 << 20
"""A thread's stack where `ulimit -s` is unlimited (glibc's default otherwise follows it)."""
SESSION_ROOM_BYTES = 48 << 20
"""Address space a session takes beside its threads' stacks (the model, its arena), with
room to spare: onnxruntime starts its threads while it allocates them."""


def _check_room_for_threads(threads: int | None) -> None:
    """MemoryError when the stacks of onnxruntime's intra-op threads (`threads`; None: one a
    CPU, at most) and the session (SESSION_ROOM_BYTES) do not fit under the address-space
    limit (`ulimit -v`): onnxruntime hangs when it cannot start a thread. Nothing to check
    without a limit, or off Linux."""
    try:
        import resource

        with open("/proc/self/statm") as handle:
            used = int(handle.read().split()[0]) * os.sysconf("SC_PAGE_SIZE")
    except (ImportError, OSError, ValueError):
        return
    limit = resource.getrlimit(resource.RLIMIT_AS)[0]
    if limit == resource.RLIM_INFINITY:
        return
    stack = resource.getrlimit(resource.RLIMIT_STACK)[0]
    stack = THREAD_STACK_BYTES if stack == resource.RLIM_INFINITY else stack
    count = threads or os.cpu_count() or 1
    needed = (count - 1) * stack + SESSION_ROOM_BYTES  # the calling thread is one of them
    if used + needed > limit:
        raise MemoryError(
            f"a policy on {count} onnxruntime threads needs {needed >> 20} MiB of address space, "
            f"and {max(limit - used, 0) >> 20} MiB are left under the limit (ulimit -v); ask for fewer threads"
        )


def _session_from_bytes(model: bytes, path: Path, threads: int | None) -> ort.InferenceSession:
    options = session_options(threads)
    _check_room_for_threads(threads)
    try:
        return ort.InferenceSession(model, sess_options=options, providers=["CPUExecutionProvider"])
    except Exception as error:  # onnxruntime raises its own types for every kind of bad file
        raise ContractError(f"{path} is not a readable ONNX model: {error}") from error


def open_session(path: str | os.PathLike, threads: int | None = None) -> ort.InferenceSession:
    """An onnxruntime CPU session on the file at `path`, without the contract check.

    Raises FileNotFoundError for a missing file and ContractError for a file
    onnxruntime cannot load.
    """
    path = Path(path)
    return _session_from_bytes(_read_policy_file(path), path, threads)


def describe_session(
    session: ort.InferenceSession,
) -> tuple[tuple[TensorInfo, ...], tuple[TensorInfo, ...], dict[str, str]]:
    """A session's declared inputs, outputs and metadata_props; ContractError for
    metadata that is not UTF-8 text (onnxruntime cannot hand it over)."""
    inputs = tuple(TensorInfo.from_node_arg(arg) for arg in session.get_inputs())
    outputs = tuple(TensorInfo.from_node_arg(arg) for arg in session.get_outputs())
    try:
        metadata = dict(session.get_modelmeta().custom_metadata_map)
    except UnicodeDecodeError as error:
        raise ContractError(f"its metadata is not UTF-8 text ({error.reason} at byte {error.start} of a value)") from None
    return inputs, outputs, metadata


def check_contract(
    source: str | os.PathLike | ort.InferenceSession, *, strict: bool = False
) -> ContractReport:
    """Check a model file or an open session against the contract, version 1.

    Returns the report (every check with pass / warn / fail). With `strict`,
    raises ContractError carrying the first refusal's message instead.
    A path that cannot be loaded raises FileNotFoundError or ContractError.
    """
    session = source if isinstance(source, ort.InferenceSession) else open_session(source)
    try:
        report = check_model(*describe_session(session))
    except ContractError as error:
        if session is source:
            raise
        raise ContractError(f"{source}: {error}") from None
    if strict:
        report.raise_for_refusal()
    return report


# --- acting ----------------------------------------------------------------------


def action_to_control(actions) -> np.ndarray:
    """Pursuer action indices [...] (int, 0..8) -> controls [..., 2] float64:
    (acceleration m/s^2, yaw rate rad/s), by the pursuer action table."""
    actions = np.asarray(actions)
    if actions.dtype.kind not in "iu":
        raise ValueError(f"actions have dtype {actions.dtype}, expected integer action indices")
    if actions.size and (actions.min() < 0 or actions.max() >= NUM_PURSUER_ACTIONS):
        raise ValueError(
            f"actions must lie in [0, {NUM_PURSUER_ACTIONS - 1}], got values in "
            f"[{actions.min()}, {actions.max()}]"
        )
    return PURSUER_ACTIONS[actions]


@dataclass(frozen=True)
class PolicyOutput:
    """What a policy computes for observations with leading shape `...`."""

    q_values: np.ndarray | None
    """[..., 9] float32: expected return of each pursuer action; None for a policy that
    gives actions only (`terl_rt.policy.protocol.CallablePolicy`)."""
    target_weights: np.ndarray | None
    """[..., E] float32 target preference per evader slot (0 on padding), or None
    for models without target selection."""
    actions: np.ndarray
    """[...] int64: argmax of q_values (the first one on ties), or what a shield or
    risk-aware acting chose instead (terl_rt.safety)."""
    quantiles: np.ndarray | None = None
    """[..., K, 9] float32: each action's return at the fixed fractions tau_k = (k + 0.5) / K,
    K = 32 (q_values their mean); None unless asked for from a policy that has them."""
    overridden: np.ndarray | None = None
    """[...] bool: the shield replaced the action the policy (or its risk-aware choice)
    preferred (terl_rt.safety.shield); None without a shield."""

    def first_non_finite(self) -> tuple[str, int, float] | None:
        """(output name, row, value) of the first NaN or Inf in q_values, then in target_weights,
        then in quantiles (row: its index along the first axis), or None when every value is finite."""
        for name, values in (("q_values", self.q_values), ("target_weights", self.target_weights),
                             ("quantiles", self.quantiles)):
            if values is None or np.isfinite(values).all():
                continue
            where = tuple(int(i) for i in np.argwhere(~np.isfinite(values))[0])
            return name, where[0], float(values[where])
        return None


class PolicyRunError(ContractError):
    """A policy that loaded failed inside onnxruntime while it ran (a Reshape that cannot
    apply to this batch, memory it could not allocate): the model is at fault, or the
    machine lacks memory for it; the message names the policy, the batch and the failure."""


MAX_FAILURE_CHARS = 300
"""onnxruntime's own message in a PolicyRunError is cut to this many characters."""


def _run_failure(policy: OnnxPolicy, rows: int, error: Exception) -> PolicyRunError:
    """The PolicyRunError for `error`, raised by onnxruntime on a batch of `rows` rows:
    onnxruntime's node and reason, without its source locations."""
    text = " ".join(str(error).split()) or type(error).__name__
    node = re.search(r"while running (\S+) node", text)
    # "... Status Message: file.h:84 Signature(...) condition was false. The reason." -> the reason
    text = re.split(r"Status Message: |was false\. ", text)[-1]
    if len(text) > MAX_FAILURE_CHARS:
        text = text[: MAX_FAILURE_CHARS - 3] + "..."
    memory = "allocat" in text.lower() or isinstance(error, MemoryError)
    what = "ran out of memory" if memory else "failed"
    where = f" in a {node.group(1)} node" if node else ""
    return PolicyRunError(
        f"policy {policy.name} ({policy.path}) {what} inside onnxruntime{where} on a batch of {rows} rows: {text}"
    )


class OnnxPolicy:
    """One exported policy file, checked against the contract when loaded.

    `threads` sets onnxruntime's intra-op threads (None: its default); execution
    is sequential and deterministic. `model`: the file's bytes, already read (a Ray
    worker gets them from the object store, with no shared filesystem); `path` then only
    names the policy. Raises FileNotFoundError for a missing file and ContractError for
    an unreadable file or one that breaks the contract; `evaluate` raises PolicyRunError
    when the model fails inside onnxruntime.
    """

    def __init__(self, path: str | os.PathLike, threads: int | None = None, model: bytes | None = None):
        self._path = Path(path)
        if model is None:
            model = _read_policy_file(self._path)
        self._model = model
        self._sha256 = hashlib.sha256(model).hexdigest()
        self._session = _session_from_bytes(model, self._path, threads)
        self._report = check_contract(self._session)
        self._report.raise_for_refusal()
        for warning in self._report.warnings:
            logger.warning("%s: %s", self._path, warning.detail)
        self._output_names = ["q_values"]
        if self._report.has_target_weights:
            self._output_names.append("target_weights")

    def __repr__(self) -> str:
        return f"OnnxPolicy({str(self._path)!r}, name={self.name!r}, sha256={self._sha256[:12]}...)"

    @property
    def path(self) -> Path:
        return self._path

    @property
    def name(self) -> str:
        """The model name from metadata `terl.model`."""
        return self._report.metadata[META_MODEL]

    @property
    def metadata(self) -> dict[str, str]:
        """All metadata_props (a copy)."""
        return dict(self._report.metadata)

    @property
    def has_target_weights(self) -> bool:
        return self._report.has_target_weights

    @property
    def has_quantiles(self) -> bool:
        """The file gives the optional output `quantiles` (contract revision 1.1)."""
        return self._report.has_quantiles

    @property
    def sha256(self) -> str:
        """Hex SHA-256 of the file as loaded."""
        return self._sha256

    @property
    def model(self) -> bytes:
        """The ONNX file's bytes as loaded (what `sha256` hashes)."""
        return self._model

    @property
    def report(self) -> ContractReport:
        """The contract check run at load (warnings included)."""
        return self._report

    def evaluate(self, observation: Observation | Mapping[str, np.ndarray], quantiles: bool = False) -> PolicyOutput:
        """Q-values, target weights and greedy actions for every row of `observation`, and
        with `quantiles` the quantiles [..., K, 9] too (ValueError for a file without them).

        The rows go to onnxruntime in calls of at most CALL_ROWS rows, leading dims
        flattened and restored; a row's outputs are the same, bit for bit, whatever rows
        share its call, and whether the quantiles are asked for or not.
        Raises ValueError for an observation that breaks the layout (see
        `observation_inputs`).
        """
        if quantiles and not self.has_quantiles:
            raise ValueError(f"policy {self.name} ({self._path}) has no quantiles output (contract revision 1.1)")
        names = self._output_names + ["quantiles"] * quantiles
        inputs, leading = observation_inputs(observation)
        rows = math.prod(leading)
        num_evaders = inputs["evaders"].shape[-2]
        if rows == 0:
            return PolicyOutput(
                q_values=np.zeros(leading + (NUM_PURSUER_ACTIONS,), np.float32),
                target_weights=(
                    np.zeros(leading + (num_evaders,), np.float32) if self.has_target_weights else None
                ),
                actions=np.zeros(leading, np.int64),
                quantiles=np.zeros(leading + (NUM_QUANTILES, NUM_PURSUER_ACTIONS), np.float32) if quantiles else None,
            )

        flat = {name: array.reshape((rows,) + array.shape[len(leading):]) for name, array in inputs.items()}
        results = [np.concatenate(parts) for parts in zip(*(
            self._run({name: array[part] for name, array in flat.items()}, names)
            for part in _calls(rows)
        ))]
        q_values = self._checked_output("q_values", results[0], (rows, NUM_PURSUER_ACTIONS))
        target_weights = None
        if self.has_target_weights:
            target_weights = self._checked_output("target_weights", results[1], (rows, num_evaders))
            target_weights = target_weights.reshape(leading + (num_evaders,))
        quantile_values = None
        if quantiles:
            shape = (NUM_QUANTILES, NUM_PURSUER_ACTIONS)
            quantile_values = self._checked_output("quantiles", results[-1], (rows,) + shape).reshape(leading + shape)
        actions = np.argmax(q_values, axis=-1).astype(np.int64)
        return PolicyOutput(
            q_values=q_values.reshape(leading + (NUM_PURSUER_ACTIONS,)),
            target_weights=target_weights,
            actions=actions.reshape(leading),
            quantiles=quantile_values,
        )

    def _run(self, feed: dict[str, np.ndarray], names: list[str]) -> list[np.ndarray]:
        """One onnxruntime call on `feed`'s rows. A single row goes in twice: onnxruntime's
        one-row kernels round differently from its batched ones, and a row's result must not
        depend on the rows beside it (an episode evaluated alone or batched with others
        decides the same, bit for bit)."""
        rows = len(feed["ego"])
        if rows == 1:
            feed = {name: np.concatenate([array, array]) for name, array in feed.items()}
        feed = {name: np.ascontiguousarray(array) for name, array in feed.items()}
        try:
            results = self._session.run(names, feed)
        except Exception as error:  # onnxruntime raises its own types (Fail, RuntimeException, ...)
            raise _run_failure(self, len(feed["ego"]), error) from None
        return [result[:rows] for result in results]

    def act(self, observation: Observation | Mapping[str, np.ndarray]) -> np.ndarray:
        """Greedy pursuer actions [...] int64 for observations with leading shape `...`."""
        return self.evaluate(observation).actions

    @staticmethod
    def action_to_control(actions) -> np.ndarray:
        """Action indices [...] -> (acceleration m/s^2, yaw rate rad/s) [..., 2]."""
        return action_to_control(actions)

    def _checked_output(self, name: str, value: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
        # Declared shapes were checked at load; dims left unknown there are checked here.
        if value.shape != shape or value.dtype != np.float32:
            raise ContractError(
                f"{self._path}: output '{name}' came back as {value.dtype} {list(value.shape)}, "
                f"the contract says float32 {list(shape)}"
            )
        return value


CALL_ROWS = 128
"""rows of one onnxruntime call at most: a larger batch goes in near-equal calls of up to
this many rows, whose activations stay in the cores' caches (per row 1,600 rows in one call
took about 1.25x the CPU time of 128-row calls, large-80, one thread, measured under load)."""


def _calls(rows: int) -> list[slice]:
    """The rows [0, rows) cut into ceil(rows / CALL_ROWS) near-equal consecutive calls."""
    count = max(1, math.ceil(rows / CALL_ROWS))
    bounds = [rows * k // count for k in range(count + 1)]
    return [slice(bounds[k], bounds[k + 1]) for k in range(count)]


def policy_info(policy: Any) -> dict[str, Any]:
    """What logs and reports keep of a policy (`terl_rt.policy.protocol.Policy`): name,
    sha256, path (str) and metadata (an ONNX file's metadata_props); a policy without a file
    (a torch network, a function) has an empty sha256 and no metadata."""
    return {"name": policy.name, "sha256": getattr(policy, "sha256", ""), "path": str(policy.path),
            "metadata": getattr(policy, "metadata", {})}
