"""`python -m training curve`: learning curves of a run's kept snapshots, evaluated once each."""

from __future__ import annotations

import json

import pytest

from training.__main__ import main
from training.checkpoint import CONFIG_FILE, Counters, save_snapshot
from training.config import Config
from training.lab.snapshot_curves import EVALUATIONS_FILE
from training.networks import network_from_config
from training.seed_state import METRICS_FILE


def tiny() -> Config:
    return Config.of(model="terl", hidden=16, layers=1, heads=2, eval_max_steps=20)


def make_run(folder, steps=(160, 320)):
    """A run folder with its config, a kept snapshot at each of `steps` and a metrics log whose
    snapshot record at the last step evaluated small-11 (2 episodes from seed 6000) at 0.5."""
    config = tiny()
    folder.mkdir(parents=True)
    config.to_file(folder / CONFIG_FILE)
    for step in steps:
        save_snapshot(folder / "snapshots" / str(step), config, network_from_config(config.network), Counters(env_step=step))
    recorded = {"scenario": "small-11", "episodes": 2, "seed": 6000, "success_rate": 0.5, "travel_time_s_mean": 9.5,
                "collision_ratio_mean": 0.25, "steps_mean": 19.0}
    record = {"kind": "snapshot", "env_step": steps[-1], "score": 0.0, "best": True, "evaluations": [recorded]}
    (folder / METRICS_FILE).write_text(json.dumps(record) + "\n")
    return folder


CURVE = ["--scenario", "small-11", "--scenario", "small-15", "--episodes", "2", "--max-steps", "20", "--json"]


def test_a_curve_evaluates_each_snapshot_once_and_reads_what_the_run_recorded(tmp_path, capsys):
    run = make_run(tmp_path / "run")
    assert main(["curve", str(run), *CURVE, "-o", str(tmp_path / "curves.png")]) == 0
    captured = capsys.readouterr()
    points = json.loads(captured.out)
    assert [(p["env_step"], p["scenario"]) for p in points] == [
        (160, "small-11"), (160, "small-15"), (320, "small-11"), (320, "small-15")]
    assert all(p["run"] == "seed 1" and p["episodes"] == 2 and p["seed"] == 6000 for p in points)
    assert all(p["success_low"] <= p["success_rate"] <= p["success_high"] for p in points)
    recorded = points[2]  # the run's own evaluation, not run again
    assert (recorded["success_rate"], recorded["collision_ratio_mean"], recorded["max_steps"]) == (0.5, 0.25, 20)
    assert captured.err.count("episodes of") == 3  # what was neither recorded nor stored
    assert (tmp_path / "curves.png").stat().st_size > 0
    stored = json.loads((run / "snapshots" / "160" / EVALUATIONS_FILE).read_text())
    assert [e["scenario"] for e in stored] == ["small-11", "small-15"]

    assert main(["curve", str(run), *CURVE]) == 0  # everything stored: nothing evaluated again
    again = capsys.readouterr()
    assert json.loads(again.out) == points and "episodes of" not in again.err
    assert main(["curve", str(run), "--scenario", "small-11", "--episodes", "2", "--max-steps", "20", "--seed", "7000",
                 "--json"]) == 0  # other episodes: evaluated
    assert capsys.readouterr().err.count("episodes of") == 2


def test_a_curve_prints_a_table_by_default(tmp_path, capsys):
    run = make_run(tmp_path / "run", steps=(320,))
    assert main(["curve", str(run), "--scenario", "small-11", "--episodes", "2", "--max-steps", "20"]) == 0
    table = capsys.readouterr().out.splitlines()
    assert table[0].startswith("| run | step | preset | success")
    assert table[2] == "| seed 1 | 320 | small-11 | 0.50 [0.01, 0.99] | 9.5 s | 0.250 |"


def test_a_curve_names_what_it_cannot_read(tmp_path, capsys):
    (tmp_path / "empty").mkdir()
    tiny().to_file(tmp_path / "empty" / CONFIG_FILE)
    assert main(["curve", str(tmp_path / "empty"), *CURVE]) == 2
    assert "no snapshots/ (the run kept no snapshot: keep_snapshots)" in capsys.readouterr().err

    run = make_run(tmp_path / "run", steps=(320,))
    (run / "snapshots" / "320" / EVALUATIONS_FILE).write_text("[{")
    assert main(["curve", str(run), *CURVE]) == 2
    assert f"{run / 'snapshots' / '320' / EVALUATIONS_FILE}: not JSON" in capsys.readouterr().err

    (run / "snapshots" / "320" / EVALUATIONS_FILE).write_text('[{"scenario": "small-11"}]')
    assert main(["curve", str(run), *CURVE]) == 2
    assert "not a list of evaluations (each with collision_ratio_mean, episodes" in capsys.readouterr().err

    assert main(["curve", str(run), "--scenario", "huge-500"]) == 2
    assert "unknown scenario 'huge-500'" in capsys.readouterr().err


def test_the_stage_starts_of_seeds_on_one_schedule_are_drawn_once(tmp_path):
    from training.lab.curves import stage_starts

    logs = []
    for seed, stages in ((1, [(200, "curriculum-2"), (100, "curriculum-1")]), (2, [(100, "curriculum-1")])):
        log = tmp_path / f"seed-{seed}.jsonl"
        log.write_text("".join(json.dumps({"kind": "stage", "env_step": step, "stage": name}) + "\n" for step, name in stages)
                       + json.dumps({"kind": "train", "env_step": 300}) + "\n")
        logs.append(log)
    assert stage_starts(logs) == [{"env_step": 100, "stage": "curriculum-1"}, {"env_step": 200, "stage": "curriculum-2"}]


def test_a_pick_takes_the_most_successes_then_the_fewest_collisions_then_the_latest_step():
    from training.lab.curves import CurvesError
    from training.lab.snapshot_curves import picked_snapshot

    def point(step, scenario, success, collisions):
        return {"env_step": step, "scenario": scenario, "success_rate": success, "collision_ratio_mean": collisions}

    points = [point(500, "small-15", 0.9, 0.0), point(500, "large-80", 1.0, 0.0), point(1000, "small-15", 1.0, 0.5),
              point(1500, "small-15", 1.0, 0.2), point(2000, "small-15", 1.0, 0.2), point(2500, "small-15", 0.8, 0.0)]
    assert picked_snapshot(points, "small-15")["env_step"] == 2000
    assert picked_snapshot(points, "large-80")["env_step"] == 500
    with pytest.raises(CurvesError, match="no snapshot evaluated on cc-28"):
        picked_snapshot(points, "cc-28")


def test_a_curve_names_the_folder_of_each_runs_pick(tmp_path, capsys):
    run = make_run(tmp_path / "run")
    assert main(["curve", str(run), "--scenario", "small-15", "--pick", "small-11", "--episodes", "2",
                 "--max-steps", "20"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert [line.split(" | ")[2] for line in lines[2:6]] == ["small-15", "small-11", "small-15", "small-11"]
    (picked,) = [line for line in lines if line.startswith("picked by small-11: seed 1 at ")]
    step = picked.split(" at ")[1].split(" ")[0]
    assert picked.endswith(f"({run / 'snapshots' / step})") and (run / "snapshots" / step).is_dir()

    assert main(["curve", str(run), "--scenario", "small-11", "--pick", "small-11", "--episodes", "2",
                 "--max-steps", "20", "--json"]) == 0
    points = json.loads(capsys.readouterr().out)
    assert sum(point["picked"] for point in points) == 1
