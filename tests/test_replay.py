"""Bit-exact replay of logged episodes (terl_rt.logs.resimulate.verify)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from onnx_models import write_test_policy
from tiny_worlds import capture_scenario

from terl_rt.evaluation.evaluate import evaluate_policy as evaluate
from terl_rt.evaluation.play import run_episode
from terl_rt.logs.format import EpisodeLogError
from terl_rt.logs.reader import EpisodeLogReader
from terl_rt.logs.resimulate import verify
from terl_rt.logs.writer import EpisodeLogWriter
from terl_rt.policy.onnx_policy import OnnxPolicy, policy_info
from terl_rt.sim.scenario import Scenario
from terl_rt.sim.world import WORLD_VERSION


@pytest.fixture(scope="module")
def policy(tmp_path_factory) -> OnnxPolicy:
    return OnnxPolicy(write_test_policy(tmp_path_factory.mktemp("policy") / "linear.onnx"))


def write_log(policy, path: Path, scenario: Scenario, seed: int, tamper=None) -> Path:
    """Log one episode; `tamper(record)` may return a changed record before it is written."""
    records = []
    metrics = run_episode(policy, scenario, seed, on_step=records.append)
    with EpisodeLogWriter(path, policy_info(policy)) as writer:
        writer.begin_episode(scenario, seed, 0)
        for record in records:
            writer.write_step(tamper(record) if tamper else record)
        writer.end_episode(metrics)
    return path


def test_verify_passes_on_a_real_log(policy, tmp_path):
    path = tmp_path / "real.mcap"
    evaluate(policy, Scenario.preset("small-11"), episodes=2, seed=4, max_steps=20, log_path=path)
    for episode in (0, 1):
        report = verify(path, episode)
        assert report.ok and report.complete, report.format()
        assert report.steps_checked == 20 and report.seed == 4 + episode
        assert "bit-identical" in report.format()


def logged_evader_actions(path: Path) -> list[list[int]]:
    return [step.evader_actions.tolist() for step in EpisodeLogReader(path).steps(0) if step.step > 0]


def test_the_log_names_a_non_default_evader_and_verify_resimulates_with_it(policy, tmp_path):
    gap, apf = tmp_path / "gap.mcap", tmp_path / "apf.mcap"
    scenario = Scenario.preset("small-11")
    evaluate(policy, scenario.replace(evader="widest-gap"), episodes=1, seed=2, max_steps=20, log_path=gap)
    evaluate(policy, scenario, episodes=1, seed=2, max_steps=20, log_path=apf)
    assert EpisodeLogReader(gap).episode(0).scenario.evader == "widest-gap"
    assert logged_evader_actions(gap) != logged_evader_actions(apf)  # an APF re-simulation would not match
    report = verify(gap)
    assert report.ok and report.steps_checked == 20, report.format()
    assert report.evader == "widest-gap" and report.to_dict()["evader"] == "widest-gap"
    assert report.format().startswith("episode 0 (small-11/widest-gap, seed 2): ok")


def test_verify_passes_through_captures_and_collisions(policy, tmp_path):
    report = verify(write_log(policy, tmp_path / "capture.mcap", capture_scenario(8), seed=0))
    assert report.ok, report.format()


def test_verify_finds_a_state_nudged_by_one_ulp(policy, tmp_path):
    def nudge(record):
        if record.step != 5:
            return record
        state = {name: np.copy(value) for name, value in record.state.items()}
        state["pursuer_xy"][3, 1] = np.nextafter(state["pursuer_xy"][3, 1], np.inf)
        return dataclasses.replace(record, state=state)

    path = write_log(policy, tmp_path / "nudged.mcap", capture_scenario(8), seed=0, tamper=nudge)
    report = verify(path)
    assert not report.ok
    assert (report.mismatch.step, report.mismatch.field) == (5, "pursuer_xy")
    assert report.mismatch.detail.startswith("[3, 1]")
    assert "MISMATCH at step 5, pursuer_xy" in report.format()


def test_verify_finds_a_changed_action(policy, tmp_path):
    def other_action(record):
        if record.step != 3:
            return record
        actions = record.pursuer_actions.copy()
        actions[0] = (actions[0] + 1) % 9
        return dataclasses.replace(record, pursuer_actions=actions)

    path = write_log(policy, tmp_path / "acted.mcap", capture_scenario(8), seed=0, tamper=other_action)
    report = verify(path)
    assert not report.ok and report.mismatch.step == 3


def test_verify_of_a_cut_off_log_checks_what_is_there(policy, tmp_path):
    path = tmp_path / "cut.mcap"
    records = []
    run_episode(policy, capture_scenario(8), 0, on_step=records.append)
    writer = EpisodeLogWriter(path, policy_info(policy))
    writer.begin_episode(capture_scenario(8), 0, 0)
    for record in records[:4]:
        writer.write_step(record)
    report = verify(path)  # the writer was never closed
    assert report.ok and not report.complete and report.steps_checked == 3
    assert "cut off" in report.format()
    writer.close()


# ---------------------------------------------------------------- logs of another world version
OLD_WORLD_LOG = Path(__file__).parent / "data" / "world-v1.mcap"
"""`terl-rt eval --scenario small-11 --episodes 1 --max-steps 5 --log` by the simulator before
world version 2 (reset velocity with the current, collided pursuers gone within their step)."""


def test_log_records_the_world_version(policy, tmp_path):
    path = tmp_path / "now.mcap"
    evaluate(policy, Scenario.preset("small-11"), episodes=1, seed=0, max_steps=3, log_path=path)
    assert EpisodeLogReader(path).world_version == WORLD_VERSION == "2"


def test_log_of_another_world_version_still_lists():
    reader = EpisodeLogReader(OLD_WORLD_LOG)
    assert reader.world_version == "1"
    assert [entry.steps for entry in reader.episodes] == [5]


def test_verify_refuses_a_log_of_another_world_version_in_one_sentence():
    with pytest.raises(EpisodeLogError, match="world version 1; this terl-rt simulates world version 2"):
        verify(OLD_WORLD_LOG, 0)
