"""Results a researcher can use: every episode in --json and --csv, confidence intervals, ETA."""

from __future__ import annotations

import csv
import json

import click
import numpy as np
import pytest
from click.testing import CliRunner
from onnx_models import write_test_policy

from terl_rt import Scenario, Simulator
from terl_rt.cli.eval import CSV_COLUMNS, TABLE_WIDTH
from terl_rt.cli.main import cli
from terl_rt.evaluation.episodes import ScenarioResult, episode_outcome
from terl_rt.evaluation.stats import (
    CI_METRICS,
    bootstrap_interval,
    clopper_pearson,
    episode_intervals,
    mean_intervals,
    success_interval,
    travel_times,
)
from terl_rt.policy.onnx_policy import OnnxPolicy
from terl_rt.sim.metrics import EpisodeMetrics


def metrics(success: bool, steps: int, collided: int = 0, encircled: int = 1, pursuers: int = 10) -> EpisodeMetrics:
    return EpisodeMetrics(
        success=success, steps=steps, travel_time_s=steps * 0.5, collision_ratio=collided / pursuers,
        evaders_encircled=encircled, pursuers_collided=collided,
    )


@pytest.fixture(scope="module")
def policy(tmp_path_factory):
    return write_test_policy(tmp_path_factory.mktemp("results") / "linear.onnx")


def invoke(*args):
    return CliRunner().invoke(cli, [str(arg) for arg in args])


def test_bootstrap_interval_is_deterministic_and_brackets_the_mean():
    values = np.random.default_rng(5).normal(50.0, 10.0, 20)
    low, high = bootstrap_interval(values)
    assert (low, high) == bootstrap_interval(values)
    assert low < values.mean() < high
    # about 1.96 standard errors either side
    assert (high - low) / 2 == pytest.approx(1.96 * values.std() / np.sqrt(20), rel=0.2)
    assert bootstrap_interval([1.0, 1.0, 1.0]) == (1.0, 1.0)
    assert all(np.isnan(bootstrap_interval([])))


def test_episode_intervals_cover_success_travel_times_and_collisions():
    episodes = [metrics(True, 100), metrics(False, 1000, collided=8), metrics(True, 120, collided=1)] * 4
    intervals = episode_intervals(episodes, limit_s=500.0)
    assert set(intervals) == set(CI_METRICS)
    low, high = intervals["success_rate"]
    assert 0.0 <= low < 2 / 3 < high <= 1.0
    groups = mean_intervals([episodes, episodes[:3]], [500.0, 500.0])
    assert set(groups) == set(intervals)


def test_success_interval_is_exact_for_all_successes():
    # Clopper-Pearson at k = n: the lower bound solves p^n = 0.025, so 0.025^(1/20) = 0.8316 at n = 20.
    assert success_interval(20, 20) == pytest.approx((0.025 ** (1 / 20), 1.0), abs=1e-9)
    assert success_interval(1000, 1000)[0] == pytest.approx(0.025 ** (1 / 1000), abs=1e-9)  # 0.9963
    assert success_interval(0, 20) == pytest.approx((0.0, 1 - 0.025 ** (1 / 20)), abs=1e-9)


@pytest.mark.parametrize("successes, trials", [(0, 7), (3, 20), (17, 20), (500, 1000), (999, 1000)])
def test_clopper_pearson_without_scipy_is_scipys_interval(successes, trials):
    binomtest = pytest.importorskip("scipy.stats").binomtest
    exact = binomtest(successes, trials).proportion_ci(0.95, method="exact")
    assert clopper_pearson(successes, trials) == pytest.approx((exact.low, exact.high), abs=1e-9)


def test_travel_time_over_successes_and_with_failures_at_the_limit():
    # successes at 50 s and 60 s, a failure after 20 s: successes 55 s; failures at the 500 s limit (50 + 60 + 500) / 3.
    times = travel_times([metrics(True, 100), metrics(True, 120), metrics(False, 40, collided=8)], limit_s=500.0)
    assert times["travel_time_s_success"].tolist() == [50.0, 60.0]
    assert times["travel_time_s_limit"].mean() == pytest.approx(610 / 3)
    assert times["travel_time_s"].tolist() == [50.0, 60.0, 20.0]


def test_outcome_names_how_an_episode_ended():
    assert episode_outcome(metrics(True, 50), 1000) == "success"
    assert episode_outcome(metrics(False, 1000), 1000) == "step_limit"
    assert episode_outcome(metrics(False, 40, collided=8), 1000) == "too_few_pursuers"


def test_eval_json_carries_every_episode_the_step_limit_and_versions(policy):
    result = invoke("eval", "--policy", policy, "--scenario", "small-11", "--episodes", "3", "--seed", "7",
                    "--max-steps", "4", "--json")
    assert result.exit_code == 0, result.output
    out = json.loads(result.stdout)
    assert out["terl_rt"] and out["policy"]["contract"] == "1" and len(out["policy"]["sha256"]) == 64
    (row,) = out["scenarios"]
    assert row["max_steps"] == 4 and row["seed"] == 7
    assert [e["seed"] for e in row["per_episode"]] == [7, 8, 9]
    for episode in row["per_episode"]:
        assert set(episode) == {
            "episode", "seed", "outcome", "success", "steps", "travel_time_s", "collisions", "collisions_teammate",
            "collisions_evader", "collisions_obstacle", "collision_ratio", "captures", "return",
        }
        assert episode["outcome"] in ("success", "step_limit", "too_few_pursuers")
    assert set(row["ci95"]) == set(CI_METRICS)
    low, high = row["ci95"]["travel_time_s"]
    assert low <= row["travel_time_s_mean"] <= high


def test_an_episode_s_return_is_every_reward_of_every_pursuer_summed():
    scenario = Scenario.preset("small-11").replace(max_steps=6)
    sim = Simulator(scenario, seed=3)
    sim.reset()
    rng = np.random.default_rng(0)
    total = 0.0
    while not sim.done:
        _, info = sim.step(rng.integers(0, 9, scenario.pursuers))
        total += info.reward.sum()
    assert sim.metrics().team_return == pytest.approx(total, rel=1e-12)


def test_eval_csv_writes_one_row_per_episode(policy, tmp_path):
    path = tmp_path / "episodes.csv"
    result = invoke("eval", "--policy", policy, "--scenario", "small-11", "--scenario", "small-15",
                    "--episodes", "2", "--max-steps", "4", "--csv", path)
    assert result.exit_code == 0, result.output
    with open(path, newline="") as handle:
        rows = list(csv.DictReader(handle))
    assert tuple(rows[0]) == CSV_COLUMNS
    assert [(r["scenario"], r["episode"], r["seed"]) for r in rows] == [
        ("small-11", "0", "0"), ("small-11", "1", "1"), ("small-15", "0", "0"), ("small-15", "1", "1"),
    ]
    assert all(r["outcome"] == "step_limit" and r["max_steps"] == "4" for r in rows)


def test_eval_table_shows_the_intervals(policy):
    result = invoke("eval", "--policy", policy, "--scenario", "small-11", "--episodes", "2", "--max-steps", "4")
    assert result.exit_code == 0, result.output
    header, row = result.stdout.splitlines()[1:3]
    # success, travel over successes, collision ratio (travel with failures at the limit: --json, --csv)
    assert "95 % CI" in header and "mean ± std" not in header
    assert row.count("[") == 3
    assert max(len(header), len(row)) <= TABLE_WIDTH


def test_the_progress_bar_shows_an_eta(policy, monkeypatch):
    """evaluate_with_progress's bar, once click has timed an episode, shows the time left."""
    import terl_rt.cli.options as options

    bars = []
    real = click.progressbar

    def spy(*args, **kwargs):
        bars.append(real(*args, **kwargs))
        return bars[-1]

    monkeypatch.setattr(options.click, "progressbar", spy)
    options.evaluate_with_progress(OnnxPolicy(policy), [Scenario.preset("small-11")], 2, 0, max_steps=2)
    (bar,) = bars
    bar.finished, bar.pos, bar.length, bar.avg, bar.eta_known = False, 3, 10, [2.0], True  # 2 s an episode
    assert bar.show_eta and "00:00:14" in bar.format_progress_line()


def test_report_tables_show_intervals_per_preset_and_per_group():
    from datetime import datetime, timezone

    from terl_rt.paper.report import group_summaries, render_markdown

    episodes = tuple(metrics(k % 4 != 0, 80 + 10 * k, collided=k % 3) for k in range(20))

    def result(name: str) -> ScenarioResult:
        return ScenarioResult(
            name=name, episodes=20, seed=0, max_steps=1000, success_rate=0.75, travel_time_s_mean=87.5,
            travel_time_s_std=28.8, collision_ratio_mean=0.095, steps_mean=175.0, wall_s=1.0, per_episode=episodes,
        )

    results = [result("small-11"), result("small-15")]
    text = render_markdown(results, {"name": "p", "sha256": "0" * 64}, "terl-rt report", datetime.now(timezone.utc))
    row = next(line for line in text.splitlines() if line.startswith("| small-11 |"))
    assert row.count("[") == 5  # success, travel as run, over successes, with failures at the limit, collisions
    group_row = next(line for line in text.split("## Per scale group")[1].splitlines() if line.startswith("| small |"))
    assert group_row.count("[") == 5  # and travel of every episode as it ran
    (small,) = group_summaries(results)
    low, high = small.ci95["success_rate"]
    assert low < 0.75 < high
    assert small.to_dict()["ci95"]["travel_time_s"] == list(small.ci95["travel_time_s"])
