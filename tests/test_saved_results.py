"""terl_rt.paper.saved_results: a finished evaluation written and read back."""

from __future__ import annotations

import logging

from terl_rt.evaluation.episodes import scenario_result
from terl_rt.paper.saved_results import SavedResults
from terl_rt.sim.metrics import EpisodeMetrics
from terl_rt.sim.scenario import Scenario

SHA = "ab" * 32


def made_result(scenario: Scenario, seed: int = 3):
    episodes = [EpisodeMetrics(True, 70, 35.0, 0.0, 3, 0, 812.25),
                EpisodeMetrics(False, 1000, 500.0, 2 / 15, 1, 2, -0.1 + 0.2)]
    return scenario_result(scenario, seed, episodes, wall_s=1.25)


def test_a_saved_result_reads_back_equal(tmp_path):
    scenario = Scenario.preset("small-15").replace(max_steps=1000)
    saved = SavedResults(tmp_path / "progress")
    assert saved.load(SHA, scenario, 2, 3) is None and saved.count() == 0
    result = made_result(scenario)
    saved.save(SHA, scenario, result)
    assert saved.load(SHA, scenario, 2, 3) == result and saved.count() == 1
    saved.remove()
    assert not (tmp_path / "progress").exists()


def test_another_policy_scenario_step_limit_episodes_or_seed_is_another_evaluation(tmp_path):
    scenario = Scenario.preset("small-15")
    saved = SavedResults(tmp_path)
    saved.save(SHA, scenario, made_result(scenario))
    assert saved.load("cd" * 32, scenario, 2, 3) is None
    assert saved.load(SHA, Scenario.preset("cc-28"), 2, 3) is None
    assert saved.load(SHA, scenario.replace(max_steps=999), 2, 3) is None
    assert saved.load(SHA, scenario, 3, 3) is None
    assert saved.load(SHA, scenario, 2, 4) is None


def test_a_file_that_is_no_such_result_is_evaluated_again_with_a_warning(tmp_path, caplog):
    scenario = Scenario.preset("small-15")
    saved = SavedResults(tmp_path)
    path = saved.save(SHA, scenario, made_result(scenario))
    for broken in ("{", '{"key": 1}', path.read_text().replace('"success"', '"succeeded"')):
        path.write_text(broken)
        with caplog.at_level(logging.WARNING):
            assert saved.load(SHA, scenario, 2, 3) is None
        assert "is no saved evaluation of small-15" in caplog.text
        caplog.clear()


def test_a_saved_result_is_published_whole_through_the_one_writer(tmp_path):
    scenario = Scenario.preset("small-15")
    saved = SavedResults(tmp_path)
    path = saved.save(SHA, scenario, made_result(scenario))
    assert [entry.name for entry in tmp_path.iterdir()] == [path.name]
    (tmp_path / f".{path.stem}.4711.abcd.partial.json").write_text("{")  # a run killed while writing
    assert saved.count() == 1
