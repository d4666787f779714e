"""Stopping a `--workers` run: SIGTERM, SIGHUP, Ctrl-C while the workers start, a worker that
dies, a policy file replaced during the run (issue 41). Each ends in one line, keeps what
was run, and never hangs."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from onnx_models import write_test_policy
from processes import children, cmdline, wait_for_log

from terl_rt.evaluation.episodes import evaluate_policy as evaluate
from terl_rt.logs.reader import EpisodeLogReader
from terl_rt.logs.resimulate import verify
from terl_rt.policy.onnx_policy import OnnxPolicy
from terl_rt.sim.scenario import Scenario

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def policy_path(tmp_path_factory) -> Path:
    return write_test_policy(tmp_path_factory.mktemp("policy") / "linear.onnx")


def _start(policy_path: Path, log: Path) -> subprocess.Popen:
    """`python -m terl_rt eval` of 6 episodes of small-11 (400 steps) on 2 workers, logged to
    `log`, in its own process group, with this checkout's terl_rt; stderr is kept."""
    command = [
        sys.executable, "-m", "terl_rt", "eval", "--policy", str(policy_path), "--scenario", "small-11",
        "--episodes", "6", "--max-steps", "400", "--workers", "2", "--log", str(log),
    ]
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1"}
    return subprocess.Popen(command, start_new_session=True, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            text=True, env=env)


def _finish(process: subprocess.Popen, limit_s: float = 30.0) -> tuple[int, str]:
    """(exit status, stderr) of `process`, which must end within `limit_s`; killed if it does not."""
    try:
        _, stderr = process.communicate(timeout=limit_s)
    except subprocess.TimeoutExpired:
        os.killpg(process.pid, signal.SIGKILL)
        process.communicate()
        pytest.fail(f"the evaluation did not end within {limit_s} s")
    return process.returncode, stderr


def _workers(process: subprocess.Popen) -> list[int]:
    """The worker processes of `process` (spawned pool workers, not multiprocessing's resource tracker)."""
    return sorted(pid for pid in children(process.pid) if "spawn_main" in cmdline(pid))


def _error_line(stderr: str) -> str:
    """The one `Error:` line, the last on stderr (a progress bar may come before it); no traceback."""
    errors = [line for line in stderr.splitlines() if line.startswith("Error: ")]
    assert len(errors) == 1 and stderr.endswith(errors[0] + "\n"), stderr
    assert "Traceback" not in stderr, stderr
    return errors[0]


def _assert_log_keeps_complete_steps(log: Path, episodes_at_least: int) -> None:
    reader = EpisodeLogReader(log)
    assert not reader.truncated, reader.problem
    assert len(reader.episodes) >= episodes_at_least
    assert all(e.steps > 0 for e in reader.episodes)
    assert all(verify(log, e.number).ok for e in reader.episodes)


@pytest.mark.parametrize("signum, to_group", [(signal.SIGTERM, False), (signal.SIGHUP, True)],
                         ids=["sigterm-to-the-process", "sighup-to-the-terminal-group"])
def test_sigterm_or_sighup_of_a_worker_run_writes_the_held_steps_and_exits_128_plus_signal(
        policy_path, tmp_path, signum, to_group):
    log = tmp_path / "stopped.mcap"
    process = _start(policy_path, log)
    wait_for_log(process, log)
    (os.killpg if to_group else os.kill)(process.pid, signum)
    status, stderr = _finish(process)
    assert status == 128 + signum, stderr
    assert _error_line(stderr).startswith("Error: stopped by " + signal.Signals(signum).name)
    # Both workers' episodes are in the log: the one written live and the one held in memory.
    _assert_log_keeps_complete_steps(log, episodes_at_least=2)


def test_ctrl_c_while_the_workers_start_prints_no_worker_traceback(policy_path, tmp_path):
    log = tmp_path / "early.mcap"
    process = _start(policy_path, log)
    deadline = time.monotonic() + 30
    while not _workers(process) and time.monotonic() < deadline:  # spawned, still importing
        time.sleep(0.01)
    os.killpg(process.pid, signal.SIGINT)
    status, stderr = _finish(process)
    assert status != 0
    assert "Traceback" not in stderr and "BrokenProcessPool" not in stderr, stderr


def test_a_worker_killed_mid_run_ends_the_run_in_one_line_keeping_what_was_run(policy_path, tmp_path):
    log = tmp_path / "worker-killed.mcap"
    process = _start(policy_path, log)
    wait_for_log(process, log)
    os.kill(_workers(process)[-1], signal.SIGKILL)
    status, stderr = _finish(process)
    assert status == 2, stderr
    assert "a worker process ended unexpectedly" in _error_line(stderr)
    _assert_log_keeps_complete_steps(log, episodes_at_least=1)


def test_a_policy_file_replaced_during_a_worker_run_is_not_read_again(policy_path, tmp_path):
    """The workers run the bytes the run opened, whatever the file holds by the time they start."""
    path = tmp_path / "replaced.onnx"
    path.write_bytes(policy_path.read_bytes())
    policy = OnnxPolicy(path)
    path.write_bytes(b"not an onnx model any more")
    scenario = Scenario.preset("small-11")
    with_workers = evaluate(policy, scenario, episodes=2, seed=0, max_steps=5, workers=2)
    alone = evaluate(OnnxPolicy(policy_path), scenario, episodes=2, seed=0, max_steps=5)
    assert with_workers.episodes == 2
    assert (with_workers.steps_mean, with_workers.collision_ratio_mean) == (alone.steps_mean, alone.collision_ratio_mean)
