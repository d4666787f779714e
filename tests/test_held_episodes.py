"""A batched logged run keeps every step taken on disk, even when it is SIGKILLed: the
episodes waiting for their turn in the log are streamed to side logs beside it
(terl_rt.logs.held), deleted once their steps are in the log."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from one_line import invoke
from onnx_models import write_test_policy
from processes import start_eval, wait_for_log

from terl_rt.logs.held import held_folder, held_logs
from terl_rt.logs.reader import EpisodeLogReader
from terl_rt.logs.resimulate import verify

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def policy(tmp_path_factory) -> Path:
    return write_test_policy(tmp_path_factory.mktemp("held") / "linear.onnx")


def test_a_finished_batched_run_leaves_no_side_logs(policy, tmp_path):
    log = tmp_path / "run.mcap"
    result = invoke("eval", "--policy", policy, "--scenario", "small-11", "--episodes", "3", "--max-steps", "20",
                    "--log", log)
    assert result.exit_code == 0, result.output
    assert len(EpisodeLogReader(log).episodes) == 3
    assert not held_folder(log).exists()


def test_sigkill_of_a_batched_logged_run_keeps_the_steps_of_every_episode(policy, tmp_path):
    log = tmp_path / "killed.mcap"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    # One worker, 4 episodes in one World: episode 0 goes to the log as it runs, 1 to 3 wait.
    process = subprocess.Popen(
        [sys.executable, "-m", "terl_rt", "eval", "--policy", str(policy), "--scenario", "small-11",
         "--episodes", "4", "--max-steps", "400", "--log", str(log)],
        cwd=tmp_path, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )
    try:
        wait_for_log(process, log, size=60_000)
        process.send_signal(signal.SIGKILL)
        assert process.wait(timeout=30) == -signal.SIGKILL
    finally:
        process.kill()
    reader = EpisodeLogReader(log)
    assert reader.episodes[0].steps > 0 and verify(log, 0).ok
    held = held_logs(log)
    assert [path.name for path in held] == [f"episode-{number:06d}.mcap" for number in (1, 2, 3)]
    for number, path in enumerate(held, start=1):
        episode = EpisodeLogReader(path).episodes[0]
        assert episode.index == number and episode.steps > 0
        assert verify(path, 0).ok  # each held step is the one the episode took
    replayed = invoke("replay", log)
    assert replayed.exit_code == 0
    assert "killed with 3 more episode(s) held beside the log" in replayed.stderr


def test_side_logs_of_an_earlier_killed_run_go_when_the_log_is_replaced(policy, tmp_path):
    log = tmp_path / "run.mcap"
    held_folder(log).mkdir()
    (held_folder(log) / "episode-000001.mcap").write_bytes(b"from a killed run")
    result = invoke("eval", "--policy", policy, "--scenario", "small-11", "--episodes", "2", "--max-steps", "10",
                    "--log", log)
    assert result.exit_code == 0, result.output
    assert not held_folder(log).exists()


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="flock and the run's process group")
def test_replay_of_a_log_a_worker_run_is_still_writing_says_so_not_that_it_was_killed(policy, tmp_path):
    log = tmp_path / "live.mcap"
    process = start_eval(policy, log)
    try:
        deadline = time.monotonic() + 120
        while not (log.exists() and held_logs(log)) and time.monotonic() < deadline:
            assert process.poll() is None, "the run ended before it held an episode back"
            time.sleep(0.05)
        os.kill(process.pid, signal.SIGSTOP)  # the parent writes the log and the side logs: both stand still
        replayed = invoke("replay", log)
    finally:
        os.killpg(process.pid, signal.SIGKILL)
        process.wait()
    assert replayed.exit_code == 0, replayed.output
    assert f"note: a run (pid {process.pid}) is still writing this log" in replayed.stderr
    assert "wait beside the log for their turn" in replayed.stderr and "killed" not in replayed.stderr
