"""The learner's options, each on a tiny case whose answer is known: the shaped store,
double-DQN targets, a subsampled store, a restored replay buffer, the best-snapshot choice,
fine-tunes, several team sizes, the collision value, a falling step size and the value check."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

from training.buffer import ReplayBuffer, pad_evader_slots
from training.config import SECTION_OF, Config, ConfigError
from training.losses import quantile_td_target, td_target
from training.networks import network_from_config
from terl_rt.policy.contract import INPUT_NAMES
from training.checkpoint import read_counters
from terl_rt.sim.reward import taught_reward
from terl_rt.sim.rollout import Rollout
from terl_rt.sim.scenario import Scenario
from terl_rt.sim.world import World
from training.acting import TransitionStore, subsample_per_group
from training.seed_state import BEST_FOLDER, METRICS_FILE, REPLAY_FILE, SNAPSHOTS_FOLDER, snapshot_score
from training.train import learning_rate_at, train

SHAPES = {"ego": (4,), "teammates": (5, 7), "evaders": (8, 7), "obstacles": (5, 5), "mask": (19,)}


def marked(values) -> dict[str, np.ndarray]:
    """Observation rows whose ego[0] carries a marker (the step number), to follow them through."""
    values = np.asarray(values, np.float32)
    rows = {key: np.zeros((len(values),) + shape, np.bool_ if key == "mask" else np.float32) for key, shape in SHAPES.items()}
    rows["ego"][:, 0] = values
    return rows


# ---------------------------------------------------------------- potential shaping
def test_the_store_carries_each_pursuers_potential_from_step_to_step():
    # two steps of a real world: the stored rewards are the shaped ones, the second step's
    # computed from the potential the first step of the same pursuer ended in.
    config = tiny(potential_shaping=2.0, gamma=0.9)
    scenario = Scenario.preset("small-11")
    rollout = Rollout(World(scenario, 1, seed=5))
    buffer = ReplayBuffer(1000, scenario.evader_slots)
    store = TransitionStore(buffer, config.data, config.learner.gamma, scenario.pursuers)
    rng = np.random.default_rng(0)
    potential, expected = np.zeros(scenario.pursuers), []
    for _ in range(2):
        turn = rollout.turn()
        states = turn.observation.rows(turn.rows).as_inputs()
        step = rollout.step(rng.integers(0, 9, len(turn.rows)))
        store.add(turn.rows, states, step.actions, step.observation, step.result, rng)
        reward, potential = taught_reward(step.result.reward_terms[0], step.result.collided[0], step.result.collided[0],
                                          potential, 0.9, shaping=2.0)
        expected += reward.tolist()
    assert buffer.rewards[: len(buffer)].tolist() == pytest.approx(expected, rel=1e-6)
    assert len(buffer) == 2 * scenario.pursuers


def test_a_shaped_run_trains_and_records_its_setting(tmp_path):
    run = tmp_path / "shaped"
    train(tiny(potential_shaping=1.0, total_steps=320), run, show_progress=False)
    assert json.loads((run / "config.json").read_text())["data"]["potential_shaping"] == 1.0
    assert read_counters(run).updates > 0


def test_fine_tune_with_shaping_refills_rather_than_learn_from_unshaped_returns(curriculum_run, tmp_path):
    run, out = curriculum_run, tmp_path / "shaped"
    held = read_counters(run).replay_transitions
    assert fine_tune(run, out, tiny(potential_shaping=1.0, total_steps=560, buffer_size=1000), tmp_path) == 0
    note = next(r["note"] for r in records(out) if r["kind"] == "resume")
    assert "its saved replay buffer was stored under other potential_shaping" in note
    assert f"refilled to its capacity, 1,000 transitions (the checkpoint held {held:,})" in note


# ---------------------------------------------------------------- double DQN
def test_double_dqn_target_values_the_online_choice_with_the_target_network():
    # target Q(s') = [1, 4]; the online network prefers action 0: r + 0.5 * 1 (not 0.5 * 4)
    next_q = torch.tensor([[1.0, 4.0]])
    one = torch.tensor([2.0]), torch.tensor([0.0]), next_q, torch.tensor([0.5])
    assert td_target(*one).tolist() == [4.0]
    assert td_target(*one, best=torch.tensor([0])).tolist() == [2.5]
    quantiles = torch.tensor([[[1.0, 4.0], [3.0, 0.0]]])  # [R=1, N'=2, A=2], means 2 and 2 -> argmax 0
    assert quantile_td_target(torch.tensor([0.0]), torch.tensor([0.0]), quantiles, torch.tensor([1.0]),
                              best=torch.tensor([1])).tolist() == [[4.0, 0.0]]


# ---------------------------------------------------------------- subsampled store
def test_subsample_keeps_at_most_the_limit_of_each_world():
    worlds = np.array([0, 0, 0, 1, 1, 2, 2, 2, 2])
    kept = subsample_per_group(worlds, 2, np.random.default_rng(0))
    assert np.bincount(worlds[kept]).tolist() == [2, 2, 2]
    assert len(set(kept.tolist())) == len(kept)
    draws = {tuple(subsample_per_group(worlds, 1, np.random.default_rng(seed)).tolist()) for seed in range(20)}
    assert len(draws) > 1  # a random subset, not always the first


# ---------------------------------------------------------------- restored buffer
def test_saved_buffer_loads_back_oldest_first(tmp_path):
    buffer = ReplayBuffer(4, evader_slots=8)
    for step in range(6):  # wraps around: rows of steps 2..5 remain
        buffer.add(marked([step]), np.array([step % 9]), np.array([float(step)]), marked([step + 1]),
                   np.array([step == 5]), np.array([0.5]))
    buffer.save(tmp_path / "replay.npz")
    restored = ReplayBuffer(10, evader_slots=8)
    restored.load(tmp_path / "replay.npz")
    assert len(restored) == 4 and restored.rewards[:4].tolist() == [2.0, 3.0, 4.0, 5.0]
    assert restored.dones[:4].tolist() == [False, False, False, True]
    assert restored.observations["ego"][:4, 0].tolist() == [2.0, 3.0, 4.0, 5.0]
    with pytest.raises(ValueError, match="saved with 8 evader slots, this buffer has 14"):
        ReplayBuffer(10, evader_slots=14).load(tmp_path / "replay.npz")


def tiny(**changes) -> Config:
    return Config.of(
        model="terl", hidden=16, layers=1, heads=2, total_steps=480, num_envs=8, buffer_size=20_000,
        batch_size=32, learning_starts=160, target_network_frequency=160, log_frequency=160,
        checkpoint_frequency=240, snapshot_frequency=0, snapshot_episodes=1, snapshot_preset="small-11",
        eval_max_steps=20,
    ).replace(**changes)


def records(run) -> list[dict]:
    return [json.loads(line) for line in (run / METRICS_FILE).read_text().splitlines()]


@pytest.fixture(scope="module")
def curriculum_run(tmp_path_factory) -> Path:
    """`tiny` with a snapshot every 160 steps, trained to its end: what the resume and fine-tune
    tests start from (they read it, and write elsewhere)."""
    run = tmp_path_factory.mktemp("learner") / "run"
    train(tiny(snapshot_frequency=160), run, show_progress=False)
    return run


def test_resume_continues_with_the_saved_replay_buffer(curriculum_run, tmp_path):
    run = shutil.copytree(curriculum_run, tmp_path / "run")
    saved = np.load(run / REPLAY_FILE)["rewards"].size
    assert saved > 0
    train(tiny(snapshot_frequency=160, total_steps=640), run, resume=run, show_progress=False)
    note = next(r["note"] for r in records(run) if r["kind"] == "resume")
    assert f"with its replay buffer ({saved:,} transitions)" in note


# ---------------------------------------------------------------- best snapshot
def test_snapshot_score_ranks_success_then_collisions_and_time():
    config = Config.of(eval_max_steps=1000).run  # 500 s limit
    good = {"success_rate": 1.0, "collision_ratio_mean": 0.0, "travel_time_s_mean": 50.0}
    slow = {**good, "travel_time_s_mean": 250.0}
    failing = {**slow, "success_rate": 0.75}
    assert snapshot_score([good], config) == pytest.approx(0.9)
    assert snapshot_score([good, slow], config) == pytest.approx((0.9 + 0.5) / 2)
    assert snapshot_score([good], config) > snapshot_score([slow], config) > snapshot_score([failing], config)


def test_best_snapshot_is_kept_and_logged(curriculum_run):
    run, counters = curriculum_run, read_counters(curriculum_run)
    snapshots = [r for r in records(run) if r["kind"] == "snapshot"]
    assert [r["env_step"] for r in snapshots] == [160, 320, 480]
    assert [e["scenario"] for e in snapshots[0]["evaluations"]] == ["curriculum-2", "small-11"]  # stage 2 from 137
    best = max(snapshots, key=lambda r: r["score"])
    first_best = next(r for r in snapshots if r["score"] == best["score"])
    assert counters.best_step == first_best["env_step"] and counters.best_score == pytest.approx(best["score"])
    assert json.loads((run / BEST_FOLDER / "state.json").read_text())["counters"]["env_step"] == first_best["env_step"]
    assert [r["best"] for r in snapshots][0] is True



def test_kept_snapshots_export_and_refuse_to_resume(tmp_path):
    from training.checkpoint import export_checkpoint, load_network

    run = tmp_path / "run"
    train(tiny(snapshot_frequency=160, keep_snapshots=True, total_steps=320), run, show_progress=False)
    kept = sorted((run / SNAPSHOTS_FOLDER).iterdir(), key=lambda folder: int(folder.name))
    assert [folder.name for folder in kept] == ["160", "320"]
    assert sorted(path.name for path in kept[0].iterdir()) == ["config.json", "model.safetensors", "state.json"]
    model, config, counters = load_network(kept[0])
    assert counters.env_step == 160 and config.run.keep_snapshots
    assert export_checkpoint(kept[0], tmp_path / "160.onnx").is_file()
    with pytest.raises(ValueError, match="not resumed; resume from its run folder or best/"):
        train(config, tmp_path / "resumed", resume=kept[0], show_progress=False)

def test_dropout_of_the_transformer_layers_comes_from_the_config():
    from training.networks import network_from_config

    for p in (0.0, 0.1):
        model = network_from_config(Config.of(hidden=16, layers=1, heads=2, dropout=p).network)
        rates = {m.p for m in model.modules() if isinstance(m, torch.nn.Dropout)}
        assert rates == {p}


# ---------------------------------------------------------------- fine-tune: a new config on a checkpoint
def fine_tune(run, out, config: Config, tmp_path) -> int:
    """`python -m training train --resume RUN --config FILE --out OUT`; returns the exit status."""
    from training.__main__ import main

    config_file = tmp_path / f"{out.name}.json"
    config.to_file(config_file)
    return main(["train", "--resume", str(run), "--config", str(config_file), "--out", str(out), "--quiet", "--threads", "1"])


def test_fine_tune_on_a_larger_team_refills_and_starts_its_own_best(curriculum_run, tmp_path):
    run, out = curriculum_run, tmp_path / "medium"
    assert read_counters(run).best_score is not None
    medium = tiny(curriculum=False, scenario="medium-48", num_envs=2, total_steps=640, snapshot_frequency=80,
                  buffer_size=1000)  # the refill fills it
    assert fine_tune(run, out, medium, tmp_path) == 0

    after = read_counters(out)
    assert after.env_step == 640 and after.stages[-1] == "medium-48"
    assert after.best_step in (560, 640)  # its own snapshots, not the curriculum's best
    assert json.loads((out / "config.json").read_text())["schedule"]["scenario"] == "medium-48"
    note = next(r["note"] for r in records(out) if r["kind"] == "resume")
    assert "its saved replay buffer does not fit" in note and "8 evader slots, this buffer has 14" in note
    assert "snapshots are evaluated anew (curriculum, scenario changed)" in note
    snapshots = [r for r in records(out) if r["kind"] == "snapshot"]
    assert [e["scenario"] for e in snapshots[-1]["evaluations"]] == ["medium-48", "small-11"]


def test_fine_tune_on_another_reward_refills_rather_than_learn_from_old_rewards(curriculum_run, tmp_path):
    run, out = curriculum_run, tmp_path / "published"
    assert (run / REPLAY_FILE).is_file()
    assert fine_tune(run, out, tiny(reward="published", success_ends_transitions=False, total_steps=560,
                                        buffer_size=1000), tmp_path) == 0
    note = next(r["note"] for r in records(out) if r["kind"] == "resume")
    assert "its saved replay buffer was stored under other reward, success_ends_transitions" in note
    assert "evaluated anew" not in note  # same scenarios: the best carries on


def test_fine_tune_refuses_another_network(tmp_path, capsys):
    run = tmp_path / "run"
    train(tiny(total_steps=80, learning_starts=0), run, show_progress=False)
    assert fine_tune(run, tmp_path / "wider", tiny(hidden=32, total_steps=160), tmp_path) == 2
    assert "hidden 32 against 16" in capsys.readouterr().err


# ---------------------------------------------------------------- several team sizes in one run
def test_padded_evader_slots_are_empty_and_leave_the_q_values_unchanged():
    rollout = Rollout(World(Scenario.preset("small-15"), 1, seed=3))
    turn = rollout.turn()
    inputs = turn.observation.rows(turn.rows).as_inputs()  # 8 evader slots
    padded = pad_evader_slots(inputs, 20)
    assert padded["evaders"].shape == (15, 20, 7) and padded["mask"].shape == (15, 1 + 5 + 20 + 5)
    assert not padded["evaders"][:, 8:].any() and not padded["mask"][:, 14:26].any()
    assert (padded["mask"][:, :14] == inputs["mask"][:, :14]).all()
    assert (padded["mask"][:, 26:] == inputs["mask"][:, 14:]).all()  # the obstacles' columns move past the padding
    model = network_from_config(tiny().network).eval()
    with torch.no_grad():
        q = [model.q_values(*(torch.from_numpy(rows[key]) for key in INPUT_NAMES)) for rows in (inputs, padded)]
    assert torch.allclose(q[0], q[1], atol=1e-6)
    with pytest.raises(ValueError, match="20 evader slots, more than 8"):
        pad_evader_slots(padded, 8)


def test_a_mixed_run_steps_each_team_in_turn_into_one_buffer(tmp_path):
    run = tmp_path / "mixed"
    # 80 batch steps of 2 worlds, 40 for each team: at most 40 * 2 * (15 + 48) = 5,040 transitions
    # (48-pursuer worlds alone would give up to 7,680, 15-pursuer ones up to 2,400).
    config = tiny(curriculum=False, scenario="small-15", mixed_scenarios=("medium-48",), num_envs=2, total_steps=160)
    counters = train(config, run, show_progress=False)
    assert counters.stages == ["small-15+medium-48"]
    saved = np.load(run / REPLAY_FILE)
    assert int(saved["evader_slots"]) == 14  # medium-48's, the small-15 rows padded to it
    assert 40 * 2 * 48 < saved["rewards"].size <= 40 * 2 * (15 + 48)
    assert {r["stage"] for r in records(run) if r["kind"] == "train"} == {"small-15+medium-48"}


def test_mixed_scenarios_must_be_presets_named_once():
    with pytest.raises(ConfigError, match="mixed_scenarios: unknown preset 'huge-500'"):
        tiny(curriculum=False, mixed_scenarios=("huge-500",))
    with pytest.raises(ConfigError, match="mixed_scenarios: a preset appears twice"):
        tiny(curriculum=False, scenario="small-15", mixed_scenarios=("small-15",))
    with pytest.raises(ConfigError, match="'mixed_scenarios' must be a list of strings"):
        Config.from_dict({"mixed_scenarios": [1, 2]})


# ---------------------------------------------------------------- the value of a collision
def test_a_collision_ends_on_the_collision_value_and_other_steps_are_unchanged():
    scenario = Scenario.preset("small-11")
    stored = {}
    for value in (0.0, -100.0):
        rollout = Rollout(World(scenario, 1, seed=5))
        buffer = ReplayBuffer(100, scenario.evader_slots)
        config = tiny(collision_value=value, gamma=0.9)
        store = TransitionStore(buffer, config.data, config.learner.gamma, scenario.pursuers)
        turn = rollout.turn()
        states = turn.observation.rows(turn.rows).as_inputs()
        step = rollout.step(np.zeros(len(turn.rows), np.int64))
        step.result.collided[0, :2] = True  # pursuers 0 and 1 collide in this step
        store.add(turn.rows, states, step.actions, step.observation, step.result, np.random.default_rng(0))
        stored[value] = buffer.rewards[: len(buffer)].copy()
        assert buffer.dones[:2].all() and not buffer.dones[2 : len(buffer)].any()
    assert stored[-100.0][:2] == pytest.approx(stored[0.0][:2] - 90.0)  # gamma * V_c
    assert (stored[-100.0][2:] == stored[0.0][2:]).all()
    with pytest.raises(ConfigError, match="collision_value: must be <= 0"):
        tiny(collision_value=5.0)


# ---------------------------------------------------------------- a falling step size
def test_the_step_size_falls_linearly_from_decay_start_to_the_end():
    config = tiny(learning_rate=1e-4, final_learning_rate=2e-5, decay_start=200, total_steps=600)
    assert [learning_rate_at(config.learner, 600, step) for step in (0, 200, 400, 600)] == pytest.approx(
        [1e-4, 1e-4, 6e-5, 2e-5]
    )
    assert learning_rate_at(tiny(learning_rate=1e-4).learner, 600, 400) == 1e-4  # no final rate: constant
    with pytest.raises(ConfigError, match="decay_start: 600 must come before total_steps 600"):
        tiny(final_learning_rate=1e-5, decay_start=600, total_steps=600)


def test_a_run_logs_and_uses_the_falling_step_size(tmp_path):
    run = tmp_path / "decay"
    config = tiny(learning_rate=1e-3, final_learning_rate=1e-4, decay_start=160, total_steps=480)
    train(config, run, show_progress=False)
    logged = {r["env_step"]: r["learning_rate"] for r in records(run) if r["kind"] == "train"}
    assert logged[320] == pytest.approx(learning_rate_at(config.learner, 480, 320 - config.schedule.num_envs))
    assert logged[480] < logged[320] < 1e-3
    optimizer = torch.load(run / "optimizer.pt", weights_only=True)
    assert optimizer["param_groups"][0]["lr"] == pytest.approx(logged[480])


# ---------------------------------------------------------------- Q-values against returns
class ConstantQ(torch.nn.Module):
    """Q = 7 for every action: the greedy action is 0, the gap to the returns is 7 - return."""

    def q_values(self, ego, teammates, evaders, obstacles, mask):
        return torch.full((len(ego), 9), 7.0)


def test_value_check_compares_q_with_the_discounted_return_that_follows():
    from training.lab.values import value_check

    scenario = Scenario.preset("small-11").replace(max_steps=3)
    check = value_check(ConstantQ(), tiny(gamma=0.5), scenario, episodes=1, seed=3)
    rollout, rewards = Rollout(World(scenario, 1, seed=3)), []
    for _ in range(3):  # the same episode, stepped by hand: no pursuer collides in it
        turn = rollout.turn()
        step = rollout.step(np.zeros(len(turn.rows), np.int64))
        assert not step.result.collided.any()
        rewards.append(step.result.reward[0])
    r0, r1, r2 = rewards  # [N] each; the episode is cut after 3 steps, so the returns end there
    returns = np.concatenate([r0 + 0.5 * r1 + 0.25 * r2, r1 + 0.5 * r2, r2])
    assert check.pursuer_steps == 3 * scenario.pursuers
    assert check.q_mean == 7.0
    assert check.return_mean == pytest.approx(returns.mean())
    assert check.gap_mean == pytest.approx(7.0 - returns.mean())
    assert check.correlation is None  # a constant Q correlates with nothing


def test_an_exploring_value_check_follows_the_episode_its_random_actions_make():
    from training.lab.values import value_check

    scenario = Scenario.preset("small-11").replace(max_steps=5)
    greedy = value_check(ConstantQ(), tiny(), scenario, episodes=1, seed=3)
    exploring = value_check(ConstantQ(), tiny(), scenario, episodes=1, seed=3, epsilon=1.0)
    again = value_check(ConstantQ(), tiny(), scenario, episodes=1, seed=3, epsilon=1.0)
    assert (greedy.epsilon, exploring.epsilon) == (0.0, 1.0)
    assert exploring.return_mean != greedy.return_mean  # other actions, another episode
    assert again == exploring  # the same seed draws the same actions


def test_values_command_prints_a_row_per_checkpoint_and_names_a_bad_scenario(tmp_path, capsys):
    from training.__main__ import main
    from training.checkpoint import Counters, save_snapshot

    save_snapshot(tmp_path / "net", tiny(), network_from_config(tiny().network), Counters(env_step=160))
    assert main(["values", str(tmp_path / "net"), "--scenario", "small-11", "--episodes", "1", "--json"]) == 0
    row = json.loads(capsys.readouterr().out)
    assert row["scenario"] == "small-11" and row["pursuer_steps"] > 0 and row["checkpoint"] == str(tmp_path / "net")
    assert main(["values", str(tmp_path / "net"), "--scenario", "huge-500"]) == 2
    assert "unknown scenario 'huge-500'" in capsys.readouterr().err


# ---------------------------------------------------------------- configs of earlier runs
def test_a_flat_config_of_an_earlier_run_reads_with_its_values():
    """Runs in progress wrote every field at the top level, retired knobs included: they resume."""
    path = Path(__file__).parents[2] / "tests" / "data" / "flat-config-of-an-earlier-run.json"  # actor seed 1, 200 k
    flat = json.loads(path.read_text())
    config = Config.from_file(path)
    assert flat["n_step"] == 1 and flat["emergency_weight"] == 1.0  # retired, at their neutral values
    for name, value in flat.items():
        if name in config.to_dict()[SECTION_OF.get(name, "run")]:
            assert config.value(name) == (tuple(value) if isinstance(value, list) else value), name
    assert Config.from_dict(config.to_dict()) == config  # and the config by part reads back the same


def test_a_retired_knob_away_from_its_neutral_value_is_refused():
    with pytest.raises(ConfigError, match="'n_step' was retired .* reads only at 1, got 3"):
        Config.from_dict({"n_step": 3})
    assert Config.from_dict({"eval_frequency": 100_000, "target_tau": 0.0}) == Config()


# ---------------------------------------------------------------- one evaluator
def test_a_snapshot_measures_what_terl_rt_eval_measures_on_the_exported_policy(tmp_path):
    from terl_rt.evaluation.evaluate import evaluate_policy
    from terl_rt.policy.onnx_policy import OnnxPolicy
    from training.checkpoint import export_checkpoint

    run = tmp_path / "run"
    config = tiny(total_steps=320, snapshot_frequency=320, snapshot_episodes=2, eval_max_steps=30)
    train(config, run, show_progress=False)
    snapshot = [r for r in records(run) if r["kind"] == "snapshot"][-1]
    policy = OnnxPolicy(export_checkpoint(run, tmp_path / "last.onnx"))
    for evaluation, scenario in zip(snapshot["evaluations"], ("curriculum-5", "small-11")):
        # `terl-rt eval --scenario S --episodes 2 --seed 20240 --max-steps 30`: episode k on seed 20240 + k
        result = evaluate_policy(policy, Scenario.preset(scenario), 2, config.run.eval_seed, max_steps=30)
        assert evaluation["scenario"] == scenario and evaluation["seed"] == config.run.eval_seed
        assert (evaluation["success_rate"], evaluation["steps_mean"]) == (result.success_rate, result.steps_mean)
        assert evaluation["collision_ratio_mean"] == pytest.approx(result.collision_ratio_mean)


def test_building_a_config_draws_no_random_numbers():
    # A resume reads its config after restoring the generators: reading it must not move them.
    torch.manual_seed(0)
    before = torch.get_rng_state()
    Config.of(model="terl-no-ts", hidden=32, heads=2)
    Config.from_dict({"network": {"model": "iqn", "layers": 0, "heads": 0}})
    assert torch.equal(torch.get_rng_state(), before)
