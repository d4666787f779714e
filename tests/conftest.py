"""Fixtures shared by the test modules, and two settings every test runs under."""

from __future__ import annotations

import signal
import sys
from pathlib import Path

import pytest
from one_line import invoke
from onnx_models import write_test_policy

# A suite started in the background by a shell without job control starts with SIGINT ignored, and
# every command a test starts would inherit that: the tests of Ctrl-C need it delivered.
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)


@pytest.fixture(scope="session", autouse=True)
def one_torch_thread_in_shared_fixtures():
    """Module and session fixtures (set up before a test's own) run torch on one thread too."""
    torch = sys.modules.get("torch")
    if torch is not None:
        torch.set_num_threads(1)


@pytest.fixture(autouse=True)
def one_torch_thread():
    """Tests that use torch run it on one thread: two threads that share the cores with another
    process (a parallel test run, a training run) stall on each other, up to 7x slower. Tests of
    the runtime alone never import torch, and this does not either."""
    torch = sys.modules.get("torch")
    if torch is None:
        yield
        return
    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(previous)


@pytest.fixture(scope="session")
def logged_eval(tmp_path_factory) -> dict[str, Path]:
    """A test policy (linear-test) and the log of its `terl-rt eval` of 2 small-11 episodes of
    30 steps: {"folder": their folder, "policy": the .onnx, "log": the .mcap}, which no test
    may change."""
    folder = tmp_path_factory.mktemp("logged-eval")
    policy = write_test_policy(folder / "linear.onnx")
    log = folder / "run.mcap"
    result = invoke("eval", "--policy", policy, "--scenario", "small-11", "--episodes", "2", "--max-steps", "30",
                    "--log", log)
    assert result.exit_code == 0, result.output
    return {"folder": folder, "policy": policy, "log": log}
