"""The decentralised shield (terl_rt.safety.shield) and where it is worn: evaluation, logs,
replay, Foxglove, the CLI, decide and the PettingZoo wrapper."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from click.testing import CliRunner
from onnx_models import write_test_policy
from sim_helpers import DEFAULT, far_row, idle_evader, initial_scenario

import terl_rt
from terl_rt.cli.main import cli
from terl_rt.logs.foxglove import COLORS, scene_update
from terl_rt.logs.reader import EpisodeLogReader
from terl_rt.policy.embed import decide, observe
from terl_rt.policy.protocol import CallablePolicy
from terl_rt.safety.acting import Acting
from terl_rt.safety.shield import Shield, own_paths, safety_scores, shielded_actions
from terl_rt.sim.rollout import Rollout
from terl_rt.sim.state import snapshot
from terl_rt.sim.world import World

AHEAD = 7
"""pursuer action (a = +0.4, w = 0): index 2 * 3 + 1, full speed straight on."""


def head_on(max_steps: int = 40):
    """Pursuers 0 and 1 at 3 m/s towards each other along y = 60, 30 m apart (contact in
    about 4.6 s straight on); two more and the evader parked far away."""
    return initial_scenario(
        [[40.0, 60.0, 0.0, 3.0], [70.0, 60.0, math.pi, 3.0], far_row(0, 10.0), far_row(2, 10.0)],
        [far_row(1, 110.0)], max_steps=max_steps,
    )


def straight_on(observation):
    return np.full(len(observation.ego), AHEAD)


def drive(acting: Acting, scenario, steps: int = 20) -> tuple[np.ndarray, int]:
    """Run `straight_on` under `acting` for `steps` steps: (pursuers active at the end, overrides)."""
    world = World(scenario, num_envs=1, seed=0, evader_policy=idle_evader())
    rollout, overrides = Rollout(world), 0
    policy = CallablePolicy(straight_on)
    for _ in range(steps):
        turn = rollout.turn()
        output = acting.act(policy, turn.observation.rows(turn.rows), scenario.params)
        overrides += 0 if output.overridden is None else int(output.overridden.sum())
        rollout.step(output.actions)
    return world.state.pursuer_active[0].copy(), overrides


def test_two_pursuers_head_on_collide_unshielded_and_pass_each_other_shielded():
    active, _ = drive(Acting(), head_on())
    assert not active[0] and not active[1]
    active, overrides = drive(Acting(shield=Shield()), head_on())
    assert active.all() and overrides >= 2


def test_shield_leaves_alone_a_pursuer_with_nothing_in_reach():
    # 20 m apart on parallel courses, both at 3 m/s: in 2 s neither can close 20 m - 2.24 m.
    observation = observe((50.0, 50.0), 0.0, (3.0, 0.0), teammates=[(50.0, 70.0, 3.0, 0.0)])
    scores = safety_scores(observation, DEFAULT, Shield())
    assert np.isinf(scores).all()
    output = Acting(shield=Shield()).act(CallablePolicy(straight_on), observation, DEFAULT)
    assert output.actions.tolist() == [AHEAD] and output.overridden.tolist() == [False]


def test_shield_never_forbids_moving_away_from_a_pursuer_already_inside_the_margin():
    # A teammate 2.6 m off (clearance 0.36 m < 0.5 m) moving away at 3 m/s: every action keeps
    # the clearance it has, so every one is kept.
    observation = observe((50.0, 50.0), math.pi, (-3.0, 0.0), teammates=[(52.6, 50.0, 3.0, 0.0)])
    assert (safety_scores(observation, DEFAULT, Shield()) >= 0).all()


def test_kept_policy_action_stands_and_a_dropped_one_goes_to_the_best_kept_q_value():
    scores = np.array([[1.0, -1.0, 2.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]] * 2)
    q_values = np.array([[5.0, 9.0, 1.0, 7.0, 0, 0, 0, 0, 0]] * 2)
    # Row 0 chose 2 (kept): it stands. Row 1 chose 1 (dropped): the best kept Q is action 3.
    assert shielded_actions(np.array([2, 1]), q_values, scores).tolist() == [2, 3]


def test_policy_without_q_values_falls_back_to_the_kept_action_of_largest_clearance():
    scores = np.array([[1.0, -1.0, 2.0, 0.5, 0, 0, 0, 0, 0]])
    assert shielded_actions(np.array([1]), None, scores).tolist() == [2]


def test_none_kept_takes_the_action_of_largest_clearance():
    scores = -np.arange(1.0, 10.0)[None]  # -1 .. -9: action 0 comes least close
    assert shielded_actions(np.array([8]), np.arange(9.0)[None], scores).tolist() == [0]


def test_own_paths_move_as_the_simulator_moves_a_pursuer():
    # A lone pursuer at 2 m/s, heading 0, taking each action for one step, in a world without
    # a current: the first predicted step is the simulator's step, in the ego frame.
    speed = 2.0
    paths = own_paths(np.array([speed]), DEFAULT, 1)[0, :, 1]
    for action in range(9):
        scenario = initial_scenario([[60.0, 60.0, 0.0, speed], far_row(0, 10.0), far_row(2, 10.0)],
                                    [far_row(1, 110.0)])
        world = World(scenario, num_envs=1, seed=0, evader_policy=idle_evader())
        world.reset()
        world.step(np.array([[action, 4, 4]]))
        moved = world.state.pursuer_xy[0, 0] - 60.0
        assert moved == pytest.approx([paths[action].real, paths[action].imag], abs=1e-12)


def test_shield_parameters_out_of_range_are_refused_in_one_line():
    for margin, horizon in ((-0.1, 4), (math.nan, 4), (0.5, 0), (0.5, 2.0)):
        with pytest.raises(ValueError, match="^shield (margin|horizon)") as error:
            Shield(margin, horizon)
        assert "\n" not in str(error.value)


@pytest.fixture(scope="module")
def linear(tmp_path_factory):
    return write_test_policy(tmp_path_factory.mktemp("shield") / "linear.onnx")


def test_shielded_episodes_are_the_same_alone_and_batched_and_count_their_overrides(linear):
    alone = terl_rt.evaluate(linear, "small-11", episodes=2, seed=3, max_steps=60, envs=1, shield=True).result
    batched = terl_rt.evaluate(linear, "small-11", episodes=2, seed=3, max_steps=60, shield=True).result
    assert alone.per_episode == batched.per_episode
    assert all(m.decisions > 0 and m.shield_overrides is not None for m in batched.per_episode)
    assert batched.to_dict()["acting"]["label"] == "shield 0.5 m / 4 steps"
    plain = terl_rt.evaluate(linear, "small-11", episodes=1, seed=3, max_steps=60).result
    assert "acting" not in plain.to_dict() and "shield_overrides" not in plain.per_episode[0].to_dict()


def test_log_records_each_override_and_replay_counts_them(tmp_path):
    log = tmp_path / "shielded.mcap"
    result = terl_rt.evaluate(CallablePolicy(straight_on), head_on(12), episodes=1, log=log, shield=True).result
    reader = EpisodeLogReader(log)
    counts = reader.shield_overrides(0)
    assert counts.sum() == result.per_episode[0].shield_overrides > 0
    flagged = [step for step in reader.steps(0) if step.shield_overrode is not None and step.shield_overrode.any()]
    assert flagged and len(flagged[0].shield_overrode) == len(flagged[0].payload("/actions")["decided"])
    out = CliRunner().invoke(cli, ["replay", str(log), "--episode", "0"])
    assert out.exit_code == 0 and "shield:" in out.output and "shield overrode, by pursuer" in out.output
    listed = json.loads(CliRunner().invoke(cli, ["replay", str(log), "--json"]).output)
    assert listed["episodes"][0]["shield_overrides"] == counts.sum()
    assert CliRunner().invoke(cli, ["replay", str(log), "--verify"]).exit_code == 0


def test_foxglove_shows_an_overridden_pursuer_amber():
    world = World(head_on(), num_envs=1, seed=0)
    world.reset()
    scene = scene_update(snapshot(world.state, 0), (120.0, 120.0), 0, DEFAULT.robot_radius, 0.5, shielded=[1])
    pursuers = {entity["id"]: entity for entity in scene["entities"] if entity["id"].startswith("pursuer/")}
    amber = dict(zip("rgba", COLORS["pursuer_shielded"]))
    assert pursuers["pursuer/1"]["cubes"][0]["color"] == amber
    assert {"key": "shield_overrode", "value": "true"} in pursuers["pursuer/1"]["metadata"]
    assert pursuers["pursuer/0"]["cubes"][0]["color"] != amber


def test_eval_shield_options_reach_the_results_and_their_labels(linear):
    out = CliRunner().invoke(cli, ["eval", "--policy", str(linear), "--scenario", "small-11", "--episodes", "1",
                                   "--max-steps", "20", "--shield", "--shield-margin", "1", "--shield-horizon", "3",
                                   "--json"])
    assert out.exit_code == 0, out.output
    result = json.loads(out.output)
    assert result["acting"]["shield"] == {"margin_m": 1.0, "horizon_steps": 3}
    row = result["scenarios"][0]
    assert row["acting"]["label"] == "shield 1 m / 3 steps" and "shield_overrides" in row["per_episode"][0]
    table = CliRunner().invoke(cli, ["eval", "--policy", str(linear), "--scenario", "small-11", "--episodes", "1",
                                     "--max-steps", "20", "--shield"])
    assert "[shield 0.5 m / 4 steps]" in table.output.splitlines()[0]


def test_shield_parameters_without_shield_are_refused_in_one_line(linear):
    out = CliRunner().invoke(cli, ["eval", "--policy", str(linear), "--shield-margin", "1"])
    assert out.exit_code == 2 and out.output.count("\n") == 1 and "pass --shield" in out.output


def test_sweep_labels_its_shielded_rows(linear, tmp_path):
    out = CliRunner().invoke(cli, ["sweep", "--policy", str(linear), "--scenario", "small-11", "--episodes", "1",
                                   "--max-steps", "20", "--shield", "--out", str(tmp_path)])
    assert out.exit_code == 0, out.output
    assert "| linear-test [shield 0.5 m / 4 steps] |" in (tmp_path / "sweep.md").read_text()
    assert "shield 0.5 m / 4 steps" in (tmp_path / "sweep.csv").read_text()


def test_report_comparison_stays_greedy(linear, tmp_path):
    other = write_test_policy(tmp_path / "other.onnx", seed=1, model="iqn")
    out = CliRunner().invoke(cli, ["report", "--policy", str(linear), "--policy", str(other), "--shield",
                                   "--out", str(tmp_path / "report")])
    assert out.exit_code == 2 and "the paper's comparison runs every policy as the paper did" in out.output


def test_report_of_one_policy_names_its_shield(linear, tmp_path):
    pytest.importorskip("matplotlib")
    out = CliRunner().invoke(cli, ["report", "--policy", str(linear), "--scenario", "small-11", "--episodes", "1",
                                   "--max-steps", "20", "--shield", "--out", str(tmp_path)])
    assert out.exit_code == 0, out.output
    page = (tmp_path / "results.md").read_text()
    assert page.startswith("# linear-test [shield 0.5 m / 4 steps] against the TERL paper")
    assert "--shield --shield-margin 0.5 --shield-horizon 4" in page


def test_decide_under_the_shield_says_it_overrode(linear):
    from terl_rt.policy.onnx_policy import OnnxPolicy

    policy = OnnxPolicy(linear)
    arguments = dict(ego_xy=(50.0, 50.0), ego_heading=0.0, ego_velocity=(3.0, 0.0), teammates=[(58.0, 50.0, -3.0, 0.0)])
    plain, shielded = decide(policy, **arguments), decide(policy, **arguments, shield=True)
    assert not plain.overridden
    assert shielded.overridden and shielded.action != plain.action


def test_pettingzoo_wrapper_keeps_two_head_on_pursuers_apart():
    pytest.importorskip("pettingzoo")
    from terl_rt.envs import ShieldedParallelEnv, parallel_env

    env = ShieldedParallelEnv(parallel_env(head_on()))
    env.reset(seed=0)
    flagged = collided = 0
    for _ in range(15):
        _, _, _, _, infos = env.step({agent: AHEAD for agent in env.agents})
        flagged += sum(info["shield_overrode"] for info in infos.values())
        collided += sum(info["collided"] for info in infos.values())
    assert flagged >= 2 and collided == 0


def test_bench_shield_times_each_rule(linear):
    out = CliRunner().invoke(cli, ["bench", "shield", "--policy", str(linear), "--scenario", "small-11",
                                   "--steps", "2", "--envs", "1", "--json"])
    assert out.exit_code == 0, out.output
    rows = json.loads(out.output)["rows"]
    assert [row["acting"] for row in rows] == ["", "shield 0.5 m / 4 steps"] and rows[0]["ratio"] == 1.0
