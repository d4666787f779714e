"""Steps go to sinks (terl_rt.logs.sink): a user's own, the MCAP log, several at once, each
getting whole episodes in episode order however many workers run them (issue 76, part 1)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from onnx_models import write_test_policy

import terl_rt
from terl_rt.evaluation.play import run_episode
from terl_rt.evaluation.runs import EpisodeSpec, InOrderLog
from terl_rt.logs.reader import EpisodeLogReader
from terl_rt.logs.sink import StepSink, StepSinks
from terl_rt.policy.onnx_policy import OnnxPolicy
from terl_rt.sim.scenario import Scenario

SCENARIO = Scenario.preset("small-11").replace(max_steps=12)


class Recorder:
    """A sink of one's own: every call, in order, with what identifies it."""

    def __init__(self) -> None:
        self.calls: list[tuple] = []
        self.closed = False

    def begin_episode(self, scenario, seed, index):
        self.calls.append(("begin", scenario.name, seed, index))

    def write_step(self, record):
        self.calls.append(("step", record.step, record.state["pursuer_xy"].copy()))

    def end_episode(self, metrics):
        self.calls.append(("end", metrics))

    def abandon_episode(self):
        self.calls.append(("abandon",))

    def close(self):
        self.closed = True

    def episodes(self) -> list[list[tuple]]:
        """The calls cut at each begin."""
        out: list[list[tuple]] = []
        for call in self.calls:
            if call[0] == "begin":
                out.append([])
            out[-1].append(call)
        return out


@pytest.fixture(scope="module")
def policy_path(tmp_path_factory) -> Path:
    return write_test_policy(tmp_path_factory.mktemp("policy") / "linear.onnx")


def test_a_sink_of_ones_own_gets_each_episode_whole_in_episode_order(policy_path):
    sink = Recorder()
    assert isinstance(sink, StepSink)
    evaluation = terl_rt.evaluate(policy_path, SCENARIO, episodes=3, seed=5, log=sink)
    episodes = sink.episodes()
    assert [episode[0] for episode in episodes] == [("begin", "small-11", 5 + k, k) for k in range(3)]
    for episode, metrics in zip(episodes, evaluation.result.per_episode):
        assert [call[1] for call in episode[1:-1]] == list(range(metrics.steps + 1))  # step 0 after reset
        assert episode[-1] == ("end", metrics)
    assert not sink.closed  # the caller opened it, the caller closes it
    assert evaluation.log_path is None and evaluation.logged_episodes == 0


def test_a_sink_sees_a_run_on_workers_as_it_sees_one_process(policy_path):
    alone, on_workers = Recorder(), Recorder()
    terl_rt.evaluate(policy_path, SCENARIO, episodes=3, seed=0, log=alone)
    terl_rt.evaluate(policy_path, SCENARIO, episodes=3, seed=0, log=on_workers, workers=2)
    assert len(alone.calls) == len(on_workers.calls)
    for ours, theirs in zip(alone.calls, on_workers.calls):
        assert ours[:2] == theirs[:2]
        if ours[0] == "step":
            np.testing.assert_array_equal(ours[2], theirs[2])


def test_a_log_and_a_sink_together_get_the_same_steps(policy_path, tmp_path):
    sink, log = Recorder(), tmp_path / "both.mcap"
    evaluation = terl_rt.evaluate(policy_path, SCENARIO, episodes=2, seed=0, log=[log, sink])
    assert evaluation.log_path == log and evaluation.logged_episodes == 2
    reader = EpisodeLogReader(log)
    logged = [step.state["pursuer_xy"] for episode in reader.episodes for step in reader.steps(episode.number)]
    recorded = [call[2] for call in sink.calls if call[0] == "step"]
    assert len(logged) == len(recorded)
    for ours, theirs in zip(logged, recorded):
        np.testing.assert_array_equal(ours, theirs)


def test_a_stopped_run_abandons_the_episode_a_sink_has_begun(policy_path):
    """Episode 1 waits while episode 0 runs; stopped, the run gives the sink what waits,
    episode 0 abandoned before episode 1 begins (as the MCAP log leaves them unended)."""
    policy = OnnxPolicy(policy_path)
    scenario = SCENARIO.replace(max_steps=5)
    streams: dict[int, list] = {0: [], 1: []}
    for k in streams:
        run_episode(policy, scenario, k, streams[k].append)
    sink = Recorder()
    order = InOrderLog([EpisodeSpec(0, scenario, k, k) for k in range(2)], sink, lambda index, metrics: None)
    for record in streams[1][:3]:
        order.receive("step", 1, record)
    for record in streams[0][:2]:
        order.receive("step", 0, record)
    order.flush_waiting()
    assert [call[:2] for call in sink.calls] == [
        ("begin", "small-11"), ("step", 0), ("step", 1), ("abandon",),
        ("begin", "small-11"), ("step", 0), ("step", 1), ("step", 2),
    ]


def test_several_sinks_are_all_closed_when_one_fails_to_close():
    class FailsToClose(Recorder):
        def close(self):
            raise OSError("disk gone")

    first, second = FailsToClose(), Recorder()
    with pytest.raises(OSError, match="disk gone"):
        StepSinks([first, second]).close()
    assert second.closed


def test_log_takes_only_paths_and_sinks(policy_path):
    with pytest.raises(TypeError, match="log takes an MCAP file's path, a StepSink .* got int"):
        terl_rt.evaluate(policy_path, SCENARIO, episodes=1, log=42)
    with pytest.raises(TypeError, match="got object"):
        terl_rt.evaluate(policy_path, SCENARIO, episodes=1, log=[Recorder(), object()])


def test_a_run_writes_one_mcap_log(policy_path, tmp_path):
    with pytest.raises(ValueError, match="a run writes one episode log, got 2"):
        terl_rt.evaluate(policy_path, SCENARIO, episodes=1, log=[tmp_path / "a.mcap", tmp_path / "b.mcap"])
    assert not list(tmp_path.iterdir())  # neither was published
