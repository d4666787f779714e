"""Property tests: any scenario file or embedding input either works soundly or raises the
documented error naming the field (issue 14, items 3 and 6). Never another exception, never a hang."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import terl_rt.sim.reset
from terl_rt.policy.embed import observe
from terl_rt.sim.params import INTEGER_PARAMS, PARAM_RANGES, WorldParams
from terl_rt.sim.scenario import SCENARIO_LIMITS, Scenario, ScenarioError, loads_json
from terl_rt.sim.simulator import Simulator

FIELDS = [f.name for f in dataclasses.fields(Scenario)]
PARAMS = list(WorldParams.field_names())
SETTINGS = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])


@pytest.fixture(autouse=True)
def quick_placement(monkeypatch):
    """A crowded world fails placement within a second here (30 s in real use)."""
    monkeypatch.setattr(terl_rt.sim.reset, "PLACEMENT_TIME_LIMIT_S", 1.0)


numbers = st.one_of(
    st.integers(-10, 10), st.integers(-(10**40), 10**40), st.integers(0, 3000),
    st.floats(allow_nan=True, allow_infinity=True), st.floats(-1e3, 1e3), st.floats(0, 1, exclude_min=True),
)
json_values = st.recursive(
    st.one_of(st.none(), st.booleans(), numbers, st.text(max_size=8)),
    lambda inner: st.one_of(st.lists(inner, max_size=4), st.dictionaries(st.text(max_size=6), inner, max_size=4)),
    max_leaves=12,
)


def base() -> dict:
    return Scenario.preset("curriculum-2").replace(max_steps=4).to_dict()


def run_soundly(scenario: Scenario) -> None:
    """A few steps: observations, rewards and positions stay finite, metrics are finite and non-negative."""
    try:
        sim = Simulator(scenario, seed=0)
        sim.reset()
    except ScenarioError:  # placement failed: the documented error
        return
    rng = np.random.default_rng(0)
    for _ in range(3):
        if sim.done:
            break
        observation, info = sim.step(rng.integers(0, 9, scenario.pursuers))
        floats = (observation.ego, observation.teammates, observation.evaders, observation.obstacles, info.reward)
        assert all(np.isfinite(array).all() for array in floats)
    state = sim.state()
    assert np.isfinite(state["pursuer_xy"]).all() and np.isfinite(state["evader_xy"]).all()
    metrics = sim.metrics()
    assert metrics.travel_time_s >= 0 and metrics.steps >= 0 and 0 <= metrics.collision_ratio <= 1


def load(data) -> Scenario | None:
    """Scenario.from_dict: the scenario, or None after a ScenarioError that names a field."""
    try:
        return Scenario.from_dict(data)
    except ScenarioError as error:
        message = str(error)
        assert message and len(message) < 600, message
        return None


@SETTINGS
@given(st.dictionaries(st.sampled_from(FIELDS + ["bogus"]), json_values, max_size=6))
def test_random_objects_load_or_raise_a_scenario_error(data):
    scenario = load(data)
    if scenario is not None:
        run_soundly(scenario)


@SETTINGS
@given(st.sampled_from(FIELDS[1:]), json_values)
def test_one_field_of_a_valid_scenario_replaced_loads_or_names_it(field, value):
    data = base()
    data[field] = value
    try:
        scenario = Scenario.from_dict(data)
    except ScenarioError as error:
        assert field in str(error) or "initial_state" in str(error) or "arena" in str(error), str(error)
        return
    run_soundly(scenario)


@SETTINGS
@given(st.dictionaries(st.sampled_from(PARAMS), numbers, min_size=1, max_size=4))
def test_random_params_load_and_run_soundly_or_name_the_constant(params):
    data = base()
    data["params"] = params
    try:
        scenario = Scenario.from_dict(data)
    except ScenarioError as error:
        assert any(f"params.{name}" in str(error) for name in params) or "arena" in str(error) or "pursuers" in str(
            error), str(error)
        return
    run_soundly(scenario)


robot = st.lists(st.floats(-300, 300), min_size=4, max_size=4)


@SETTINGS
@given(st.lists(robot, min_size=3, max_size=6), st.lists(robot, min_size=1, max_size=3),
       st.lists(st.lists(st.floats(-300, 300), min_size=3, max_size=3), max_size=3))
def test_random_initial_states_load_and_run_soundly_or_are_refused(pursuers, evaders, obstacles):
    data = {"name": "random", "arena": [120.0, 120.0], "max_steps": 4,
            "initial_state": {"pursuers": pursuers, "evaders": evaders, "obstacles": obstacles, "vortices": []}}
    scenario = load(data)
    if scenario is None:
        return
    init = scenario.initial_state
    robots = np.concatenate([init.pursuers[:, :2], init.evaders[:, :2]])
    gaps = np.sqrt(((robots[:, None] - robots[None]) ** 2).sum(-1)) + np.eye(len(robots)) * 1e9
    assert gaps.min() > 2 * scenario.params.robot_radius
    run_soundly(scenario)


@SETTINGS
@given(st.binary(max_size=200) | st.text(max_size=200).map(str.encode))
def test_random_files_load_or_raise_a_scenario_error(tmp_path_factory, content):
    path = tmp_path_factory.mktemp("fuzz") / "s.json"
    path.write_bytes(content)
    try:
        Scenario.from_file(path)
    except ScenarioError as error:
        assert str(error).startswith(str(path))


# ------------------------------------------------------------- the JSON itself
def test_duplicate_keys_are_an_error_naming_the_key():
    with pytest.raises(ScenarioError, match="pursuers: the key appears twice"):
        loads_json('{"name": "a", "pursuers": 3, "pursuers": 4}')


@pytest.mark.parametrize("text, words", [
    ("[" * 100_000 + "]" * 100_000, "nested too deeply"),
    ('{"name": "a", "pursuers": ' + "9" * 5000 + "}", "5000-digit integer"),
    ('{"name": "a", "clear_r": 1.' + "5" * 5000 + "}", "character number"),
])
def test_pathological_json_is_a_scenario_error(text, words):
    with pytest.raises(ScenarioError, match=words):
        loads_json(text)


def test_error_lines_never_echo_huge_values():
    with pytest.raises(ScenarioError) as caught:
        Scenario.from_dict({"name": "a", "reward": "x" * 3_000_000})
    assert len(str(caught.value)) < 300


def test_device_and_oversized_scenario_files_are_refused(tmp_path):
    with pytest.raises(ScenarioError, match="not a regular file"):
        Scenario.from_file("/dev/zero")
    big = tmp_path / "big.json"
    big.write_bytes(b" " * (5 * 1024 * 1024))
    with pytest.raises(ScenarioError, match="MAX_SCENARIO_FILE_BYTES"):
        Scenario.from_file(big)


@pytest.mark.parametrize("params, field", [
    ({"dt": 0}, "params.dt"), ({"dt": -0.05}, "params.dt"), ({"substeps": 0}, "params.substeps"),
    ({"substeps": 10**9}, "params.substeps"), ({"pursuer_max_speed": 0}, "params.pursuer_max_speed"),
    ({"robot_radius": -1}, "params.robot_radius"), ({"perception_radius": 0}, "params.perception_radius"),
    ({"obstacle_radius_min": 2.0, "obstacle_radius_max": 1.0}, "params.obstacle_radius_max"),
    ({"placement_tries": 10**12}, "params.placement_tries"),
])
def test_nonsense_params_name_the_constant_and_its_range(params, field):
    with pytest.raises(ScenarioError, match=rf"{field}: must") as caught:
        Scenario.from_dict({"name": "a", "params": params})
    assert "[" in str(caught.value) or "(" in str(caught.value) or ">=" in str(caught.value)


@pytest.mark.parametrize("field, value", [
    ("pursuers", 10**6), ("evaders", 10**6), ("obstacles", 10**6), ("vortices", 10**6),
    ("evader_slots", 10**6), ("max_steps", 10**9), ("arena", [1e7, 1e7]),
])
def test_huge_worlds_name_the_limit_and_where_to_raise_it(field, value):
    with pytest.raises(ScenarioError, match=rf"{field}: .*SCENARIO_LIMITS\['{field}'\]"):
        Scenario.from_dict({"name": "a", field: value})


@pytest.mark.parametrize("pursuers, obstacles, words", [
    ([[10, 10, 0, 0], [11, 10, 0, 0], [50, 50, 0, 0]], [], "pursuers[0] and pursuers[1] overlap"),
    ([[10, 10, 0, 0], [30, 10, 0, 0], [50, 50, 0, 0]], [[30.5, 10, 1.0]], "pursuers[1] is inside or touching obstacles[0]"),
    ([[10, 10, 0, 0], [30, 10, 0, 0], [5000, 50, 0, 0]], [], "pursuers[2]: (5000, 50) m is too far outside"),
])
def test_initial_states_follow_the_worlds_rules(pursuers, obstacles, words):
    data = {"name": "a", "initial_state": {"pursuers": pursuers, "evaders": [[90, 90, 0, 0]], "obstacles": obstacles}}
    with pytest.raises(ScenarioError) as caught:
        Scenario.from_dict(data)
    assert words in str(caught.value)


def test_every_limit_and_range_is_documented():
    for name in PARAM_RANGES:
        assert name in WorldParams.field_names()
    assert set(PARAM_RANGES) == set(WorldParams.field_names())
    source = open(terl_rt.sim.params.__file__).read()
    assert source.count("Valid: ") >= len(PARAM_RANGES)
    assert set(SCENARIO_LIMITS) <= set(FIELDS)


def test_every_preset_stays_valid():
    for name in Scenario.presets():
        assert Scenario.from_dict(json.loads(json.dumps(Scenario.preset(name).to_dict()))) == Scenario.preset(name)


def edge_values(low: float, high: float, low_open: bool, high_open: bool, integer: bool) -> list[float]:
    """The bounds a range admits, the number just inside an open one, and tiny values above an open 0."""
    step_in = (lambda bound, towards: bound + (1 if towards > bound else -1)) if integer else math.nextafter
    values = [step_in(low, high) if low_open else low, step_in(high, low) if high_open else high]
    if low == 0 and not integer:
        values += [1e-300, 1e-30, 1e-6]
    return values


@pytest.mark.parametrize("name", PARAMS)
def test_every_constant_at_the_edges_of_its_range_runs_soundly(name):
    """Each constant alone at its extremes (5e-324 for a range open at 0): a sound episode
    (run_soundly) or the documented ScenarioError."""
    for value in edge_values(*PARAM_RANGES[name], integer=name in INTEGER_PARAMS):
        data = base()
        data["params"] = {name: value}
        try:
            scenario = Scenario.from_dict(data)
        except ScenarioError:
            continue
        run_soundly(scenario)


# ------------------------------------------------------------- the embedding API
finite_or_not = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.floats(-1e3, 1e3),
                          st.integers(-(10**30), 10**30))
row4 = st.lists(finite_or_not, min_size=4, max_size=4)
row3 = st.lists(finite_or_not, min_size=3, max_size=3)


@SETTINGS
@given(
    ego_xy=st.lists(finite_or_not, min_size=1, max_size=3), heading=finite_or_not,
    teammates=st.lists(row4, max_size=4), evaders=st.lists(row4, max_size=3), obstacles=st.lists(row3, max_size=3),
    slots=st.integers(-2, 10**6), params=st.dictionaries(st.sampled_from(PARAMS), numbers, max_size=2),
)
def test_observe_works_or_raises_a_value_error_naming_the_argument(ego_xy, heading, teammates, evaders, obstacles,
                                                                   slots, params):
    try:
        world = dataclasses.replace(WorldParams(), **{k: type(getattr(WorldParams(), k))(v) for k, v in params.items()})
    except (OverflowError, ValueError):  # not even a WorldParams: float(10**40) fits, int(nan) does not
        world = WorldParams()
    arguments = ("ego_xy", "ego_heading", "ego_velocity", "teammates", "evaders", "obstacles", "evader_slots",
                 "params")
    try:
        observation = observe(ego_xy, heading, (0.5, 0.5), teammates, evaders, obstacles, slots, world)
    except ValueError as error:
        assert str(error).startswith(arguments), str(error)
        assert len(str(error)) < 400
        return
    for name, value in observation.as_inputs().items():
        if value.dtype.kind == "f":
            assert np.isfinite(value).all(), name


def test_observe_refuses_nan_and_negative_radii_and_range_in_params():
    for params, name in [(WorldParams(robot_radius=math.nan), "params.robot_radius"),
                         (WorldParams(perception_radius=-5.0), "params.perception_radius"),
                         (WorldParams(robot_radius=-0.5), "params.robot_radius")]:
        with pytest.raises(ValueError, match=name):
            observe((0, 0), 0.0, (0, 0), params=params)


def test_observe_refuses_inputs_too_large_for_memory():
    with pytest.raises(ValueError, match="teammates: 100000 rows"):
        observe((0, 0), 0.0, (0, 0), teammates=np.zeros((100_000, 4)))
    with pytest.raises(ValueError, match="evader_slots"):
        observe((0, 0), 0.0, (0, 0), evader_slots=10**9)
