"""Ctrl-C at any moment of a logged run keeps a log that verifies (issue 78, item 1).

Runs of one process and of two workers are interrupted by a real SIGINT sent at many
moments: as the k-th step is written (to the log or to a side log), the k-th episode
begins or ends in a log, the k-th episode is reported, or the policy is called for the
k-th time. Every kept log must be closed whole, hold each episode at most once, in order,
and re-simulate bit for bit, with no side log, lock or temporary file left beside it.
"""

from __future__ import annotations

import os
import signal
from collections import Counter
from collections.abc import Callable
from contextlib import nullcontext
from pathlib import Path

import pytest
from onnx_models import write_test_policy

from terl_rt.evaluation.evaluate import evaluate
from terl_rt.evaluation.pool import LocalBackend
from terl_rt.logs.reader import EpisodeLogReader
from terl_rt.logs.resimulate import verify
from terl_rt.logs.writer import EpisodeLogWriter
from terl_rt.policy.onnx_policy import OnnxPolicy
from terl_rt.sim.scenario import Scenario

UNEVEN = Scenario.preset("small-11").replace(
    name="uneven", pursuers=3, evaders=1, arena=(40.0, 40.0), obstacles=6, min_pursuer_evader_init_dis=5.0,
    clear_r=3.0, max_steps=24,
)
"""Three pursuers among obstacles: the linear test policy loses one to a collision at a
seed's own step, so with seeds 1-4 (24, 12, 22 and 24 steps, run together) episodes 1
and 2 end while episode 0 is still written to the log: their steps wait, then catch up."""
SEED, EPISODES = 1, 4
WRITER_CALLS = ("write_step", "begin_episode", "end_episode")


@pytest.fixture(scope="module")
def policy(tmp_path_factory) -> OnnxPolicy:
    return OnnxPolicy(write_test_policy(tmp_path_factory.mktemp("ctrl-c") / "linear.onnx"))


def _run(policy: OnnxPolicy, log: Path, workers: int, on_call: Callable[[str], None], monkeypatch) -> None:
    """Evaluate UNEVEN logged to `log` on `workers`, calling `on_call(name)` before each
    call of WRITER_CALLS (every log's), of the policy ("evaluate", this process's only)
    and after each episode is reported ("finished")."""
    with monkeypatch.context() as patch:
        for owner, name in [(EpisodeLogWriter, name) for name in WRITER_CALLS] + [(policy, "evaluate")]:
            original = getattr(owner, name)

            def hooked(*args, _original=original, _name=name, **kwargs):
                on_call(_name)
                return _original(*args, **kwargs)

            patch.setattr(owner, name, hooked)
        with LocalBackend(workers, envs=EPISODES) as backend:
            evaluate(policy, UNEVEN, EPISODES, SEED, log=log, backend=backend,
                     progress=lambda scenario, count: nullcontext(lambda index, metrics: on_call("finished")))


def _interrupt_at(name: str, k: int) -> Callable[[str], None]:
    """An on_call that sends this process SIGINT at the k-th (0-based) call of `name`."""
    calls = Counter()

    def on_call(called: str) -> None:
        calls[called] += 1
        if called == name and calls[called] == k + 1:
            os.kill(os.getpid(), signal.SIGINT)

    return on_call


def _assert_kept_log_verifies(log: Path, moment: str) -> None:
    """What the module docstring asks of a kept log; `moment` names it in a failure."""
    reader = EpisodeLogReader(log)
    assert not reader.truncated, (moment, reader.problem)
    indexes = [episode.index for episode in reader.episodes]
    assert indexes == sorted(set(indexes)), (moment, indexes)
    for episode in reader.episodes:
        report = verify(log, episode.number)
        assert report.ok and episode.chunks, (moment, report.format())
    assert [path.name for path in log.parent.iterdir()] == [log.name], moment


def _interrupt_at_many_moments(policy, tmp_path, monkeypatch, workers: int, moments: dict[str, int]) -> None:
    """Interrupt the run at `moments[name]` calls of each hooked call `name` (at most all),
    spread evenly over a whole run's calls, one run each."""
    counts = Counter()
    _run(policy, tmp_path / "whole.mcap", workers, lambda name: counts.update([name]), monkeypatch)
    for name, many in moments.items():
        assert counts[name], (name, counts)
        for k in sorted({counts[name] * j // many for j in range(many)}):
            log = tmp_path / f"{name}-{k}" / "run.mcap"
            log.parent.mkdir()
            try:
                _run(policy, log, workers, _interrupt_at(name, k), monkeypatch)
            except KeyboardInterrupt:
                pass
            else:  # a worker run told after its last episode has nothing left to stop
                assert [e.complete for e in EpisodeLogReader(log).episodes] == [True] * EPISODES, (name, k)
            _assert_kept_log_verifies(log, f"SIGINT at {name} call {k}")


def test_ctrl_c_at_any_moment_of_a_one_process_run_keeps_a_log_that_verifies(policy, tmp_path, monkeypatch):
    _interrupt_at_many_moments(policy, tmp_path, monkeypatch, workers=1, moments={
        "write_step": 16, "begin_episode": 10, "end_episode": 10, "finished": 4, "evaluate": 4,
    })


def test_ctrl_c_at_many_moments_of_a_two_worker_run_keeps_a_log_that_verifies(policy, tmp_path, monkeypatch):
    _interrupt_at_many_moments(policy, tmp_path, monkeypatch, workers=2, moments={
        "write_step": 3, "end_episode": 1, "finished": 2,
    })
