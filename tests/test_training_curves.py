"""Training curves: the PNG of a run's metrics.jsonl."""

from __future__ import annotations

import json

import pytest
from PIL import Image

from training.__main__ import main
from training.lab.curves import CurvesError, plot_curves, plot_seed_curves, read_metrics

pytest.importorskip("matplotlib")


def write_metrics(path, records):
    path.write_text("".join(json.dumps(r) + "\n" for r in records))


RECORDS = [
    {"kind": "train", "env_step": 1000, "success_rate": None, "mean_return": None},
    {"kind": "stage", "env_step": 1500, "stage": "curriculum-2"},
    {"kind": "train", "env_step": 2000, "success_rate": 0.0, "mean_return": -900.0},
    {"kind": "train", "env_step": 3000, "success_rate": 0.5, "mean_return": -100.0},
]


def test_curves_png_is_written_from_the_metrics_log(tmp_path):
    write_metrics(tmp_path / "metrics.jsonl", RECORDS)
    out = plot_curves(tmp_path / "metrics.jsonl", tmp_path / "curves.png", title="run")
    with Image.open(out) as image:
        assert image.format == "PNG" and image.size[0] > 400


def test_snapshot_evaluations_are_plotted_with_the_best_starred(tmp_path):
    evaluation = {"scenario": "small-15", "success_rate": 1.0, "collision_ratio_mean": 0.03}
    snapshots = [
        {"kind": "snapshot", "env_step": 2000, "score": -1.0, "best": True,
         "evaluations": [dict(evaluation, scenario="curriculum-2", success_rate=0.0), evaluation]},
        {"kind": "snapshot", "env_step": 3000, "score": 0.8, "best": True, "evaluations": [evaluation, evaluation]},
    ]
    write_metrics(tmp_path / "metrics.jsonl", RECORDS + snapshots)
    out = plot_curves(tmp_path / "metrics.jsonl", tmp_path / "curves.png")
    with Image.open(out) as image:
        assert image.format == "PNG"


@pytest.mark.parametrize("star_best", [True, False])
def test_seed_curves_star_the_best_snapshot_only_where_it_ships(tmp_path, monkeypatch, star_best):
    from matplotlib.axes import Axes

    markers = []  # each plot call's format string
    plot = Axes.plot
    monkeypatch.setattr(Axes, "plot", lambda axis, *args, **kw: markers.extend(args[2:3]) or plot(axis, *args, **kw))
    evaluation = {"scenario": "small-15", "success_rate": 1.0, "collision_ratio_mean": 0.03}
    snapshot = {"kind": "snapshot", "env_step": 2000, "score": 0.8, "best": True, "evaluations": [evaluation] * 2}
    out = plot_seed_curves({"seed 1": RECORDS + [snapshot]}, tmp_path / "seeds.png", star_best=star_best)
    assert out.stat().st_size > 0
    assert ("*" in markers) == star_best


def test_a_log_without_finished_episodes_is_refused_by_name(tmp_path):
    write_metrics(tmp_path / "metrics.jsonl", RECORDS[:2])
    with pytest.raises(CurvesError, match="no training record with finished episodes"):
        plot_curves(tmp_path / "metrics.jsonl", tmp_path / "curves.png")


def test_a_corrupt_line_is_named(tmp_path):
    (tmp_path / "metrics.jsonl").write_text('{"kind": "train"}\n{oops\n')
    with pytest.raises(CurvesError, match=r"metrics.jsonl:2"):
        read_metrics(tmp_path / "metrics.jsonl")


def test_plot_command_exits_2_with_one_line_on_a_missing_run(tmp_path, capsys):
    assert main(["plot", str(tmp_path / "absent"), "-o", str(tmp_path / "c.png")]) == 2
    assert capsys.readouterr().err.startswith("Error:")
