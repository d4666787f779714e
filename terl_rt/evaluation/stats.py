"""Confidence intervals over episodes.

A success rate is a binomial proportion: its 95 % interval is the exact (Clopper-Pearson)
one (`clopper_pearson`: scipy's `binomtest(...).proportion_ci` to 1e-9, without scipy,
whose second OpenBLAS can abort or never return under a memory limit). At 20 successes
in 20 it reads [0.83, 1.00]; at 1,000 in 1,000, [0.996, 1.00]. Means of travel times and
collision ratios get a percentile bootstrap: the episodes are resampled with replacement
BOOTSTRAP_RESAMPLES times from a generator seeded with BOOTSTRAP_SEED, so the same
episodes always give the same interval.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from terl_rt.sim.metrics import EpisodeMetrics

CONFIDENCE = 0.95
BOOTSTRAP_RESAMPLES = 2000
BOOTSTRAP_SEED = 0

CI_METRICS = ("success_rate", "travel_time_s", "travel_time_s_success", "travel_time_s_limit", "collision_ratio")
"""The quantities given with an interval: names of the keys of `episode_intervals`. Travel
times (s): of every episode as it ran, of the successful ones, and with every failure
counted at the step limit."""


def _binomial_tail(successes: int, trials: int, p: float, upper: bool) -> float:
    """P(X >= successes) (upper) or P(X <= successes) for X ~ Binomial(trials, p), summed
    in log space (math.lgamma) so that thousands of trials stay finite."""
    if p <= 0.0 or p >= 1.0:
        return float((p >= 1.0) if upper else (p <= 0.0))
    ks = range(successes, trials + 1) if upper else range(0, successes + 1)
    log_n = math.lgamma(trials + 1)
    return math.fsum(
        math.exp(log_n - math.lgamma(k + 1) - math.lgamma(trials - k + 1) + k * math.log(p) + (trials - k) * math.log1p(-p))
        for k in ks
    )


def clopper_pearson(successes: int, trials: int, confidence: float = CONFIDENCE) -> tuple[float, float]:
    """The exact (Clopper-Pearson) interval of a binomial proportion, without scipy: the
    lower bound is the p at which P(X >= successes) = (1 - confidence) / 2, the upper the p
    at which P(X <= successes) is, each found by bisection to 1e-12 (0 and 1 at the ends)."""
    tail = (1.0 - confidence) / 2

    def solve(upper: bool) -> float:
        low, high = 0.0, 1.0
        while high - low > 1e-12:
            middle = (low + high) / 2
            # P(X >= k) grows with p (the lower bound); P(X <= k) falls (the upper bound).
            if (_binomial_tail(successes, trials, middle, upper) < tail) == upper:
                low = middle
            else:
                high = middle
        return (low + high) / 2

    return (0.0 if successes == 0 else solve(True), 1.0 if successes == trials else solve(False))


def success_interval(successes: int, trials: int, confidence: float = CONFIDENCE) -> tuple[float, float]:
    """The exact (Clopper-Pearson) `confidence` interval of a success rate of `successes`
    in `trials` episodes (`clopper_pearson`); (nan, nan) without episodes."""
    if trials == 0:
        return (float("nan"), float("nan"))
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence must lie in (0, 1), got {confidence}")
    return clopper_pearson(successes, trials, confidence)


def travel_times(per_episode: Sequence[EpisodeMetrics], limit_s: float) -> dict[str, np.ndarray]:
    """[K] s each, by CI_METRICS name: `travel_time_s` every episode as it ran,
    `travel_time_s_success` the successful ones only, `travel_time_s_limit` every episode
    with each failure counted at the step limit `limit_s` (s)."""
    ran = np.array([m.travel_time_s for m in per_episode], dtype=float)
    success = np.array([m.success for m in per_episode], dtype=bool)
    return {
        "travel_time_s": ran,
        "travel_time_s_success": ran[success],
        "travel_time_s_limit": np.where(success, ran, limit_s),
    }


def bootstrap_interval(
    values: Sequence[float] | np.ndarray,
    confidence: float = CONFIDENCE,
    resamples: int = BOOTSTRAP_RESAMPLES,
    seed: int = BOOTSTRAP_SEED,
) -> tuple[float, float]:
    """Percentile bootstrap interval of the mean of `values`; (nan, nan) when empty."""
    data = np.asarray(values, dtype=float)
    if data.size == 0:
        return (float("nan"), float("nan"))
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence must lie in (0, 1), got {confidence}")
    rng = np.random.default_rng(seed)
    means = data[rng.integers(0, data.size, size=(resamples, data.size))].mean(axis=1)
    tail = (1.0 - confidence) / 2
    low, high = np.quantile(means, [tail, 1.0 - tail])
    return (float(low), float(high))


def episode_intervals(per_episode: Sequence[EpisodeMetrics], limit_s: float) -> dict[str, tuple[float, float]]:
    """95 % intervals over `per_episode`, by CI_METRICS name: the success rate's exact one
    (`success_interval`), bootstrap ones of the mean travel times (s; failures at the step
    limit `limit_s` s in `travel_time_s_limit`) and of the mean collision ratio."""
    out = {"success_rate": success_interval(sum(m.success for m in per_episode), len(per_episode))}
    for name, values in travel_times(per_episode, limit_s).items():
        out[name] = bootstrap_interval(values)
    out["collision_ratio"] = bootstrap_interval([m.collision_ratio for m in per_episode])
    return out


def mean_intervals(groups: Sequence[Sequence[EpisodeMetrics]], limit_s: Sequence[float]) -> dict[str, tuple[float, float]]:
    """Intervals of the mean over groups (presets) of each group's mean, by CI_METRICS
    name; `limit_s` [G] s: each group's step limit. The success rate's is the exact interval
    of the pooled episodes (the mean of the presets' rates when they ran as many episodes
    each, as a report's do); the others resample the episodes within each group, so every
    preset keeps its weight."""
    if not groups:
        nan = (float("nan"), float("nan"))
        return dict.fromkeys(CI_METRICS, nan)
    out = {"success_rate": success_interval(sum(m.success for g in groups for m in g), sum(len(g) for g in groups))}
    columns = [{**travel_times(g, limit), "collision_ratio": np.array([m.collision_ratio for m in g])}
               for g, limit in zip(groups, limit_s)]
    rng = np.random.default_rng(BOOTSTRAP_SEED)
    tail = (1.0 - CONFIDENCE) / 2
    for name in CI_METRICS[1:]:
        total = np.zeros(BOOTSTRAP_RESAMPLES)
        for column in columns:
            data = column[name]
            if data.size == 0:  # a preset without a success: no mean of its successes' times
                total[:] = np.nan
                break
            total += data[rng.integers(0, data.size, size=(BOOTSTRAP_RESAMPLES, data.size))].mean(axis=1)
        low, high = np.quantile(total / len(groups), [tail, 1.0 - tail])
        out[name] = (float(low), float(high))
    return out


def format_interval(interval: tuple[float, float], digits: int) -> str:
    """'[low, high]' with `digits` decimals."""
    low, high = interval
    return f"[{low:.{digits}f}, {high:.{digits}f}]"
