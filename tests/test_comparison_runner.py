"""terl_rt.paper.runner: a comparison's evaluations kept as they finish and read back by the
next run, without the command line."""

from __future__ import annotations

from types import SimpleNamespace

from made_results import made_result

from terl_rt.paper.runner import PROGRESS_FOLDER, ComparisonRunner
from terl_rt.sim.scenario import Scenario

SHA = "ab" * 32


def counting_runner(tmp_path, calls: list, max_steps: int | None = None) -> ComparisonRunner:
    """A runner whose evaluations are made results, each call noted in `calls`."""
    def evaluate(policy, scenario, episodes):
        calls.append((scenario.name, scenario.max_steps, episodes))
        return made_result(scenario.name, episodes=episodes, max_steps=scenario.max_steps)

    return ComparisonRunner(tmp_path, seed=0, max_steps=max_steps, evaluate=evaluate)


def test_a_second_runner_evaluates_only_what_the_first_left(tmp_path):
    policy = SimpleNamespace(sha256=SHA)
    small, cc = Scenario.preset("small-15"), Scenario.preset("cc-28")
    calls: list = []
    first = counting_runner(tmp_path, calls).results(policy, [small], 2)
    lines: list = []
    second = ComparisonRunner(tmp_path, 0, None, counting_runner(tmp_path, calls).evaluate, lines.append)
    again = second.results(policy, [small, cc], 2)
    assert calls == [("small-15", small.max_steps, 2), ("cc-28", cc.max_steps, 2)]
    assert again[0].per_episode == first[0].per_episode and "read back" in lines[0]


def test_the_runners_step_limit_is_part_of_what_it_saves(tmp_path):
    policy = SimpleNamespace(sha256=SHA)
    calls: list = []
    counting_runner(tmp_path, calls, max_steps=50).results(policy, [Scenario.preset("small-15")], 2)
    counting_runner(tmp_path, calls).results(policy, [Scenario.preset("small-15")], 2)
    assert [limit for _, limit, _ in calls] == [50, Scenario.preset("small-15").max_steps]


def test_finish_removes_the_saved_results_unless_kept(tmp_path):
    runner = counting_runner(tmp_path, [])
    runner.results(SimpleNamespace(sha256=SHA), [Scenario.preset("small-15")], 2)
    runner.finish(keep=True)
    assert (tmp_path / PROGRESS_FOLDER).is_dir()
    runner.finish(keep=False)
    assert not (tmp_path / PROGRESS_FOLDER).exists()
