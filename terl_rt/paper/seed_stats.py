"""Aggregates over training seeds as rliable recommends (Agarwal et al. 2021, "Deep RL at
the edge of the statistical precipice"): interquartile mean, mean, stratified bootstrap
intervals and the probability of improvement.

The data of one method on one scale group is a list with one array a preset ("task" in
rliable's words) of shape [S, K, Q]: S seeds ("runs"), K episodes of each seed on that
preset, Q per-episode metrics (success 0/1, travel time in s, collision ratio, ...).
A seed's score on a preset is its mean over the K episodes; `scores` gives the [S, P]
matrix of P presets that rliable's aggregates read (there [runs, tasks]).

Intervals come from a two-level stratified bootstrap (`bootstrap_scores`): in each of
RESAMPLES resamples, for every preset apart, the S seeds are drawn with replacement, and
then each drawn seed's K episodes on that preset are drawn with replacement. So an
interval carries both sources of noise: which seeds were trained (rliable's bootstrap over
runs, stratified by task) and which episodes were run. The generator is seeded with
BOOTSTRAP_SEED: the same episodes always give the same interval.

rliable itself (PyPI `rliable` 1.2.0) is not used: it pulls arch, pandas, seaborn and
absl-py into what is otherwise a NumPy runtime, and its bootstrap resamples runs only,
not the episodes within a run. The three formulas it implements are a few lines each.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

CONFIDENCE = 0.95
RESAMPLES = 2000
BOOTSTRAP_SEED = 0

Aggregate = Callable[[np.ndarray], np.ndarray]
"""An aggregate of scores [..., S, P] over their last two axes, giving [...]."""


def scores(presets: Sequence[np.ndarray]) -> np.ndarray:
    """[S, P, Q]: each seed's mean over its episodes of each preset; `presets` [P] arrays
    [S, K_p, Q] (K_p episodes of every seed on preset p)."""
    return np.stack([_check(data, presets[0].shape[0]).mean(axis=1) for data in presets], axis=1)


def mean(values: np.ndarray) -> np.ndarray:
    """Mean over the last two axes ([..., S, P] -> [...]): every (seed, preset) score weighs the same."""
    return values.mean(axis=(-2, -1))


def iqm(values: np.ndarray) -> np.ndarray:
    """Interquartile mean over the last two axes ([..., S, P] -> [...]): the mean of the
    scores left once the floor(n / 4) lowest and floor(n / 4) highest of the n = S * P
    are cut (scipy.stats.trim_mean(..., 0.25) over both axes, as rliable computes it). With
    fewer than 4 scores nothing is cut and it is the mean."""
    flat = np.sort(values.reshape(*values.shape[:-2], -1), axis=-1)
    cut = flat.shape[-1] // 4
    return flat[..., cut:flat.shape[-1] - cut].mean(axis=-1)


def bootstrap_scores(presets: Sequence[np.ndarray], rng: np.random.Generator, resamples: int = RESAMPLES) -> np.ndarray:
    """[R, S, P, Q] scores of `resamples` stratified bootstrap resamples of `presets` ([P]
    arrays [S, K_p, Q]): for each preset apart, S seeds drawn with replacement, then each
    drawn seed's K_p episodes drawn with replacement (the module's docstring)."""
    seeds = presets[0].shape[0]
    out = []
    for data in presets:
        _check(data, seeds)
        episodes = data.shape[1]
        seed_index = rng.integers(0, seeds, size=(resamples, seeds, 1))
        episode_index = rng.integers(0, episodes, size=(resamples, seeds, episodes))
        out.append(data[seed_index, episode_index].mean(axis=2))  # [R, S, K, Q] -> [R, S, Q]
    return np.stack(out, axis=2)


def percentile_interval(samples: np.ndarray, confidence: float = CONFIDENCE) -> np.ndarray:
    """[2, ...]: the (1 - confidence) / 2 and (1 + confidence) / 2 quantiles of `samples`
    [R, ...] over their first axis (the percentile bootstrap interval)."""
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence must lie in (0, 1), got {confidence}")
    tail = (1.0 - confidence) / 2
    return np.quantile(samples, [tail, 1.0 - tail], axis=0)


def aggregates_with_intervals(
    presets: Sequence[np.ndarray], aggregates: Sequence[Aggregate], resamples: int = RESAMPLES,
    seed: int = BOOTSTRAP_SEED,
) -> tuple[np.ndarray, np.ndarray]:
    """(values [A, Q], intervals [A, 2, Q]): each of the A `aggregates` (`mean`, `iqm`) of
    the scores of `presets` ([P] arrays [S, K_p, Q]) and its 95 % stratified bootstrap
    interval, all from the same resamples."""
    point = np.moveaxis(scores(presets), -1, 0)  # [Q, S, P]
    resampled = np.moveaxis(bootstrap_scores(presets, np.random.default_rng(seed), resamples), -1, 1)  # [R, Q, S, P]
    return (np.stack([aggregate(point) for aggregate in aggregates]),
            np.stack([percentile_interval(aggregate(resampled)) for aggregate in aggregates]))


def probability_of_improvement(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """P(X > Y) averaged over presets: for each preset, the share of (seed of X, seed of Y)
    pairs where X's score is higher, a tie counting one half (the Mann-Whitney U statistic
    over S_x * S_y), then the mean over presets. x [..., S_x, P], y [..., S_y, P] -> [...].
    1 when every score of X beats every one of Y, 0.5 when all are equal. For a metric
    where lower is better, pass the negated scores."""
    difference = x[..., :, None, :] - y[..., None, :, :]  # [..., S_x, S_y, P]
    wins = (difference > 0).astype(float) + 0.5 * (difference == 0)
    return wins.mean(axis=(-3, -2, -1))


def improvement_with_interval(
    x: Sequence[np.ndarray], y: Sequence[np.ndarray], sign: np.ndarray,
    resamples: int = RESAMPLES, seed: int = BOOTSTRAP_SEED,
) -> tuple[np.ndarray, np.ndarray]:
    """(P(X > Y) [Q], interval [2, Q]) of methods X and Y on the same presets (each [P]
    arrays [S, K_p, Q]; the seed counts may differ), metric q compared on sign[q] x score
    (+1 where higher is better, -1 where lower is); X and Y are resampled independently,
    each stratified as in `bootstrap_scores`."""
    sign = np.asarray(sign, dtype=float)
    point = probability_of_improvement(np.moveaxis(sign * scores(x), -1, 0), np.moveaxis(sign * scores(y), -1, 0))
    rng = np.random.default_rng(seed)
    x_samples = np.moveaxis(sign * bootstrap_scores(x, rng, resamples), -1, 1)
    y_samples = np.moveaxis(sign * bootstrap_scores(y, rng, resamples), -1, 1)
    return point, percentile_interval(probability_of_improvement(x_samples, y_samples))


def _check(data: np.ndarray, seeds: int) -> np.ndarray:
    """`data` if it is [S, K, Q] with `seeds` seeds and at least one episode."""
    if data.ndim != 3 or data.shape[0] != seeds or data.shape[1] < 1:
        raise ValueError(
            f"every preset's episodes must be [S={seeds}, K >= 1, Q] (seeds, episodes, metrics), got {list(data.shape)}"
        )
    return data
