"""The paper's comparison with several training seeds a method: who each policy is, and the
aggregates over seeds (what `terl_rt.paper.seed_comparison_files` writes as
docs/comparison.md, .png, .json and the marl-eval export).

A grid ships each seed's policy as exported/comparison/<method>-seed-<S>.onnx, its
metadata naming the method (`terl.method`, a recipe stem: terl, iqn, dqn, mean,
terl-no-re, terl-no-ts) and the seed (`terl.seed`). A file without those keys counts as
one seed of the method its `terl.model` names, its seed read from `terl.training_config`'s
"seed" (`policy_identity`); the file's name is not read.

`seed_statistics` takes one `SeedRun` a policy (its evaluations on the same scenarios) and
computes, per method and scale group, the mean and the interquartile mean over seeds of
each metric's per-(seed, preset) means with 95 % stratified bootstrap intervals, and the
probability that TERL beats each other method (`terl_rt.paper.seed_stats`); and the
paper's claims judged on those means (`seed_claim_checks`).

Beyond the paper, `beyond_scenarios` grows large-80's world to BEYOND_PURSUERS pursuers as
`terl-rt bench scaling` does (evaders a quarter of the pursuers, the arena grown to keep
the density); each is a scale group of its own.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass

import numpy as np

from terl_rt.evaluation.episodes import ScenarioResult
from terl_rt.evaluation.speed import scaling_scenario
from terl_rt.evaluation.stats import success_interval, travel_times
from terl_rt.paper import seed_stats
from terl_rt.paper.claims import NOT_MEASURED, ClaimCheck, check_claims
from terl_rt.paper.comparison import DEFAULT_TERL, ComparisonError, method_name, paper_order
from terl_rt.paper.numbers import REPORT_GROUPS, TERL, scale_group
from terl_rt.policy.contract import META_METHOD, META_MODEL, META_SEED, META_TRAINING_CONFIG
from terl_rt.sim.scenario import Scenario

CANNOT_TELL = "cannot tell"
"""A claim's verdict when the 95 % intervals overlap where the criterion compares them."""

BEYOND_PURSUERS: tuple[int, ...] = (160, 240, 400)
"""Team sizes past the paper's largest (80), in the worlds of `terl-rt bench scaling`."""

METRICS: tuple[str, ...] = ("success_rate", "travel_time_s", "travel_time_s_limit", "collision_ratio")
"""The per-episode metrics aggregated: success (0 or 1), travel time (s) as run, travel
time (s) with each failure counted at the step limit, collision ratio."""
HIGHER_IS_BETTER = np.array([1.0, -1.0, -1.0, -1.0])
"""+1 where a higher value of METRICS' metric is better, -1 where lower is."""
AGGREGATES = {"mean": seed_stats.mean, "iqm": seed_stats.iqm}
"""The aggregates over seeds: mean and interquartile mean of the (seed, preset) scores."""


@dataclass(frozen=True)
class SeedRun:
    """One seed's policy and its evaluations."""

    method: str
    """the paper's name of its method (`comparison.method_name` of the recipe stem): TERL, IQN, ..."""
    seed: int | None
    """its training seed; None where its metadata does not say."""
    policy: Mapping
    """name, sha256, path and metadata, as `terl_rt.policy.onnx_policy.policy_info` gives them."""
    results: tuple[ScenarioResult, ...]
    """its evaluations, one a scenario, the same scenarios for every run."""


def method_stem(metadata: Mapping[str, str]) -> str:
    """The recipe stem of a policy's method: `terl.method`, else `terl.model` ("" if neither)."""
    return metadata.get(META_METHOD) or metadata.get(META_MODEL, "")


def policy_identity(metadata: Mapping[str, str], terl: str = DEFAULT_TERL) -> tuple[str, int | None]:
    """(the paper's method name, training seed or None) of a policy's metadata: the method
    `method_name` gives its `method_stem` (`terl`: the stem that stands for TERL); the seed
    from `terl.seed`, else that of `terl.training_config`'s JSON: its "run" section's "seed"
    (the config as `training` writes it), or a "seed" at the top (the flat config of the first
    exports). ValueError when terl.seed is not an integer."""
    method = method_name(method_stem(metadata), terl)
    if META_SEED in metadata:
        try:
            return method, int(metadata[META_SEED])
        except ValueError:
            raise ValueError(f"metadata '{META_SEED}' is {metadata[META_SEED]!r}, expected an integer") from None
    try:
        config = json.loads(metadata.get(META_TRAINING_CONFIG, "{}"))
        run = config.get("run")
        seed = run.get("seed") if isinstance(run, dict) else config.get("seed")
    except (ValueError, AttributeError):
        seed = None
    return method, seed if isinstance(seed, int) and not isinstance(seed, bool) else None


def check_seeds(policies: Sequence[tuple[str, int | None, str]]) -> None:
    """Raise ComparisonError when two of the (method, seed, policy path) triples are one
    method and either the same seed or one of them without a seed (they cannot be told apart)."""
    for first, (method, seed, path) in enumerate(policies):
        for other_method, other_seed, other_path in policies[first + 1:]:
            if method != other_method:
                continue
            if seed is None or other_seed is None:
                unseeded = path if seed is None else other_path
                raise ComparisonError(
                    f"{path} and {other_path} are both method {method!r} and {unseeded} has no seed (metadata "
                    "terl.seed, or the seed of terl.training_config), so they cannot be told apart as seeds"
                )
            if seed == other_seed:
                raise ComparisonError(f"{path} and {other_path} are both method {method!r}, seed {seed}")


def beyond_scenarios() -> list[Scenario]:
    """The worlds of BEYOND_PURSUERS pursuers (`terl_rt.evaluation.speed.scaling_scenario`)."""
    return [scaling_scenario(pursuers) for pursuers in BEYOND_PURSUERS]


def beyond_group(pursuers: int) -> str:
    """The scale group of the world of `pursuers` pursuers beyond the paper: '160 pursuers'."""
    return f"{pursuers} pursuers"


SEED_GROUPS: tuple[str, ...] = (*REPORT_GROUPS, *(beyond_group(n) for n in BEYOND_PURSUERS))
"""The scale groups of a seed comparison, in order: the paper's, then the ones beyond it."""
_BEYOND_NAMES = {scaling_scenario(n).name: beyond_group(n) for n in BEYOND_PURSUERS}
"""scaling_scenario(n).name -> its group."""


def group_of(scenario_name: str) -> str | None:
    """The scale group of a scenario (one of SEED_GROUPS), None for one outside them."""
    return scale_group(scenario_name) or _BEYOND_NAMES.get(scenario_name)


# --- aggregates --------------------------------------------------------------------------


@dataclass(frozen=True)
class Aggregate:
    """One method on one scale group, over its seeds."""

    method: str
    group: str
    seeds: int
    presets: tuple[str, ...]
    episodes: int
    """episodes of each seed on each preset (the fewest where they differ)."""
    values: dict
    """aggregate ('mean', 'iqm') -> metric (METRICS) -> value."""
    ci95: dict
    """aggregate -> metric -> (low, high): 95 % stratified bootstrap interval, but for the
    success rate where `success_exact`."""
    success_exact: bool = False
    """the success rate's intervals are the exact (Clopper-Pearson) one over every episode of
    the group (`exact_success_interval`): one seed, or every episode alike."""

    def to_dict(self) -> dict:
        return {**asdict(self), "presets": list(self.presets),
                "ci95": {a: {m: list(ci) for m, ci in by.items()} for a, by in self.ci95.items()}}


@dataclass(frozen=True)
class Improvement:
    """P(TERL > other) on one scale group: the probability that a TERL seed's score on a
    preset beats the other method's, ties counting one half, averaged over the presets."""

    method: str
    """the other method."""
    group: str
    probability: dict
    """metric (METRICS) -> P(TERL better): higher success, lower travel time and collisions."""
    ci95: dict
    """metric -> (low, high): 95 % stratified bootstrap interval, both methods resampled."""

    def to_dict(self) -> dict:
        return {**asdict(self), "ci95": {m: list(ci) for m, ci in self.ci95.items()}}


def episode_metrics(result: ScenarioResult) -> np.ndarray:
    """[K, Q]: each episode's METRICS."""
    episodes = result.per_episode
    times = travel_times(episodes, result.limit_s)
    return np.column_stack([
        [float(m.success) for m in episodes], times["travel_time_s"], times["travel_time_s_limit"],
        [m.collision_ratio for m in episodes],
    ])


def method_runs(runs: Sequence[SeedRun]) -> dict[str, list[SeedRun]]:
    """method -> its runs by seed, the methods in the paper's order."""
    by_method: dict[str, list[SeedRun]] = {}
    for run in sorted(runs, key=lambda r: (paper_order(r.method), -1 if r.seed is None else r.seed)):
        by_method.setdefault(run.method, []).append(run)
    return by_method


def group_presets(runs: Sequence[SeedRun]) -> dict[str, list[np.ndarray]]:
    """group -> [P] arrays [S, K, Q] (S seeds of one method; a preset's K episodes, the
    fewest any seed ran), for every group whose presets every seed was evaluated on."""
    names = [r.name for r in runs[0].results]
    per_seed = [{r.name: r for r in run.results} for run in runs]
    out: dict[str, list[np.ndarray]] = {}
    for group in SEED_GROUPS:
        presets = [n for n in names if group_of(n) == group]
        if not presets or any(name not in results for results in per_seed for name in presets):
            continue
        arrays = []
        for name in presets:
            metrics = [episode_metrics(results[name]) for results in per_seed]
            episodes = min(len(m) for m in metrics)
            arrays.append(np.stack([m[:episodes] for m in metrics]))
        out[group] = arrays
    return out


@dataclass(frozen=True)
class SeedStatistics:
    """What a seed comparison reports, computed once (`seed_statistics`)."""

    aggregates: tuple[Aggregate, ...]
    """every method on every group its seeds were all evaluated on, in SEED_GROUPS' order,
    then the paper's order of methods."""
    improvements: tuple[Improvement, ...]
    """P(TERL better) than every other method on every group both were evaluated on; none without TERL."""
    claims: tuple[ClaimCheck, ...]
    """the paper's claims judged on the aggregates (`seed_claim_checks`)."""


def seed_statistics(runs: Sequence[SeedRun]) -> SeedStatistics:
    """The aggregates, probabilities of improvement and claims of `runs`."""
    by_method = method_runs(runs)
    presets = {method: group_presets(seed_runs) for method, seed_runs in by_method.items()}
    rows, better = [], []
    for group in SEED_GROUPS:
        for method, seed_runs in by_method.items():
            if group not in presets[method]:
                continue
            values, intervals = seed_stats.aggregates_with_intervals(presets[method][group], list(AGGREGATES.values()))
            ci95 = {name: _intervals_by_metric(intervals[a]) for a, name in enumerate(AGGREGATES)}
            exact = exact_success_interval(presets[method][group])
            if exact is not None:
                for by_metric in ci95.values():
                    by_metric["success_rate"] = exact
            rows.append(Aggregate(
                method, group, len(seed_runs), tuple(r.name for r in seed_runs[0].results if group_of(r.name) == group),
                min(p.shape[1] for p in presets[method][group]),
                {name: _by_metric(values[a]) for a, name in enumerate(AGGREGATES)}, ci95, exact is not None,
            ))
        terl = presets.get(TERL, {}).get(group)
        for method in by_method:
            other = presets[method].get(group)
            if method == TERL or terl is None or other is None or len(other) != len(terl):
                continue
            value, interval = seed_stats.improvement_with_interval(terl, other, HIGHER_IS_BETTER)
            better.append(Improvement(method, group, _by_metric(value), _intervals_by_metric(interval)))
    return SeedStatistics(tuple(rows), tuple(better), tuple(seed_claim_checks(rows)))


def exact_success_interval(presets: Sequence[np.ndarray]) -> tuple[float, float] | None:
    """The exact (Clopper-Pearson) 95 % interval of the success rate over every episode of
    `presets` ([P] arrays [S, K, Q]) where the stratified bootstrap cannot move (one seed: no
    seeds to draw again; every episode alike: nothing to draw but that), None elsewhere. The
    success rate's mean (and IQM) is then the pooled rate: a group's presets run alike many
    episodes, and with one seed or every score equal nothing is trimmed."""
    success = np.concatenate([data[..., METRICS.index("success_rate")].ravel() for data in presets])
    if presets[0].shape[0] > 1 and 0 < success.sum() < success.size:
        return None
    return success_interval(int(success.sum()), success.size)


def _by_metric(values: np.ndarray) -> dict[str, float]:
    """[Q] -> metric -> value."""
    return {metric: float(value) for metric, value in zip(METRICS, values)}


def _intervals_by_metric(intervals: np.ndarray) -> dict[str, tuple[float, float]]:
    """[2, Q] -> metric -> (low, high)."""
    return {metric: (float(intervals[0, q]), float(intervals[1, q])) for q, metric in enumerate(METRICS)}


# --- claims --------------------------------------------------------------------------


def seed_claim_checks(rows: Sequence[Aggregate]) -> list[ClaimCheck]:
    """The paper's claims (`claims.CLAIMS`) judged on the means over seeds and their
    95 % stratified bootstrap intervals: 'reproduces' or 'does not reproduce' where the
    intervals give that verdict too, 'cannot tell' where they overlap, 'not measured'
    where a method or group a claim needs was not evaluated."""
    checks = check_claims({
        (row.method, row.group): (row.values["mean"], row.ci95["mean"]) for row in rows if row.group in REPORT_GROUPS
    })
    return [
        check if check.verdict == NOT_MEASURED or check.clear else ClaimCheck(
            check.claim, check.criterion, check.measured, CANNOT_TELL, check.clear, check.in_paper)
        for check in checks
    ]
