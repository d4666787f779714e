"""No command writes over an existing file unless asked (--force), none over its own inputs (issue 14, item 2)."""

from __future__ import annotations

from pathlib import Path

import pytest
from click.testing import CliRunner
from onnx_models import write_test_policy
from tiny_worlds import capture_scenario

from terl_rt.cli.main import cli
from terl_rt.logs.reader import EpisodeLogReader


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("outputs")
    scenario = folder / "capture.json"
    capture_scenario(max_steps=4).to_file(scenario)
    policy = write_test_policy(folder / "linear.onnx")
    log = folder / "eval.mcap"
    result = invoke("eval", "--policy", policy, "--scenario-file", scenario, "--episodes", "1", "--log", log)
    assert result.exit_code == 0, result.output
    return {"folder": folder, "policy": policy, "scenario": scenario, "log": log}


def invoke(*args):
    return CliRunner().invoke(cli, [str(arg) for arg in args])


def assert_one_error(result, *words):
    assert result.exit_code == 2, result.output
    assert result.stderr.startswith("Error: ") and result.stderr.count("\n") == 1, result.stderr
    for word in words:
        assert word in result.stderr
    assert "Traceback" not in result.output


def _eval(files, log, *extra):
    return invoke("eval", "--policy", files["policy"], "--scenario-file", files["scenario"], "--episodes", "1",
                  "--log", log, *extra)


def test_eval_refuses_an_existing_log_without_force(files, tmp_path):
    log = tmp_path / "old.mcap"
    log.write_bytes(b"keep me")
    assert_one_error(_eval(files, log), "exists", "--force")
    assert log.read_bytes() == b"keep me"


def test_eval_with_force_replaces_an_existing_log(files, tmp_path):
    log = tmp_path / "old.mcap"
    log.write_bytes(b"replace me")
    result = _eval(files, log, "--force")
    assert result.exit_code == 0, result.output
    assert EpisodeLogReader(log).episodes[0].complete
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


@pytest.mark.parametrize("which", ["policy", "scenario"])
@pytest.mark.parametrize("force", [False, True])
def test_eval_never_writes_the_log_over_its_own_inputs(files, which, force):
    before = files[which].read_bytes()
    result = _eval(files, files[which], *(["--force"] if force else []))
    assert_one_error(result, "never written over")
    assert files[which].read_bytes() == before


def test_eval_that_fails_before_its_first_step_leaves_the_old_log(files, tmp_path):
    log = tmp_path / "old.mcap"
    log.write_bytes(b"keep me")
    unplaceable = tmp_path / "crowded.json"
    unplaceable.write_text('{"name": "crowded", "arena": [40, 40], "pursuers": 30, "evaders": 2, "obstacles": 0, '
                           '"vortices": 0, "clear_r": 15, "params": {"placement_tries": 20}}')
    result = invoke("eval", "--policy", files["policy"], "--scenario-file", unplaceable, "--episodes", "1",
                    "--log", log, "--force")
    assert result.exit_code == 2, result.output
    assert log.read_bytes() == b"keep me"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["crowded.json", "old.mcap"]


def test_eval_makes_the_log_folder(files, tmp_path):
    log = tmp_path / "a" / "b" / "x.mcap"
    assert _eval(files, log).exit_code == 0
    assert EpisodeLogReader(log).episodes


@pytest.mark.parametrize("output", ["/dev/null", "."])
def test_outputs_that_are_not_regular_files_are_refused(files, output):
    assert_one_error(_eval(files, output, "--force"), output)


def test_render_refuses_an_existing_image_and_its_own_log(files, tmp_path):
    image = tmp_path / "old.png"
    image.write_bytes(b"keep me")
    assert_one_error(invoke("render", files["log"], "-o", image), "exists", "--force")
    assert image.read_bytes() == b"keep me"
    before = files["log"].read_bytes()
    copy = files["log"].with_suffix(".png")  # the log's own name under an image suffix is fine...
    assert invoke("render", files["log"], "-o", copy).exit_code == 0
    copy.unlink()
    for force in ([], ["--force"]):  # ...but the log itself, even through a link, never
        link = tmp_path / "link.png"
        link.unlink(missing_ok=True)
        link.symlink_to(files["log"])
        assert_one_error(invoke("render", files["log"], "-o", link, *force), "never written over")
    assert files["log"].read_bytes() == before


@pytest.mark.parametrize("looped", ["log", "image", "image folder"])
def test_a_symlink_loop_among_renders_paths_is_one_line(files, tmp_path, looped):
    loop = tmp_path / "loop"
    loop.symlink_to(tmp_path / "back")
    (tmp_path / "back").symlink_to(loop)
    log, image = {
        "log": (loop, tmp_path / "ep.png"),
        "image": (files["log"], loop.with_suffix(".png")),
        "image folder": (files["log"], loop / "ep.png"),
    }[looped]
    if looped == "image":
        image.symlink_to(loop)
    assert_one_error(invoke("render", log, "-o", image, "--force"), str(loop.name))


def test_render_with_force_replaces_an_image_and_makes_folders(files, tmp_path):
    image = tmp_path / "old.png"
    image.write_bytes(b"replace me")
    assert invoke("render", files["log"], "-o", image, "--force").exit_code == 0
    assert image.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert invoke("render", files["log"], "-o", tmp_path / "new" / "ep.gif").exit_code == 0
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


def test_report_refuses_existing_results_before_evaluating(files, tmp_path):
    (tmp_path / "results.md").write_text("shipped")
    result = invoke("report", "--policy", files["policy"], "--scenario", "small-11", "--episodes", "1",
                    "--max-steps", "2", "--out", tmp_path)
    assert_one_error(result, "results.md", "exists", "--force")
    assert (tmp_path / "results.md").read_text() == "shipped"
    assert not (tmp_path / "results.png").exists()


def test_report_refuses_the_shipped_docs_without_force(files, monkeypatch):
    repo = Path(__file__).resolve().parents[1]
    before = (repo / "docs" / "results.md").read_bytes()
    monkeypatch.chdir(repo)
    result = invoke("report", "--policy", files["policy"], "--scenario", "small-11", "--episodes", "1",
                    "--max-steps", "2", "--out", "docs")
    assert_one_error(result, "results.md", "--force")
    assert (repo / "docs" / "results.md").read_bytes() == before


def test_report_writes_into_report_of_the_working_folder_by_default(files, monkeypatch, tmp_path):
    monkeypatch.chdir(tmp_path)
    result = invoke("report", "--policy", files["policy"], "--scenario", "small-11", "--episodes", "1",
                    "--max-steps", "2")
    assert result.exit_code == 0, result.output
    assert {path.name for path in (tmp_path / "report").iterdir()} == {"results.md", "results.png"}


def test_report_with_force_replaces_results_and_makes_the_folder(files, tmp_path):
    out = tmp_path / "new" / "docs"
    args = ("report", "--policy", files["policy"], "--scenario", "small-11", "--episodes", "1", "--max-steps", "2",
            "--out", out)
    assert invoke(*args).exit_code == 0
    assert invoke(*args, "--force").exit_code == 0
    assert sorted(p.name for p in out.iterdir()) == ["results.md", "results.png"]
    assert "--force" in (out / "results.md").read_text()


def test_report_never_writes_over_its_policy(files, tmp_path):
    policy = tmp_path / "results.md"
    policy.write_bytes(files["policy"].read_bytes())
    result = invoke("report", "--policy", policy, "--scenario", "small-11", "--episodes", "1", "--out", tmp_path,
                    "--force")
    assert_one_error(result, "never written over")
    assert policy.read_bytes() == files["policy"].read_bytes()
