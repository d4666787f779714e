"""Model cards: the evaluation section read from a comparison.json."""

from __future__ import annotations

import json

import pytest

from training.lab.card import CardError, evaluation_lines


def comparison_file(tmp_path, model="iqn"):
    group = {
        "group": "small", "presets": ["small-11", "small-15"], "success_rate": 0.5, "travel_time_s_mean": 120.25,
        "collision_ratio_mean": 0.125,
        "ci95": {"success_rate": [0.25, 0.75], "travel_time_s": [100.0, 140.5], "collision_ratio": [0.1, 0.15]},
    }
    data = {
        "command": "terl-rt report --policy exported", "date": "2026-11-23T09:46:09.351451+00:00",
        "methods": [{"method": "IQN", "policy": {"metadata": {"terl.model": model}}, "groups": [group]}],
    }
    path = tmp_path / "comparison.json"
    path.write_text(json.dumps(data))
    return path


def test_the_evaluation_section_is_the_models_group_rows_with_intervals(tmp_path):
    lines = evaluation_lines(comparison_file(tmp_path), "iqn")
    assert lines[0].startswith("`terl-rt report --policy exported` (2026-11-23 09:46 UTC)")
    assert lines[-1] == "| small | small-11, small-15 | 0.50 [0.25, 0.75] | 120.2 [100.0, 140.5] | 0.125 [0.100, 0.150] |"


def test_a_comparison_without_the_model_or_not_a_comparison_is_named(tmp_path):
    with pytest.raises(CardError, match="no policy of model 'dqn'"):
        evaluation_lines(comparison_file(tmp_path), "dqn")
    bad = tmp_path / "bad.json"
    bad.write_text("[1, 2]")
    with pytest.raises(CardError, match="bad.json: not a comparison.json"):
        evaluation_lines(bad, "iqn")


def test_snapshots_prints_the_runs_table_or_its_json(tmp_path, capsys):
    from training.__main__ import main

    evaluation = {"scenario": "medium-48", "success_rate": 1.0, "travel_time_s_mean": 76.55, "collision_ratio_mean": 0.036}
    record = {"kind": "snapshot", "env_step": 380_000, "score": 0.8214, "best": True,
              "evaluations": [dict(evaluation, scenario="small-15", travel_time_s_mean=67.06), evaluation]}
    (tmp_path / "metrics.jsonl").write_text(json.dumps({"kind": "resume", "env_step": 375_000}) + "\n" + json.dumps(record) + "\n")
    assert main(["snapshots", str(tmp_path)]) == 0
    assert capsys.readouterr().out.splitlines() == [
        "| step | score | current stage | medium-48 |",
        "|---:|---:|---|---|",
        "| 380 k | 0.821 (best so far) | small-15: 1.00 / 67.1 s / 0.036 | 1.00 / 76.5 s / 0.036 |",
    ]
    assert main(["snapshots", str(tmp_path), "--json"]) == 0
    assert json.loads(capsys.readouterr().out) == [record]


def test_snapshots_of_a_folder_that_is_no_run_is_refused_by_name(tmp_path, capsys):
    from training.__main__ import main

    assert main(["snapshots", str(tmp_path)]) == 1
    assert "no metrics.jsonl (not a training run folder)" in capsys.readouterr().err
