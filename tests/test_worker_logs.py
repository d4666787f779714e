"""`--workers` runs stream their steps to the log and end with their parent (issue 14, item 1)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from onnx_models import write_test_policy
from kept_logs import assert_log_keeps_complete_steps
from processes import assert_all_end, children, start_eval, wait_for_log

from terl_rt.evaluation.evaluate import evaluate_policy as evaluate
from terl_rt.logs.reader import EpisodeLogReader
from terl_rt.logs.resimulate import verify
from terl_rt.policy.onnx_policy import OnnxPolicy
from terl_rt.sim.scenario import Scenario


@pytest.fixture(scope="module")
def policy_path(tmp_path_factory) -> Path:
    return write_test_policy(tmp_path_factory.mktemp("policy") / "linear.onnx")


def _workers(process: subprocess.Popen, log: Path) -> set[int]:
    """The worker process ids of a 2-worker `terl-rt eval`, once its log has grown."""
    wait_for_log(process, log)
    workers = children(process.pid)
    assert workers, "no worker process found"
    return workers


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_sigkill_of_a_worker_run_keeps_the_streamed_steps_and_ends_the_workers(policy_path, tmp_path):
    log = tmp_path / "killed.mcap"
    process = start_eval(policy_path, log)
    try:
        workers = _workers(process, log)
        os.kill(process.pid, signal.SIGKILL)
        process.wait(timeout=10)
        assert_all_end(workers)
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait()
    reader = EpisodeLogReader(log)
    assert reader.truncated
    assert reader.episodes and sum(e.steps for e in reader.episodes) > 0
    last = reader.episodes[-1]
    assert len(list(reader.steps(last.number))) == len(last.chunks)
    assert verify(log, last.number).ok


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_ctrl_c_of_a_worker_run_writes_every_received_step_and_ends_the_workers(policy_path, tmp_path):
    log = tmp_path / "interrupted.mcap"
    process = start_eval(policy_path, log)
    try:
        workers = _workers(process, log)
        os.killpg(process.pid, signal.SIGINT)
        assert process.wait(timeout=20) != 0
        assert_all_end(workers)
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait()
    assert_log_keeps_complete_steps(log)  # closed on the way out, every episode complete


def test_the_log_of_two_workers_grows_while_the_first_episode_runs(policy_path, tmp_path):
    """Steps reach the file while the episode is still running, not when it ends."""
    log = tmp_path / "growing.mcap"
    sizes = []

    def progress(index, metrics):
        sizes.append(log.stat().st_size)

    result = evaluate(OnnxPolicy(policy_path), Scenario.preset("small-11"), episodes=2, seed=0, max_steps=30,
                      workers=2, log_path=log, progress=progress)
    assert result.episodes == 2
    reader = EpisodeLogReader(log)
    assert [e.steps for e in reader.episodes] == [30, 30]
    assert sizes[0] < log.stat().st_size


def test_steps_held_back_for_episode_order_are_written_when_the_run_stops(policy_path, tmp_path):
    """Episode 1's steps wait while episode 0 runs; stopped, the run writes them (unended) too."""
    from terl_rt.evaluation.play import run_episode
    from terl_rt.evaluation.runs import EpisodeSpec, InOrderLog
    from terl_rt.logs.writer import EpisodeLogWriter
    from terl_rt.policy.onnx_policy import policy_info

    policy = OnnxPolicy(policy_path)
    scenario = Scenario.preset("small-11").replace(max_steps=5)
    streams = {k: [] for k in range(3)}
    ends = {k: run_episode(policy, scenario, k, streams[k].append) for k in range(3)}
    finished = []
    log = tmp_path / "held.mcap"
    with EpisodeLogWriter(log, policy_info(policy)) as writer:
        specs = [EpisodeSpec(0, scenario, k, k) for k in range(3)]
        order = InOrderLog(specs, writer, lambda index, metrics: finished.append(index))
        for record in streams[1]:
            order.receive("step", 1, record)
        order.receive("end", 1, ends[1])
        for record in streams[2][:3]:
            order.receive("step", 2, record)
        for record in streams[0][:4]:
            order.receive("step", 0, record)
        order.flush_waiting()
    assert finished == []
    episodes = EpisodeLogReader(log).episodes
    assert [(e.index, e.steps, e.complete) for e in episodes] == [(0, 3, False), (1, 5, True), (2, 2, False)]
    assert all(verify(log, e.number).ok for e in episodes)


@pytest.mark.parametrize("bad", [float("nan"), float("inf")])
@pytest.mark.parametrize("workers", [1, 2])
def test_a_policy_with_non_finite_outputs_stops_the_run_naming_policy_and_step(tmp_path, bad, workers):
    from click.testing import CliRunner
    from onnx_models import write_constant_policy

    from terl_rt.cli.main import cli

    path = write_constant_policy(tmp_path / "nan.onnx", [0, 1, bad, 0, 0, 0, 0, 0, 0])
    log = tmp_path / "nan.mcap"
    result = CliRunner().invoke(cli, ["eval", "--policy", str(path), "--scenario", "small-11", "--episodes", "2",
                                      "--max-steps", "5", "--workers", str(workers), "--log", str(log)])
    assert result.exit_code == 2, result.output
    errors = [line for line in result.stderr.splitlines() if line.startswith("Error:")]
    assert len(errors) == 1 and "Traceback" not in result.output
    assert "nan.onnx" in errors[0] and "step 1" in errors[0] and "non-finite q_values" in errors[0]


def test_a_worker_whose_parent_died_while_it_started_ends_at_once():
    # The worker is told its parent's pid; a different parent (it was re-parented) ends it.
    code = "from terl_rt.evaluation.worker import _die_with_parent; _die_with_parent(-1); print('alive')"
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=30)
    assert result.returncode == 1 and "alive" not in result.stdout
