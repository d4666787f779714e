"""Sweeps over policies x scenarios x seeds, and choosing a backend, without Ray (issue 17)."""

from __future__ import annotations

import csv
import json
import subprocess
import sys
from pathlib import Path

import pytest
from click.testing import CliRunner
from onnx_models import write_test_policy

from terl_rt.cli.main import cli
from terl_rt.evaluation.backends import RayMissing, open_backend
from terl_rt.evaluation.evaluate import evaluate_policy
from terl_rt.evaluation.pool import LocalBackend
from terl_rt.evaluation.sweep import TABLE_COLUMNS, run_sweep
from terl_rt.policy.onnx_policy import OnnxPolicy
from terl_rt.sim.scenario import Scenario

SCENARIOS = ("small-11", "small-15")


@pytest.fixture(scope="module")
def policy_files(tmp_path_factory) -> list[Path]:
    folder = tmp_path_factory.mktemp("sweep-policies")
    return [write_test_policy(folder / f"linear-{seed}.onnx", seed=seed) for seed in (0, 1)]


def invoke(*args):
    return CliRunner().invoke(cli, [str(arg) for arg in args])


@pytest.mark.parametrize("workers", [1, 2])
def test_a_sweep_row_is_the_evaluation_of_its_policy_on_its_scenario(policy_files, workers):
    policies = [OnnxPolicy(path) for path in policy_files]
    scenarios = [Scenario.preset(name) for name in SCENARIOS]
    sweep = run_sweep(policies, scenarios, episodes=2, seed=3, backend=LocalBackend(workers), max_steps=8)
    assert [(row.policy_path, row.result.name) for row in sweep.rows] == [
        (str(path), name) for path in policy_files for name in SCENARIOS
    ]
    for row in sweep.rows:
        alone = evaluate_policy(OnnxPolicy(row.policy_path), Scenario.preset(row.result.name), 2, 3, max_steps=8)
        assert row.result.per_episode == alone.per_episode
        assert (row.result.seed, row.result.max_steps) == (3, 8)


def test_sweep_progress_hears_every_episode_in_sweep_order(policy_files):
    seen = []
    run_sweep([OnnxPolicy(policy_files[0])], [Scenario.preset(name) for name in SCENARIOS], 2, 0, LocalBackend(2),
              max_steps=3, progress=lambda number, metrics: seen.append(number))
    assert seen == [0, 1, 2, 3]


def test_sweep_command_writes_one_table_as_json_csv_and_markdown(policy_files, tmp_path):
    folder = policy_files[0].parent  # a folder stands for its .onnx files, by name
    out = tmp_path / "table"
    args = ["sweep", "--policy", folder, "--scenario", "small-11", "--scenario", "small-15", "--episodes", "2",
            "--max-steps", "5", "--out", out]
    result = invoke(*args)
    assert result.exit_code == 0, result.output
    rows = list(csv.DictReader(open(out / "sweep.csv")))
    assert tuple(rows[0]) == TABLE_COLUMNS
    assert [(Path(r["policy_path"]).name, r["scenario"]) for r in rows] == [
        (path.name, name) for path in policy_files for name in SCENARIOS
    ]
    table = json.loads((out / "sweep.json").read_text())
    assert table["backend"] == "local" and len(table["rows"]) == 4
    assert all(len(row["per_episode"]) == 2 for row in table["rows"])
    markdown = (out / "sweep.md").read_text()
    assert markdown.count("\n") == 2 + 4 and "linear-1.onnx" in markdown
    assert invoke(*args).exit_code == 2  # never over an existing table without --force
    assert invoke(*args, "--force", "--workers", "2").exit_code == 0
    assert list(csv.DictReader(open(out / "sweep.csv"))) == rows


def test_sweep_command_names_a_non_default_evader_in_every_table(policy_files, tmp_path):
    out = tmp_path / "still"
    result = invoke("sweep", "--policy", policy_files[0], "--scenario", "small-11", "--evader", "still",
                    "--episodes", "1", "--max-steps", "3", "--out", out)
    assert result.exit_code == 0, result.output
    assert [(r["scenario"], r["evader"]) for r in csv.DictReader(open(out / "sweep.csv"))] == [("small-11", "still")]
    assert json.loads((out / "sweep.json").read_text())["rows"][0]["evader"] == "still"
    assert "| small-11/still |" in (out / "sweep.md").read_text()


def test_the_cli_and_the_evaluation_import_without_ray():
    probe = "import terl_rt.cli.main, terl_rt.evaluation.sweep, sys; print('ray' in sys.modules)"
    assert subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True).stdout.split() == ["False"]


def test_the_ray_backend_without_ray_says_how_to_install_it(monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)  # `import ray` fails, as when Ray is not installed
    monkeypatch.delitem(sys.modules, "terl_rt.evaluation.ray_backend", raising=False)
    with pytest.raises(RayMissing, match=r"pip install -e '\.\[ray\]'"):
        open_backend("ray")


@pytest.mark.parametrize("command", ["eval", "report", "sweep"])
def test_backend_ray_without_ray_is_one_error_line(monkeypatch, tmp_path, command):
    monkeypatch.setitem(sys.modules, "ray", None)
    monkeypatch.delitem(sys.modules, "terl_rt.evaluation.ray_backend", raising=False)
    out = [] if command == "eval" else ["--out", tmp_path]
    result = invoke(command, "--backend", "ray", "--episodes", "1", *out)
    assert result.exit_code == 2, result.output
    assert result.stderr.count("\n") == 1 and result.stderr.startswith("Error: the ray backend needs Ray")
    assert "pip install -e '.[ray]'" in result.stderr


def test_an_address_without_the_ray_backend_is_one_error_line():
    result = invoke("eval", "--address", "127.0.0.1:6379", "--episodes", "1")
    assert result.exit_code == 2 and result.stderr.count("\n") == 1
    assert "--backend ray" in result.stderr


def test_an_unknown_backend_is_refused():
    with pytest.raises(ValueError, match="local, ray"):
        open_backend("dask")
    assert invoke("eval", "--backend", "dask").exit_code == 2
