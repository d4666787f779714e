"""Faster variants of a policy, offered only when they decide as the float graph does.

`optimize_policy` builds each variant of VARIANTS from the policy's ONNX graph and checks
it, stopping at the first check it fails:

1. changed: the graph differs from the float one (a fusion that finds nothing offers nothing);
2. rows alone: every row's outputs are the same, bit for bit, whatever rows share its call,
   without which batched evaluation would not be bit-identical to per-episode runs;
3. decisions: the same greedy action as the float graph on at least DECISION_AGREEMENT of
   the recorded observations' rows (`record_observations`: the float policy's own episodes);
4. suite: on every scenario, its success rate lies inside the float policy's exact 95 %
   interval over the same episodes (terl_rt.evaluation.evaluate.evaluate_policy);
5. faster: its median call on the recorded rows of the largest scenario takes at most
   1 / MIN_SPEEDUP of the float's.

A variant that fails is not offered. Needs the `optimize` extra (onnx, for onnxruntime's
quantisation and transformer tools).
"""

from __future__ import annotations

import contextlib
import io
import logging
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from terl_rt.evaluation.evaluate import evaluate_policy
from terl_rt.evaluation.stats import success_interval
from terl_rt.policy.flops import OnnxMissing
from terl_rt.policy.onnx_policy import OnnxPolicy, observation_inputs
from terl_rt.sim.observation import Observation
from terl_rt.sim.rollout import Rollout
from terl_rt.sim.scenario import Scenario
from terl_rt.sim.world import World

logger = logging.getLogger(__name__)

DECISION_AGREEMENT = 0.995
"""the share of recorded rows on which a variant must choose the float graph's action."""
MIN_SPEEDUP = 1.1
"""how much faster a variant's median call must be than the float's to be offered: beyond
the timing noise of one sitting (a copy of the float graph can read 1.05x)."""


def _fused(source: Path, target: Path, calibration: Sequence[Observation]) -> None:
    """onnxruntime's transformer optimizer: attention, LayerNorm, GELU and bias fusions."""
    from onnxruntime.transformers.optimizer import optimize_model

    optimize_model(str(source), model_type="bert", num_heads=0, hidden_size=0, opt_level=0).save_model_to_file(str(target))


def _int8_dynamic(source: Path, target: Path, calibration: Sequence[Observation]) -> None:
    """Dynamic int8 quantisation of the matrix products (activation scales from each call's rows)."""
    from onnxruntime.quantization import QuantType, quantize_dynamic

    quantize_dynamic(str(source), str(target), weight_type=QuantType.QInt8)


def _int8_static(source: Path, target: Path, calibration: Sequence[Observation]) -> None:
    """Static int8 (QDQ): per-channel weights, activation scales calibrated on the recorded rows."""
    from onnxruntime.quantization import CalibrationDataReader, QuantFormat, QuantType, quantize_static

    class Recorded(CalibrationDataReader):
        def __init__(self) -> None:
            self.feeds = iter([observation_inputs(observation)[0] for observation in calibration])

        def get_next(self):
            return next(self.feeds, None)

    quantize_static(str(source), str(target), Recorded(), quant_format=QuantFormat.QDQ, per_channel=True,
                    weight_type=QuantType.QInt8, activation_type=QuantType.QUInt8)


def build_quietly(build: Callable[[Path, Path, Sequence[Observation]], None], source: Path, target: Path,
                  calibration: Sequence[Observation]) -> None:
    """`build(source, target, calibration)` with what onnxruntime's tools print (their
    warnings, through logging, and stray prints on stdout) kept off the terminal: logged at
    debug level here, so that `-vv` shows it."""
    printed = io.StringIO()
    logging.disable(logging.WARNING)
    try:
        with contextlib.redirect_stdout(printed):
            build(source, target, calibration)
    finally:
        logging.disable(logging.NOTSET)
        if printed.getvalue().strip():
            logger.debug("onnxruntime's tools printed: %s", printed.getvalue().strip())


BUILD_FAILURE_CHARS = 160
"""A variant's build failure is reported in at most this many characters (onnxruntime's own
messages run to a screenful)."""


def build_failure(error: Exception) -> str:
    """The one-line report of a variant that could not be built: the error's type and
    message, cut to BUILD_FAILURE_CHARS."""
    text = " ".join(f"{type(error).__name__}: {error}".split())
    return text if len(text) <= BUILD_FAILURE_CHARS else text[: BUILD_FAILURE_CHARS - 3] + "..."


VARIANTS: dict[str, Callable[[Path, Path, Sequence[Observation]], None]] = {
    "fused": _fused,
    "int8-dynamic": _int8_dynamic,
    "int8-static": _int8_static,
}
"""name -> build(float file, variant file, recorded observations)."""


@dataclass(frozen=True)
class VariantCheck:
    """What one variant's checks found."""

    name: str
    passed: bool
    failed_check: str | None
    """the first check it failed: build, changed, rows alone, decisions, suite or faster (None: passed)."""
    detail: str
    """what that check measured, or the passing variant's figures."""
    agreement: float | None = None
    """share of recorded rows with the float graph's greedy action."""
    speedup: float | None = None
    """float's median call time over the variant's, on the largest scenario's rows."""
    model: bytes | None = None
    """the variant's ONNX file (passing variants only)."""


def record_observations(policy: OnnxPolicy, scenarios: Sequence[Scenario], seed: int, envs: int = 4,
                        steps: int = 60, every: int = 5) -> list[Observation]:
    """Observations of the deciding pursuers met in the float policy's own episodes: for
    each scenario `envs` worlds (seed `seed`) driven `steps` steps, the rows of every
    `every`-th step, one Observation (leading shape [R]) per scenario."""
    recorded = []
    for scenario in scenarios:
        rollout = Rollout(World(scenario, num_envs=envs, seed=seed))
        kept = []
        for step in range(steps):
            turn = rollout.turn()
            rows = turn.observation.rows(turn.rows)
            if step % every == 0:
                kept.append(rows)
            rollout.step(policy.act(rows))
        recorded.append(Observation(**{
            name: np.concatenate([getattr(rows, name) for rows in kept]) for name in Observation.__dataclass_fields__
        }))
    return recorded


def _operators(policy: OnnxPolicy) -> list[str]:
    """The operator types of the policy's graph, in order."""
    import onnx

    return [node.op_type for node in onnx.load_from_string(policy.model).graph.node]


def _rows_alone(variant: OnnxPolicy, observation: Observation) -> bool:
    """The variant gives every row the same outputs in one call of all rows and in calls of 3."""
    together = variant.evaluate(observation)
    rows = len(observation.ego)
    apart = [variant.evaluate(observation.take(np.arange(start, min(start + 3, rows)))) for start in range(0, rows, 3)]
    return np.array_equal(together.q_values, np.concatenate([part.q_values for part in apart]))


def _median_call_s(policy: OnnxPolicy, other: OnnxPolicy, observation: Observation, calls: int = 20) -> tuple[float, float]:
    """Median seconds of one call of `observation` by each policy, timed in turn."""
    times = ([], [])
    for _ in range(calls + 1):
        for index, subject in enumerate((policy, other)):
            start = time.perf_counter()
            subject.evaluate(observation)
            times[index].append(time.perf_counter() - start)
    return float(np.median(times[0][1:])), float(np.median(times[1][1:]))


def check_variant(name: str, variant: OnnxPolicy, policy: OnnxPolicy, recorded: Sequence[Observation],
                  scenarios: Sequence[Scenario], episodes: int, seed: int) -> VariantCheck:
    """Run the module's checks on `variant` against the float `policy`, in order (the
    decision agreement is measured first, so that every variant that was built reports it)."""
    if _operators(variant) == _operators(policy):
        return VariantCheck(name, False, "changed", "the graph came out with the float one's operators "
                            "(nothing was fused or quantised)")
    same = np.concatenate([variant.act(observation) == policy.act(observation) for observation in recorded])
    agreement = float(same.mean())
    if not all(_rows_alone(variant, observation) for observation in recorded):
        return VariantCheck(name, False, "rows alone", "a row's outputs depend on the rows beside it in a call "
                            f"(batched evaluation would differ); same action on {100 * agreement:.2f} % of rows",
                            agreement)
    if agreement < DECISION_AGREEMENT:
        return VariantCheck(name, False, "decisions",
                            f"the float graph's action on {100 * agreement:.2f} % of {same.size} recorded rows "
                            f"(needs {100 * DECISION_AGREEMENT:.1f} %)", agreement)
    for scenario in scenarios:
        ours = evaluate_policy(policy, scenario, episodes, seed)
        theirs = evaluate_policy(variant, scenario, episodes, seed)
        low, high = success_interval(round(ours.success_rate * episodes), episodes)
        if not low <= theirs.success_rate <= high:
            return VariantCheck(name, False, "suite",
                                f"success {theirs.success_rate:.2f} on {scenario.name}, outside the float's "
                                f"[{low:.2f}, {high:.2f}] over {episodes} episodes", agreement)
    largest = max(recorded, key=lambda observation: observation.ego.shape[0])
    float_s, variant_s = _median_call_s(policy, variant, largest)
    if float_s < MIN_SPEEDUP * variant_s:
        return VariantCheck(name, False, "faster", f"median call {1e3 * variant_s:.2f} ms against the float's "
                            f"{1e3 * float_s:.2f} ms (needs {MIN_SPEEDUP:g}x)", agreement, float_s / variant_s)
    return VariantCheck(name, True, None, f"same action on {100 * agreement:.2f} % of rows, "
                        f"{float_s / variant_s:.2f}x faster a call", agreement, float_s / variant_s, variant.model)


def optimize_policy(policy: OnnxPolicy, scenarios: Sequence[Scenario], episodes: int, seed: int,
                    variants: Sequence[str] = tuple(VARIANTS), threads: int | None = 1) -> list[VariantCheck]:
    """Build and check every variant of `variants` (VARIANTS' names) of the float `policy`:
    observations recorded on `scenarios` (seed `seed`), the suite check over `episodes`
    episodes a scenario, each variant on `threads` onnxruntime threads (the float policy's
    own, for fair timings). A variant that onnxruntime's tools cannot build fails its
    "build" check. Raises OnnxMissing without onnx."""
    try:
        import onnx  # noqa: F401  (onnxruntime's tools need it)
    except ImportError as error:
        raise OnnxMissing("optimising a policy needs onnx; install it with: pip install -e '.[optimize]'") from error
    recorded = record_observations(policy, scenarios, seed)
    checks = []
    with tempfile.TemporaryDirectory(prefix="terl-optimize-") as folder:
        source = Path(folder) / "float.onnx"
        source.write_bytes(policy.model)
        for name in variants:
            target = Path(folder) / f"{name}.onnx"
            try:
                build_quietly(VARIANTS[name], source, target, recorded)
                variant = OnnxPolicy(target, threads=threads, model=target.read_bytes())
            except Exception as error:  # onnxruntime's tools raise their own types for graphs they cannot handle
                checks.append(VariantCheck(name, False, "build", build_failure(error)))
                continue
            checks.append(check_variant(name, variant, policy, recorded, scenarios, episodes, seed))
    return checks
