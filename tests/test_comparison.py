"""Several policies against the paper's comparison: terl_rt.paper.comparison and
`terl-rt report --policy A --policy B ...`.

The claims are checked on hand-made group means whose answer is known: one set that
reproduces every claim, then one number changed at a time so that exactly one claim
fails. The CLI runs tiny linear policies (tests/onnx_models.py) named as the paper's
models, one short episode a scenario.
"""

from __future__ import annotations

import json
import math
from dataclasses import replace
from datetime import datetime, timezone

import pytest
from click.testing import CliRunner
from made_results import made_result
from onnx_models import write_broken_policy, write_test_policy
from PIL import Image

from terl_rt.cli.main import cli
from terl_rt.evaluation.stats import CI_METRICS
from terl_rt.paper.claims import CLAIMS, DOES_NOT_REPRODUCE, NOT_MEASURED, REPRODUCES
from terl_rt.paper.comparison import (
    ComparisonError,
    MethodRun,
    check_methods,
    claim_checks,
    paper_order,
    method_name,
    render_comparison_markdown,
    table_iii,
    table_iv,
    write_comparison,
)
from terl_rt.paper.numbers import PAPER_METHODS, SMALL_RELEASED
from terl_rt.paper.report import REPORT_SUITE, GroupSummary

DATE = datetime(2025, 3, 1, 12, 30, tzinfo=timezone.utc)


def summary(group: str, success: float, time_s: float, collisions: float = 0.02) -> GroupSummary:
    """A group mean with narrow intervals: +-0.01 on rates (none at 0 and 1, as the bootstrap
    gives for all-equal episodes) and +-0.5 s on the travel time."""

    def rate(value):
        return (value, value) if value in (0.0, 1.0) else (value - 0.01, value + 0.01)

    return GroupSummary(
        group=group, presets=(group,), success_rate=success, travel_time_s_mean=time_s,
        collision_ratio_mean=collisions,
        ci95={"success_rate": rate(success), "travel_time_s": (time_s - 0.5, time_s + 0.5),
              "collision_ratio": rate(collisions)},
    )


# method -> group -> (success, travel time s, collision ratio): every claim of policy.md
# section 4 holds, most with the paper's own numbers.
REPRODUCING = {
    "TERL": {"small": (1.0, 46.0, 0.0), SMALL_RELEASED: (1.0, 40.0, 0.0), "medium": (1.0, 64.0, 0.01),
             "large": (1.0, 63.0, 0.03), "CC": (0.80, 227.0, 0.03)},
    "IQN": {"small": (1.0, 40.0, 0.02), SMALL_RELEASED: (1.0, 38.0, 0.0), "medium": (0.8, 90.0, 0.2),
            "large": (0.6, 120.0, 0.4), "CC": (0.0, 150.5, 0.93)},
    "DQN": {"small": (1.0, 42.0, 0.02), SMALL_RELEASED: (0.97, 39.0, 0.0), "medium": (0.7, 95.0, 0.2),
            "large": (0.5, 130.0, 0.4), "CC": (0.0, 252.5, 0.90)},
    "MEAN": {"small": (0.97, 50.0, 0.03), SMALL_RELEASED: (0.97, 45.0, 0.0), "medium": (0.5, 110.0, 0.3),
             "large": (0.2, 150.0, 0.5), "CC": (0.0, 210.8, 0.92)},
    "w/o RE": {"small": (1.0, 50.0, 0.02), "medium": (1.0, 81.5, 0.45), "large": (0.75, 162.0, 0.75),
               "CC": (0.05, 240.0, 0.91)},
    "w/o TS": {"small": (1.0, 53.0, 0.0), "medium": (1.0, 78.0, 0.03), "large": (1.0, 84.7, 0.04),
               "CC": (0.55, 390.6, 0.06)},
}


def groups_of(table) -> dict[str, dict[str, GroupSummary]]:
    return {method: {g: summary(g, *numbers) for g, numbers in by_group.items()} for method, by_group in table.items()}


def changed(method: str, group: str, index: int, value: float) -> dict:
    """REPRODUCING with one number changed (index 0 success, 1 travel time, 2 collision ratio)."""
    table = {m: dict(by_group) for m, by_group in REPRODUCING.items()}
    numbers = list(table[method][group])
    numbers[index] = value
    table[method][group] = tuple(numbers)
    return table


def verdicts(checks) -> dict[str, str]:
    return {check.claim: check.verdict for check in checks}


# --- names -----------------------------------------------------------------------------


def test_methods_take_the_papers_names_and_order():
    assert [method_name(m) for m in PAPER_METHODS] == ["TERL", "IQN", "DQN", "MEAN", "w/o RE", "w/o TS"]
    assert method_name("linear-test") == "linear-test"
    methods = ("linear-test", "w/o TS", "IQN", "other-test", "TERL")
    assert sorted(methods, key=paper_order) == ["TERL", "IQN", "w/o TS", "linear-test", "other-test"]


def test_two_policies_of_one_method_are_refused_naming_both():
    check_methods([("TERL", "a.onnx"), ("IQN", "b.onnx")])
    with pytest.raises(ComparisonError, match=r"a\.onnx and c\.onnx are both method 'TERL'"):
        check_methods([("TERL", "a.onnx"), ("IQN", "b.onnx"), ("TERL", "c.onnx")])


# --- claims ----------------------------------------------------------------------------


def test_numbers_that_reproduce_every_claim_reproduce_every_claim():
    checks = claim_checks(groups_of(REPRODUCING))
    assert len(checks) == len(CLAIMS) == 11
    assert all(check.verdict == REPRODUCES for check in checks), [c for c in checks if c.verdict != REPRODUCES]
    # Intervals of +-0.01 and +-0.5 s lie apart everywhere here.
    assert all(check.clear for check in checks)


@pytest.mark.parametrize(("method", "group", "index", "value", "claim"), [
    # MEAN succeeds in 95 % at small scale: not *over* 95 %.
    ("MEAN", "small", 0, 0.95, "At small scale every method succeeds in over 95 % of episodes"),
    ("IQN", SMALL_RELEASED, 0, 0.90, "At small scale every method succeeds in over 95 % of episodes (released config)"),
    ("TERL", "large", 0, 0.95, "TERL keeps 100 % success at medium and large scale"),
    ("IQN", "large", 0, 1.0, "IQN degrades with scale"),  # 1.0 at large = 1.0 at small: no drop
    ("DQN", "large", 0, 1.0, "DQN degrades with scale"),
    ("MEAN", "medium", 0, 0.8, "MEAN does worst"),  # ties IQN's 0.8: not below it
    ("DQN", "CC", 2, 0.5, "Every baseline fails CC, with about 0.9 of its pursuers collided"),
    ("IQN", "CC", 0, 0.05, "Every baseline fails CC, with about 0.9 of its pursuers collided"),
    ("w/o RE", "CC", 0, 0.80, "Removing relation extraction costs success on CC"),  # = TERL's 0.80
    ("w/o TS", "CC", 0, 0.90, "Removing target selection costs success on CC"),
    ("w/o RE", "small", 1, 40.0, "Removing relation extraction costs travel time at every scale"),  # 40 < 46 s
    ("w/o TS", "medium", 1, 60.0, "Removing target selection costs travel time at every scale"),  # 60 < 64 s
])
def test_one_number_across_its_criterion_fails_that_claim_alone(method, group, index, value, claim):
    outcome = verdicts(claim_checks(groups_of(changed(method, group, index, value))))
    assert outcome.pop(claim) == DOES_NOT_REPRODUCE
    assert set(outcome.values()) == {REPRODUCES}


def test_a_missing_method_leaves_its_claims_not_measured_and_names_it():
    groups = groups_of({m: g for m, g in REPRODUCING.items() if m != "DQN"})
    checks = {check.claim: check for check in claim_checks(groups)}
    for claim in ("At small scale every method succeeds in over 95 % of episodes", "DQN degrades with scale",
                  "MEAN does worst", "Every baseline fails CC, with about 0.9 of its pursuers collided"):
        assert checks[claim].verdict == NOT_MEASURED
        assert "DQN" in checks[claim].measured and checks[claim].clear is None
    assert checks["IQN degrades with scale"].verdict == REPRODUCES
    assert checks["Removing target selection costs success on CC"].verdict == REPRODUCES


def test_a_missing_group_leaves_its_claims_not_measured():
    groups = groups_of({m: {g: n for g, n in by_group.items() if g != "CC"} for m, by_group in REPRODUCING.items()})
    checks = verdicts(claim_checks(groups))
    assert checks["Removing relation extraction costs success on CC"] == NOT_MEASURED
    assert checks["Removing relation extraction costs travel time at every scale"] == NOT_MEASURED
    assert checks["TERL keeps 100 % success at medium and large scale"] == REPRODUCES


def test_measured_figures_are_shown_with_their_intervals():
    (check,) = [c for c in claim_checks(groups_of(REPRODUCING)) if c.claim == "IQN degrades with scale"]
    assert check.criterion == "IQN's success rate at large scale < at small scale"
    assert check.measured == "IQN large success 0.60 [0.59, 0.61]; IQN small success 1.00 [1.00, 1.00]"


def test_a_verdict_within_the_intervals_is_not_clear():
    groups = groups_of(REPRODUCING)
    # IQN large 0.95 [0.85, 1.00] against small 1.00: below on the means, not between the intervals.
    groups["IQN"]["large"] = replace(groups["IQN"]["large"], success_rate=0.95,
                                     ci95={**groups["IQN"]["large"].ci95, "success_rate": (0.85, 1.0)})
    # MEAN at small 0.93 [0.90, 0.96]: under 0.95 on the mean, but its interval reaches over it.
    groups["MEAN"]["small"] = replace(groups["MEAN"]["small"], success_rate=0.93,
                                      ci95={**groups["MEAN"]["small"].ci95, "success_rate": (0.90, 0.96)})
    # DQN at small 0.90 [0.85, 0.94]: under 0.95 and its whole interval too.
    checks = {check.claim: check for check in claim_checks(groups)}
    iqn = checks["IQN degrades with scale"]
    assert (iqn.verdict, iqn.clear) == (REPRODUCES, False)
    small = checks["At small scale every method succeeds in over 95 % of episodes"]
    assert (small.verdict, small.clear) == (DOES_NOT_REPRODUCE, False)
    groups["DQN"]["small"] = replace(groups["DQN"]["small"], success_rate=0.90,
                                     ci95={**groups["DQN"]["small"].ci95, "success_rate": (0.85, 0.94)})
    (small,) = [c for c in claim_checks(groups) if c.claim == small.claim]
    assert (small.verdict, small.clear) == (DOES_NOT_REPRODUCE, True)  # one clear failure settles it


def test_unknown_intervals_leave_clear_unknown():
    groups = groups_of(REPRODUCING)
    groups["IQN"]["large"] = replace(groups["IQN"]["large"], ci95=dict.fromkeys(groups["IQN"]["large"].ci95,
                                                                                  (math.nan, math.nan)))
    (check,) = [c for c in claim_checks(groups) if c.claim == "IQN degrades with scale"]
    assert (check.verdict, check.clear) == (REPRODUCES, None)


def test_each_claim_is_also_checked_on_the_papers_own_tables():
    paper = {check.claim: check.in_paper for check in claim_checks(groups_of(REPRODUCING))}
    assert paper["TERL keeps 100 % success at medium and large scale"] == "holds"
    assert paper["Every baseline fails CC, with about 0.9 of its pursuers collided"] == "holds"  # 0.93, 0.90, 0.92
    assert paper["Removing target selection costs travel time at every scale"] == "holds"
    # The paper's ablation has w/o RE faster than TERL at small scale (36.39 s < 45.98 s).
    assert paper["Removing relation extraction costs travel time at every scale"] == "does not hold"
    # IQN, DQN and MEAN below CC are in Fig. 3 only.
    assert paper["IQN degrades with scale"] == "not in its tables"


# --- tables and files ------------------------------------------------------------------


def made_runs(methods=tuple(PAPER_METHODS)) -> list[MethodRun]:
    """One run a model on every report preset, made numbers different for each method."""
    runs = []
    for i, model in enumerate(methods):
        results = tuple(made_result(name, successes=20 - i, travel_s=40.0 + 10 * k + i, collided=i)
                        for k, name in enumerate(REPORT_SUITE))
        info = {"name": model, "sha256": f"{i}" * 64, "path": f"exported/{model}.onnx",
                "metadata": {"terl.model": model, "terl.training_steps": "200000"}}
        runs.append(MethodRun(method_name(model), info, results))
    return runs


def test_table_iii_sets_every_method_on_cc_beside_the_papers_row():
    rows = table_iii(made_runs())
    assert [row.method for row in rows] == ["TERL", "IQN", "DQN", "MEAN", "w/o RE", "w/o TS"]
    assert {row.measured.presets for row in rows} == {("cc-28",)}
    paper = {row.method: (row.paper.success_rate, row.paper.travel_time_s) for row in rows}
    assert paper["TERL"] == (0.80, 226.78) and paper["IQN"] == (0.00, 150.50)
    assert paper["w/o RE"] == (0.05, 100.42)  # from the ablation table, the only one with it on CC


def test_table_iv_sets_the_ablations_per_group_beside_the_papers_ablation():
    rows = table_iv(made_runs())
    assert [(row.measured.group, row.method) for row in rows[:6]] == [
        ("small", "TERL"), ("small", "w/o RE"), ("small", "w/o TS"),
        (SMALL_RELEASED, "TERL"), (SMALL_RELEASED, "w/o RE"), (SMALL_RELEASED, "w/o TS"),
    ]
    assert len(rows) == 15
    paper = {(row.measured.group, row.method): row.paper.travel_time_s for row in rows}
    assert paper[(SMALL_RELEASED, "w/o RE")] == paper[("small", "w/o RE")] == 36.39
    assert paper[("CC", "TERL")] == 194.05  # the ablation's CC row, not the comparison's


def test_comparison_writes_markdown_figure_and_json(tmp_path):
    pytest.importorskip("matplotlib")
    paths = write_comparison(made_runs()[::-1], tmp_path / "docs", "terl-rt report --policy exported", date=DATE)
    assert [p.name for p in paths] == ["comparison.md", "comparison.png", "comparison.json"]
    text = paths.markdown.read_text()
    assert text.startswith("# TERL, IQN, DQN, MEAN, w/o RE and w/o TS against the paper's comparison")
    for heading in ("## Claims", "## Table III: CC (cc-28)", "## Table IV: ablation per scale group",
                    "## Every method per scale group"):
        assert heading in text
    # Table III: measured with its interval, then the paper's CC row.
    (iqn,) = [line for line in text.split("## Table III")[1].splitlines() if line.startswith("| IQN | ")]
    assert iqn.startswith("| IQN | 0.95 [0.75, 1.00] | 161.0 [")  # 19 of 20: exact interval and iqn.endswith("| 0.00 | 150.50 | 0.93 |")
    assert f"| {SMALL_RELEASED} | w/o TS | " in text
    assert text.count("**reproduces**") + text.count("**does not reproduce**") == 11
    with Image.open(paths.figure) as image:
        assert image.format == "PNG" and image.size[0] >= 900 and image.size[0] >= 2.5 * image.size[1]
    data = json.loads(paths.json.read_text())
    assert [m["method"] for m in data["methods"]] == ["TERL", "IQN", "DQN", "MEAN", "w/o RE", "w/o TS"]
    assert [s["name"] for s in data["methods"][0]["scenarios"]] == list(REPORT_SUITE)
    assert len(data["methods"][0]["scenarios"][0]["per_episode"]) == 20
    assert data["table_iii"][1]["paper"] == {"success_rate": 0.0, "travel_time_s": 150.5, "collision_ratio": 0.93}
    assert set(data["table_iv"][0]["ci95"]) == set(CI_METRICS)
    assert len(data["claims"]) == 11 and set(data["claims"][0]) == {
        "claim", "criterion", "measured", "verdict", "clear", "in_paper"}


def test_markdown_without_cc_or_ablations_says_so():
    runs = [MethodRun(r.method, r.policy, tuple(x for x in r.results if x.name == "small-11"))
            for r in made_runs(("iqn", "dqn"))]
    text = render_comparison_markdown(runs, "terl-rt report", DATE)
    assert "cc-28 was not evaluated." in text and "Neither TERL nor an ablation was evaluated." in text
    assert "**not measured**" in text


def test_comparison_needs_two_distinct_methods(tmp_path):
    (terl,) = made_runs(("terl",))
    with pytest.raises(ValueError, match="at least two"):
        write_comparison([terl], tmp_path, "terl-rt report")
    with pytest.raises(ComparisonError, match="both method 'TERL'"):
        write_comparison([terl, terl], tmp_path, "terl-rt report")
    assert not list(tmp_path.iterdir())


# --- CLI -------------------------------------------------------------------------------


def invoke(*args):
    return CliRunner().invoke(cli, [str(arg) for arg in args])


@pytest.fixture(scope="module")
def policies(tmp_path_factory):
    """A folder of three tiny policies standing for TERL, IQN and w/o RE."""
    folder = tmp_path_factory.mktemp("policies")
    for seed, model in enumerate(("terl", "iqn", "terl-no-re")):
        write_test_policy(folder / f"{model}.onnx", seed=seed, model=model)
    return folder


TINY = ("--scenario", "small-published-7", "--scenario", "cc-28", "--episodes", "2", "--max-steps", "2")


def test_report_with_several_policies_writes_the_comparison(policies, tmp_path):
    pytest.importorskip("matplotlib")
    out = tmp_path / "docs"
    result = invoke("report", "--policy", policies / "iqn.onnx", "--policy", policies / "terl.onnx", *TINY,
                    "--out", out)
    assert result.exit_code == 0, result.output
    assert "IQN: " in result.stderr  # each method (its progress bars only on a terminal)
    assert f"wrote {out / 'comparison.md'}, {out / 'comparison.png'} and {out / 'comparison.json'}" in result.stdout
    assert "not measured" in next(line for line in result.stdout.splitlines() if "IQN degrades" in line)
    assert sorted(p.name for p in out.iterdir()) == ["comparison.json", "comparison.md", "comparison.png"]
    text = (out / "comparison.md").read_text()
    assert text.startswith("# TERL and IQN against the paper's comparison")
    assert "| TERL | terl | " in text and "| IQN | iqn | " in text
    assert f"--policy {policies / 'iqn.onnx'} --policy {policies / 'terl.onnx'} --scenario small-published-7" in text
    table_iii_text = text.split("## Table III")[1].split("##")[0]
    assert [line.split(" | ")[0] for line in table_iii_text.splitlines() if line.startswith("| ") and "---" not in line] \
        == ["| method", "| TERL", "| IQN"]
    assert f"| {SMALL_RELEASED} | TERL | " in text
    assert "indicative only" in text


def test_report_of_a_folder_compares_every_policy_in_it_with_json(policies, tmp_path):
    pytest.importorskip("matplotlib")
    result = invoke("report", "--policy", policies, *TINY, "--out", tmp_path, "--json")
    assert result.exit_code == 0, result.output
    out = json.loads(result.stdout)
    assert [m["method"] for m in out["methods"]] == ["TERL", "IQN", "w/o RE"]  # the paper's order
    assert out["files"]["json"] == str(tmp_path / "comparison.json")
    assert json.loads((tmp_path / "comparison.json").read_text())["claims"] == out["claims"]


def test_report_with_one_policy_writes_only_results(policies, tmp_path):
    pytest.importorskip("matplotlib")
    result = invoke("report", "--policy", policies / "iqn.onnx", "--scenario", "small-published-7",
                    "--episodes", "1", "--max-steps", "2", "--out", tmp_path)
    assert result.exit_code == 0, result.output
    assert sorted(p.name for p in tmp_path.iterdir()) == ["results.md", "results.png"]


def test_a_folder_without_onnx_files_is_one_error_line(tmp_path):
    (tmp_path / "notes.txt").write_text("no policies here")
    result = invoke("report", "--policy", tmp_path, "--out", tmp_path / "docs")
    assert result.exit_code == 2
    assert result.stderr == f"Error: --policy {tmp_path} is a folder without .onnx files\n"


def test_two_policies_of_one_method_are_one_error_line(policies, tmp_path):
    other = write_test_policy(tmp_path / "other-terl.onnx", seed=5, model="terl")
    result = invoke("report", "--policy", policies / "terl.onnx", "--policy", other, *TINY, "--out", tmp_path / "docs")
    assert result.exit_code == 2
    assert result.stderr.startswith("Error: --policy: ") and result.stderr.count("\n") == 1
    assert f"{policies / 'terl.onnx'} and {other} are both method 'TERL'" in result.stderr
    assert not (tmp_path / "docs").exists() or not list((tmp_path / "docs").iterdir())


def test_a_policy_that_breaks_the_contract_is_one_error_line_naming_it(policies, tmp_path):
    broken = write_broken_policy(tmp_path / "broken.onnx", "eight_actions")
    result = invoke("report", "--policy", policies / "terl.onnx", "--policy", broken, *TINY, "--out", tmp_path / "docs")
    assert result.exit_code == 2
    assert result.stderr.startswith("Error: ") and result.stderr.count("\n") == 1
    assert str(broken) in result.stderr
    assert "small-published-7" not in result.stderr  # refused before any evaluation


def test_an_existing_comparison_is_refused_before_evaluating_and_replaced_with_force(policies, tmp_path):
    pytest.importorskip("matplotlib")
    (tmp_path / "comparison.md").write_text("an earlier comparison")
    args = ("report", "--policy", policies / "terl.onnx", "--policy", policies / "iqn.onnx", "--scenario",
            "small-published-7", "--episodes", "1", "--max-steps", "2", "--out", tmp_path)
    refused = invoke(*args)
    assert refused.exit_code == 2
    assert refused.stderr == f"Error: --out {tmp_path / 'comparison.md'} exists; pass --force to replace it\n"
    assert (tmp_path / "comparison.md").read_text() == "an earlier comparison"
    replaced = invoke(*args, "--force")
    assert replaced.exit_code == 0, replaced.output
    assert (tmp_path / "comparison.md").read_text().startswith("# TERL and IQN")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["comparison.json", "comparison.md", "comparison.png"]


def test_a_progress_folder_that_is_a_file_is_one_error_line_before_any_evaluation(policies, tmp_path):
    pytest.importorskip("matplotlib")
    (tmp_path / ".report-progress").write_text("not a folder")
    result = invoke("report", "--policy", policies, *TINY, "--out", tmp_path)
    assert result.exit_code == 2, result.output
    assert result.stderr == (f"Error: --out {tmp_path}: {tmp_path / '.report-progress'} is not a folder, and the "
                             "comparison keeps its evaluations there as they finish; move it away\n")
