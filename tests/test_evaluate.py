"""Evaluation: episodes, seeds, workers, summaries and interrupted runs (terl_rt.evaluation.episodes)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest
from onnx_models import write_test_policy
from tiny_worlds import capture_scenario

from terl_rt.evaluation.evaluate import evaluate_policy as evaluate
from terl_rt.evaluation.play import run_episode
from terl_rt.logs.reader import EpisodeLogReader
from terl_rt.logs.resimulate import verify
from terl_rt.policy.onnx_policy import OnnxPolicy
from terl_rt.sim.metrics import EpisodeMetrics, summarize
from terl_rt.sim.scenario import Scenario, ScenarioError

REPO_ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def policy_path(tmp_path_factory) -> Path:
    return write_test_policy(tmp_path_factory.mktemp("policy") / "linear.onnx")


@pytest.fixture(scope="module")
def policy(policy_path) -> OnnxPolicy:
    return OnnxPolicy(policy_path)


def metrics(success: bool, steps: int, collided: int, pursuers: int = 10) -> EpisodeMetrics:
    return EpisodeMetrics(
        success=success, steps=steps, travel_time_s=0.5 * steps, collision_ratio=collided / pursuers,
        evaders_encircled=0, pursuers_collided=collided,
    )


def test_summarize_takes_means_and_population_spread():
    # travel times 10 s and 20 s: mean 15, population std 5; success 1 of 2; collisions (0.1 + 0.3) / 2.
    summary = summarize([metrics(True, 20, 1), metrics(False, 40, 3)])
    assert summary.success_rate == 0.5
    assert summary.travel_time_s_mean == 15.0
    assert summary.travel_time_s_std == 5.0
    assert summary.collision_ratio_mean == pytest.approx(0.2)
    assert summary.steps_mean == 30.0


def test_summarize_of_no_episode_is_nan():
    assert np.isnan(summarize([]).success_rate)


def test_evaluate_runs_the_requested_episodes_within_max_steps(policy):
    result = evaluate(policy, Scenario.preset("small-11"), episodes=2, seed=0, max_steps=15)
    assert result.name == "small-11" and result.episodes == 2 and result.max_steps == 15
    assert len(result.per_episode) == 2
    assert all(m.steps <= 15 for m in result.per_episode)
    assert result.steps_mean == np.mean([m.steps for m in result.per_episode])
    assert result.wall_s > 0


def test_episode_k_runs_alone_with_seed_plus_k(policy):
    scenario = Scenario.preset("small-11")
    three = evaluate(policy, scenario, episodes=3, seed=5, max_steps=12)
    alone = evaluate(policy, scenario, episodes=1, seed=7, max_steps=12)
    assert three.per_episode[2] == alone.per_episode[0]


def test_policy_is_called_once_per_step_on_every_active_pursuer(policy):
    calls = []

    class Spy:
        def evaluate(self, observation):
            calls.append(observation.pursuer_index.copy())
            return policy.evaluate(observation)

    records = []
    result = run_episode(Spy(), capture_scenario(max_steps=5), seed=0, on_step=records.append)
    assert len(calls) == result.steps == 5
    # Step 1 collides pursuers 3 and 4: the 7 pursuers decide once, then the 5 left.
    assert calls[0].tolist() == list(range(7))
    assert all(c.tolist() == [0, 1, 2, 5, 6] for c in calls[1:])
    assert records[1].pursuer_actions.shape == (7,)
    assert records[2].pursuer_actions[[3, 4]].tolist() == [0, 0]  # collided: filled with 0


def test_capture_scenario_counts_the_capture_and_the_collision(policy):
    result = evaluate(policy, capture_scenario(max_steps=6), episodes=1, seed=0)
    episode = result.per_episode[0]
    assert (episode.evaders_encircled, episode.pursuers_collided, episode.steps) == (1, 2, 6)
    assert result.collision_ratio_mean == pytest.approx(2 / 7)
    assert result.success_rate == 0.0


def test_two_workers_give_the_same_results_and_log_as_one(policy, tmp_path):
    scenario = Scenario.preset("small-11")
    one = evaluate(policy, scenario, episodes=3, seed=2, max_steps=10, log_path=tmp_path / "one.mcap")
    two = evaluate(policy, scenario, episodes=3, seed=2, max_steps=10, workers=2, log_path=tmp_path / "two.mcap")
    assert two.per_episode == one.per_episode
    assert (tmp_path / "two.mcap").read_bytes() == (tmp_path / "one.mcap").read_bytes()


def test_progress_reports_each_episode_in_order(policy):
    seen = []
    evaluate(policy, Scenario.preset("small-11"), episodes=3, seed=0, max_steps=3,
             progress=lambda index, m: seen.append((index, m.steps)))
    assert seen == [(0, 3), (1, 3), (2, 3)]


def test_evaluate_accepts_a_policy_path(policy_path):
    assert evaluate(str(policy_path), capture_scenario(3), episodes=1, seed=0).episodes == 1


@pytest.mark.parametrize("kwargs, error", [
    ({"episodes": 0}, ValueError),
    ({"workers": 0}, ValueError),
    ({"max_steps": 0}, ScenarioError),
])
def test_bad_arguments_are_refused(policy, kwargs, error):
    arguments = {"episodes": 1, "seed": 0, **kwargs}
    with pytest.raises(error):
        evaluate(policy, capture_scenario(3), **arguments)


def test_interrupted_evaluation_keeps_every_step_taken_logged(policy, tmp_path):
    log = tmp_path / "interrupted.mcap"

    def interrupt(index, m):
        if index == 1:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        evaluate(policy, capture_scenario(4), episodes=5, seed=0, log_path=log, progress=interrupt)
    reader = EpisodeLogReader(log)
    assert not reader.truncated  # closed on the way out
    # The 5 episodes ran together: 0 and 1 ended, 2-4 keep the steps they took, unended.
    assert [e.complete for e in reader.episodes] == [True, True, False, False, False]
    assert all(e.steps > 0 for e in reader.episodes)


def test_killed_evaluation_leaves_a_log_readable_to_its_last_step(policy_path, tmp_path):
    log = tmp_path / "killed.mcap"
    script = textwrap.dedent(f"""
        from terl_rt.evaluation.evaluate import evaluate_policy as evaluate
        from terl_rt.sim.scenario import Scenario
        evaluate({str(policy_path)!r}, Scenario.preset("small-15"), episodes=50, seed=0, log_path={str(log)!r})
    """)
    process = subprocess.Popen([sys.executable, "-c", script], cwd=tmp_path)
    try:
        deadline = time.monotonic() + 60
        while (not log.exists() or log.stat().st_size < 200_000) and time.monotonic() < deadline:
            assert process.poll() is None, "the evaluation ended before it could be killed"
            time.sleep(0.05)
    finally:
        os.kill(process.pid, signal.SIGKILL)
        process.wait()
    reader = EpisodeLogReader(log)
    assert reader.truncated and "cut off" in reader.problem
    assert reader.episodes and reader.episodes[0].steps > 0
    last = reader.episodes[-1]
    assert len(list(reader.steps(last.number))) == len(last.chunks)
    report = verify(log, last.number)
    assert report.ok, report.format()

