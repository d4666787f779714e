"""scripts/safety-table.py: docs/safety.md's tables from the measurement's sweeps (issue 75)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from click.testing import CliRunner
from onnx_models import write_test_policy

from terl_rt.cli.main import cli

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "safety-table.py"


def sweep(policy: Path, folder: Path, *options: str) -> None:
    """One sweep as scripts/safety-measurement.sh runs it, on two presets and a short limit."""
    args = ["sweep", "--policy", str(policy), "--scenario", "small-11", "--scenario", "medium-48", "--episodes", "2",
            "--max-steps", "6", "--seed", "0", "--out", str(folder), *options]
    result = CliRunner().invoke(cli, args)
    assert result.exit_code == 0, result.output


def test_the_table_pairs_each_rule_with_the_greedy_episodes_and_names_the_missed_goals(tmp_path):
    policy = write_test_policy(tmp_path / "linear.onnx", seed=0)
    out = tmp_path / "safety"
    sweep(policy, out / "terl" / "plain" / "paper")
    sweep(policy, out / "terl" / "shield" / "paper", "--shield")
    table = subprocess.run([sys.executable, str(SCRIPT), str(out)], capture_output=True, text=True, check=True).stdout
    rows = [line for line in table.splitlines() if line.startswith("| plain") or line.startswith("| shield")]
    assert [row.split(" | ")[:3] for row in rows] == [
        ["| plain", "small", "2"], ["| plain", "medium", "2"], ["| shield", "small", "2"], ["| shield", "medium", "2"],
    ]
    greedy, shielded = rows[0].split(" | "), rows[2].split(" | ")
    assert greedy[5] == "—" and greedy[-1] == "— |"  # no ratio to itself, no overrides without the shield
    assert shielded[5] == "1.00 [1.00, 1.00]"  # both run to the 6-step limit: the same travel time
    assert float(shielded[-1].rstrip(" |")) >= 0.0
    # six steps encircle nothing: every rule misses the success goals, and the groups beyond are not there yet
    assert "- plain: misses small: success 0.000; medium: success 0.000 (not every group measured yet)" in table
    assert "- shield: misses small: success 0.000" in table


def test_a_sweep_that_did_not_act_by_its_folders_rule_is_refused(tmp_path):
    policy = write_test_policy(tmp_path / "linear.onnx", seed=0)
    out = tmp_path / "safety"
    sweep(policy, out / "terl" / "plain" / "paper")
    sweep(policy, out / "terl" / "cvar-0.75" / "paper", "--shield")  # the rule a bash loop once left behind
    run = subprocess.run([sys.executable, str(SCRIPT), str(out)], capture_output=True, text=True)
    assert run.returncode != 0
    assert "acted as 'shield 0.5 m / 4 steps', which is not its folder's rule 'cvar-0.75'" in run.stderr
