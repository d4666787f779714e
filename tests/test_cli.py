"""The terl-rt command line, driven through click's CliRunner."""

from __future__ import annotations

import json
from pathlib import Path

import click
import pytest
from click.testing import CliRunner
from onnx_models import write_broken_policy, write_random_bytes, write_test_policy
from PIL import Image
from one_line import assert_one_error
from tiny_worlds import capture_scenario

import terl_rt.cli.eval
import terl_rt.policy.shipped
from terl_rt.cli.main import cli
from terl_rt.evaluation.episodes import RESULTS_SCHEMA

ROW_KEYS = {
    "name", "episodes", "seed", "max_steps", "success_rate", "travel_time_s_mean", "travel_time_s_std",
    "collision_ratio_mean", "steps_mean", "ci95", "wall_s", "per_episode", "travel_time_s_success_mean",
    "travel_time_s_limit_mean", "limit_s", "evader", "collisions_touched",
}


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("cli")
    scenario_file = folder / "capture.json"
    capture_scenario(max_steps=6).to_file(scenario_file)
    return {
        "folder": folder,
        "policy": write_test_policy(folder / "linear.onnx"),
        "scenario": scenario_file,
    }


@pytest.fixture(scope="module")
def log(files) -> Path:
    """An MCAP log of two episodes of the capture scenario, written by `terl-rt eval --log`."""
    path = files["folder"] / "eval.mcap"
    result = invoke("eval", "--policy", files["policy"], "--scenario-file", files["scenario"],
                    "--episodes", "2", "--log", path)
    assert result.exit_code == 0, result.output
    return path


def invoke(*args):
    return CliRunner().invoke(cli, [str(arg) for arg in args])


def test_eval_prints_a_table_per_scenario(files):
    result = invoke("eval", "--policy", files["policy"], "--scenario", "small-11", "--scenario", "small-15",
                    "--episodes", "2", "--max-steps", "5")
    assert result.exit_code == 0, result.output
    lines = result.stdout.splitlines()
    assert "travel, successes (s)" in lines[1] and "success" in lines[1]  # failures at the limit: --json, --csv
    assert lines[2].split()[:2] == ["small-11", "2"] and lines[3].split()[:2] == ["small-15", "2"]


def test_eval_json_is_one_object_with_the_documented_keys(files):
    result = invoke("eval", "--policy", files["policy"], "--scenario", "small-11", "--episodes", "2",
                    "--max-steps", "4", "--json")
    assert result.exit_code == 0, result.output
    out = json.loads(result.stdout)  # the whole of stdout is one object
    assert set(out) == {"terl_rt", "schema", "policy", "acting", "seed", "scenarios"}
    assert out["schema"] == RESULTS_SCHEMA
    assert out["policy"]["name"] == "linear-test"
    (row,) = out["scenarios"]
    assert set(row) == ROW_KEYS
    assert (row["name"], row["episodes"], row["steps_mean"]) == ("small-11", 2, 4.0)


def test_eval_json_sends_what_the_run_prints_to_stderr(files, monkeypatch):
    # Ray prints a dying worker's `(raylet)` report to the driver's stdout while the episodes run
    # (the real thing, a Ray worker killed under --json, is tests/test_ray_backend.py's, marked slow).
    def printing_run(*args, **kwargs):
        print("(raylet) A worker died or was killed while executing a task.")
        return evaluate(*args, **kwargs)

    evaluate = terl_rt.cli.eval.evaluate_with_progress
    monkeypatch.setattr(terl_rt.cli.eval, "evaluate_with_progress", printing_run)
    result = invoke("eval", "--policy", files["policy"], "--scenario", "small-11", "--episodes", "1",
                    "--max-steps", "2", "--json")
    assert result.exit_code == 0, result.output
    assert json.loads(result.stdout)["scenarios"][0]["episodes"] == 1  # stdout holds the JSON alone
    assert "(raylet) A worker died" in result.stderr


def test_eval_reads_a_scenario_file_and_shows_no_progress_off_a_terminal(files):
    result = invoke("eval", "--policy", files["policy"], "--scenario-file", files["scenario"],
                    "--episodes", "1", "--json")
    assert result.exit_code == 0, result.output
    assert json.loads(result.stdout)["scenarios"][0]["name"] == "tiny-capture"
    assert "tiny-capture" not in result.stderr  # the runner's stderr is no terminal: no bar, no stray label


def test_eval_with_two_workers_matches_one(files):
    common = ("eval", "--policy", files["policy"], "--scenario", "small-11", "--episodes", "2",
              "--max-steps", "6", "--json")
    one = json.loads(invoke(*common).stdout)["scenarios"][0]
    two = json.loads(invoke(*common, "--workers", "2").stdout)["scenarios"][0]
    for key in ROW_KEYS - {"wall_s"}:
        assert one[key] == two[key], key


def test_eval_evader_option_runs_that_evader_and_names_it(files):
    common = ("eval", "--policy", files["policy"], "--scenario", "small-11", "--episodes", "1", "--max-steps", "3")
    table = invoke(*common, "--evader", "still")
    assert table.exit_code == 0, table.output
    assert table.stdout.splitlines()[2].split()[:2] == ["small-11/still", "1"]
    (row,) = json.loads(invoke(*common, "--evader", "still", "--json").stdout)["scenarios"]
    assert (row["name"], row["evader"]) == ("small-11", "still")
    (default,) = json.loads(invoke(*common, "--json").stdout)["scenarios"]
    assert default["evader"] == "apf"


def test_eval_evader_option_overrides_a_scenario_files_evader(files, tmp_path):
    path = tmp_path / "gap.json"
    path.write_text(json.dumps({**capture_scenario(max_steps=2).to_dict(), "evader": "widest-gap"}))
    common = ("eval", "--policy", files["policy"], "--scenario-file", path, "--episodes", "1", "--json")
    assert json.loads(invoke(*common).stdout)["scenarios"][0]["evader"] == "widest-gap"
    assert json.loads(invoke(*common, "--evader", "apf").stdout)["scenarios"][0]["evader"] == "apf"


@pytest.mark.parametrize("command", ["eval", "report", "sweep"])
def test_an_unknown_evader_is_one_error_line_naming_the_known_ones(command):
    assert_one_error(invoke(command, "--evader", "fast"), "--evader", "unknown evader 'fast'", "apf, still, widest-gap")


def test_eval_without_the_default_policy_says_to_pass_one(monkeypatch, tmp_path):
    monkeypatch.setattr(terl_rt.policy.shipped, "DEFAULT_POLICY", Path("exported") / "absent-policy.onnx")
    monkeypatch.setattr(terl_rt.policy.shipped, "PACKAGED_POLICY", ("terl_rt.policy", "default/absent-policy.onnx"))
    monkeypatch.chdir(tmp_path)
    result = invoke("eval", "--episodes", "1")
    assert result.exit_code == 2
    assert result.stderr.strip() == "Error: no policy at exported/absent-policy.onnx yet; pass --policy"


def test_info_prints_metadata_and_the_contract_report(files):
    result = invoke("info", files["policy"])
    assert result.exit_code == 0, result.output
    assert "terl.model = linear-test" in result.stdout
    assert "[pass] input 'ego': float32 [B, 4]" in result.stdout
    assert "[fail]" not in result.stdout


def test_info_says_whether_the_contract_holds_on_its_first_line(files):
    first = invoke("info", files["policy"]).stdout.splitlines()[0]
    assert first.endswith("meets the contract (46 of 46 checks pass)"), first
    broken = invoke("info", write_broken_policy(files["folder"] / "eight-first.onnx", "eight_actions"))
    assert "refused by the contract: output 'q_values'" in broken.stdout.splitlines()[0]


def test_info_json(files):
    out = json.loads(invoke("info", files["policy"], "--json").stdout)
    assert out["ok"] and out["metadata"]["terl.model"] == "linear-test" and len(out["sha256"]) == 64
    assert {check["status"] for check in out["checks"]} == {"pass"}


def test_info_on_a_contract_breaking_policy_shows_the_report_and_exits_2(files):
    path = write_broken_policy(files["folder"] / "eight.onnx", "eight_actions")
    result = invoke("info", path)
    assert result.exit_code == 2
    assert "[fail] output 'q_values' sizes" in result.stdout
    assert result.stderr.count("\n") == 1 and result.stderr.startswith("Error:")


def test_replay_lists_the_episodes(log):
    result = invoke("replay", log)
    assert result.exit_code == 0, result.output
    rows = [line.split() for line in result.stdout.splitlines()[2:]]
    assert [row[:4] for row in rows] == [["0", "tiny-capture", "0", "6"], ["1", "tiny-capture", "1", "6"]]


def test_replay_list_header_names_every_column_of_its_rows(log):
    header, *rows = invoke("replay", log).stdout.splitlines()[1:]
    columns = ["#", "scenario", "seed", "steps", "outcome", "travel (s)", "encircled", "collision ratio", "return"]
    assert [name for name in columns if name in header] == columns
    assert {len(row.split()) for row in rows} == {len(columns)}


def test_replay_episode_shows_its_events(log):
    result = invoke("replay", log, "--episode", "1")
    assert result.exit_code == 0, result.output
    assert "capture      evader 0, pursuers [0, 1, 2]" in result.stdout
    assert "collision    pursuer 3" in result.stdout


def test_replay_verify_passes_on_a_real_log(log):
    result = invoke("replay", log, "--verify")
    assert result.exit_code == 0, result.output
    assert result.stdout.count("bit-identical") == 2


def test_replay_verify_of_a_log_of_another_world_version_is_one_error_line():
    old = Path(__file__).parent / "data" / "world-v1.mcap"
    result = invoke("replay", old, "--verify")
    assert result.exit_code == 2
    assert result.stderr.count("\n") == 1 and result.stderr.startswith("Error: ")
    assert "world version 1; this terl-rt simulates world version 2" in result.stderr


def test_replay_verify_json(log):
    out = json.loads(invoke("replay", log, "--verify", "--episode", "0", "--json").stdout)
    assert out["ok"] and out["episodes"][0]["steps_checked"] == 6


def test_render_writes_png_and_gif(log, tmp_path):
    for name in ("final.png", "episode.gif"):
        result = invoke("render", log, "--episode", "1", "-o", tmp_path / name, "--every", "2")
        assert result.exit_code == 0, result.output
        with Image.open(tmp_path / name) as image:
            assert image.format == name.split(".")[1].upper()
    with Image.open(tmp_path / "episode.gif") as image:
        assert image.n_frames == 4  # steps 0, 2, 4, 6


def test_bench_policy_reports_latency_per_batch_size(files):
    result = invoke("bench", "policy", "--policy", files["policy"], "--scenario", "small-11",
                    "--batch", "1", "--batch", "30", "--calls", "3", "--json")
    assert result.exit_code == 0, result.output
    rows = json.loads(result.stdout)["rows"]
    assert [row["batch"] for row in rows] == [1, 30]
    assert all(0 < row["ms_p50"] <= row["ms_p99"] and row["calls"] == 3 for row in rows)
    assert rows[1]["us_per_pursuer"] == pytest.approx(1e3 * rows[1]["ms_p50"] / 30)
    assert rows[0]["mflop_per_row"] > 0 and rows[0]["matmul_share"] > 0


def test_bench_policy_table(files):
    result = invoke("bench", "policy", "--policy", files["policy"], "--scenario", "small-11", "--calls", "2")
    assert result.exit_code == 0, result.output
    assert "p99 (ms)" in result.stdout and "of matmul" in result.stdout


def test_bench_policies_times_files_side_by_side_and_says_which_give_the_first_ones_outputs(files):
    other = write_test_policy(files["folder"] / "other.onnx", seed=1)
    result = invoke("bench", "policies", files["policy"], files["policy"], other, "--scenario", "small-11",
                    "--rounds", "1", "--threads", "1", "--json")
    assert result.exit_code == 0, result.output
    (row,) = json.loads(result.stdout)["scenarios"]
    assert row["scenario"] == "small-11" and row["rows"] > 0 and 0 < row["valid_tokens"] <= 1
    assert row["same_outputs"] == [True, True, False] and row["speedups"][0] == 1.0
    assert all(us > 0 for us in row["us_per_row"])
    lonely = invoke("bench", "policies", files["policy"])
    assert lonely.exit_code == 2 and "at least two policy files" in lonely.output


def test_bench_eval_times_batch_sizes_side_by_side_with_the_same_episodes(files):
    result = invoke("bench", "eval", "--policy", files["policy"], "--scenario", "small-11", "--episodes", "3",
                    "--max-steps", "4", "--workers", "1", "--envs", "1", "--envs", "3", "--json")
    assert result.exit_code == 0, result.output
    out = json.loads(result.stdout)
    assert [row["envs"] for row in out["rows"]] == [1, 3] and out["identical"]
    assert all(row["episodes"] == 3 and row["run_s"] > 0 for row in out["rows"])


def _bad_inputs(files, log) -> dict[str, tuple]:
    folder = files["folder"]
    bad_json = folder / "bad.json"
    bad_json.write_text("{ not json")
    unknown_field = folder / "unknown.json"
    unknown_field.write_text(json.dumps({"name": "x", "pursuers": 5, "speed": 3}))
    truncated = folder / "truncated.mcap"
    truncated.write_bytes(log.read_bytes()[:20])
    corrupt = folder / "corrupt.mcap"
    data = bytearray(log.read_bytes())
    data[8] = 0x7F  # the header record's opcode
    corrupt.write_bytes(bytes(data))
    policy = files["policy"]
    return {
        "missing policy": (("eval", "--policy", folder / "absent.onnx"), "no policy file"),
        "malformed policy": (("eval", "--policy", write_random_bytes(folder / "noise.onnx")), "not a readable ONNX model"),
        "contract-breaking policy": (
            ("eval", "--policy", write_broken_policy(folder / "v2.onnx", "wrong_contract_version")),
            "terl.contract",
        ),
        "unknown scenario": (("eval", "--policy", policy, "--scenario", "huge-9000"), "unknown scenario 'huge-9000'"),
        "two scenario sources": (("eval", "--policy", policy, "--scenario", "small-11", "--suite", "paper"), "only one of"),
        "scenario file not JSON": (("eval", "--policy", policy, "--scenario-file", bad_json), "not valid JSON"),
        "scenario file unknown field": (("eval", "--policy", policy, "--scenario-file", unknown_field), "speed: unknown field"),
        "missing scenario file": (("eval", "--policy", policy, "--scenario-file", folder / "none.json"), "no such scenario file"),
        "log under a file": (("eval", "--policy", policy, "--episodes", "1", "--log", policy / "x.mcap"), "cannot make its folder"),
        "info on noise": (("info", folder / "noise.onnx"), "not a readable ONNX model"),
        "bench unknown scenario": (("bench", "policy", "--policy", policy, "--scenario", "nope"), "unknown scenario 'nope'"),
        "missing log": (("replay", folder / "absent.mcap"), "no episode log"),
        "truncated log": (("replay", truncated), "cut off"),
        "corrupt log": (("replay", corrupt), "corrupt"),
        "log that is a policy": (("replay", policy), "not an MCAP file"),
        "absent episode": (("replay", log, "--episode", "5"), "no episode 5"),
        "render absent episode": (("render", log, "--episode", "5", "-o", folder / "x.png"), "no episode 5"),
        "render unknown format": (("render", log, "-o", folder / "x.bmp"), "unknown output format"),
    }


BAD_INPUTS = [
    "missing policy", "malformed policy", "contract-breaking policy", "unknown scenario",
    "two scenario sources", "scenario file not JSON", "scenario file unknown field", "missing scenario file",
    "log under a file", "info on noise", "bench unknown scenario", "missing log", "truncated log",
    "corrupt log", "log that is a policy", "absent episode", "render absent episode", "render unknown format",
]


@pytest.mark.parametrize("case", BAD_INPUTS)
def test_bad_input_exits_2_with_one_line(files, log, case):
    args, message = _bad_inputs(files, log)[case]
    result = invoke(*args)
    assert result.exit_code == 2, result.output
    assert result.stderr.startswith("Error: ") and result.stderr.count("\n") == 1, result.stderr
    assert message in result.stderr
    assert "Traceback" not in result.output


def test_debug_shows_the_exception(files):
    result = CliRunner().invoke(cli, ["--debug", "eval", "--policy", str(files["folder"] / "absent.onnx")])
    assert isinstance(result.exception, FileNotFoundError)


def _commands(group, path=("terl-rt",)):
    for name, command in group.commands.items():
        yield (*path, name), command
        if isinstance(command, click.Group):
            yield from _commands(command, (*path, name))


@pytest.mark.parametrize("path", [" ".join(path) for path, _ in _commands(cli)])
def test_every_subcommand_s_help_shows_examples_of_itself(path):
    words = path.split()[1:]
    result = invoke(*words, "--help")
    assert result.exit_code == 0, result.output
    examples = result.stdout.split("Examples:")[1]
    assert f"terl-rt {' '.join(words)}" in examples


def test_help_prints_ranges_as_people_write_them():
    text = " ".join(invoke("eval", "--help").stdout.split())
    assert "0 to 2^62" in text and "1 to 10^6" in text
    assert "<=x<=" not in text and "4611686018427387904" not in text


def test_an_unknown_preset_suggests_the_closest_one():
    result = invoke("eval", "--scenario", "small15")
    assert result.exit_code == 2
    assert "unknown scenario 'small15' (did you mean 'small-15'?)" in result.stderr


def test_eval_sweep_and_report_take_one_stack_of_run_options():
    from terl_rt.cli.options import run_options

    stacked = [param.name for param in click.command("probe")(run_options(lambda **_: None)).params]
    assert stacked == [
        "evader", "seed", "max_steps", "workers", "backend", "address", "threads",
        "shield", "shield_margin", "shield_horizon", "risk",
    ]
    for name in ("eval", "sweep", "report"):
        names = [param.name for param in cli.commands[name].params]
        assert names[names.index("evader") :][: len(stacked)] == stacked, name
