"""Fixtures shared by the test modules."""

from __future__ import annotations

from pathlib import Path

import pytest
from one_line import invoke
from onnx_models import write_test_policy


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
