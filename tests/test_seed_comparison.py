"""The comparison over training seeds: terl_rt.paper.seed_comparison, its files
(seed_comparison_files), its marl-eval export and `terl-rt report` on policies that carry
terl.method and terl.seed.

The library tests use hand-made results (tests/made_results.py) whose aggregates are
known: every TERL seed succeeds everywhere, one IQN seed always and the other never.
The CLI runs tiny linear policies (tests/onnx_models.py), two short episodes a scenario.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tarfile
from dataclasses import replace
from datetime import datetime, timezone
from pathlib import Path

import pytest
from click.testing import CliRunner
from made_results import made_result
from onnx_models import write_test_policy
from PIL import Image

from terl_rt.cli.main import cli
from terl_rt.evaluation.speed import scaling_scenario
from terl_rt.evaluation.stats import success_interval
from terl_rt.paper.comparison import ComparisonError
from terl_rt.paper.marl_eval import ABSOLUTE, ENVIRONMENT, STEP, marl_eval_dict
from terl_rt.paper.runner import PROGRESS_FOLDER, over_seeds
from terl_rt.paper.seed_comparison import (
    CANNOT_TELL,
    SeedRun,
    beyond_scenarios,
    check_seeds,
    group_of,
    policy_identity,
    seed_statistics,
)
from terl_rt.paper.seed_comparison_files import (
    EXACT_NOTE,
    MARL_EVAL_NAME,
    OUTPUT_NAMES,
    render_seed_markdown,
    seed_comparison_dict,
    write_seed_comparison,
)
from terl_rt.policy.onnx_policy import OnnxPolicy

DATE = datetime(2025, 3, 1, 12, 30, tzinfo=timezone.utc)
PRESETS = ("small-11", "small-15", "large-72", "cc-28")


def made_run(method: str, seed: int, successes: int, travel_s: float = 40.0, collided: int = 0,
             presets=PRESETS, episodes: int = 4) -> SeedRun:
    """One seed's run: `successes` of `episodes` succeed on every preset."""
    results = tuple(made_result(name, successes, travel_s, collided, episodes=episodes) for name in presets)
    policy = {"name": method.lower(), "path": f"{method.lower()}-seed-{seed}.onnx", "sha256": "0" * 64,
              "metadata": {"terl.training_steps": "1000000"}}
    return SeedRun(method, seed, policy, results)


def made_runs() -> list[SeedRun]:
    """TERL: 2 seeds that always succeed in 40 s; IQN: seed 1 always succeeds in 60 s, seed 2 never."""
    return [
        made_run("IQN", 2, successes=0, travel_s=60.0, collided=10),
        made_run("TERL", 1, successes=4), made_run("TERL", 2, successes=4),
        made_run("IQN", 1, successes=4, travel_s=60.0),
    ]


def row(stats, method: str, group: str):
    (found,) = [r for r in stats.aggregates if r.method == method and r.group == group]
    return found


# --- which method and seed -------------------------------------------------------------


def test_method_and_seed_come_from_terl_method_and_terl_seed():
    assert policy_identity({"terl.model": "terl", "terl.method": "terl-no-re", "terl.seed": "3"}) == ("w/o RE", 3)


def test_a_file_without_them_is_its_models_method_with_its_training_configs_seed():
    metadata = {"terl.model": "iqn", "terl.training_config": json.dumps({"seed": 7, "batch_size": 128})}
    assert policy_identity(metadata) == ("IQN", 7)
    nested = {"terl.model": "terl", "terl.training_config": json.dumps({"run": {"seed": 2}, "learner": {}})}
    assert policy_identity(nested) == ("TERL", 2)
    assert policy_identity({"terl.model": "dqn"}) == ("DQN", None)


def test_a_seed_that_is_no_integer_is_refused():
    with pytest.raises(ValueError, match="'terl.seed' is 'one'"):
        policy_identity({"terl.model": "terl", "terl.seed": "one"})


def test_two_policies_of_one_method_and_seed_are_refused_naming_both():
    with pytest.raises(ComparisonError, match="a.onnx and b.onnx are both method 'TERL', seed 1"):
        check_seeds([("TERL", 1, "a.onnx"), ("IQN", 1, "c.onnx"), ("TERL", 1, "b.onnx")])


def test_a_method_with_several_policies_needs_each_ones_seed():
    with pytest.raises(ComparisonError, match="b.onnx has no seed"):
        check_seeds([("TERL", 1, "a.onnx"), ("TERL", None, "b.onnx")])
    check_seeds([("TERL", None, "a.onnx"), ("IQN", None, "b.onnx")])  # one a method: nothing to tell apart


def test_the_worlds_beyond_the_paper_are_bench_scalings():
    worlds = beyond_scenarios()
    assert [w.pursuers for w in worlds] == [160, 240, 400]
    assert [w.evaders for w in worlds] == [40, 60, 100]
    assert worlds[0] == scaling_scenario(160)
    assert [group_of(w.name) for w in worlds] == ["160 pursuers", "240 pursuers", "400 pursuers"]
    assert group_of("large-72") == "large" and group_of("curriculum-1") is None


# --- aggregates ------------------------------------------------------------------------


def test_seeds_that_all_succeed_have_a_mean_of_one_and_the_exact_interval_of_their_episodes():
    terl = row(seed_statistics(made_runs()), "TERL", "small")
    assert (terl.seeds, terl.presets, terl.episodes) == (2, ("small-11", "small-15"), 4)
    assert terl.values["mean"]["success_rate"] == terl.values["iqm"]["success_rate"] == 1.0
    # A bootstrap of 16 successes in 16 can only draw 1.00: the exact interval of 16 in 16 instead.
    assert terl.success_exact
    assert terl.ci95["mean"]["success_rate"] == terl.ci95["iqm"]["success_rate"] == success_interval(16, 16)


def test_one_seed_has_the_exact_interval_of_its_episodes_and_the_markdown_says_so():
    stats = seed_statistics([made_run("TERL", 1, successes=3)])
    terl = row(stats, "TERL", "large")
    assert terl.values["mean"]["success_rate"] == 0.75
    assert terl.success_exact and terl.ci95["mean"]["success_rate"] == success_interval(3, 4)
    markdown = render_seed_markdown([made_run("TERL", 1, successes=3)], stats, "terl-rt report", DATE)
    assert "0.75 [0.19, 0.99] †" in markdown and EXACT_NOTE in markdown


def test_seeds_that_differ_keep_the_stratified_bootstrap_interval():
    assert not row(seed_statistics(made_runs()), "IQN", "large").success_exact


def test_a_seed_that_never_learns_stays_in_the_mean_and_widens_its_interval():
    iqn = row(seed_statistics(made_runs()), "IQN", "large")
    assert iqn.values["mean"]["success_rate"] == 0.5  # (1 + 0) / 2
    low, high = iqn.ci95["mean"]["success_rate"]
    assert low == 0.0 and high == 1.0  # resampling the seeds can draw the failed one twice, or the other
    assert iqn.values["mean"]["collision_ratio"] == pytest.approx(0.25)  # (0 + 10 / 20) / 2
    assert iqn.values["mean"]["travel_time_s_limit"] == pytest.approx((60.0 + 500.0) / 2)  # failures at 1000 x 0.5 s


def test_the_probability_that_terl_does_better_counts_seed_pairs():
    better = {(b.method, b.group): b for b in seed_statistics(made_runs()).improvements}
    # Success: TERL's 1.0 ties IQN seed 1 (0.5) and beats seed 2 (1): (0.5 + 1) / 2. Time: 40 s < 60 s: 1.
    assert better[("IQN", "small")].probability["success_rate"] == pytest.approx(0.75)
    assert better[("IQN", "small")].probability["travel_time_s"] == 1.0
    assert better[("IQN", "small")].probability["collision_ratio"] == pytest.approx(0.75)
    assert set(b.method for b in better.values()) == {"IQN"}


def test_claims_are_judged_on_the_means_and_say_cannot_tell_where_the_intervals_overlap():
    runs = made_runs() + [made_run("w/o RE", 1, successes=0, travel_s=80.0),
                          made_run("w/o RE", 2, successes=0, travel_s=80.0)]
    verdicts = {check.claim: check.verdict for check in seed_statistics(runs).claims}
    assert verdicts["Removing relation extraction costs success on CC"] == "reproduces"  # 0 [0, 0] < 1 [1, 1]
    assert verdicts["TERL keeps 100 % success at medium and large scale"] == "not measured"  # no medium preset
    # IQN's success is 0.5 [0, 1] at small and at large scale: the intervals overlap.
    assert verdicts["IQN degrades with scale"] == CANNOT_TELL


def test_the_markdown_names_every_seed_and_sets_the_aggregates_beside_the_paper():
    runs = made_runs()
    text = render_seed_markdown(runs, seed_statistics(runs), "terl-rt report --policy exported/comparison", DATE)
    assert text.startswith("# TERL and IQN against the paper's comparison, over training seeds")
    assert "- seeds: TERL 2 and IQN 2" in text
    assert "| TERL | 1 | terl | `terl-seed-1.onnx` |" in text and "| IQN | 2 | iqn | `iqn-seed-2.onnx` |" in text
    assert "| CC | IQN | 2 | 0.50 [0.00, 1.00] |" in text and text.count("| 0.00 | 150.50 | 0.93 |") == 1
    assert "| small | IQN | 0.75 [" in text  # P(TERL better) on success


def test_each_seed_is_judged_against_the_papers_goals_as_a_report_judges_one_policy():
    beyond = scaling_scenario(160).name
    runs = [made_run("TERL", 1, successes=4, presets=(*PRESETS, beyond)),
            made_run("IQN", 2, successes=0, travel_s=60.0, collided=10, presets=(*PRESETS, beyond))]
    text = render_seed_markdown(runs, seed_statistics(runs), "terl-rt report", DATE)
    section = text[text.index("## Each seed against the paper's goals"):]
    assert "| method | seed | small | large | CC | 160 pursuers | goals met |" in section
    # TERL seed 1: every episode encircled in 40 s, none collided: all 9 goals of its 3 groups
    assert "| TERL | 1 | 1.00 [0.63, 1.00], 40.0 s, 0.000 | 1.00 [0.40, 1.00], 40.0 s, 0.000 " in section
    assert "| 4/4, 0.000 | 9 of 9 |" in section
    iqn = next(line for line in section.splitlines() if line.startswith("| IQN | 2 |"))
    assert iqn.startswith("| IQN | 2 | 0.00 [0.00, 0.37], ") and iqn.endswith("| 0/4, 0.500 | 0 of 9 |")
    data = seed_comparison_dict(runs, seed_statistics(runs), "terl-rt report", DATE)
    assert [(row["method"], row["seed"], row["goals_met"], row["goals"]) for row in data["seeds"]] == [
        ("TERL", 1, 9, 9), ("IQN", 2, 0, 9)]
    assert data["seeds"][0]["beyond"] == [{"group": "160 pursuers", "successes": 4, "episodes": 4, "collision_ratio": 0.0}]


def test_the_comparison_writes_markdown_figure_json_and_the_marl_eval_export(tmp_path):
    pytest.importorskip("matplotlib")
    paths = write_seed_comparison(made_runs(), tmp_path / "docs", "terl-rt report", date=DATE)
    assert sorted(p.name for p in (tmp_path / "docs").iterdir()) == sorted(OUTPUT_NAMES)
    with Image.open(paths.figure) as image:
        assert image.format == "PNG" and image.size[0] >= 2.5 * image.size[1]
    data = json.loads(paths.json.read_text())
    assert [(r["method"], r["seed"]) for r in data["runs"]] == [("TERL", 1), ("TERL", 2), ("IQN", 1), ("IQN", 2)]
    assert data["statistics"]["resamples"] == 2000
    assert {(a["method"], a["group"]) for a in data["aggregates"]} == {
        (m, g) for m in ("TERL", "IQN") for g in ("small", "large", "CC")}
    assert set(data["aggregates"][0]["ci95"]) == {"mean", "iqm"}
    assert len(data["claims"]) == 11


def test_the_same_episodes_give_the_same_json():
    first, second = (json.dumps(seed_comparison_dict(runs, seed_statistics(runs), "terl-rt report", DATE))
                     for runs in (made_runs(), made_runs()))
    assert first == second


def with_returns(run: SeedRun, team_return: float) -> SeedRun:
    """`run` with every episode's return set to `team_return` (made results have none)."""
    return replace(run, results=tuple(
        replace(r, per_episode=tuple(replace(m, team_return=team_return) for m in r.per_episode)) for r in run.results))


def test_the_marl_eval_export_nests_environment_task_algorithm_run_and_step():
    runs = [with_returns(run, 12.5) for run in made_runs()]
    data = marl_eval_dict([(run.method, str(run.seed), run.policy, run.results) for run in runs])
    assert list(data) == [ENVIRONMENT] == ["terl-rt"]
    assert sorted(data["terl-rt"]) == sorted(PRESETS)
    assert sorted(data["terl-rt"]["cc-28"]) == ["iqn", "terl"]  # the recipe stems
    run = data["terl-rt"]["cc-28"]["iqn"]["2"]
    assert set(run) == {STEP, ABSOLUTE} == {"step_1", "absolute_metrics"}
    assert run["step_1"]["step_count"] == 1_000_000
    metrics = ("success", "travel_time_s", "collision_ratio", "return")
    assert set(run["step_1"]) == {"step_count", *metrics}
    assert run["step_1"]["success"] == [0.0] * 4 and run["step_1"]["collision_ratio"] == [0.5] * 4
    assert run["step_1"]["return"] == [12.5] * 4
    assert run["absolute_metrics"] == {name: run["step_1"][name] for name in metrics}


def test_the_marl_eval_export_leaves_out_returns_an_episode_lacks():
    old = made_result("small-11", episodes=2)  # made episodes have no return, as logs written before it
    data = marl_eval_dict([("TERL", "1", {}, (old,))])
    assert "return" not in data["terl-rt"]["small-11"]["terl"]["1"]["step_1"]
    assert data["terl-rt"]["small-11"]["terl"]["1"]["step_1"]["step_count"] == 0  # no terl.training_steps


# --- CLI -------------------------------------------------------------------------------


def invoke(*args):
    return CliRunner().invoke(cli, [str(arg) for arg in args])


@pytest.fixture(scope="module")
def seeded(tmp_path_factory):
    """A folder as a grid exports it: terl and iqn, seeds 1 and 2, with terl.method and terl.seed."""
    folder = tmp_path_factory.mktemp("comparison")
    for index, (method, seed) in enumerate((("terl", 1), ("terl", 2), ("iqn", 1), ("iqn", 2))):
        write_test_policy(folder / f"{method}-seed-{seed}.onnx", seed=index, model=method,
                          metadata={"terl.method": method, "terl.seed": str(seed)})
    return folder


TINY = ("--scenario", "small-published-7", "--scenario", "cc-28", "--episodes", "2", "--max-steps", "2")


def test_report_of_a_grids_folder_compares_over_seeds(seeded, tmp_path):
    pytest.importorskip("matplotlib")
    result = invoke("report", "--policy", seeded, *TINY, "--out", tmp_path)
    assert result.exit_code == 0, result.output
    assert "[1/4] TERL seed 1: " in result.stderr and "[4/4] IQN seed 2: " in result.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(OUTPUT_NAMES)
    assert result.stdout.strip().endswith(f"and {tmp_path / MARL_EVAL_NAME}")
    text = (tmp_path / "comparison.md").read_text()
    assert "- seeds: TERL 2 and IQN 2" in text and "## Probability that TERL does better" in text
    marl = json.loads((tmp_path / MARL_EVAL_NAME).read_text())
    assert sorted(marl["terl-rt"]["cc-28"]["terl"]) == ["1", "2"]
    assert len(marl["terl-rt"]["cc-28"]["iqn"]["2"]["step_1"]["success"]) == 2


def test_terl_names_the_method_that_stands_for_the_papers_terl(seeded, tmp_path):
    pytest.importorskip("matplotlib")
    authors = write_test_policy(tmp_path / "terl-authors-seed-1.onnx", seed=5, model="terl",
                                metadata={"terl.method": "terl-authors", "terl.seed": "1"})
    assert policy_identity(OnnxPolicy(authors).metadata, terl="terl-authors") == ("TERL", 1)
    assert policy_identity(OnnxPolicy(seeded / "terl-seed-1.onnx").metadata, terl="terl-authors") == ("terl", 1)
    result = invoke("report", "--policy", authors, "--policy", seeded / "terl-seed-1.onnx", "--terl", "terl-authors",
                    "--scenario", "small-published-7", "--episodes", "1", "--max-steps", "2", "--out", tmp_path / "docs")
    assert result.exit_code == 0, result.output
    assert f"[1/2] TERL seed 1: {authors}" in result.stderr and "[2/2] terl seed 1: " in result.stderr
    text = (tmp_path / "docs" / "comparison.md").read_text()
    assert "- seeds: TERL 1 and terl 1" in text and "- TERL: method terl-authors (`--terl`), the one the claims are judged on" in text
    assert "--terl terl-authors" in text
    marl = json.loads((tmp_path / "docs" / MARL_EVAL_NAME).read_text())
    assert sorted(marl["terl-rt"]["small-published-7"]) == ["terl", "terl-authors"]  # by recipe stem, not by role
    missing = invoke("report", "--policy", seeded, "--terl", "terl-authors", *TINY, "--out", tmp_path / "none")
    assert missing.exit_code == 2
    assert missing.stderr == "Error: --terl terl-authors: no policy is of that method (their methods: iqn, terl)\n"


def test_two_files_of_one_method_and_seed_are_one_error_line(seeded, tmp_path):
    twin = write_test_policy(tmp_path / "twin.onnx", seed=9, model="terl", metadata={"terl.method": "terl", "terl.seed": "1"})
    result = invoke("report", "--policy", seeded / "terl-seed-1.onnx", "--policy", twin, *TINY, "--out", tmp_path / "docs")
    assert result.exit_code == 2
    assert result.stderr == (f"Error: --policy: {seeded / 'terl-seed-1.onnx'} and {twin} are both method 'TERL', "
                             "seed 1\n")


def test_beyond_carries_one_policy_on_to_the_larger_worlds(seeded, tmp_path):
    pytest.importorskip("matplotlib")
    result = invoke("report", "--policy", seeded / "terl-seed-1.onnx", "--beyond", "--scenario", "small-published-7",
                    "--episodes", "1", "--max-steps", "1", "--out", tmp_path, "--json")
    assert result.exit_code == 0, result.output
    out = json.loads(result.stdout)
    assert [s["name"] for s in out["runs"][0]["scenarios"]] == ["small-published-7", "scale-160", "scale-240", "scale-400"]
    assert [a["group"] for a in out["aggregates"]] == [
        "small (released config)", "160 pursuers", "240 pursuers", "400 pursuers"]
    assert "--beyond" in out["command"]


def test_a_one_file_method_beside_a_grids_seeds_counts_as_its_training_configs_seed(seeded, tmp_path):
    old = write_test_policy(tmp_path / "terl.onnx", seed=7, model="terl",
                            metadata={"terl.training_config": json.dumps({"seed": 3})})
    policies = [OnnxPolicy(path) for path in (old, seeded / "terl-seed-1.onnx")]
    assert over_seeds(policies)
    assert [policy_identity(p.metadata) for p in policies] == [("TERL", 3), ("TERL", 1)]
    one_each = [OnnxPolicy(write_test_policy(tmp_path / f"{m}.onnx", model=m)) for m in ("terl", "iqn")]
    assert not over_seeds(one_each)  # today's one file a method: the comparison without seeds


def test_a_comparison_cut_off_goes_on_from_the_evaluations_it_finished(seeded, tmp_path, monkeypatch):
    pytest.importorskip("matplotlib")
    from terl_rt.cli import report_comparison

    clean = invoke("report", "--policy", seeded, *TINY, "--out", tmp_path / "clean", "--json")
    assert clean.exit_code == 0, clean.output
    assert not (tmp_path / "clean" / PROGRESS_FOLDER).exists()
    evaluate = report_comparison.evaluate_with_progress
    calls = []

    cut_at = [4]

    def cut_off_at_the_fourth(*args, **kwargs):
        calls.append(args[1][0].name)
        if len(calls) in cut_at:
            raise KeyboardInterrupt
        return evaluate(*args, **kwargs)

    monkeypatch.setattr(report_comparison, "evaluate_with_progress", cut_off_at_the_fourth)
    cut = invoke("report", "--policy", seeded, *TINY, "--out", tmp_path / "cut", "--json")
    assert cut.exit_code != 0 and not (tmp_path / "cut" / MARL_EVAL_NAME).exists()
    assert len(list((tmp_path / "cut" / PROGRESS_FOLDER).glob("*.json"))) == 3
    calls.clear()
    cut_at.clear()
    again = invoke("report", "--policy", seeded, *TINY, "--out", tmp_path / "cut", "--json")
    assert again.exit_code == 0, again.output
    assert len(calls) == 8 - 3 and "3 results of an earlier run in" in again.stderr
    assert json.loads(again.stdout)["aggregates"] == json.loads(clean.stdout)["aggregates"]
    assert not (tmp_path / "cut" / PROGRESS_FOLDER).exists()


def test_keep_progress_leaves_the_evaluations_for_a_later_comparison_with_more_policies(seeded, tmp_path):
    pytest.importorskip("matplotlib")
    first = invoke("report", "--policy", seeded / "terl-seed-1.onnx", "--policy", seeded / "iqn-seed-1.onnx", *TINY,
                   "--out", tmp_path, "--keep-progress")
    assert first.exit_code == 0, first.output
    assert len(list((tmp_path / PROGRESS_FOLDER).glob("*.json"))) == 4  # 2 policies x 2 scenarios
    every = invoke("report", "--policy", seeded, *TINY, "--out", tmp_path, "--force")
    assert every.exit_code == 0, every.output
    assert "4 results of an earlier run in" in every.stderr and "[4/4] IQN seed 2: " in every.stderr
    assert not (tmp_path / PROGRESS_FOLDER).exists()
    alone = invoke("report", "--policy", seeded / "terl-seed-1.onnx", "--out", tmp_path / "one", "--keep-progress")
    assert alone.exit_code == 2
    assert alone.stderr == "Error: --keep-progress: only a comparison (several policies, or --beyond) keeps its evaluations\n"


def test_beyond_episodes_sets_the_episodes_of_the_larger_worlds_alone(seeded, tmp_path):
    pytest.importorskip("matplotlib")
    result = invoke("report", "--policy", seeded / "terl-seed-1.onnx", "--beyond", "--scenario", "small-published-7",
                    "--episodes", "2", "--beyond-episodes", "1", "--max-steps", "1", "--out", tmp_path, "--json")
    assert result.exit_code == 0, result.output
    out = json.loads(result.stdout)
    assert [s["episodes"] for s in out["runs"][0]["scenarios"]] == [2, 1, 1, 1]
    assert "--episodes 2 --beyond-episodes 1" in out["command"]
    alone = invoke("report", "--policy", seeded, "--beyond-episodes", "1", "--out", tmp_path / "x")
    assert alone.exit_code == 2
    assert alone.stderr == "Error: --beyond-episodes: the worlds past the paper's are evaluated only with --beyond\n"


def test_the_device_command_brings_back_its_results_and_pages_and_stops_on_time(seeded, tmp_path):
    # scripts/device-report.sh as a device machine runs it, on one policy with the worlds past the
    # paper: it packs the pages and its four results (small-published-7 and the three worlds);
    # unpacked elsewhere, the same report reads all four back; cut off by its minutes (wherever it
    # is: the worlds would run a million episodes each), it stops in time and exits 0.
    pytest.importorskip("matplotlib")
    root = Path(__file__).parents[1]
    archive_path = tmp_path / "out" / "report.tar.gz"
    archive_path.parent.mkdir()
    options = ["--policy", str(seeded / "terl-seed-1.onnx"), "--scenario", "small-published-7", "--episodes", "1",
               "--max-steps", "1", "--beyond"]

    def device_report(docs: Path, minutes: str, beyond_episodes: str) -> str:
        env = {**os.environ, "OUT": str(archive_path.parent), "REPORT_OUT": str(docs), "WORKERS": "1",
               "PATH": f"{Path(sys.executable).parent}:{os.environ['PATH']}"}
        archive_path.unlink(missing_ok=True)
        done = subprocess.run(["bash", str(root / "scripts" / "device-report.sh"), minutes, *options,
                               "--beyond-episodes", beyond_episodes],
                              cwd=root, env=env, capture_output=True, text=True, timeout=300)
        assert done.returncode == 0, done.stderr
        return done.stderr

    def packed() -> list[str]:
        with tarfile.open(archive_path) as archive:
            return sorted(archive.getnames())

    device_report(tmp_path / "device", "5", "1")
    pages = ["comparison-marl-eval.json", "comparison.json", "comparison.md", "comparison.png"]
    assert [name for name in packed() if not name.startswith(".report-progress")] == pages
    assert len([name for name in packed() if name.startswith(".report-progress/") and name.endswith(".json")]) == 4
    with tarfile.open(archive_path) as archive:
        archive.extractall(tmp_path / "docs", filter="data")
    stderr = device_report(tmp_path / "docs", "5", "1")
    assert "4 results of an earlier run in" in stderr and stderr.count("episodes read back from") == 4
    stderr = device_report(tmp_path / "docs", "0.03", "1000000")  # cut off wherever it is after 1.8 s
    assert "stopped after 0.03 minutes: the same command goes on from" in stderr
