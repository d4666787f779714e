"""Stopping a `--workers` run: Ctrl-C while the workers start, SIGTERM, SIGHUP, a worker that
dies, a policy file replaced during the run (issue 41). Each ends in one line, keeps what
was run, and never hangs. The limits are generous (the tests run under load) but bounded,
and every wait polls for the state it needs."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from onnx_models import write_test_policy
from kept_logs import assert_log_keeps_complete_steps
from processes import children, cmdline, wait_for_log

from terl_rt.evaluation.evaluate import evaluate_policy as evaluate
from terl_rt.policy.onnx_policy import OnnxPolicy
from terl_rt.sim.scenario import Scenario

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")

ROOT = Path(__file__).resolve().parents[1]

CLI = "import signal; signal.signal(signal.SIGHUP, signal.SIG_DFL); from terl_rt.cli.main import cli; cli()"
"""terl-rt with SIGHUP's default action, which a run under nohup (as CI may be) inherits ignored."""


@pytest.fixture(scope="module")
def policy_path(tmp_path_factory) -> Path:
    return write_test_policy(tmp_path_factory.mktemp("policy") / "linear.onnx")


def _start(policy_path: Path, log: Path) -> subprocess.Popen:
    """`terl-rt eval` of 6 episodes of small-11 (400 steps) on 2 workers, logged to `log`, in a
    process group of its own (what a terminal's Ctrl-C reaches), with this checkout's terl_rt;
    stderr is kept."""
    command = [
        sys.executable, "-c", CLI, "eval", "--policy", str(policy_path), "--scenario", "small-11",
        "--episodes", "6", "--max-steps", "400", "--workers", "2", "--log", str(log),
    ]
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1"}
    return subprocess.Popen(command, start_new_session=True, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            text=True, env=env)


def _finish(process: subprocess.Popen, limit_s: float = 20.0) -> tuple[int, str]:
    """(exit status, stderr) of `process`, which must end within `limit_s`; killed if it does not."""
    try:
        _, stderr = process.communicate(timeout=limit_s)
    except subprocess.TimeoutExpired:
        os.killpg(process.pid, signal.SIGKILL)
        for pid in _workers(process):
            os.kill(pid, signal.SIGKILL)
        process.communicate()
        pytest.fail(f"the evaluation did not end within {limit_s} s")
    return process.returncode, stderr


def _workers(process: subprocess.Popen) -> list[int]:
    """The worker processes of `process`, in the order they were started (by pid)."""
    return sorted(pid for pid in children(process.pid) if "terl_rt.evaluation.worker" in cmdline(pid))


def _wait_for_workers(process: subprocess.Popen, count: int = 1, limit_s: float = 60.0) -> list[int]:
    deadline = time.monotonic() + limit_s
    while len(workers := _workers(process)) < count:
        assert process.poll() is None and time.monotonic() < deadline, "no worker started"
        time.sleep(0.005)
    return workers


def _error_line(stderr: str) -> str:
    """The one `Error:` line, the last on stderr (a progress bar may come before it); no traceback."""
    errors = [line for line in stderr.splitlines() if line.startswith("Error: ")]
    assert len(errors) == 1 and stderr.endswith(errors[0] + "\n"), stderr
    assert "Traceback" not in stderr and "BrokenProcessPool" not in stderr, stderr
    return errors[0]


def test_ctrl_c_while_the_workers_start_ends_in_one_line_five_times_in_five(policy_path, tmp_path):
    """Ctrl-C reaches the process group at five moments of the workers' start, from their
    first instruction (0 s) through their imports to their first steps (0.8 s): never a worker
    traceback, never a hang."""
    for attempt, delay_s in enumerate((0.0, 0.02, 0.1, 0.3, 0.8)):
        log = tmp_path / f"early-{attempt}.mcap"
        process = _start(policy_path, log)
        workers = _wait_for_workers(process)
        time.sleep(delay_s)
        os.killpg(process.pid, signal.SIGINT)
        status, stderr = _finish(process)
        assert status == 128 + signal.SIGINT, (attempt, stderr)
        assert _error_line(stderr).startswith("Error: stopped by SIGINT"), attempt
        assert not any(cmdline(pid) for pid in workers), f"attempt {attempt}: a worker outlived the run"
        if log.exists():
            assert_log_keeps_complete_steps(log, episodes_at_least=0)


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
    # Episode 0 is written live; the episodes running beside it (2 and 4 in the first
    # worker's batch, 1, 3, 5 in the second's) were held in memory and are written too.
    assert_log_keeps_complete_steps(log, episodes_at_least=2)


def test_a_worker_killed_mid_run_ends_the_run_in_one_line_keeping_what_was_run(policy_path, tmp_path):
    log = tmp_path / "worker-killed.mcap"
    process = _start(policy_path, log)
    workers = _wait_for_workers(process, count=2)
    wait_for_log(process, log)
    os.kill(workers[-1], signal.SIGKILL)
    status, stderr = _finish(process)
    assert status == 2, stderr
    line = _error_line(stderr)
    assert f"pid {workers[-1]}" in line and "ended unexpectedly (killed by SIGKILL" in line, line
    assert_log_keeps_complete_steps(log, episodes_at_least=2)


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
