"""`terl_rt.evaluate`, the one call: a policy by path, name, object or function; one scenario
or several; the log it opens (terl_rt.evaluation.evaluate, terl_rt.policy.protocol)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from onnx_models import write_test_policy
from tiny_worlds import capture_scenario

import terl_rt
from terl_rt.logs.reader import EpisodeLogReader
from terl_rt.policy.onnx_policy import OnnxPolicy
from terl_rt.policy.protocol import CallablePolicy, Policy
from terl_rt.policy.shipped import NoShippedPolicy, default_policy_path


@pytest.fixture(scope="module")
def policy(tmp_path_factory) -> OnnxPolicy:
    return OnnxPolicy(write_test_policy(tmp_path_factory.mktemp("policy") / "linear.onnx"))


def test_an_onnx_policy_and_a_users_function_meet_the_protocol(policy):
    assert isinstance(policy, Policy)
    assert isinstance(CallablePolicy(policy.act), Policy)


def test_a_shipped_policy_is_found_by_name():
    evaluation = terl_rt.evaluate("terl", "small-11", episodes=1, max_steps=3)
    assert evaluation.policy["path"] == str(default_policy_path())
    assert evaluation.result.episodes == 1 and evaluation.result.max_steps == 3


def test_an_unknown_name_is_no_shipped_policy():
    with pytest.raises(NoShippedPolicy, match="no shipped policy of that name"):
        terl_rt.evaluate("no-such-policy", "small-11", episodes=1)


def test_a_function_of_observations_decides_as_the_policy_it_calls(policy):
    scenario = capture_scenario(3)
    alone = terl_rt.evaluate(policy, scenario, episodes=2, seed=4)
    called = terl_rt.evaluate(lambda observation: policy.act(observation), scenario, episodes=2, seed=4)
    assert called.result.per_episode == alone.result.per_episode
    assert called.policy == {"name": "<lambda>", "sha256": "", "path": "<<lambda>>", "metadata": {}}


def test_a_function_that_returns_no_action_indices_is_refused_naming_it():
    def stay(observation):
        return np.full(len(observation.ego), 9)  # one past the last action

    with pytest.raises(ValueError, match=r"policy stay returned actions in \[9, 9\]"):
        terl_rt.evaluate(stay, capture_scenario(3), episodes=1)


def test_a_policy_without_a_file_runs_in_this_process_only(policy):
    with pytest.raises(ValueError, match="runs in this process only"):
        terl_rt.evaluate(policy.act, capture_scenario(3), episodes=2, workers=2)


def test_several_scenarios_give_a_result_each_and_one_log(policy, tmp_path):
    log = tmp_path / "two.mcap"
    evaluation = terl_rt.evaluate(policy, ["small-11", capture_scenario(3)], episodes=2, max_steps=4, log=log)
    assert [result.name for result in evaluation.results] == ["small-11", capture_scenario(3).name]
    assert evaluation.log_path == log and evaluation.logged_episodes == 4
    assert len(EpisodeLogReader(log).episodes) == 4
    with pytest.raises(ValueError, match="read `results`"):
        evaluation.result


def test_an_existing_log_is_kept_without_replace_log(policy, tmp_path):
    log = tmp_path / "kept.mcap"
    log.write_bytes(b"earlier")
    with pytest.raises(FileExistsError):
        terl_rt.evaluate(policy, capture_scenario(3), episodes=1, log=log, replace_log=False)
    assert log.read_bytes() == b"earlier"


def test_progress_opens_a_context_a_scenario_told_of_each_episode(policy):
    seen = []

    class Recorder:
        def __init__(self, scenario, episodes):
            self.name = scenario.name

        def __enter__(self):
            return lambda index, metrics: seen.append((self.name, index))

        def __exit__(self, *exc):
            seen.append((self.name, "done"))

    terl_rt.evaluate(policy, ["small-11", "small-15"], episodes=2, max_steps=2, progress=Recorder)
    assert seen == [("small-11", 0), ("small-11", 1), ("small-11", "done"),
                    ("small-15", 0), ("small-15", 1), ("small-15", "done")]


def test_the_package_gives_evaluate_without_loading_it_at_import():
    assert terl_rt.evaluate is terl_rt.evaluation.evaluate.evaluate
    with pytest.raises(AttributeError):
        terl_rt.no_such_name  # noqa: B018


def test_a_path_given_as_a_path_is_never_taken_for_a_name(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(FileNotFoundError) as error:
        terl_rt.evaluate(Path("terl"), "small-11", episodes=1)
    assert not isinstance(error.value, NoShippedPolicy)
