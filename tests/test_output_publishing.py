"""Outputs are written whole, never over another run's, and the results survive a full disk (issue 41, item 1)."""

from __future__ import annotations

import os
import resource
import subprocess
import sys
import threading
from pathlib import Path

import pytest
from one_line import assert_one_error, invoke
from onnx_models import write_test_policy
from processes import start_eval, wait_for_log
from tiny_worlds import capture_scenario

from terl_rt.files import OutputBusy, OutputExists, OutputHold, atomic_output, atomic_outputs, publish, temporary_beside
from terl_rt.logs.reader import EpisodeLogReader

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("publishing")
    scenario = folder / "capture.json"
    capture_scenario(max_steps=4).to_file(scenario)
    return {"folder": folder, "policy": write_test_policy(folder / "linear.onnx"), "scenario": scenario}


def eval_args(files, *extra) -> list[str]:
    return ["eval", "--policy", str(files["policy"]), "--scenario-file", str(files["scenario"]), "--episodes", "2",
            *map(str, extra)]


def leftovers(folder: Path) -> list[str]:
    return sorted(path.name for path in folder.iterdir() if ".partial" in path.name)


# --- the writer ------------------------------------------------------------------------


def test_publishing_over_a_file_that_appeared_meanwhile_fails_and_keeps_it(tmp_path):
    target = tmp_path / "out.csv"
    first, second = temporary_beside(target), temporary_beside(target)
    first.write_text("first run\n")
    second.write_text("second run\n")
    publish(first, target)
    with pytest.raises(OutputExists) as caught:
        publish(second, target)
    assert caught.value.filename == str(target) and "another run" in str(caught.value)
    assert target.read_text() == "first run\n" and not first.exists()


def test_of_two_threads_publishing_one_path_exactly_one_wins(tmp_path):
    target = tmp_path / "race.json"
    outcomes: list[str] = []
    start = threading.Barrier(8)

    def run(number: int) -> None:
        staging = temporary_beside(target)
        staging.write_text(f"{number}\n")
        start.wait()
        try:
            publish(staging, target)
            outcomes.append(f"won {number}")
        except OutputExists:
            outcomes.append("refused")
            staging.unlink()

    threads = [threading.Thread(target=run, args=(number,)) for number in range(8)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    winners = [outcome for outcome in outcomes if outcome.startswith("won")]
    assert len(winners) == 1 and outcomes.count("refused") == 7
    assert target.read_text() == winners[0].split()[1] + "\n" and leftovers(tmp_path) == []


def test_a_held_path_is_refused_to_a_second_hold_until_released_and_leaves_no_file(tmp_path):
    target = tmp_path / "run.mcap"
    first = OutputHold(target)
    with pytest.raises(OutputBusy, match=rf"another run \(pid {os.getpid()}\) is writing it"):
        OutputHold(target)
    first.release()
    OutputHold(target).release()
    assert list(tmp_path.iterdir()) == []


@pytest.mark.skipif(sys.platform == "win32", reason="no flock: no hold")
def test_the_holder_of_a_path_is_named_while_it_holds_it_and_asking_makes_no_file(tmp_path):
    target = tmp_path / "run.mcap"
    assert OutputHold.holder(target) is None and list(tmp_path.iterdir()) == []
    hold = OutputHold(target)
    assert OutputHold.holder(target) == str(os.getpid())
    hold.release()
    assert OutputHold.holder(target) is None and list(tmp_path.iterdir()) == []


def test_a_failed_write_leaves_the_earlier_file_and_no_temporary_file(tmp_path):
    target = tmp_path / "report.md"
    target.write_text("earlier\n")
    with pytest.raises(RuntimeError), atomic_output(target, replace=True) as staging:
        staging.write_text("half")
        raise RuntimeError("the run failed")
    assert target.read_text() == "earlier\n" and leftovers(tmp_path) == []


def test_a_write_error_names_the_target_not_the_temporary_file(tmp_path):
    target = tmp_path / "out.csv"
    with pytest.raises(OSError) as caught, atomic_output(target) as staging:
        raise OSError(28, "No space left on device", str(staging))
    assert caught.value.filename == str(target) and caught.value.errno == 28


def test_a_folder_of_outputs_is_published_file_by_file_and_names_its_files_in_errors(tmp_path):
    with atomic_outputs(tmp_path, ("a.md", "b.png")) as staging:
        (staging / "a.md").write_text("a")
        (staging / "b.png").write_text("b")
    assert (tmp_path / "a.md").read_text() == "a" and (tmp_path / "b.png").read_text() == "b"
    with pytest.raises(OSError) as caught, atomic_outputs(tmp_path, ("c.md",)) as staging:
        raise OSError(27, "File too large", str(staging / "c.md"))
    assert caught.value.filename == str(tmp_path / "c.md")
    assert sorted(path.name for path in tmp_path.iterdir()) == ["a.md", "b.png"]


# --- the commands ----------------------------------------------------------------------


@pytest.mark.parametrize("option", ["--log", "--csv"])
def test_an_empty_output_path_is_refused(files, option):
    assert_one_error(invoke(*eval_args(files, option, "")), option, "empty")


@pytest.mark.parametrize("command", ["sweep", "report"])
def test_an_empty_output_folder_is_refused(files, command):
    assert_one_error(invoke(command, "--policy", files["policy"], "--episodes", "1", "--out", " "), "--out", "empty")


def test_publishing_where_hard_links_are_refused_claims_the_name_exclusively(tmp_path, monkeypatch):
    def no_links(source, target):
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(os, "link", no_links)
    target = tmp_path / "out.md"
    with atomic_output(target) as staging:
        staging.write_text("first\n")
    with pytest.raises(OutputExists), atomic_output(target) as staging:
        staging.write_text("second\n")
    assert target.read_text() == "first\n" and leftovers(tmp_path) == []


def test_an_output_in_a_folder_that_takes_no_file_is_refused_before_the_first_episode(files):
    # /proc takes no new file, even for root (for whom permission bits are no bar).
    result = invoke(*eval_args(files, "--csv", "/proc/terl-rt-test.csv"))
    assert_one_error(result, "--csv", "/proc/terl-rt-test.csv", "cannot write")
    assert "episodes" not in result.stderr  # no progress bar: no episode ran


def test_report_at_an_unwritable_folder_fails_before_evaluating(files):
    result = invoke("report", "--policy", files["policy"], "--scenario", "small-11", "--episodes", "1",
                    "--out", "/proc/terl-rt-report")
    assert_one_error(result, "--out")


def test_eval_csv_goes_through_a_temporary_file_and_prints_results_first(files, tmp_path):
    csv_path = tmp_path / "episodes.csv"
    result = invoke(*eval_args(files, "--csv", csv_path))
    assert result.exit_code == 0, result.output
    assert result.stdout.index("capture") < result.stdout.index("csv:")
    assert csv_path.read_text().count("\n") == 3 and leftovers(tmp_path) == []


def _limited_run(limit_bytes: int, args: list[str], cwd: Path) -> subprocess.CompletedProcess:
    """`terl-rt ARGS` in a process that may write no file beyond `limit_bytes` (ulimit -f):
    what a full disk does to a write (EFBIG instead of ENOSPC; Python ignores SIGXFSZ)."""

    def limit() -> None:
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit_bytes, limit_bytes))

    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    return subprocess.run([sys.executable, "-m", "terl_rt", *args], cwd=cwd, env=env, preexec_fn=limit,
                          capture_output=True, text=True, timeout=120)


def test_a_full_disk_keeps_the_earlier_csv_and_still_prints_the_results(files, tmp_path):
    csv_path = tmp_path / "episodes.csv"
    csv_path.write_text("the earlier run's rows\n")
    run = _limited_run(64, eval_args(files, "--csv", csv_path, "--force"), tmp_path)
    assert run.returncode == 2, run.stderr
    errors = [line for line in run.stderr.splitlines() if line.startswith("Error: ")]
    assert errors == [f"Error: {csv_path}: File too large"], run.stderr
    assert "capture" in run.stdout and "success" in run.stdout  # the table reached the terminal
    assert csv_path.read_text() == "the earlier run's rows\n" and leftovers(tmp_path) == []


def test_two_runs_started_together_on_one_log_never_replace_each_other(files, tmp_path):
    log = tmp_path / "shared.mcap"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    runs = [
        subprocess.Popen([sys.executable, "-m", "terl_rt", *eval_args(files, "--seed", seed, "--log", log)],
                         cwd=tmp_path, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        for seed in (0, 100)
    ]
    outcomes = [(run.wait(timeout=120), run.stdout.read(), run.stderr.read()) for run in runs]
    codes = sorted(code for code, _, _ in outcomes)
    assert codes == [0, 2], outcomes
    loser = next(stderr for code, _, stderr in outcomes if code == 2)
    assert str(log) in loser and ("exists" in loser or "another run" in loser) and "Traceback" not in loser
    winner_seed = 0 if outcomes[0][0] == 0 else 100
    assert [episode.seed for episode in EpisodeLogReader(log).episodes] == [winner_seed, winner_seed + 1]
    assert leftovers(tmp_path) == []


def test_a_forced_run_is_refused_while_another_run_writes_its_log(files, tmp_path):
    """--force replaces what was there before; it never races a run that is still writing."""
    log = tmp_path / "shared.mcap"
    first = start_eval(files["policy"], log, "--episodes", "2", "--max-steps", "150", "--workers", "1")
    try:
        wait_for_log(first, log)
        second = invoke(*eval_args(files, "--log", log, "--force"))
        assert_one_error(second, str(log), f"another run (pid {first.pid}) is writing it")
        assert first.wait(timeout=300) == 0
    finally:
        if first.poll() is None:
            first.kill()
            first.wait()
    reader = EpisodeLogReader(log)
    assert [(e.seed, e.complete) for e in reader.episodes] == [(0, True), (1, True)] and not reader.truncated
    assert leftovers(tmp_path) == []


def _in_a_read_only_folder(folder: Path, args: list[str]) -> subprocess.CompletedProcess | None:
    """`terl-rt ARGS` run in `folder` made a read-only filesystem (a tmpfs mounted read-only in
    a mount namespace of its own, `unshare`); None where this machine allows no such mount."""
    command = ["unshare", "-rm", "sh", "-c", 'mount -t tmpfs -o ro none "$0" && cd "$0" && exec "$@"', str(folder),
               sys.executable, "-m", "terl_rt", *args]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    try:
        probe = subprocess.run(command[:5] + [str(folder), "true"], capture_output=True, timeout=60)
    except FileNotFoundError:
        return None
    if probe.returncode != 0:
        return None
    return subprocess.run(command, env=env, capture_output=True, text=True, timeout=120)


@pytest.mark.parametrize("option, output", [("--log", "rel.mcap"), ("--csv", "rel.csv")])
def test_a_read_only_working_folder_is_refused_naming_the_output_given(files, tmp_path, option, output):
    run = _in_a_read_only_folder(tmp_path, eval_args(files, option, output))
    if run is None:
        pytest.skip("no read-only mount can be made here (unshare -rm)")
    assert run.returncode == 2, run.stderr
    assert run.stderr == f"Error: {option} {output}: cannot write in . (Read-only file system)\n"


def test_a_file_size_limit_ends_a_logged_run_in_one_line_keeping_its_steps_and_no_lock(files, tmp_path):
    log = tmp_path / "run.mcap"
    run = _limited_run(12_000, eval_args(files, "--log", log), tmp_path)
    assert run.returncode == 2, run.stderr
    assert [line for line in run.stderr.splitlines() if line.startswith("Error: ")] == [f"Error: {log}: File too large"]
    assert not (tmp_path / f".{log.name}.lock").exists() and leftovers(tmp_path) == []
    reader = EpisodeLogReader(log)
    assert reader.truncated and reader.episodes[0].chunks  # up to its last complete step
