"""Confidence intervals over episodes: a percentile bootstrap with a fixed seed.

`terl-rt eval` and `terl-rt report` give each scenario's success rate, mean travel time
and mean collision ratio with a 95 % interval: the episodes are resampled with
replacement BOOTSTRAP_RESAMPLES times from a generator seeded with BOOTSTRAP_SEED, so
the same episodes always give the same interval. With 20 episodes an interval is
wide (a success rate of 1.00 over 20 episodes reads [1.00, 1.00]: the bootstrap cannot
see failures that never happened; read it as "at least about 0.86" by the rule of three).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from terl_rt.sim.metrics import EpisodeMetrics

CONFIDENCE = 0.95
BOOTSTRAP_RESAMPLES = 2000
BOOTSTRAP_SEED = 0

CI_METRICS = ("success_rate", "travel_time_s", "collision_ratio")
"""The quantities given with an interval: names of the keys of `episode_intervals`."""


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


def episode_intervals(per_episode: Sequence[EpisodeMetrics]) -> dict[str, tuple[float, float]]:
    """95 % intervals of the success rate, the mean travel time (s) and the mean
    collision ratio over `per_episode`, by CI_METRICS name."""
    columns = {
        "success_rate": [float(m.success) for m in per_episode],
        "travel_time_s": [m.travel_time_s for m in per_episode],
        "collision_ratio": [m.collision_ratio for m in per_episode],
    }
    return {name: bootstrap_interval(columns[name]) for name in CI_METRICS}


def mean_intervals(groups: Sequence[Sequence[EpisodeMetrics]]) -> dict[str, tuple[float, float]]:
    """Intervals of the mean over groups (presets) of each group's mean: the episodes are
    resampled within each group, so every preset keeps its weight."""
    if not groups:
        nan = (float("nan"), float("nan"))
        return dict.fromkeys(CI_METRICS, nan)
    rng = np.random.default_rng(BOOTSTRAP_SEED)
    out = {}
    getters = {
        "success_rate": lambda m: float(m.success),
        "travel_time_s": lambda m: m.travel_time_s,
        "collision_ratio": lambda m: m.collision_ratio,
    }
    tail = (1.0 - CONFIDENCE) / 2
    for name in CI_METRICS:
        total = np.zeros(BOOTSTRAP_RESAMPLES)
        for group in groups:
            data = np.array([getters[name](m) for m in group], dtype=float)
            total += data[rng.integers(0, data.size, size=(BOOTSTRAP_RESAMPLES, data.size))].mean(axis=1)
        low, high = np.quantile(total / len(groups), [tail, 1.0 - tail])
        out[name] = (float(low), float(high))
    return out


def format_interval(interval: tuple[float, float], digits: int) -> str:
    """'[low, high]' with `digits` decimals."""
    low, high = interval
    return f"[{low:.{digits}f}, {high:.{digits}f}]"
