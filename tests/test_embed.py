"""Embedding a policy in one's own controller (terl_rt.policy.embed)."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from onnx_models import write_test_policy
from tiny_worlds import capture_scenario

import terl_rt.policy.embed
from terl_rt.policy.embed import decide, observe
from terl_rt.policy.onnx_policy import OnnxPolicy
from terl_rt.sim.actions import PURSUER_ACTIONS
from terl_rt.sim.scenario import Scenario
from terl_rt.sim.simulator import Simulator

REPO_ROOT = Path(__file__).resolve().parents[1]
GROUPS = ("ego", "teammates", "evaders", "obstacles", "mask")


@pytest.fixture(scope="module")
def policy_path(tmp_path_factory) -> Path:
    return write_test_policy(tmp_path_factory.mktemp("policy") / "linear.onnx")


@pytest.fixture(scope="module")
def policy(policy_path) -> OnnxPolicy:
    return OnnxPolicy(policy_path)


def python_blocks(text: str) -> list[str]:
    """Code of the examples in a text: ```python fences, or an indented block after '::'."""
    fenced = re.findall(r"```python\n(.*?)```", text, flags=re.S)
    if fenced:
        return fenced
    blocks = re.findall(r"::\n\n((?:    .*\n|\n)+)", text)
    return [re.sub(r"^    ", "", block, flags=re.M) for block in blocks]


def run_example(code: str, policy_path: Path) -> dict:
    code = code.replace('"exported/terl.onnx"', repr(str(policy_path)))
    namespace: dict = {}
    exec(compile(code, "<example>", "exec"), namespace)
    return namespace


def test_module_example_runs(policy_path, capsys):
    (example,) = python_blocks(terl_rt.policy.embed.__doc__)
    namespace = run_example(example, policy_path)
    decision = namespace["decision"]
    assert 0 <= decision.action < 9
    assert capsys.readouterr().out.count("\n") == 2


def test_the_embedding_pages_example_runs(policy_path):
    page = REPO_ROOT / "docs" / "embedding.md"
    examples = [block for block in python_blocks(page.read_text()) if "terl_rt.policy.embed" in block]
    assert examples, "docs/embedding.md has no embedding example"
    for example in examples:
        run_example(example, policy_path)


def world_rows(state: dict, pursuer: int) -> dict:
    """What pursuer `pursuer` would pass to observe(): the others, world frame."""
    others = [i for i in np.flatnonzero(state["pursuer_active"]) if i != pursuer]
    free = state["evader_active"]
    return {
        "ego_xy": state["pursuer_xy"][pursuer],
        "ego_heading": state["pursuer_theta"][pursuer],
        "ego_velocity": state["pursuer_vel"][pursuer],
        "teammates": np.column_stack([state["pursuer_xy"][others], state["pursuer_vel"][others]]),
        "evaders": np.column_stack([state["evader_xy"][free], state["evader_vel"][free]]),
        "obstacles": np.column_stack([state["obstacle_xy"], state["obstacle_r"]]),
        "encircled": state["evader_xy"][~free],
    }


@pytest.mark.parametrize("scenario, steps", [(Scenario.preset("small-15"), 7), (capture_scenario(), 2)])
def test_observe_equals_the_simulators_observation_row(scenario, steps):
    # After capture_scenario's first step one evader is encircled and two pursuers collided:
    # the caller leaves them out, as the simulator does, and passes the encircled evader
    # apart (it still sets the pursuit status).
    simulator = Simulator(scenario, seed=1)
    observation = simulator.reset()
    rng = np.random.default_rng(0)
    for _ in range(steps):
        observation, _ = simulator.step(rng.integers(0, 9, scenario.pursuers))
    state = simulator.state()
    for row, pursuer in enumerate(observation.pursuer_index):
        mine = observe(**world_rows(state, pursuer), evader_slots=scenario.evader_slots, params=scenario.params)
        assert mine.pursuer_index.tolist() == [0]
        for group in GROUPS:
            assert np.array_equal(getattr(mine, group)[0], getattr(observation, group)[row]), (pursuer, group)


def test_decide_equals_the_policy_on_the_simulators_row(policy):
    scenario = Scenario.preset("small-11")
    simulator = Simulator(scenario, seed=2)
    observation = simulator.reset()
    expected = policy.evaluate(observation)
    state = simulator.state()
    for row, pursuer in enumerate(observation.pursuer_index):
        decision = decide(policy, **world_rows(state, pursuer), evader_slots=scenario.evader_slots)
        assert decision.action == expected.actions[row]
        assert np.array_equal(decision.q_values, expected.q_values[row])
        assert np.array_equal(decision.target_weights, expected.target_weights[row])
        assert (decision.acceleration, decision.yaw_rate) == tuple(PURSUER_ACTIONS[decision.action])


def test_a_lone_pursuer_with_nothing_around_is_fine(policy):
    decision = decide(policy, ego_xy=(5.0, 5.0), ego_heading=0.0, ego_velocity=(0.0, 0.0))
    assert decision.target_weights.tolist() == [0.0] * 8
    mine = observe((5.0, 5.0), 0.0, (0.0, 0.0))
    assert mine.mask[0].tolist() == [True] + [False] * 18
    assert mine.ego[0].tolist() == [0.0, 0.0, 20.0, 0.0]  # d_nearest capped at R = 20 m


def test_teammates_beyond_perception_are_not_seen():
    # R + r = 20 + 1.118 m: a teammate at 21.0 m is seen, one at 21.2 m is not.
    near = observe((0.0, 0.0), 0.0, (0.0, 0.0), teammates=[(21.0, 0.0, 0.0, 0.0)])
    far = observe((0.0, 0.0), 0.0, (0.0, 0.0), teammates=[(21.2, 0.0, 0.0, 0.0)])
    assert near.mask[0, 1] and not far.mask[0, 1]


@pytest.mark.parametrize("given", [None, "exported/terl.onnx"], ids=["none", "path"])
def test_a_policy_that_is_not_an_opened_policy_is_a_type_error_naming_it(given):
    with pytest.raises(TypeError, match=r"policy must be an opened policy such as OnnxPolicy\(path\)"):
        decide(given, (1.0, 2.0), 0.5, (0.5, 0.0))


@pytest.mark.parametrize("changes, message", [
    ({"ego_xy": (1.0, float("nan"))}, "ego_xy"),
    ({"ego_xy": (1.0, 2.0, 3.0)}, "ego_xy"),
    ({"ego_heading": float("inf")}, "ego_heading"),
    ({"ego_heading": "north"}, "ego_heading"),
    ({"ego_velocity": [[1.0, 0.0]]}, "ego_velocity"),
    ({"teammates": [(1.0, 2.0, 3.0)]}, "teammates"),
    ({"evaders": [(1.0, 2.0, float("nan"), 0.0)]}, r"evaders\[0\]: vx is nan"),
    ({"obstacles": [(1.0, 2.0, -1.0)]}, r"obstacles\[0\]: radius"),
    ({"obstacles": "rocks"}, "obstacles"),
    ({"evader_slots": 0}, "evader_slots"),
    ({"params": {"perception_radius": 10}}, "params"),
])
def test_bad_input_is_a_value_error_naming_the_argument(policy, changes, message):
    arguments = {"ego_xy": (1.0, 2.0), "ego_heading": 0.5, "ego_velocity": (0.5, 0.0), **changes}
    with pytest.raises(ValueError, match=message):
        decide(policy, **arguments)
