"""Episodes as Ray tasks on a local Ray instance of 2 CPUs (issue 17): the same results and
logs as a local run, a worker killed mid-run, interrupted and killed runs.

They need Ray (the `ray` extra; the `dev` extra installs it too, so they run in CI) and are
marked `ray`: `python -m pytest -m ray` runs them alone. Without Ray they are skipped.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from click.testing import CliRunner
from onnx_models import write_constant_policy, write_test_policy
from kept_logs import assert_log_keeps_complete_steps
from processes import alive, assert_all_end, cmdline, descendants, start_eval, wait_for_log

from terl_rt.cli.main import cli
from terl_rt.evaluation.evaluate import evaluate_policy
from terl_rt.evaluation.pool import LocalBackend
from terl_rt.evaluation.sweep import run_sweep
from terl_rt.logs.reader import EpisodeLogReader
from terl_rt.logs.resimulate import verify
from terl_rt.policy.onnx_policy import OnnxPolicy
from terl_rt.sim.scenario import Scenario

RayBackend = pytest.importorskip("terl_rt.evaluation.ray_backend", reason="needs Ray: pip install -e '.[ray]'").RayBackend

pytestmark = [
    pytest.mark.ray,
    pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc"),
]

RAY_AGENTS = ("ray::DashboardAgent", "ray::RuntimeEnvAgent")
"""Ray's per-node agents: after a SIGKILL of the driver they notice their raylet has gone
and end by themselves, but only after a minute or two."""


@pytest.fixture(scope="module")
def backend():
    """A local Ray instance with 2 CPUs, stopped after this module's tests."""
    with RayBackend(workers=2) as ray_backend:
        yield ray_backend


@pytest.fixture(scope="module")
def policy_path(tmp_path_factory) -> Path:
    return write_test_policy(tmp_path_factory.mktemp("ray-policy") / "linear.onnx")


@pytest.fixture(scope="module")
def policy(policy_path) -> OnnxPolicy:
    return OnnxPolicy(policy_path)


def test_ray_gives_the_results_and_the_log_of_a_local_run(policy, backend, tmp_path):
    scenario = Scenario.preset("small-11")
    local = evaluate_policy(policy, scenario, 4, 5, max_steps=20, log_path=tmp_path / "local.mcap")
    on_ray = evaluate_policy(policy, scenario, 4, 5, max_steps=20, log_path=tmp_path / "ray.mcap", backend=backend)
    assert on_ray.per_episode == local.per_episode
    assert (tmp_path / "ray.mcap").read_bytes() == (tmp_path / "local.mcap").read_bytes()


def test_ray_results_are_the_same_whatever_the_number_of_workers(policy, backend):
    scenario = Scenario.preset("small-15")
    one = evaluate_policy(policy, scenario, 3, 0, max_steps=15, backend=RayBackend(workers=1))  # the same instance
    two = evaluate_policy(policy, scenario, 3, 0, max_steps=15, backend=backend)
    local = evaluate_policy(policy, scenario, 3, 0, max_steps=15, workers=2)
    assert one.per_episode == two.per_episode == local.per_episode


def test_a_sweep_on_ray_is_the_local_sweep(tmp_path, backend):
    policies = [OnnxPolicy(write_test_policy(tmp_path / f"p{seed}.onnx", seed=seed)) for seed in (0, 1)]
    scenarios = [Scenario.preset("small-11"), Scenario.preset("small-15")]
    local = run_sweep(policies, scenarios, 2, 0, LocalBackend(1), max_steps=10)
    on_ray = run_sweep(policies, scenarios, 2, 0, backend, max_steps=10)
    assert [row.result.per_episode for row in on_ray.rows] == [row.result.per_episode for row in local.rows]


def test_the_policy_reaches_the_workers_without_its_file(tmp_path, backend):
    path = write_test_policy(tmp_path / "gone.onnx", seed=2)
    policy = OnnxPolicy(path)
    path.unlink()  # workers read the bytes from Ray's object store, not the file
    scenario = Scenario.preset("small-11")
    assert (evaluate_policy(policy, scenario, 2, 0, max_steps=10, backend=backend).per_episode
            == evaluate_policy(policy, scenario, 2, 0, max_steps=10).per_episode)


@pytest.mark.slow  # Ray's own retry of a lost task; a worker lost by the local pool: test_stopping_worker_runs
def test_a_worker_killed_mid_batch_is_run_again_and_counted_once(policy, backend, tmp_path):
    log = tmp_path / "killed-worker.mcap"
    killed: list[str] = []

    def kill_one_batch_worker() -> None:
        deadline = time.monotonic() + 60
        while (not log.exists() or log.stat().st_size < 100_000) and time.monotonic() < deadline:
            time.sleep(0.01)
        running = [pid for pid in descendants(os.getpid()) if cmdline(pid).startswith("ray::batch_task")]
        if running:
            os.kill(running[0], signal.SIGKILL)
            killed.append(cmdline(running[0]) or "killed")

    killer = threading.Thread(target=kill_one_batch_worker)
    killer.start()
    scenario = Scenario.preset("small-11")
    try:
        on_ray = evaluate_policy(policy, scenario, 4, 0, max_steps=150, log_path=log, backend=backend)
    finally:
        killer.join()
    assert killed, "no batch was running when the log had grown"
    local = evaluate_policy(policy, scenario, 4, 0, max_steps=150, log_path=tmp_path / "local.mcap")
    assert on_ray.per_episode == local.per_episode
    assert log.read_bytes() == (tmp_path / "local.mcap").read_bytes()  # no step twice, none lost


@pytest.mark.slow  # a second Ray instance (13 s idle, racy on a loaded machine); in CI: test_cli's --json test
def test_with_json_stdout_holds_the_json_alone_when_a_ray_worker_dies(policy_path, tmp_path):
    """Ray prints the dying worker's `(raylet)` lines to the driver's stdout: they go to stderr."""
    log = tmp_path / "json.mcap"
    command = [sys.executable, "-m", "terl_rt", "eval", "--policy", str(policy_path), "--scenario", "small-11",
               "--episodes", "4", "--max-steps", "60", "--backend", "ray", "--workers", "2", "--log", str(log), "--json"]
    process = subprocess.Popen(command, start_new_session=True, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                               text=True)
    try:
        wait_for_log(process, log, size=50_000)
        batches = [pid for pid in descendants(process.pid) if cmdline(pid).startswith("ray::batch_task")]
        assert batches, "no batch was running when the log had grown"
        os.kill(batches[0], signal.SIGKILL)
        stdout, stderr = process.communicate(timeout=300)
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait()
    assert process.returncode == 0, stderr[-3000:]
    assert "(raylet)" in stderr  # what the killed worker made Ray print
    assert [scenario["episodes"] for scenario in json.loads(stdout)["scenarios"]] == [4]


def test_a_policy_with_nan_outputs_on_ray_is_one_error_line(tmp_path, backend):
    path = write_constant_policy(tmp_path / "nan.onnx", [0, 1, float("nan"), 0, 0, 0, 0, 0, 0])
    result = CliRunner().invoke(cli, ["eval", "--policy", str(path), "--scenario", "small-11", "--episodes", "2",
                                      "--max-steps", "5", "--backend", "ray"])
    assert result.exit_code == 2, result.output
    errors = [line for line in result.stderr.splitlines() if line.startswith("Error:")]
    assert len(errors) == 1 and "Traceback" not in result.output
    assert "nan.onnx" in errors[0] and "step 1" in errors[0] and "non-finite q_values" in errors[0]


def test_an_unreachable_cluster_is_one_error_line_at_once():
    start = time.monotonic()
    result = subprocess.run(
        [sys.executable, "-c", "from terl_rt.cli.main import cli; cli()", "eval", "--episodes", "1",
         "--backend", "ray", "--address", "127.0.0.1:1"],
        capture_output=True, text=True, timeout=60,
    )
    assert result.returncode == 2
    errors = [line for line in result.stderr.splitlines() if line.startswith("Error:")]
    assert len(errors) == 1 and "127.0.0.1:1" in errors[0] and "ray start --head" in errors[0]
    assert time.monotonic() - start < 30


LONG_RUN = ("--episodes", "40", "--max-steps", "1000")
"""A run still under way when its log has grown (batched episodes finish fast): the runs below are stopped."""


@pytest.mark.slow  # a Ray instance of its own (1-4 min on a loaded machine); Ctrl-C of the local pool in CI: test_worker_logs
def test_ctrl_c_of_a_ray_run_writes_every_received_step_and_stops_ray(policy_path, tmp_path):
    log = tmp_path / "interrupted.mcap"
    process = start_eval(policy_path, log, "--backend", "ray", *LONG_RUN)
    try:
        wait_for_log(process, log)
        ray_processes = descendants(process.pid)
        os.killpg(process.pid, signal.SIGINT)  # what Ctrl-C in a terminal does
        assert process.wait(timeout=30) != 0
        assert_all_end(ray_processes, limit_s=10)
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait()
    assert_log_keeps_complete_steps(log)  # closed on the way out, every episode complete


@pytest.mark.slow  # the path of Ctrl-C above; SIGTERM of the local pool in CI: test_stopping_worker_runs
def test_sigterm_of_a_ray_run_writes_every_received_step_and_exits_143(policy_path, tmp_path):
    """Not Ray's stack dump and SIGABRT: the run stops as for Ctrl-C, with status 128 + SIGTERM."""
    log = tmp_path / "terminated.mcap"
    process = start_eval(policy_path, log, "--backend", "ray", *LONG_RUN)
    try:
        wait_for_log(process, log)
        ray_processes = descendants(process.pid)
        os.kill(process.pid, signal.SIGTERM)  # `kill PID`
        assert process.wait(timeout=30) == 128 + signal.SIGTERM
        assert_all_end(ray_processes, limit_s=10)
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait()
    assert_log_keeps_complete_steps(log)  # closed on the way out, every episode complete


@pytest.mark.slow  # a Ray instance of its own; SIGKILL of the local pool in CI: test_worker_logs
def test_sigkill_of_a_ray_run_keeps_the_streamed_steps_and_ends_its_workers(policy_path, tmp_path):
    log = tmp_path / "killed.mcap"
    process = start_eval(policy_path, log, "--backend", "ray", *LONG_RUN)
    ray_processes: set[int] = set()
    try:
        wait_for_log(process, log)
        ray_processes = descendants(process.pid)
        assert any(cmdline(pid).startswith("ray::batch_task") for pid in ray_processes)
        os.kill(process.pid, signal.SIGKILL)
        process.wait(timeout=10)
        assert_all_end({pid for pid in ray_processes if not cmdline(pid).startswith(RAY_AGENTS)}, limit_s=10)
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait()
        for pid in ray_processes:  # the agents would end by themselves, later
            if alive(pid) and cmdline(pid).startswith(RAY_AGENTS):
                os.kill(pid, signal.SIGKILL)
    reader = EpisodeLogReader(log)
    assert reader.truncated
    assert reader.episodes and sum(e.steps for e in reader.episodes) > 0
    last = reader.episodes[-1]
    assert len(list(reader.steps(last.number))) == len(last.chunks)
    assert verify(log, last.number).ok
