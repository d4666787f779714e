"""A method x seed grid (`python -m training grid`): every cell a run of its own, resumable,
failing or stopping alone, and shipped as `<method>-seed-<S>.onnx` with one card per method."""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import signal
import subprocess
import sys
import tarfile
import threading
import time
from pathlib import Path

import pytest
import torch

from terl_rt.policy.contract import META_METHOD, META_SEED
from terl_rt.policy.onnx_policy import OnnxPolicy
from training.__main__ import main
from training.lab.grid import LocalProcesses, plan_grid, run_grid
from training.lab.recipe import load_recipe, segment_folder
from training.lab.ship import seed_row, shipped_line
from training.onnx_weights import network_from_onnx
from training.run_lock import LOCK_FILE, RUN_HELD, holding_run_folder

REPOSITORY = Path(__file__).resolve().parents[2]

BASE = """
ships = "exported/base.onnx"

[[segment]]
name = "first"
steps = 80
[segment.network]
hidden = 16
layers = 1
heads = 2
[segment.learner]
batch_size = 16
target_network_frequency = 40
[segment.data]
buffer_size = 2000
learning_starts = 24
[segment.schedule]
num_envs = 4
train_max_steps = 30
[segment.run]
log_frequency = 40
checkpoint_frequency = 40
snapshot_frequency = 80
snapshot_episodes = 1
snapshot_preset = "small-11"
eval_max_steps = 10

[[segment]]
name = "second"
steps = 120
"""
METHODS = {  # a method's recipe: the base with its network
    "tiny-terl": '# Tiny TERL: its notes, quoted by its card.\n#\n#   an indented line\n'
                 'extends = "base.toml"\nships = "exported/comparison/tiny-terl.onnx"\n',
    "tiny-dqn": 'extends = "base.toml"\nships = "exported/comparison/tiny-dqn.onnx"\n[network]\nmodel = "dqn"\n'
                "layers = 0\nheads = 0\n",
}
STAND_IN = """
import pathlib, signal, sys, time
out = pathlib.Path(sys.argv[sys.argv.index("--out") + 1])
if sys.argv[sys.argv.index("--seed") + 1] == "2":
    sys.exit("ValueError: seed 2 cannot learn")
signals = []
signal.signal(signal.SIGTERM, lambda number, frame: signals.append(number))
out.mkdir(parents=True)
(out / "ready").touch()
deadline = time.monotonic() + WAIT_S
while not signals and time.monotonic() < deadline:
    time.sleep(0.02)
time.sleep(0.2)  # a second signal would arrive here
(out / "signals").write_text(str(len(signals)))
sys.exit(130 if signals else 0)
"""
"""A cell's stand-in (no torch): seed 2 fails, the others wait WAIT_S seconds or for a SIGTERM."""


def write_recipes(folder: Path) -> list[Path]:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "base.toml").write_text(BASE)
    paths = []
    for method, text in METHODS.items():
        (folder / f"{method}.toml").write_text(text)
        paths.append(folder / f"{method}.toml")
    return paths


def sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture(scope="module")
def grid(tmp_path_factory):
    """A 2 x 2 grid run to its end by the command, each method's seeds trained together, and
    shipped; tiny-dqn's seed 3 failed in an earlier grid (its log is all there is of it)."""
    root = tmp_path_factory.mktemp("grid")
    recipes = write_recipes(root / "recipes")
    (root / "runs" / "tiny-dqn").mkdir(parents=True)
    (root / "runs" / "tiny-dqn" / "seed-3.log").write_text("ValueError: an earlier failure\n")
    arguments = ["grid", *map(str, recipes), "--seeds", "1,2", "--out", str(root / "runs"), "--processes", "2",
                 "--seeds-per-process", "2", "--ship", str(root / "exported")]
    assert main(arguments) == 0
    return root, recipes, arguments


# ---------------------------------------------------------------- running
def test_a_grid_runs_every_cell_as_its_recipe_with_that_seed(grid):
    root, _, _ = grid
    for method in METHODS:
        for seed in (1, 2):
            cell = root / "runs" / method / f"seed-{seed}"
            assert (cell / f"{method}.onnx").is_file()
            log = (root / "runs" / method / "seeds-1-2.log").read_text()
            assert f"seed {seed}, segment 2/2 (second, to 120 steps): starting" in log
            config = json.loads(OnnxPolicy(cell / f"{method}.onnx").metadata["terl.training_config"])
            assert config["run"]["seed"] == seed


# ---------------------------------------------------------------- shipping
def test_a_shipped_grid_names_and_tags_each_seeds_policy_by_method_and_seed(grid):
    root, _, _ = grid
    shipped = sorted(path.name for path in (root / "exported").glob("*.onnx"))
    assert shipped == ["tiny-dqn-seed-1.onnx", "tiny-dqn-seed-2.onnx", "tiny-terl-seed-1.onnx", "tiny-terl-seed-2.onnx"]
    for method in METHODS:
        for seed in (1, 2):
            metadata = OnnxPolicy(root / "exported" / f"{method}-seed-{seed}.onnx").metadata
            assert (metadata[META_METHOD], metadata[META_SEED]) == (method, str(seed))
            assert metadata["terl.model"] == ("dqn" if method == "tiny-dqn" else "terl")


def test_a_method_card_lists_every_seeds_weights_figures_and_curves(grid):
    root, recipes, _ = grid
    card = (root / "exported" / "tiny-dqn.md").read_text()
    assert f"- **Recipe**: [`{recipes[1]}`]" in card
    for seed in (1, 2):
        onnx = root / "exported" / f"tiny-dqn-seed-{seed}.onnx"
        assert f"- **Weights**: `{onnx}`, sha256 `{sha256(onnx)}`." in card
        assert f"\n| {seed} | 120 | " in card
    assert "![every seed's curves](tiny-dqn-seeds.png)" in card
    assert (root / "exported" / "tiny-dqn-seeds.png").stat().st_size > 0
    assert "## The recipe's notes" not in card  # its recipe has none
    notes = "## The recipe's notes\n\n```text\nTiny TERL: its notes, quoted by its card.\n\n  an indented line\n```\n"
    assert notes in (root / "exported" / "tiny-terl.md").read_text()


def test_a_card_says_whether_its_seeds_ship_the_best_snapshot_or_the_last_checkpoint(tmp_path):
    (tmp_path / "best.toml").write_text(BASE)
    (tmp_path / "last.toml").write_text('ships_from = "last"' + BASE)
    assert shipped_line(load_recipe(tmp_path / "best.toml")).startswith("- Shipped: each seed's best snapshot (score: ")
    assert shipped_line(load_recipe(tmp_path / "last.toml")) == (
        "- Shipped: each seed's last checkpoint (120 steps); its snapshots (1 episodes of the current stage and of "
        "small-11 from seed 20240, seeds no report uses) choose nothing.")


def test_a_seed_that_did_not_finish_keeps_its_row_in_the_card(grid):
    root, _, _ = grid
    card = (root / "exported" / "tiny-dqn.md").read_text()
    assert f"| 3 | not finished (failed, stopped or not run): see `{root / 'runs' / 'tiny-dqn' / 'seed-3.log'}` |" in card
    assert "--seeds 1,2,3 " in card and not (root / "exported" / "tiny-dqn-seed-3.onnx").exists()


def test_a_cells_logs_are_its_own_and_those_of_the_stacks_it_trained_in(tmp_path):
    cells = {cell.seed: cell for cell, _ in plan_grid(write_recipes(tmp_path / "recipes")[:1], [1, 2, 3, 12],
                                                      tmp_path / "runs")}
    folder = tmp_path / "runs" / "tiny-terl"
    folder.mkdir(parents=True)
    for name in ("seed-1.log", "seeds-1-2.log", "seeds-2.log", "seeds-12-13.log"):
        (folder / name).write_text("")
    assert cells[1].logs() == [folder / "seed-1.log", folder / "seeds-1-2.log"]
    assert cells[2].logs() == [folder / "seeds-1-2.log", folder / "seeds-2.log"]
    assert cells[12].logs() == [folder / "seeds-12-13.log"] and cells[3].logs() == []
    assert "not finished (failed, stopped or not run): no log (never run) |" in seed_row(
        cells[3], load_recipe(tmp_path / "recipes" / "tiny-terl.toml"), False, [])


# ---------------------------------------------------------------- failures and stops (stand-in cells, no torch)
def stand_in(wait_s: float) -> LocalProcesses:
    """Cells run by STAND_IN, waiting `wait_s` seconds."""
    return LocalProcesses(("-c", STAND_IN.replace("WAIT_S", str(wait_s))))


def test_a_failing_cell_gives_one_error_line_naming_its_log_and_the_others_finish(tmp_path):
    cells = plan_grid(write_recipes(tmp_path / "recipes"), [1, 2, 3], tmp_path / "runs")
    lines: list[str] = []
    outcome = run_grid(cells, stand_in(wait_s=0), at_once=2, note=lines.append)
    errors = [line for line in lines if line.startswith("Error:")]
    log = tmp_path / "runs" / "tiny-terl" / "seed-2.log"
    assert errors[0] == f"Error: tiny-terl seed 2 failed (exit 1): ValueError: seed 2 cannot learn; log {log}"
    assert len(errors) == 2 and "tiny-dqn seed 2" in errors[1]
    assert sorted(outcome.done) == ["tiny-dqn seed 1", "tiny-dqn seed 3", "tiny-terl seed 1", "tiny-terl seed 3"]
    assert outcome.exit_status == 1


def test_a_signal_to_the_grid_reaches_each_running_cell_once_and_starts_no_other(tmp_path):
    cells = plan_grid(write_recipes(tmp_path / "recipes"), [1, 3], tmp_path / "runs")  # seed 1's cells first
    started = [tmp_path / "runs" / method / "seed-1" / "ready" for method in METHODS]

    def stop_when_started():
        deadline = time.monotonic() + 60
        while not all(path.exists() for path in started) and time.monotonic() < deadline:
            time.sleep(0.02)
        os.kill(os.getpid(), signal.SIGTERM)

    threading.Thread(target=stop_when_started, daemon=True).start()
    outcome = run_grid(cells, stand_in(wait_s=60), at_once=2, note=lambda line: None)
    for method in METHODS:
        assert (tmp_path / "runs" / method / "seed-1" / "signals").read_text() == "1"
        assert not (tmp_path / "runs" / method / "seed-3").exists()
    assert sorted(outcome.stopped) == ["tiny-dqn seed 1", "tiny-dqn seed 3", "tiny-terl seed 1", "tiny-terl seed 3"]
    assert outcome.exit_status == 130


def test_a_grid_stops_its_cells_with_checkpoints_when_its_time_is_up(tmp_path):
    cells = plan_grid(write_recipes(tmp_path / "recipes"), [1, 3], tmp_path / "runs")
    lines: list[str] = []
    start = time.monotonic()
    outcome = run_grid(cells, stand_in(wait_s=60), at_once=2, note=lines.append, stop_after_s=1.0)
    assert time.monotonic() - start < 30  # the stand-ins would wait 60 s for their signal
    for method in METHODS:
        assert (tmp_path / "runs" / method / "seed-1" / "signals").read_text() == "1"
        assert not (tmp_path / "runs" / method / "seed-3").exists()
    assert any("the time limit is reached" in line for line in lines)
    assert len(outcome.stopped) == 4 and outcome.exit_status == 130


def test_a_grid_run_again_resumes_a_cut_off_cell_to_the_same_bytes_and_the_device_command_packs_it_alone(
        grid, tmp_path):
    # scripts/device-grid.sh as a device machine runs it, on the finished grid with one cell cut off
    # after its first segment: the grid skips the finished cells, trains that one on (here alone in
    # its stack: SEEDS_PER_PROCESS) to the policy it had, and the script packs it and nothing else.
    root, recipes, _ = grid
    shutil.copytree(root / "runs", tmp_path / "runs")
    cut = tmp_path / "runs" / "tiny-terl" / "seed-2"
    shutil.rmtree(segment_folder(cut, 2, load_recipe(recipes[0]).segments[1]))
    (cut / "tiny-terl.onnx").unlink()
    (tmp_path / "out").mkdir()
    env = {**os.environ, "OUT": str(tmp_path / "out"), "GRID_OUT": str(tmp_path / "runs"), "PROCESSES": "2",
           "DEVICE": "cpu", "SEEDS_PER_PROCESS": "2", "PATH": f"{Path(sys.executable).parent}:{os.environ['PATH']}"}
    done = subprocess.run(["bash", str(REPOSITORY / "scripts" / "device-grid.sh"), "5", *map(str, recipes),
                           "--seeds", "1,2"], cwd=REPOSITORY, env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert "3 of 4 cells finished before this run: tiny-terl seed 1, tiny-dqn seed 1, tiny-dqn seed 2" in done.stderr
    assert "tiny-terl seeds 2: started" in done.stderr and done.stderr.count(": started") == 1
    assert sha256(cut / "tiny-terl.onnx") == sha256(root / "runs" / "tiny-terl" / "seed-2" / "tiny-terl.onnx")
    assert sorted(path.name for path in (tmp_path / "out").iterdir()) == ["tiny-terl.tar.gz"]
    with tarfile.open(tmp_path / "out" / "tiny-terl.tar.gz") as archive:
        names = archive.getnames()
    assert "tiny-terl/seeds-2.log" in names and not any(name.startswith("tiny-terl/seed-1") for name in names)
    assert "tiny-terl/seed-2/2-second/state.json" in names and "tiny-terl/seed-2/tiny-terl.onnx" in names
    assert any(name.endswith("/best/model.safetensors") for name in names)
    assert not any(name.endswith(("replay.npz", ".run-lock")) for name in names)


@pytest.mark.ray
@pytest.mark.slow  # a Ray instance of its own: 2-5 min on a loaded machine
def test_on_ray_each_cell_is_a_task_and_a_failing_one_gives_its_error_line(tmp_path):
    grid_ray = pytest.importorskip("training.lab.grid_ray", reason="needs Ray: pip install -e '.[ray]'")
    cells = plan_grid(write_recipes(tmp_path / "recipes")[:1], [1, 2], tmp_path / "runs")
    runner = grid_ray.RayCells(None, cpus=2, program=("-c", STAND_IN.replace("WAIT_S", "0")))
    lines: list[str] = []
    outcome = run_grid(cells, runner, at_once=2, note=lines.append)
    assert (outcome.done, outcome.failed) == (["tiny-terl seed 1"], ["tiny-terl seed 2"])
    log = tmp_path / "runs" / "tiny-terl" / "seed-2.log"
    assert [line for line in lines if line.startswith("Error:")] == [
        f"Error: tiny-terl seed 2 failed (exit 1): ValueError: seed 2 cannot learn; log {log}"
    ]


# ---------------------------------------------------------------- bad input
def test_two_recipes_of_one_method_are_refused_before_anything_runs(tmp_path, capsys):
    recipes = write_recipes(tmp_path / "a")
    other = write_recipes(tmp_path / "b")
    assert main(["grid", str(recipes[0]), str(other[0]), "--seeds", "1", "--out", str(tmp_path / "runs")]) == 2
    assert capsys.readouterr().err.startswith("Error: ") and not (tmp_path / "runs").exists()


@pytest.mark.parametrize("seeds", ["1,x", "3-1", ""])
def test_seeds_that_are_no_list_or_range_of_whole_numbers_are_one_error_line(tmp_path, capsys, seeds):
    recipes = write_recipes(tmp_path / "recipes")
    assert main(["grid", str(recipes[0]), "--seeds", seeds, "--out", str(tmp_path / "runs")]) == 2
    assert capsys.readouterr().err.startswith("Error: Invalid value for '--seeds'")


def test_a_cell_that_another_run_holds_is_left_to_it_and_the_grid_says_so(tmp_path):
    # The real `python -m training run` of a tiny recipe, on a folder another process holds.
    (tmp_path / "base.toml").write_text(BASE)
    (tmp_path / "tiny-dqn.toml").write_text(METHODS["tiny-dqn"])
    cells = plan_grid([tmp_path / "tiny-dqn.toml"], [1], tmp_path / "grid")
    holder = subprocess.Popen([sys.executable, "-c", HOLDER, str(cells[0][0].out)], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        lines: list[str] = []
        outcome = run_grid(cells, LocalProcesses(), 1, lines.append)
    finally:
        holder.kill()
        holder.wait()
    assert outcome.elsewhere == ["tiny-dqn seed 1"] and outcome.exit_status == RUN_HELD
    assert f"is in use by another run (process {holder.pid})" in lines[-1]
    assert sorted(path.name for path in cells[0][0].out.iterdir()) == [LOCK_FILE]  # nothing written
    with holding_run_folder(cells[0][0].out):  # the killed holder left no stale lock
        pass


HOLDER = """
import sys, time
from pathlib import Path
from training.run_lock import holding_run_folder
with holding_run_folder(Path(sys.argv[1])):
    print("held", flush=True)
    time.sleep(600)
"""
"""A process that holds a run folder until it is killed."""


def test_keep_cells_copies_what_ships_of_a_finished_cell_and_the_resume_point_of_one_cut_off(tmp_path):
    segment_files = ("config.json", "state.json", "metrics.jsonl", "model.safetensors", "target.safetensors",
                     "optimizer.pt", "replay.npz", "snapshots/80000/model.safetensors", "best/model.safetensors",
                     "best/config.json", "best/state.json", "best/optimizer.pt", "best/target.safetensors")
    for cell, finished in (("iqn/seed-1", True), ("iqn/seed-2", False)):
        folder = tmp_path / "runs" / cell
        for segment in ("1-curriculum", "2-last-stage"):
            for name in segment_files:
                (folder / segment / name).parent.mkdir(parents=True, exist_ok=True)
                (folder / segment / name).write_text(name)
        (folder / ".run-lock").write_text("")
        if finished:
            (folder / "iqn.onnx").write_text("onnx")
        folder.with_suffix(".log").write_text("log")
    done = subprocess.run([sys.executable, str(REPOSITORY / "scripts" / "keep-cells.py"), str(tmp_path / "runs"),
                           str(tmp_path / "kept")], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert done.stdout.splitlines() == ["iqn/seed-1: finished", "iqn/seed-2: cut off"]

    def files(cell):
        return sorted(str(p.relative_to(tmp_path / "kept" / cell)) for p in (tmp_path / "kept" / cell).rglob("*")
                      if p.is_file())

    shipped = [f"{segment}/{name}" for segment in ("1-curriculum", "2-last-stage") for name in (
        "best/config.json", "best/model.safetensors", "best/state.json", "config.json", "metrics.jsonl", "state.json",
        "snapshots/80000/model.safetensors")]
    assert files("iqn/seed-1") == sorted(shipped + ["iqn.onnx"])
    assert files("iqn/seed-2") == sorted(shipped + [
        f"{segment}/best/{name}" for segment in ("1-curriculum", "2-last-stage") for name in ("optimizer.pt",
                                                                                            "target.safetensors")
    ] + ["2-last-stage/model.safetensors", "2-last-stage/optimizer.pt", "2-last-stage/target.safetensors"])
    assert (tmp_path / "kept" / "iqn" / "seed-2.log").read_text() == "log"
    # cut off as a segment begins (its log alone): the resume point is the segment before it
    (tmp_path / "runs" / "iqn" / "seed-2" / "3-large").mkdir()
    (tmp_path / "runs" / "iqn" / "seed-2" / "3-large" / "metrics.jsonl").write_text("log")
    done = subprocess.run([sys.executable, str(REPOSITORY / "scripts" / "keep-cells.py"), str(tmp_path / "runs"),
                           str(tmp_path / "kept"), "iqn/seed-2"], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert {"2-last-stage/model.safetensors", "2-last-stage/optimizer.pt", "3-large/metrics.jsonl"} <= set(files("iqn/seed-2"))


# ---------------------------------------------------------------- seeds trained together
def test_seeds_per_process_stacks_each_methods_unfinished_cells_in_seed_order(tmp_path):
    from training.lab.grid import CellStack, stack_cells

    cells = plan_grid(write_recipes(tmp_path / "recipes"), [1, 2, 3], tmp_path / "runs")
    stacks = stack_cells(cells, 2)
    names = [unit.name for unit, _ in stacks]
    assert names == ["tiny-terl seeds 1,2", "tiny-terl seeds 3", "tiny-dqn seeds 1,2", "tiny-dqn seeds 3"]
    first = stacks[0][0]
    assert isinstance(first, CellStack) and first.log == tmp_path / "runs" / "tiny-terl" / "seeds-1-2.log"
    assert first.arguments()[1:5] == ["--out", str(tmp_path / "runs" / "tiny-terl"), "--seeds", "1,2"]
    assert stack_cells(cells, 1) == cells


@pytest.mark.slow  # four cells from scratch; CI trains seeds together (the grid fixture) and one seed a stack
def test_a_grid_of_cells_alone_ships_the_policies_of_stacked_seeds(grid, tmp_path):
    root, recipes, _ = grid
    arguments = ["grid", *map(str, recipes), "--seeds", "1,2", "--out", str(tmp_path / "runs"), "--processes", "2",
                 "--ship", str(tmp_path / "exported")]
    assert main(arguments) == 0
    for method in METHODS:
        for seed in (1, 2):
            assert "segment 2/2 (second, to 120 steps): starting" in (
                tmp_path / "runs" / method / f"seed-{seed}.log").read_text()
            name = f"{method}-seed-{seed}.onnx"
            # Equal to float round-off, not in bytes: a stack trims the token slots empty in all
            # its seeds' rows (trim_padding), so a seed's tokens may be padded otherwise than alone.
            alone = network_from_onnx(tmp_path / "exported" / name)[0].state_dict()
            stacked = network_from_onnx(root / "exported" / name)[0].state_dict()
            assert alone.keys() == stacked.keys()
            for key, value in stacked.items():
                assert torch.allclose(alone[key], value, rtol=0, atol=1e-4 * float(value.abs().max())), (name, key)
    assert main(arguments) == 0  # run again: every cell finished, nothing to do
