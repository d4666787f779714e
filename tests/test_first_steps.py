"""What a newcomer tripped on, on a fresh clone (issue 54, part 5): each fixed, each pinned."""

from __future__ import annotations

import io
import json
import logging

import pytest
from one_line import invoke

from terl_rt.cli import options
from terl_rt.evaluation.optimize import BUILD_FAILURE_CHARS, build_failure, build_quietly
from terl_rt.sim.scenario import Scenario


def test_scenarios_json_name_prints_a_file_that_scenario_file_reads(tmp_path):
    printed = invoke("scenarios", "--json", "small-15")
    assert printed.exit_code == 0, printed.output
    path = tmp_path / "my_world.json"
    path.write_text(printed.stdout)
    assert Scenario.from_file(path) == Scenario.preset("small-15")
    evaluated = invoke("eval", "--scenario-file", path, "--episodes", "1", "--max-steps", "2", "--json")
    assert evaluated.exit_code == 0, evaluated.output
    assert json.loads(evaluated.stdout)["scenarios"][0]["name"] == "small-15"


def test_scenarios_name_lists_that_preset_alone():
    header, *rows = invoke("scenarios", "cc-28").stdout.splitlines()
    assert header.startswith("name") and [row.split()[0] for row in rows] == ["cc-28"]


def test_the_aec_envs_take_the_scenario_first_as_parallel_env_does():
    pytest.importorskip("pettingzoo")
    from terl_rt.envs import env, raw_env

    for make in (env, raw_env):
        made = make("small-11", max_steps=3)
        made.reset(seed=0)
        assert len(made.possible_agents) == Scenario.preset("small-11").pursuers


class Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_a_progress_bar_shows_on_a_terminal_and_nothing_elsewhere():
    for file, shown in ((io.StringIO(), False), (Terminal(), True)):
        with options.progressbar(length=2, label="small-15", file=file) as bar:
            bar.update(2)
        assert ("small-15" in file.getvalue()) == shown


def test_onnxruntimes_tools_print_nothing_while_a_variant_is_built(tmp_path, capsys, caplog):
    def noisy(source, target, calibration):  # what onnxruntime's quantisation tools do
        print("failed in shape inference <class 'AssertionError'>")
        logging.getLogger("symbolic_shape_infer").warning("Unable to determine if P + 1 <= 1+P+E+O")
        target.write_bytes(b"built")

    with caplog.at_level(logging.WARNING):
        build_quietly(noisy, tmp_path / "float.onnx", tmp_path / "variant.onnx", [])
    assert capsys.readouterr() == ("", "") and not caplog.records
    assert (tmp_path / "variant.onnx").read_bytes() == b"built"
    assert logging.getLogger().isEnabledFor(logging.WARNING)  # logging is back once it is built


def test_a_variant_that_cannot_be_built_is_reported_in_one_short_line():
    error = ValueError("INVALID_GRAPH : This is an invalid model.\n" + "In Node (...) " * 100)
    line = build_failure(error)
    assert line.startswith("ValueError: INVALID_GRAPH") and "\n" not in line
    assert len(line) == BUILD_FAILURE_CHARS and line.endswith("...")
