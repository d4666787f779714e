"""`terl-rt report` and terl_rt.paper.report: results.md and results.png against the paper.

Most tests build ScenarioResults by hand (no simulation), so the goal sentences can be
checked against numbers chosen on either side of each goal.
"""

from __future__ import annotations

import json
import os
import sys
from datetime import datetime, timezone
from pathlib import Path

import pytest
from click.testing import CliRunner
from made_results import made_result
from one_line import assert_one_error
from onnx_models import write_test_policy
from PIL import Image

from terl_rt.cli.main import cli
from terl_rt.evaluation.episodes import ScenarioResult
from terl_rt.paper.figures import MatplotlibMissing
from terl_rt.paper.numbers import GOALS, PRESET_GROUPS, SMALL_RELEASED, TERL_BY_GROUP, paper_group, scale_group
from terl_rt.paper.report import (
    REPORT_SUITE,
    comparability_note,
    goal_checks,
    group_summaries,
    render_markdown,
    where_it_stands,
    write_report,
)
from terl_rt.sim.scenario import PAPER_SUITE, PUBLISHED_SMALL_SUITE

POLICY_INFO = {
    "name": "terl-test",
    "sha256": "0123456789abcdef" * 4,
    "path": "exported/terl.onnx",
    "metadata": {"terl.training_steps": "7000000", "terl.trained_on": "curriculum-1..5"},
}
DATE = datetime(2025, 3, 1, 12, 30, tzinfo=timezone.utc)
INSTALL_HINT = "pip install -e '.[report]'"


def result(name: str, success: float = 1.0, travel: float = 40.0, collision: float = 0.0,
           episodes: int = 20, max_steps: int = 1000) -> ScenarioResult:
    """A hand-made ScenarioResult; steps_mean follows from the travel time (0.5 s a step)."""
    return ScenarioResult(
        name=name, episodes=episodes, seed=0, max_steps=max_steps, success_rate=success,
        travel_time_s_mean=travel, travel_time_s_std=2.0, collision_ratio_mean=collision,
        steps_mean=travel / 0.5, wall_s=0.0, per_episode=(),
    )


def at_goal(name: str, **changes) -> ScenarioResult:
    """A result exactly on every goal of the preset's scale group (all met), with `changes`."""
    goal = GOALS[paper_group(scale_group(name))]
    values = {"success": goal.min_success_rate, "travel": goal.max_travel_time_s,
              "collision": goal.max_collision_ratio}
    return result(name, **{**values, **changes})


def suite_at_goal(**changes_by_preset) -> list[ScenarioResult]:
    return [at_goal(name, **changes_by_preset.get(name.replace("-", "_"), {})) for name in PAPER_SUITE]


def invoke(*args):
    return CliRunner().invoke(cli, [str(arg) for arg in args])


# --- paper data -----------------------------------------------------------------------


def test_every_evaluation_preset_has_a_scale_group_and_others_have_none():
    assert set(PRESET_GROUPS) == set(PAPER_SUITE) | set(PUBLISHED_SMALL_SUITE)
    assert [scale_group(n) for n in ("small-15", "medium-51", "large-80", "cc-28")] == ["small", "medium", "large", "CC"]
    assert scale_group("curriculum-3") is None


def test_released_small_config_is_its_own_group_measured_against_small_scale():
    assert {scale_group(name) for name in PUBLISHED_SMALL_SUITE} == {SMALL_RELEASED}
    assert paper_group(SMALL_RELEASED) == "small" and paper_group("large") == "large"
    assert REPORT_SUITE == ("small-11", "small-15", "small-19", *PUBLISHED_SMALL_SUITE, *PAPER_SUITE[3:])


def test_cc_goal_uses_the_papers_comparison_row():
    assert (TERL_BY_GROUP["CC"].success_rate, TERL_BY_GROUP["CC"].travel_time_s) == (0.80, 226.78)


# --- numbers and sentences ------------------------------------------------------------


def test_group_summary_is_the_mean_over_the_groups_presets():
    results = [result("small-11", 1.0, 40.0, 0.0), result("small-15", 0.9, 50.0, 0.03),
               result("small-19", 0.8, 60.0, 0.06), result("cc-28", 0.5, 200.0, 0.1)]
    small, cc = group_summaries(results)
    # (1.0 + 0.9 + 0.8) / 3 = 0.9; (40 + 50 + 60) / 3 = 50; (0 + 0.03 + 0.06) / 3 = 0.03
    assert (small.group, small.presets) == ("small", ("small-11", "small-15", "small-19"))
    assert small.success_rate == pytest.approx(0.9)
    assert small.travel_time_s_mean == pytest.approx(50.0)
    assert small.collision_ratio_mean == pytest.approx(0.03)
    assert (cc.group, cc.success_rate) == ("CC", 0.5)


def test_numbers_on_every_goal_meet_all_twelve():
    text = where_it_stands(suite_at_goal())
    assert all(check.met for check in goal_checks(suite_at_goal()))
    for where in ("Small scale", "Medium scale", "Large scale", "CC"):
        assert f"{where} (" in text
    assert text.count("meets all three goals") == 4
    assert "12 of 12 goals are met" in text
    assert "misses" not in text and "indicative" not in text


def test_a_missed_success_goal_also_misses_the_travel_time_goal():
    # Fast failures are not fast encirclements: travel time counts only with success met.
    changes = {"success": 0.95}
    results = suite_at_goal(small_11=changes, small_15=changes, small_19=changes)
    small = where_it_stands(results).split(". ")[0]
    assert small.startswith("Small scale (small-11, small-15, small-19) meets 1 of 3 goals")
    assert "success rate 0.95 < 1.00" in small
    assert "counted only with the success goal met" in small


@pytest.mark.parametrize("changes, missed", [
    ({"travel": 46.5}, "travel time 46.5 s > 46 s"),
    ({"collision": 0.031}, "collision ratio 0.031 > 0.03"),
])
def test_one_missed_small_goal_flips_its_sentence(changes, missed):
    # All three small presets miss by the same amount, so the group mean does too.
    results = suite_at_goal(small_11=changes, small_15=changes, small_19=changes)
    text = where_it_stands(results)
    small = text.split(". ")[0]
    assert small.startswith("Small scale (small-11, small-15, small-19) meets 2 of 3 goals")
    assert f"misses {missed}" in small
    assert "11 of 12 goals are met" in text
    assert text.count("meets all three goals") == 3


def test_cc_success_goal_is_080_not_100():
    met = where_it_stands([at_goal("cc-28", success=0.80)])
    missed = where_it_stands([at_goal("cc-28", success=0.75)])
    assert "CC (cc-28) meets all three goals" in met and "success rate 0.80 ≥ 0.80" in met
    assert "misses success rate 0.75 < 0.80" in missed


def test_every_goal_missed_says_so():
    text = where_it_stands([result("large-80", success=0.5, travel=300.0, collision=0.5)])
    assert text.startswith("Large scale (large-80) misses all three goals: success rate 0.50 < 1.00, "
                           "travel time 300.0 s > 63 s and collision ratio 0.500 > 0.03.")
    assert "0 of 3 goals are met" in text


def test_a_miss_close_to_the_goal_never_shows_as_the_goal():
    # 0.9995 prints as 1.00 at two digits; the sentence must show more.
    text = where_it_stands([result("small-11", success=0.9995)])
    assert "success rate 0.9995 < 1.00" in text


def test_groups_not_evaluated_and_short_runs_are_named():
    text = where_it_stands([result("small-11", episodes=2, max_steps=5), result("curriculum-2", episodes=2, max_steps=5)])
    assert "Not evaluated: medium scale, large scale and CC." in text
    assert "The paper reports nothing for curriculum-2" in text
    assert "2 episodes a scenario, fewer than the paper's 20, and a step limit of 5, not the paper's 1000" in text
    assert "indicative only" in text


def test_more_episodes_than_the_papers_and_scenarios_it_does_not_report_leave_the_comparison_whole():
    assert comparability_note([result("small-11", episodes=50), result("scale-400", episodes=10)]) == ""
    assert comparability_note([result("small-11", episodes=10)]) == (
        "These runs used 10 episodes a scenario, fewer than the paper's 20, so the comparison is indicative only.")
    assert "a step limit of 300, not the paper's 1000" in comparability_note([result("cc-28", max_steps=300)])


# --- markdown -------------------------------------------------------------------------


def test_markdown_has_a_row_per_preset_beside_the_papers_group_numbers():
    text = render_markdown(suite_at_goal(), POLICY_INFO, "terl-rt report --episodes 20", DATE)
    assert "| paper TERL success | paper TERL travel time (s) | paper TERL collision ratio |" in text
    assert "one number per scale group, not per preset" in text
    paper_time = {"small": "45.98", "medium": "63.80", "large": "62.62", "CC": "226.78"}
    for name in PAPER_SUITE:
        (row,) = [line for line in text.splitlines() if line.startswith(f"| {name} | {scale_group(name)} | 20 |")]
        assert f"| {paper_time[scale_group(name)]} |" in row
        assert "±" in row


def test_markdown_has_a_row_per_scale_group():
    text = render_markdown(suite_at_goal(), POLICY_INFO, "terl-rt report", DATE)
    section = text.split("## Per scale group")[1].split("##")[0]
    rows = [line for line in section.splitlines() if line.startswith("| ") and "---" not in line][1:]
    assert [row.split(" | ")[0] for row in rows] == ["| small", "| medium", "| large", "| CC"]


GOLDEN = Path(__file__).parent / "data" / "report" / "paper-suite-results.md"


def golden_results() -> list[ScenarioResult]:
    """The paper suite with made episodes (different numbers on every preset)."""
    return [made_result(name, successes=20 - k % 3, travel_s=40.0 + 9 * k, collided=k % 4)
            for k, name in enumerate(PAPER_SUITE)]


def test_single_policy_markdown_of_the_paper_suite_is_unchanged():
    # GOLDEN was written by render_markdown before the comparison and the released small
    # config existed: on the paper's presets results.md must read exactly the same.
    text = render_markdown(golden_results(), POLICY_INFO, "terl-rt report --policy exported/terl.onnx --out docs", DATE)
    assert text == GOLDEN.read_text()


def test_released_small_config_adds_its_rows_and_keeps_the_others():
    # The released presets go after the table's small ones, as in REPORT_SUITE.
    released = [made_result(name, travel_s=30.0 + k) for k, name in enumerate(PUBLISHED_SMALL_SUITE)]
    suite = golden_results()
    text = render_markdown(suite[:3] + released + suite[3:], POLICY_INFO,
                           "terl-rt report --policy exported/terl.onnx --out docs", DATE)
    golden_lines = GOLDEN.read_text().splitlines()
    new_lines = [line for line in text.splitlines() if line not in golden_lines]
    # The released presets' rows, beside the paper's small-scale TERL row (45.98 s).
    for name in PUBLISHED_SMALL_SUITE:
        (row,) = [line for line in new_lines if line.startswith(f"| {name} | {SMALL_RELEASED} | 20 |")]
        assert row.endswith("| 1.00 | 45.98 | 0.00 |")
    (group_row,) = [line for line in new_lines if line.startswith(f"| {SMALL_RELEASED} | ")]
    # 60 successes of 60 pooled episodes: exact lower bound 0.025^(1/60) = 0.94.
    assert "small-published-7, small-published-11, small-published-15 | 1.00 [0.94, 1.00] | 1.00 | 31.0" in group_row
    # Every row of the paper's presets and groups is kept as it was.
    for line in golden_lines:
        if line.startswith(("| small", "| medium", "| large", "| cc-28", "| CC")):
            assert line in text
    assert "Small scale, released config (small-published-7, small-published-11, small-published-15) meets all three" in text
    assert "In all, 5 of 15 goals are met." in text
    assert "is held to the small-scale goals" in text and "is held to" not in GOLDEN.read_text()


def test_markdown_header_names_the_policy_the_command_and_the_date():
    text = render_markdown([result("small-11")], POLICY_INFO, "terl-rt report --scenario small-11", DATE)
    assert text.startswith("# terl-test against the TERL paper")
    assert "sha256: `0123456789ab`" in text
    assert "training steps: 7,000,000" in text
    assert "command: `terl-rt report --scenario small-11`" in text
    assert "date: 2025-03-01 12:30 UTC" in text
    assert "](results.png)" in text


# --- files ----------------------------------------------------------------------------


def test_report_writes_markdown_and_a_three_panel_png(tmp_path):
    pytest.importorskip("matplotlib")
    results = [at_goal(name) for name in REPORT_SUITE]
    paths = write_report(results, POLICY_INFO, tmp_path / "docs", "terl-rt report", date=DATE)
    assert paths.markdown == tmp_path / "docs" / "results.md" and paths.figure == tmp_path / "docs" / "results.png"
    assert "| cc-28 | CC |" in paths.markdown.read_text()
    assert f"| small-published-7 | {SMALL_RELEASED} |" in paths.markdown.read_text()
    with Image.open(paths.figure) as image:
        assert image.format == "PNG"
        width, height = image.size
    # Three panels side by side: at least 3 x 300 px wide and much wider than tall.
    assert width >= 900 and width >= 2.5 * height


def test_missing_matplotlib_says_how_to_install_it_and_writes_nothing(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "matplotlib", None)  # `import matplotlib` now raises ImportError
    with pytest.raises(MatplotlibMissing, match=r"pip install -e '\.\[report\]'"):
        write_report([result("small-11")], POLICY_INFO, tmp_path / "docs", "terl-rt report")
    assert not (tmp_path / "docs").exists()


# --- CLI ------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def policy(tmp_path_factory):
    return write_test_policy(tmp_path_factory.mktemp("report") / "linear.onnx")


def test_report_cli_evaluates_and_writes_both_files(policy, tmp_path):
    pytest.importorskip("matplotlib")
    out = tmp_path / "docs"
    result = invoke("report", "--policy", policy, "--scenario", "small-11", "--episodes", "2",
                    "--max-steps", "3", "--out", out)
    assert result.exit_code == 0, result.output
    assert "small-11" not in result.stderr  # a progress bar only on a terminal
    assert f"wrote {out / 'results.md'} and {out / 'results.png'}" in result.stdout
    text = (out / "results.md").read_text()
    assert "# linear-test against the TERL paper" in text
    assert f"--policy {policy} --scenario small-11 --episodes 2 --seed 0 --max-steps 3 --out {out}" in text
    assert "| small-11 | small | 2 |" in text
    assert "indicative only" in text
    with Image.open(out / "results.png") as image:
        assert image.size[0] >= 900


def test_report_cli_with_another_evader_names_it_in_the_rows_and_the_command(policy, tmp_path):
    pytest.importorskip("matplotlib")
    out = tmp_path / "still"
    result = invoke("report", "--policy", policy, "--scenario", "small-11", "--evader", "still", "--episodes", "1",
                    "--max-steps", "2", "--out", out)
    assert result.exit_code == 0, result.output
    text = (out / "results.md").read_text()
    assert "--scenario small-11 --evader still --episodes 1" in text
    assert "| small-11/still | small | 1 |" in text


def test_report_cli_json_lists_scenarios_groups_goals_and_files(policy, tmp_path):
    pytest.importorskip("matplotlib")
    result = invoke("report", "--policy", policy, "--scenario", "small-11", "--episodes", "1",
                    "--max-steps", "2", "--out", tmp_path, "--json")
    assert result.exit_code == 0, result.output
    out = json.loads(result.stdout)
    assert set(out) == {"policy", "acting", "scenarios", "groups", "goals", "files"}
    assert [row["name"] for row in out["scenarios"]] == ["small-11"]
    assert out["scenarios"][0]["steps_mean"] == 2.0
    assert [group["group"] for group in out["groups"]] == ["small"]
    assert {goal["metric"] for goal in out["goals"]} == {"success rate", "travel time", "collision ratio"}
    assert out["files"] == {"markdown": str(tmp_path / "results.md"), "figure": str(tmp_path / "results.png")}


def test_report_cli_without_matplotlib_fails_before_evaluating(policy, tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "matplotlib", None)
    result = invoke("report", "--policy", policy, "--scenario", "small-11", "--episodes", "1", "--out", tmp_path / "docs")
    assert result.exit_code == 2, result.output
    assert result.stderr.startswith("Error: ") and INSTALL_HINT in result.stderr
    assert "small-11" not in result.stderr  # no progress bar: nothing was evaluated
    assert not (tmp_path / "docs").exists()


@pytest.mark.parametrize("odd, words", [
    (lambda path: os.mkfifo(path), ["x.onnx is a FIFO"]),
    (lambda path: path.symlink_to("gone.onnx"), ["x.onnx is a broken link to gone.onnx"]),
], ids=["fifo", "dangling-link"])
def test_a_policy_folder_with_an_onnx_that_is_no_file_is_refused_naming_it(policy, tmp_path, odd, words):
    folder = tmp_path / "policies"
    folder.mkdir()
    (folder / "a.onnx").write_bytes(policy.read_bytes())
    odd(folder / "x.onnx")
    result = CliRunner().invoke(cli, ["report", "--policy", str(folder), "--scenario", "small-11", "--episodes", "1",
                                      "--out", str(tmp_path / "report")])
    assert_one_error(result, f"--policy {folder}", *words, "not a policy file")
    assert not (tmp_path / "report").exists()
