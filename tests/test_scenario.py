"""Scenarios: presets, validation errors and JSON files (world.md sections 11-12)."""

from __future__ import annotations

import json
import math
import re

import numpy as np
import pytest
from click.testing import CliRunner
from sim_helpers import initial_scenario

from terl_rt.cli.main import cli
from terl_rt.sim.params import WorldParams
from terl_rt.sim.scenario import (
    PAPER_SUITE,
    PUBLISHED_SMALL_SUITE,
    InitialState,
    Scenario,
    ScenarioError,
    curriculum_stage,
)

VALID_STATE = {
    "pursuers": [[10.0, 10.0, 0.0, 1.0], [30.0, 10.0, 1.0, 2.0], [50.0, 10.0, 2.0, 3.0]],
    "evaders": [[60.0, 60.0, 1.5, 3.5]],
    "obstacles": [[90.0, 90.0, 1.05]],
    "vortices": [[30.0, 80.0, 3.0, True], [80.0, 30.0, 4.0, False]],
}


# ---------------------------------------------------------------- presets
@pytest.mark.parametrize(
    ("name", "pursuers", "evaders", "obstacles", "size", "slots"),
    [
        ("small-11", 11, 3, 2, 120.0, 8),
        ("small-15", 15, 4, 4, 120.0, 8),
        ("small-19", 19, 5, 6, 120.0, 8),
        ("medium-48", 48, 12, 8, 200.0, 14),
        ("medium-51", 51, 13, 8, 200.0, 14),
        ("medium-56", 56, 14, 8, 200.0, 14),
        ("large-72", 72, 18, 8, 220.0, 20),
        ("large-76", 76, 19, 8, 220.0, 20),
        ("large-80", 80, 20, 8, 220.0, 20),
        ("cc-28", 28, 14, 8, 200.0, 12),
    ],
)
def test_evaluation_presets_match_the_paper_table(name, pursuers, evaders, obstacles, size, slots):
    s = Scenario.preset(name)
    assert (s.pursuers, s.evaders, s.obstacles, s.arena, s.evader_slots) == (
        pursuers, evaders, obstacles, (size, size), slots)
    assert (s.vortices, s.min_pursuer_evader_init_dis, s.clear_r, s.max_steps) == (8, 20.0, 15.0, 1000)
    assert s.initial_state is None
    assert s.params == WorldParams()


@pytest.mark.parametrize(
    ("stage", "pursuers", "evaders", "obstacles", "vortices", "init_dis"),
    [(1, 3, 1, 0, 4, 10.0), (2, 4, 1, 1, 6, 13.0), (3, 7, 2, 2, 8, 15.0), (4, 11, 3, 4, 8, 20.0), (5, 15, 4, 6, 8, 20.0)],
)
def test_curriculum_presets_match_the_training_table(stage, pursuers, evaders, obstacles, vortices, init_dis):
    s = Scenario.preset(f"curriculum-{stage}")
    assert (s.pursuers, s.evaders, s.obstacles, s.vortices, s.min_pursuer_evader_init_dis) == (
        pursuers, evaders, obstacles, vortices, init_dis)
    assert (s.arena, s.evader_slots, s.max_steps) == ((120.0, 120.0), 8, 3000)


def test_there_are_eighteen_presets_evaluation_first():
    names = Scenario.presets()
    assert len(names) == 18
    assert names[:10] == PAPER_SUITE
    assert names[10:13] == PUBLISHED_SMALL_SUITE
    assert names[13:] == tuple(f"curriculum-{k}" for k in range(1, 6))


@pytest.mark.parametrize(
    ("name", "pursuers", "evaders", "obstacles"),
    [("small-published-7", 7, 2, 2), ("small-published-11", 11, 3, 4), ("small-published-15", 15, 4, 6)],
)
def test_published_small_presets_match_the_released_evaluation_config(name, pursuers, evaders, obstacles):
    # policy.md section 2: 7 / 11 / 15 pursuers, 2 / 3 / 4 evaders, 2 / 4 / 6 obstacles;
    # the rest is the small-scale group's (world.md section 11).
    s = Scenario.preset(name)
    assert (s.pursuers, s.evaders, s.obstacles) == (pursuers, evaders, obstacles)
    small = Scenario.preset("small-15")
    assert (s.arena, s.vortices, s.evader_slots, s.max_steps, s.min_pursuer_evader_init_dis, s.clear_r) == (
        small.arena, small.vortices, small.evader_slots, small.max_steps, small.min_pursuer_evader_init_dis,
        small.clear_r)


def test_scenarios_command_lists_the_published_small_presets():
    table = CliRunner().invoke(cli, ["scenarios"])
    assert table.exit_code == 0, table.output
    (row,) = [line.split() for line in table.stdout.splitlines() if line.startswith("small-published-15 ")]
    assert row[:4] == ["small-published-15", "15", "4", "6"]
    listed = json.loads(CliRunner().invoke(cli, ["scenarios", "--json"]).stdout)
    assert listed["published_small_suite"] == list(PUBLISHED_SMALL_SUITE)
    assert [r["name"] for r in listed["scenarios"]] == list(Scenario.presets())


@pytest.mark.parametrize(
    ("env_step", "stage"),
    [(0, 1), (1_999_999, 1), (2_000_000, 2), (3_999_999, 2), (4_000_000, 3), (5_000_000, 4), (6_000_000, 5),
     (7_000_000, 5), (50_000_000, 5)],
)
def test_curriculum_stage_follows_environment_steps(env_step, stage):
    assert curriculum_stage(env_step).name == f"curriculum-{stage}"


def test_an_unknown_preset_points_to_the_list_of_presets():
    with pytest.raises(ScenarioError, match=r"unknown scenario 'tiny-3'; `terl-rt scenarios` \(Scenario.presets\(\)\) lists"):
        Scenario.preset("tiny-3")


def test_every_field_but_name_defaults_to_small_15():
    assert Scenario(name="small-15") == Scenario.preset("small-15")


# ---------------------------------------------------------------- validation
def with_fields(**fields):
    return {"name": "bad", **fields}


@pytest.mark.parametrize(
    ("data", "field"),
    [
        (with_fields(pursuer=3), "pursuer"),
        ({"arena": [120, 120]}, "name"),
        (with_fields(name=""), "name"),
        ({"name": 5}, "name"),
        (with_fields(pursuers="15"), "pursuers"),
        (with_fields(pursuers=15.5), "pursuers"),
        (with_fields(pursuers=True), "pursuers"),
        (with_fields(evaders=None), "evaders"),
        (with_fields(max_steps=10.0), "max_steps"),
        (with_fields(arena="big"), "arena"),
        (with_fields(arena=[120.0]), "arena"),
        (with_fields(arena=[120.0, "a"]), "arena"),
        (with_fields(clear_r="far"), "clear_r"),
        (with_fields(pursuers=-1), "pursuers"),
        (with_fields(evaders=-1), "evaders"),
        (with_fields(obstacles=-2), "obstacles"),
        (with_fields(vortices=-1), "vortices"),
        (with_fields(evader_slots=-1), "evader_slots"),
        (with_fields(max_steps=-5), "max_steps"),
        (with_fields(clear_r=-1.0), "clear_r"),
        (with_fields(arena=[0.0, 120.0]), "arena"),
        (with_fields(clear_r=float("nan")), "clear_r"),
        (with_fields(min_pursuer_evader_init_dis=float("inf")), "min_pursuer_evader_init_dis"),
        (with_fields(arena=[float("inf"), 120.0]), "arena"),
        (with_fields(arena=[float("nan"), 120.0]), "arena"),
        (with_fields(params={"dt": float("nan")}), "params.dt"),
        (with_fields(params={"perception_radius": float("inf")}), "params.perception_radius"),
        (with_fields(params={"bogus": 1.0}), "params.bogus"),
        (with_fields(params={"substeps": 2.5}), "params.substeps"),
        (with_fields(params={"dt": "fast"}), "params.dt"),
        (with_fields(params=[1, 2]), "params"),
    ],
)
def test_invalid_scenario_field_raises_naming_it(data, field):
    with pytest.raises(ScenarioError, match=re.escape(field)):
        Scenario.from_dict(data)


def test_scenario_must_be_a_json_object():
    with pytest.raises(ScenarioError, match="JSON object"):
        Scenario.from_dict([1, 2, 3])


def test_constructor_validates_too():
    with pytest.raises(ScenarioError, match="pursuers"):
        Scenario(name="bad", pursuers=-3)
    with pytest.raises(ScenarioError, match="evaders"):
        Scenario.preset("small-15").replace(evaders=-1)


def bad_state(**groups):
    return with_fields(initial_state={**VALID_STATE, **groups})


@pytest.mark.parametrize(
    ("data", "field"),
    [
        (bad_state(pursuers=[[10.0, 10.0, 0.0]] * 3), "initial_state.pursuers"),
        (bad_state(evaders=[[60.0, 60.0, 1.5, 3.5, 9.0]]), "initial_state.evaders"),
        (bad_state(obstacles=[[90.0, 90.0]]), "initial_state.obstacles"),
        (bad_state(vortices=[[30.0, 80.0, 3.0]]), "initial_state.vortices"),
        (bad_state(obstacles="none"), "initial_state.obstacles"),
        (bad_state(evaders=[[60.0, "a", 1.5, 3.5]]), "initial_state.evaders"),
        (bad_state(evaders=[[60.0, float("nan"), 1.5, 3.5]]), "initial_state.evaders"),
        (bad_state(evaders=[[60.0, 60.0, 1.5, 9.0]]), "initial_state.evaders"),
        (bad_state(pursuers=[[10.0, 10.0, 0.0, -1.0]] * 3), "initial_state.pursuers"),
        (bad_state(obstacles=[[90.0, 90.0, 0.0]]), "initial_state.obstacles"),
        (bad_state(vortices=[[30.0, 80.0, 3.0, 0.5]]), "initial_state.vortices"),
        (bad_state(robots=[]), "initial_state.robots"),
        (with_fields(initial_state=[1, 2]), "initial_state"),
        (with_fields(pursuers=5, initial_state=VALID_STATE), "pursuers"),
        (with_fields(obstacles=0, initial_state=VALID_STATE), "obstacles"),
    ],
)
def test_invalid_initial_state_raises_naming_the_field(data, field):
    with pytest.raises(ScenarioError, match=re.escape(field)):
        Scenario.from_dict(data)


def test_boolean_vortex_position_is_a_wrong_type():
    with pytest.raises(ScenarioError, match=re.escape("initial_state.vortices")):
        Scenario.from_dict(bad_state(vortices=[[True, 80.0, 3.0, True]]))


def test_initial_state_row_width_is_checked_on_construction():
    init = InitialState(
        pursuers=np.zeros((3, 3)), evaders=np.zeros((1, 4)), obstacles=np.zeros((0, 3)), vortices=np.zeros((0, 4))
    )
    with pytest.raises(ScenarioError, match=r"initial_state\.pursuers"):
        Scenario(name="bad", pursuers=3, evaders=1, obstacles=0, vortices=0, initial_state=init)


def test_initial_state_lengths_must_match_given_counts():
    init = initial_scenario(VALID_STATE["pursuers"], VALID_STATE["evaders"]).initial_state
    with pytest.raises(ScenarioError, match="evaders"):
        Scenario(name="bad", pursuers=3, evaders=2, obstacles=0, vortices=0, initial_state=init)


def test_initial_state_sets_the_counts_when_they_are_omitted():
    s = Scenario.from_dict({"name": "explicit", "initial_state": VALID_STATE})
    assert (s.pursuers, s.evaders, s.obstacles, s.vortices) == (3, 1, 1, 2)
    assert s.initial_state.vortices[:, 3].tolist() == [1.0, 0.0]


# ---------------------------------------------------------------- files
def test_json_round_trip_keeps_every_field(tmp_path):
    scenario = Scenario.preset("medium-51").replace(name="mine", max_steps=77, clear_r=12.5)
    path = tmp_path / "s.json"
    scenario.to_file(path)
    assert Scenario.from_file(path) == scenario


def test_json_round_trip_keeps_initial_state_and_params(tmp_path):
    params = WorldParams(perception_radius=25.0, substeps=5, reward_collision=-100.0)
    scenario = Scenario.from_dict({"name": "explicit", "initial_state": VALID_STATE}).replace(params=params)
    path = tmp_path / "explicit.json"
    scenario.to_file(path)
    loaded = Scenario.from_file(path)
    assert loaded == scenario
    assert loaded.params.substeps == 5 and isinstance(loaded.params.substeps, int)
    assert np.array_equal(loaded.initial_state.pursuers, np.array(VALID_STATE["pursuers"]))


def test_json_file_has_the_spec_layout(tmp_path):
    scenario = Scenario.from_dict({"name": "explicit", "initial_state": VALID_STATE}).replace(
        params=WorldParams(d_encircle=9.0))
    path = tmp_path / "explicit.json"
    scenario.to_file(path)
    data = json.loads(path.read_text())
    assert set(data) == {"name", "arena", "pursuers", "evaders", "obstacles", "vortices", "evader_slots", "max_steps",
                         "min_pursuer_evader_init_dis", "clear_r", "reward", "initial_state", "params"}
    assert data["params"] == {"d_encircle": 9.0}  # only the non-default constants
    assert data["initial_state"]["vortices"] == [[30.0, 80.0, 3.0, True], [80.0, 30.0, 4.0, False]]


def test_default_params_are_left_out_of_the_file():
    assert "params" not in Scenario.preset("small-15").to_dict()


def test_from_file_on_bad_json_raises_naming_the_file(tmp_path):
    path = tmp_path / "broken.json"
    path.write_text('{"name": "x", "pursuers": ')
    with pytest.raises(ScenarioError, match=re.escape(str(path))):
        Scenario.from_file(path)


def test_from_file_on_missing_file_raises_scenario_error(tmp_path):
    path = tmp_path / "absent.json"
    with pytest.raises(ScenarioError, match="absent.json"):
        Scenario.from_file(path)


def test_from_file_names_file_and_field(tmp_path):
    path = tmp_path / "neg.json"
    path.write_text(json.dumps({"name": "neg", "obstacles": -1}))
    with pytest.raises(ScenarioError, match=r"neg\.json.*obstacles"):
        Scenario.from_file(path)


def test_from_file_rejects_non_finite_json_numbers(tmp_path):
    path = tmp_path / "nan.json"
    path.write_text('{"name": "nan", "clear_r": NaN}')
    with pytest.raises(ScenarioError, match="clear_r"):
        Scenario.from_file(path)


def test_arena_read_from_json_is_a_tuple():
    s = Scenario.from_dict({"name": "wide", "arena": [200, 80.5]})
    assert s.arena == (200, 80.5)
    assert math.isclose(s.arena[1], 80.5)


def test_an_unknown_params_key_suggests_the_closest_constant():
    with pytest.raises(ScenarioError, match=r"params.perception_radus: unknown constant \(did you mean 'perception_radius'\?\)"):
        Scenario.from_dict({"name": "x", "params": {"perception_radus": 1.0}})


def test_an_unknown_scenario_field_suggests_the_closest_field():
    with pytest.raises(ScenarioError, match=r"pursuer: unknown field \(did you mean 'pursuers'\?\)"):
        Scenario.from_dict({"name": "x", "pursuer": 3})


# ---------------------------------------------------------------- the evader field
def test_presets_run_the_papers_evader():
    assert {Scenario.preset(name).evader for name in Scenario.presets()} == {"apf"}


def test_a_scenario_file_names_its_evader(tmp_path):
    path = tmp_path / "gap.json"
    path.write_text('{"name": "gap", "evader": "widest-gap"}')
    scenario = Scenario.from_file(path)
    assert scenario.evader == "widest-gap"
    scenario.to_file(path)
    assert json.loads(path.read_text())["evader"] == "widest-gap"
    assert Scenario.from_file(path) == scenario


def test_the_default_evader_is_left_out_of_the_file():
    # files (and the logs and saved results that hold them) of the paper's evader are as before
    assert "evader" not in Scenario.preset("small-15").to_dict()
    assert Scenario.from_dict({"name": "x", "evader": "apf"}) == Scenario(name="x")


@pytest.mark.parametrize("evader", ["fast", "APF", 3, None])
def test_an_unknown_evader_is_an_error_listing_the_known_ones(evader):
    with pytest.raises(ScenarioError, match=r"^evader: unknown evader .*; the evaders are apf, still, widest-gap$"):
        Scenario.from_dict({"name": "x", "evader": evader})
    with pytest.raises(ScenarioError, match="evader: unknown evader"):
        Scenario.preset("small-15").replace(evader=evader)


def test_scenarios_command_lists_the_evaders_one_a_line():
    result = CliRunner().invoke(cli, ["scenarios", "--evaders"])
    assert result.exit_code == 0, result.output
    assert [line.split()[0] for line in result.stdout.splitlines()] == ["apf", "still", "widest-gap"]
    listed = json.loads(CliRunner().invoke(cli, ["scenarios", "--evaders", "--json"]).stdout)
    assert [row["name"] for row in listed["evaders"]] == ["apf", "still", "widest-gap"]
    assert listed["default"] == "apf" and all(row["summary"] for row in listed["evaders"])
