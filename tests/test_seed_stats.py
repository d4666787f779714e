"""Aggregates over seeds (terl_rt.paper.seed_stats) on hand-worked tiny cases."""

from __future__ import annotations

import numpy as np
import pytest

from terl_rt.paper.seed_stats import (
    aggregates_with_intervals,
    bootstrap_scores,
    improvement_with_interval,
    iqm,
    mean,
    probability_of_improvement,
    scores,
)


def episodes(*per_seed: list[float]) -> np.ndarray:
    """[S, K, 1]: one metric, the episodes of each seed."""
    return np.array(per_seed, dtype=float)[:, :, None]


def test_iqm_cuts_a_quarter_of_the_scores_at_each_end():
    # 8 scores: cut 2 lowest (0, 1) and 2 highest (100, 7); mean of 2, 3, 4, 5 = 3.5.
    values = np.array([[0.0, 100.0, 3.0, 5.0], [1.0, 2.0, 4.0, 7.0]])
    assert iqm(values) == pytest.approx(3.5)
    assert mean(values) == pytest.approx(122.0 / 8)


def test_iqm_of_fewer_than_four_scores_is_their_mean():
    assert iqm(np.array([[1.0], [2.0], [6.0]])) == pytest.approx(3.0)


def test_iqm_is_taken_over_the_last_two_axes_for_each_leading_index():
    values = np.stack([np.arange(8.0).reshape(2, 4), 10 + np.arange(8.0).reshape(2, 4)])
    np.testing.assert_allclose(iqm(values), [3.5, 13.5])


def test_scores_are_each_seeds_mean_over_its_episodes_of_each_preset():
    small = episodes([1, 0, 1, 0], [1, 1, 1, 1])
    large = episodes([0, 0], [1, 0])
    np.testing.assert_allclose(scores([small, large])[..., 0], [[0.5, 0.0], [1.0, 0.5]])


def test_scores_refuse_presets_with_different_seed_counts():
    with pytest.raises(ValueError, match=r"\[S=2, K >= 1, Q\]"):
        scores([episodes([1, 0], [1, 1]), episodes([1, 0])])


def test_a_resample_draws_whole_seeds_then_episodes_within_them():
    # Seed 0 only ever scores 0, seed 1 only 10: each resampled seed's score is 0 or 10,
    # never a mixture, so episodes never cross from one seed to another.
    data = episodes([0, 0, 0], [10, 10, 10])
    resampled = bootstrap_scores([data], np.random.default_rng(1), resamples=200)
    assert resampled.shape == (200, 2, 1, 1)
    assert set(np.unique(resampled)) == {0.0, 10.0}


def test_the_interval_of_identical_seeds_and_episodes_is_the_point():
    (value,), (interval,) = aggregates_with_intervals([episodes([1, 1], [1, 1])], [mean], resamples=50)
    assert value[0] == 1.0 and interval[:, 0].tolist() == [1.0, 1.0]


def test_the_bootstrap_interval_covers_the_mean_it_was_drawn_around():
    rng = np.random.default_rng(3)
    data = rng.normal(5.0, 1.0, size=(3, 40, 1))
    values, intervals = aggregates_with_intervals([data, data + 1.0], [mean, iqm], resamples=500)
    for value, interval in zip(values, intervals):  # the mean, then the IQM
        assert interval[0, 0] < value[0] < interval[1, 0]
        assert interval[0, 0] < 5.5 < interval[1, 0]  # the true mean of both presets


def test_the_same_episodes_give_the_same_interval():
    data = [episodes([1, 0, 1], [0, 0, 1])]
    first, second = (aggregates_with_intervals(data, [iqm], resamples=100)[1] for _ in range(2))
    assert first.tobytes() == second.tobytes()


def test_probability_of_improvement_is_one_when_every_score_beats_every_other():
    better = np.array([[0.9, 0.8], [0.7, 0.95]])
    worse = np.array([[0.1, 0.2], [0.3, 0.0], [0.5, 0.6]])
    assert probability_of_improvement(better, worse) == 1.0
    assert probability_of_improvement(worse, better) == 0.0


def test_probability_of_improvement_of_equal_scores_is_one_half():
    same = np.array([[1.0], [1.0]])
    assert probability_of_improvement(same, same) == 0.5


def test_probability_of_improvement_averages_the_presets_pair_counts():
    # Preset 0: X's 2 beats Y's 1, ties Y's 2: (1 + 0.5) / 2 = 0.75. Preset 1: loses both: 0.
    x = np.array([[2.0, 0.0]])
    y = np.array([[1.0, 5.0], [2.0, 6.0]])
    assert probability_of_improvement(x, y) == pytest.approx(0.375)


def test_lower_is_better_metrics_compare_negated_scores():
    fast = [episodes([10, 12], [11, 11])]
    slow = [episodes([30, 31], [29, 35])]
    value, interval = improvement_with_interval(fast, slow, sign=np.array([-1.0]), resamples=100)
    assert value[0] == 1.0 and interval[:, 0].tolist() == [1.0, 1.0]
