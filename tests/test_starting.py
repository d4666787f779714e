"""Starting the `terl-rt` command under pressure (issue 55): Ctrl-C while it loads its
modules, an address-space limit (`ulimit -v`) and a closed stdout (`>&-`, issue 78, item 3).
Each ends in one line within seconds, never in a traceback, an abort inside a library or a
hang. The command runs as a user runs it (`python -m terl_rt`, this checkout's terl_rt);
every wait polls for the state it needs."""

from __future__ import annotations

import os
import resource
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from onnx_models import write_test_policy
from processes import wait_for_log

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")

ROOT = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "PYTHONPATH": str(ROOT)}


@pytest.fixture(scope="module")
def policy_path(tmp_path_factory) -> Path:
    return write_test_policy(tmp_path_factory.mktemp("policy") / "linear.onnx")


def _eval(policy_path: Path, *options: str, limit_bytes: int | None = None) -> subprocess.Popen:
    """`terl-rt eval` of small-11 with the test policy in a process group of its own (what a
    terminal's Ctrl-C reaches), under an address-space limit when `limit_bytes` is given."""
    def limit() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (limit_bytes, limit_bytes))

    command = [sys.executable, "-m", "terl_rt", "eval", "--policy", str(policy_path), "--scenario", "small-11",
               *options]
    return subprocess.Popen(command, start_new_session=True, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            text=True, env=ENV, preexec_fn=None if limit_bytes is None else limit)


def _finish(process: subprocess.Popen, limit_s: float = 60.0) -> tuple[int, str]:
    """(exit status, stderr) of `process`, which must end within `limit_s` (killed if not)."""
    try:
        _, stderr = process.communicate(timeout=limit_s)
    except subprocess.TimeoutExpired:
        os.killpg(process.pid, signal.SIGKILL)
        process.communicate()
        pytest.fail(f"terl-rt did not end within {limit_s} s")
    return process.returncode, stderr


def _one_error_line(stderr: str) -> str:
    """The one `Error:` line, the last on stderr (a progress bar may come before it)."""
    errors = [line for line in stderr.splitlines() if line.startswith("Error: ")]
    assert len(errors) == 1 and stderr.endswith(errors[0] + "\n"), stderr[-3000:]
    assert "Traceback" not in stderr, stderr[-3000:]
    return errors[0]


def _wait_for_library(process: subprocess.Popen, name: str, limit_s: float = 60.0) -> None:
    """Wait until `process` has mapped a shared library whose path holds `name`: it is
    loading that package's modules."""
    deadline = time.monotonic() + limit_s
    while True:
        assert process.poll() is None, f"terl-rt ended before it loaded {name}"
        try:
            if name in Path(f"/proc/{process.pid}/maps").read_text():
                return
        except OSError:
            pass
        assert time.monotonic() < deadline, f"terl-rt did not load {name} within {limit_s} s"
        time.sleep(0.002)


@pytest.mark.parametrize("library, workers", [("_multiarray_umath", "1"), ("onnxruntime_pybind11_state", "2")],
                         ids=["loading-numpy", "loading-onnxruntime-with-workers"])
def test_ctrl_c_while_terl_rt_loads_ends_in_one_line_and_exit_130(policy_path, library, workers):
    process = _eval(policy_path, "--episodes", "4", "--workers", workers)
    _wait_for_library(process, library)
    os.killpg(process.pid, signal.SIGINT)
    status, stderr = _finish(process)
    assert status == 128 + signal.SIGINT, stderr[-3000:]
    assert _one_error_line(stderr).startswith("Error: stopped by SIGINT")


def test_ctrl_c_during_a_run_in_one_process_ends_in_one_line_and_exit_130(policy_path, tmp_path):
    log = tmp_path / "run.mcap"
    process = _eval(policy_path, "--episodes", "6", "--max-steps", "400", "--log", str(log))
    wait_for_log(process, log)
    os.killpg(process.pid, signal.SIGINT)
    status, stderr = _finish(process)
    assert status == 128 + signal.SIGINT, stderr[-3000:]
    assert _one_error_line(stderr) == "Error: stopped by SIGINT"


@pytest.mark.parametrize("limit_mib, threads", [(150, None), (250, None), (350, None), (350, "64")],
                         ids=["150-MiB", "250-MiB", "350-MiB", "350-MiB-64-policy-threads"])
def test_under_an_address_space_limit_eval_runs_or_ends_in_one_memory_line(policy_path, limit_mib, threads):
    """Before issue 55: a MemoryError traceback (150 MiB), an OpenBLAS abort (250 MiB), a
    hang in scipy's OpenBLAS (350 MiB) or in onnxruntime starting 64 threads."""
    options = ("--episodes", "2", "--max-steps", "20", *(("--threads", threads) if threads else ()))
    process = _eval(policy_path, *options, limit_bytes=limit_mib << 20)
    status, stderr = _finish(process)
    if status != 0:
        assert status == 2, stderr[-3000:]
        assert "memory" in _one_error_line(stderr)



CLOSED_STDOUT_RUNS = {
    "bench": "bench sim --scenario small-11 --envs 1",
    "eval": "eval {small} --log run.mcap --csv episodes.csv",
    "info": "info {policy}",
    "layout": "layout -o layout.json",
    "optimize": "optimize {policy} -o fast.onnx",
    "render": "render {log} -o final.png",
    "replay": "replay {log} --verify",
    "report": "report {small} --out report",
    "scenarios": "scenarios",
    "sweep": "sweep {small} --out sweep",
}
"""A run of each terl-rt command, each of which prints results ({policy}, {log}: the test's)."""


def test_every_command_is_tried_with_a_closed_stdout():
    from terl_rt.cli.main import cli

    assert sorted(CLOSED_STDOUT_RUNS) == sorted(cli.commands)


@pytest.mark.parametrize("name", sorted(CLOSED_STDOUT_RUNS))
def test_a_closed_stdout_ends_a_command_in_one_line_before_it_does_anything(policy_path, logged_eval, tmp_path, name):
    """`terl-rt ... >&-`: the results would be lost, so nothing runs and nothing is written."""
    small = f"--policy {policy_path} --scenario small-11 --episodes 1"
    args = CLOSED_STDOUT_RUNS[name].format(small=small, policy=policy_path, log=logged_eval["log"]).split()
    run = subprocess.run([sys.executable, "-m", "terl_rt", *args], cwd=tmp_path, env=ENV, stderr=subprocess.PIPE,
                         text=True, timeout=60, preexec_fn=lambda: os.close(1))
    assert run.returncode == 2
    assert _one_error_line(run.stderr).startswith("Error: stdout is closed"), run.stderr
    assert list(tmp_path.iterdir()) == []
