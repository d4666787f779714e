"""The learner's options, each on a tiny case whose answer is known: n-step returns,
double-DQN targets, a subsampled store, a restored replay buffer, the best-snapshot choice,
soft target updates, a falling step size and averaged snapshots."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from safetensors.torch import load_file

from training.buffer import NStepWindow, ReplayBuffer, pad_evader_slots
from training.checkpoint import network_from_config, seed_generators
from training.config import Config, ConfigError
from training.export import INPUT_NAMES
from training.losses import quantile_td_target, td_target
from training.checkpoint import read_counters
from terl_rt.sim.reward import REWARD_TERMS
from terl_rt.sim.rollout import Rollout
from terl_rt.sim.scenario import Scenario
from terl_rt.sim.world import World
from training.train import (
    BEST_FOLDER, METRICS_FILE, REPLAY_FILE, SNAPSHOTS_FOLDER, TransitionStore, learning_rate_at, shaped_rewards,
    snapshot_score, soft_update, subsample_per_group, taught_rewards, train,
)

SHAPES = {"ego": (4,), "teammates": (5, 7), "evaders": (8, 7), "obstacles": (5, 5), "mask": (19,)}


def marked(values) -> dict[str, np.ndarray]:
    """Observation rows whose ego[0] carries a marker (the step number), to follow them through."""
    values = np.asarray(values, np.float32)
    rows = {key: np.zeros((len(values),) + shape, np.bool_ if key == "mask" else np.float32) for key, shape in SHAPES.items()}
    rows["ego"][:, 0] = values
    return rows


def push(window, step, rewards, dones=None, stops=None, rows=(0,)):
    """One step of `rows`, observations marked with the step number (the next ones with step + 1)."""
    rows = np.array(rows)
    dones = np.zeros(len(rows), bool) if dones is None else np.array(dones)
    stops = np.zeros(len(rows), bool) if stops is None else np.array(stops)
    sources, done = window.push(rows, marked([step] * len(rows)), np.full(len(rows), step % 9),
                                np.array(rewards, float), marked([step + 1] * len(rows)), dones, stops)
    return sources, done


# ---------------------------------------------------------------- n-step returns
def test_three_step_return_is_emitted_once_the_window_is_full():
    # gamma 0.5, rewards 1, 2, 4: R = 1 + 0.5 * 2 + 0.25 * 4 = 3, bootstrapped from s_3 with 0.125
    window = NStepWindow(3, 0.5, num_rows=1, shapes=SHAPES)
    assert len(push(window, 0, [1.0])[1].actions) == 0
    assert len(push(window, 1, [2.0])[1].actions) == 0
    rows, out = push(window, 2, [4.0])
    assert out.rewards.tolist() == [3.0] and out.discounts.tolist() == [0.125] and out.dones.tolist() == [False]
    assert out.observations["ego"][:, 0].tolist() == [0.0] and out.next_observations["ego"][:, 0].tolist() == [3.0]
    # the next step completes the window that started at step 1: 2 + 0.5 * 4 + 0.25 * 8 = 6
    rows, out = push(window, 3, [8.0])
    assert out.rewards.tolist() == [6.0] and out.observations["ego"][:, 0].tolist() == [1.0]


def test_a_terminal_step_flushes_every_pending_return_without_bootstrap():
    window = NStepWindow(3, 0.5, num_rows=1, shapes=SHAPES)
    push(window, 0, [1.0])
    rows, out = push(window, 1, [-80.0], dones=[True])
    # pending: from step 0, 1 + 0.5 * -80 = -39 (k = 2); from step 1, -80 (k = 1); oldest first
    assert out.rewards.tolist() == [-39.0, -80.0]
    assert out.discounts.tolist() == [0.25, 0.5] and out.dones.tolist() == [True, True]
    assert out.observations["ego"][:, 0].tolist() == [0.0, 1.0]
    assert len(push(window, 5, [1.0])[1].actions) == 0  # the row starts afresh


def test_truncation_flushes_pending_returns_bootstrapped_from_the_last_state():
    window = NStepWindow(3, 0.5, num_rows=1, shapes=SHAPES)
    push(window, 0, [1.0])
    rows, out = push(window, 1, [2.0], stops=[True])
    assert out.rewards.tolist() == [2.0, 2.0] and out.discounts.tolist() == [0.25, 0.5]
    assert out.dones.tolist() == [False, False] and out.next_observations["ego"][:, 0].tolist() == [2.0, 2.0]


def test_one_step_window_passes_every_step_through():
    window = NStepWindow(1, 0.99, num_rows=3, shapes=SHAPES)
    rows, out = push(window, 0, [1.0, 2.0], rows=(0, 2))
    assert rows.tolist() == [0, 2] and out.rewards.tolist() == [1.0, 2.0]
    assert out.discounts.tolist() == pytest.approx([0.99, 0.99])


def test_rows_that_do_not_act_keep_their_window():
    window = NStepWindow(2, 0.5, num_rows=2, shapes=SHAPES)
    push(window, 0, [1.0, 10.0], rows=(0, 1))
    rows, out = push(window, 1, [2.0], rows=(0,))  # row 1 did not act this step
    assert rows.tolist() == [0] and out.rewards.tolist() == [2.0]


# ---------------------------------------------------------------- potential shaping
def pursuer_terms(time=-1.0, guidance=0.0, cooperation=0.0, completion=0.0) -> np.ndarray:
    """One pursuer's reward terms [1, len(REWARD_TERMS)]."""
    terms = np.zeros((1, len(REWARD_TERMS)))
    for name, value in (("time", time), ("guidance", guidance), ("cooperation", cooperation), ("completion", completion)):
        terms[0, REWARD_TERMS.index(name)] = value
    return terms


def test_holding_an_open_ring_earns_only_the_potential_rent():
    # guidance 5 + cooperation 5 every step: unshaped +9 a step; shaped (k = 1, gamma 0.9)
    # the first step pays gamma * 10 - 0 - 1 = 8, later ones 0.9 * 10 - 10 - 1 = -2.
    potential, rewards = np.zeros(1), []
    for _ in range(3):
        reward, potential = shaped_rewards(pursuer_terms(guidance=5.0, cooperation=5.0), np.array([False]), potential, 0.9, 1.0)
        rewards.append(float(reward[0]))
    assert rewards == pytest.approx([8.0, -2.0, -2.0])


def test_shaping_keeps_the_crowding_penalty_and_zeroes_the_terminal_potential():
    # crowding (cooperation -10) stays a per-step cost; a terminal step gets no gamma * Phi(s')
    # and gives back Phi(s) = 2 * 4 = 8; completion is paid as it is.
    reward, potential = shaped_rewards(
        pursuer_terms(guidance=4.0, cooperation=-10.0, completion=150.0), np.array([True]), np.array([8.0]), 0.99, 2.0
    )
    assert reward.tolist() == pytest.approx([-1.0 - 10.0 + 150.0 - 8.0]) and potential.tolist() == [8.0]


def test_shaped_discounted_return_differs_from_the_unshaped_by_the_start_potential_only():
    # Ng et al.: sum_t gamma^t F_t telescopes to gamma^T Phi(s_T) - Phi(s_0) = 0 for an episode that
    # ends terminal with Phi(s_0) = 0: the shaped return is the unshaped return of the other terms.
    rng = np.random.default_rng(3)
    gamma, steps = 0.97, 12
    terms = [pursuer_terms(guidance=g, cooperation=c, completion=120.0 * (t == steps - 1))
             for t, (g, c) in enumerate(zip(rng.uniform(0, 5, steps), rng.uniform(-10, 5, steps)))]
    potential, shaped, base = np.zeros(1), 0.0, 0.0
    for t, step_terms in enumerate(terms):
        reward, potential = shaped_rewards(step_terms, np.array([t == steps - 1]), potential, gamma, 3.0)
        shaped += gamma**t * reward[0]
        income = step_terms[0, REWARD_TERMS.index("guidance")] + max(step_terms[0, REWARD_TERMS.index("cooperation")], 0.0)
        base += gamma**t * (step_terms.sum() - income)
    assert shaped == pytest.approx(base)


def test_the_store_carries_each_pursuers_potential_from_step_to_step():
    # two steps of a real world: the stored rewards are the shaped ones, the second step's
    # computed from the potential the first step of the same pursuer ended in.
    config = tiny(potential_shaping=2.0, gamma=0.9)
    scenario = Scenario.preset("small-11")
    rollout = Rollout(World(scenario, 1, seed=5))
    buffer = ReplayBuffer(1000, scenario.evader_slots)
    store = TransitionStore(buffer, config, scenario.pursuers)
    rng = np.random.default_rng(0)
    potential, expected = np.zeros(scenario.pursuers), []
    for _ in range(2):
        turn = rollout.turn()
        states = turn.observation.rows(turn.rows).as_inputs()
        step = rollout.step(rng.integers(0, 9, len(turn.rows)))
        store.add(turn.rows, states, step.actions, step.observation, step.result, rng)
        reward, potential = shaped_rewards(step.result.reward_terms[0], step.result.collided[0], potential, 0.9, 2.0)
        expected += reward.tolist()
    assert buffer.rewards[: len(buffer)].tolist() == pytest.approx(expected, rel=1e-6)
    assert len(buffer) == 2 * scenario.pursuers


def test_a_shaped_run_trains_and_records_its_setting(tmp_path):
    run = tmp_path / "shaped"
    train(tiny(potential_shaping=1.0, total_steps=320), run, show_progress=False)
    assert json.loads((run / "config.json").read_text())["potential_shaping"] == 1.0
    assert read_counters(run).updates > 0


def test_fine_tune_with_shaping_refills_rather_than_learn_from_unshaped_returns(tmp_path):
    run, out = tmp_path / "run", tmp_path / "shaped"
    train(tiny(), run, show_progress=False)
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
    return Config(
        model="terl", hidden=16, layers=1, heads=2, total_steps=480, num_envs=8, buffer_size=20_000,
        batch_size=32, learning_starts=160, target_network_frequency=160, eval_frequency=0, log_frequency=160,
        checkpoint_frequency=240, snapshot_episodes=1, snapshot_preset="small-11", eval_max_steps=20,
    ).replace(**changes)


def records(run) -> list[dict]:
    return [json.loads(line) for line in (run / METRICS_FILE).read_text().splitlines()]


def test_resume_continues_with_the_saved_replay_buffer(tmp_path):
    run = tmp_path / "run"
    train(tiny(), run, show_progress=False)
    saved = np.load(run / REPLAY_FILE)["rewards"].size
    assert saved > 0
    train(tiny(total_steps=640), run, resume=run, show_progress=False)
    note = next(r["note"] for r in records(run) if r["kind"] == "resume")
    assert f"with its replay buffer ({saved:,} transitions)" in note


def test_seed_generators_seeds_like_a_new_generator():
    rng = np.random.default_rng(99)
    seed_generators(5, rng)
    assert rng.integers(2**31, size=3).tolist() == np.random.default_rng(5).integers(2**31, size=3).tolist()


def test_a_resume_reseeds_only_when_told(tmp_path):
    run = tmp_path / "run"
    train(tiny(), run, show_progress=False)

    def resumed(name: str, **changes) -> dict[str, torch.Tensor]:
        train(tiny(total_steps=640, **changes), tmp_path / name, resume=run, show_progress=False)
        return load_file(str(tmp_path / name / "model.safetensors"))

    same = [resumed("seed-1"), resumed("seed-3", seed=3)]
    other = [resumed("reseeded-2", seed=2, resume_reseeds=True), resumed("reseeded-3", seed=3, resume_reseeds=True)]
    assert all(torch.equal(same[0][k], same[1][k]) for k in same[0])  # the checkpoint's generators continue
    assert not all(torch.equal(other[0][k], other[1][k]) for k in other[0])  # two samples
    note = next(r["note"] for r in records(tmp_path / "reseeded-2") if r["kind"] == "resume")
    assert "seeded anew from seed 2 (resume_reseeds)" in note


# ---------------------------------------------------------------- best snapshot
def test_snapshot_score_ranks_success_then_collisions_and_time():
    config = Config(eval_max_steps=1000)  # 500 s limit
    good = {"success_rate": 1.0, "collision_ratio_mean": 0.0, "travel_time_s_mean": 50.0}
    slow = {**good, "travel_time_s_mean": 250.0}
    failing = {**slow, "success_rate": 0.75}
    assert snapshot_score([good], config) == pytest.approx(0.9)
    assert snapshot_score([good, slow], config) == pytest.approx((0.9 + 0.5) / 2)
    assert snapshot_score([good], config) > snapshot_score([slow], config) > snapshot_score([failing], config)


def test_best_snapshot_is_kept_and_logged(tmp_path):
    run = tmp_path / "run"
    counters = train(tiny(snapshot_frequency=160), run, show_progress=False)
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
    assert counters.env_step == 160 and config.keep_snapshots
    assert export_checkpoint(kept[0], tmp_path / "160.onnx").is_file()
    with pytest.raises(ValueError, match="not resumed; resume from its run folder or best/"):
        train(config, tmp_path / "resumed", resume=kept[0], show_progress=False)

def test_dropout_of_the_transformer_layers_comes_from_the_config():
    from training.checkpoint import network_from_config

    for p in (0.0, 0.1):
        model = network_from_config(Config(hidden=16, layers=1, heads=2, dropout=p))
        rates = {m.p for m in model.modules() if isinstance(m, torch.nn.Dropout)}
        assert rates == {p}


# ---------------------------------------------------------------- fine-tune: a new config on a checkpoint
def fine_tune(run, out, config: Config, tmp_path) -> int:
    """`python -m training train --resume RUN --config FILE --out OUT`; returns the exit status."""
    from training.__main__ import main

    config_file = tmp_path / f"{out.name}.json"
    config.to_file(config_file)
    return main(["train", "--resume", str(run), "--config", str(config_file), "--out", str(out), "--quiet", "--threads", "1"])


def test_fine_tune_on_a_larger_team_refills_and_starts_its_own_best(tmp_path):
    run, out = tmp_path / "run", tmp_path / "medium"
    before = train(tiny(snapshot_frequency=160), run, show_progress=False)
    assert before.best_score is not None
    medium = tiny(curriculum=False, scenario="medium-48", num_envs=2, total_steps=640, snapshot_frequency=80)
    assert fine_tune(run, out, medium, tmp_path) == 0

    after = read_counters(out)
    assert after.env_step == 640 and after.stages[-1] == "medium-48"
    assert after.best_step in (560, 640)  # its own snapshots, not the curriculum's best
    assert json.loads((out / "config.json").read_text())["scenario"] == "medium-48"
    note = next(r["note"] for r in records(out) if r["kind"] == "resume")
    assert "its saved replay buffer does not fit" in note and "8 evader slots, this buffer has 14" in note
    assert "snapshots are evaluated anew (curriculum, scenario changed)" in note
    snapshots = [r for r in records(out) if r["kind"] == "snapshot"]
    assert [e["scenario"] for e in snapshots[-1]["evaluations"]] == ["medium-48", "small-11"]


def test_fine_tune_on_another_reward_refills_rather_than_learn_from_old_rewards(tmp_path):
    run, out = tmp_path / "run", tmp_path / "published"
    train(tiny(), run, show_progress=False)
    assert (run / REPLAY_FILE).is_file()
    assert fine_tune(run, out, tiny(reward="published", success_ends_transitions=True, total_steps=560), tmp_path) == 0
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
    model = network_from_config(tiny()).eval()
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
        store = TransitionStore(buffer, tiny(collision_value=value, gamma=0.9), scenario.pursuers)
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


# ---------------------------------------------------------------- taught weights of reward terms
def first_step(worlds: int):
    """(turn, step) of the first step of `worlds` small-11 worlds, every pursuer taking action 0."""
    rollout = Rollout(World(Scenario.preset("small-11"), worlds, seed=5))
    turn = rollout.turn()
    return turn, rollout.step(np.zeros(len(turn.rows), np.int64))


def test_the_emergency_weight_scales_the_emergency_term_and_nothing_else():
    turn, step = first_step(1)
    emergency = REWARD_TERMS.index("emergency")
    # Pursuer 0 is in an emergency (-5) in this step, pursuer 1 is not.
    step.result.reward_terms[0, 0, emergency], step.result.reward_terms[0, 1, emergency] = -5.0, 0.0
    step.result.reward[0] = step.result.reward_terms[0].sum(-1)
    taught = {}
    for weight in (1.0, 3.0, 0.0):
        potential = np.zeros(len(turn.rows))
        taught[weight] = taught_rewards(step.result, turn.rows, potential, tiny(emergency_weight=weight))[0]
    assert taught[1.0] == pytest.approx(step.result.reward[0])
    assert taught[3.0][0] == pytest.approx(taught[1.0][0] - 10.0)  # -5 taught three times
    assert taught[0.0][0] == pytest.approx(taught[1.0][0] + 5.0)  # not taught at all
    assert taught[3.0][1] == taught[1.0][1] == taught[0.0][1]
    with pytest.raises(ConfigError, match="emergency_weight: must be >= 0"):
        tiny(emergency_weight=-1.0)


def test_the_team_penalty_weight_scales_the_team_wide_share_of_the_cooperation_term():
    turn, step = first_step(2)
    pursuers = step.result.reward.shape[1]
    cooperation = REWARD_TERMS.index("cooperation")
    # World 0 pays every pursuer the imbalance penalty (-10, on top of any share of its own), world 1 none.
    step.result.team_cooperation[:] = [-10.0, 0.0]
    step.result.reward_terms[0, :, cooperation] -= 10.0
    step.result.reward[:] = step.result.reward_terms.sum(-1)
    taught = {}
    for weight, shaping in ((1.0, 0.0), (0.0, 0.0), (0.5, 0.0), (1.0, 1.0), (0.0, 1.0)):
        potential = np.zeros(2 * pursuers)
        config = tiny(team_penalty_weight=weight, potential_shaping=shaping)
        taught[weight, shaping] = taught_rewards(step.result, turn.rows, potential, config)[0]
    world_0 = turn.rows < pursuers
    assert taught[1.0, 0.0] == pytest.approx(step.result.reward.ravel()[turn.rows])
    assert taught[0.0, 0.0][world_0] == pytest.approx(taught[1.0, 0.0][world_0] + 10.0)  # not taught
    assert taught[0.5, 0.0][world_0] == pytest.approx(taught[1.0, 0.0][world_0] + 5.0)  # taught half
    assert (taught[0.0, 0.0][~world_0] == taught[1.0, 0.0][~world_0]).all()
    # Shaped, the ring income is paid as a potential: without the team's -10 the -10 + income of
    # world 0 is its income again, which the shaping takes out of the step's reward.
    assert taught[0.0, 1.0][~world_0] == pytest.approx(taught[1.0, 1.0][~world_0])
    with pytest.raises(ConfigError, match="team_penalty_weight: must be >= 0"):
        tiny(team_penalty_weight=-0.5)


# ---------------------------------------------------------------- soft target updates
def test_a_soft_update_moves_every_target_weight_tau_of_the_way():
    model, target = (network_from_config(tiny()) for _ in range(2))
    before = {name: weight.clone() for name, weight in target.state_dict().items()}
    soft_update(target, model, 0.25)
    for name, weight in target.state_dict().items():
        expected = before[name] + 0.25 * (model.state_dict()[name] - before[name])
        assert torch.allclose(weight, expected, atol=1e-7), name
    soft_update(target, model, 1.0)
    assert all(torch.equal(w, model.state_dict()[n]) for n, w in target.state_dict().items())


def test_a_soft_target_run_never_copies_the_target_whole(tmp_path):
    run = tmp_path / "soft"
    train(tiny(target_tau=0.5, total_steps=320), run, show_progress=False)
    model, target = load_file(run / "model.safetensors"), load_file(run / "target.safetensors")
    # The last update moved the target halfway: it differs from the online network, which a
    # copy at step 320 (a multiple of target_network_frequency = 160) would not leave.
    assert any(not torch.equal(model[name], target[name]) for name in model)
    with pytest.raises(ConfigError, match=r"target_tau: must lie in \[0, 1\]"):
        tiny(target_tau=1.5)


# ---------------------------------------------------------------- a falling step size
def test_the_step_size_falls_linearly_from_decay_start_to_the_end():
    config = tiny(learning_rate=1e-4, final_learning_rate=2e-5, decay_start=200, total_steps=600)
    assert learning_rate_at(config, 0) == pytest.approx(1e-4)
    assert learning_rate_at(config, 200) == pytest.approx(1e-4)
    assert learning_rate_at(config, 400) == pytest.approx(6e-5)
    assert learning_rate_at(config, 600) == pytest.approx(2e-5)
    assert learning_rate_at(tiny(learning_rate=1e-4), 400) == 1e-4  # no final rate: constant
    with pytest.raises(ConfigError, match="decay_start: 600 must come before total_steps 600"):
        tiny(final_learning_rate=1e-5, decay_start=600, total_steps=600)


def test_a_run_logs_and_uses_the_falling_step_size(tmp_path):
    run = tmp_path / "decay"
    config = tiny(learning_rate=1e-3, final_learning_rate=1e-4, decay_start=160, total_steps=480)
    train(config, run, show_progress=False)
    logged = {r["env_step"]: r["learning_rate"] for r in records(run) if r["kind"] == "train"}
    assert logged[320] == pytest.approx(learning_rate_at(config, 320 - config.num_envs))
    assert logged[480] < logged[320] < 1e-3
    optimizer = torch.load(run / "optimizer.pt", weights_only=True)
    assert optimizer["param_groups"][0]["lr"] == pytest.approx(logged[480])


# ---------------------------------------------------------------- averaged snapshots
def test_an_averaged_snapshot_holds_the_mean_weights_and_says_what_it_averaged(tmp_path, capsys):
    from training.__main__ import main
    from training.checkpoint import Counters, META_AVERAGED_FROM, export_checkpoint, load_network, save_snapshot
    from training.export import read_metadata

    config = tiny()
    networks = []
    for step in (160, 320):
        torch.manual_seed(step)
        networks.append(network_from_config(config))
        save_snapshot(tmp_path / str(step), config, networks[-1], Counters(env_step=step, stages=["curriculum-1"]))
    assert main(["average", str(tmp_path / "320"), str(tmp_path / "160"), "-o", str(tmp_path / "mean")]) == 0
    assert "the mean of 2 snapshots (environment steps 320, 160)" in capsys.readouterr().out
    model, _, counters = load_network(tmp_path / "mean")
    assert counters.env_step == 320  # the longest-trained snapshot's counters
    first, second = (network.state_dict() for network in networks)
    for name, weight in model.state_dict().items():
        expected = ((first[name].double() + second[name].double()) / 2).float()
        assert torch.equal(weight, expected), name
    metadata = read_metadata(export_checkpoint(tmp_path / "mean", tmp_path / "mean.onnx"))
    assert [entry["env_step"] for entry in json.loads(metadata[META_AVERAGED_FROM])] == [320, 160]


def test_averaging_refuses_one_snapshot_and_two_networks(tmp_path, capsys):
    from training.__main__ import main
    from training.checkpoint import Counters, save_snapshot

    for name, config in (("small", tiny()), ("wide", tiny(hidden=32))):
        save_snapshot(tmp_path / name, config, network_from_config(config), Counters(env_step=160))
    assert main(["average", str(tmp_path / "small"), "-o", str(tmp_path / "mean")]) == 1
    assert "averaging needs at least two snapshots, got 1" in capsys.readouterr().err
    assert main(["average", str(tmp_path / "small"), str(tmp_path / "wide"), "-o", str(tmp_path / "mean")]) == 1
    assert "another network than" in capsys.readouterr().err and not (tmp_path / "mean").exists()


# ---------------------------------------------------------------- Q-values against returns
class ConstantQ(torch.nn.Module):
    """Q = 7 for every action: the greedy action is 0, the gap to the returns is 7 - return."""

    def q_values(self, ego, teammates, evaders, obstacles, mask):
        return torch.full((len(ego), 9), 7.0)


def test_value_check_compares_q_with_the_discounted_return_that_follows():
    from training.values import value_check

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
    from training.values import value_check

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

    save_snapshot(tmp_path / "net", tiny(), network_from_config(tiny()), Counters(env_step=160))
    assert main(["values", str(tmp_path / "net"), "--scenario", "small-11", "--episodes", "1", "--json"]) == 0
    row = json.loads(capsys.readouterr().out)
    assert row["scenario"] == "small-11" and row["pursuer_steps"] > 0 and row["checkpoint"] == str(tmp_path / "net")
    assert main(["values", str(tmp_path / "net"), "--scenario", "huge-500"]) == 2
    assert "unknown scenario 'huge-500'" in capsys.readouterr().err


# ---------------------------------------------------------------- shifted values
def test_a_shifted_checkpoint_moves_every_q_value_and_keeps_the_policy(tmp_path, capsys):
    from training.__main__ import main
    from training.checkpoint import load_network

    run = tmp_path / "run"
    train(tiny(total_steps=240), run, show_progress=False)
    assert main(["shift", str(run), "--by", "-300", "-o", str(tmp_path / "shifted")]) == 0
    assert "moved by -300" in capsys.readouterr().out
    inputs = Rollout(World(Scenario.preset("small-11"), 1, seed=2)).turn().observation.rows(np.arange(11)).as_inputs()
    (before, _, counters), (after, _, shifted_counters) = load_network(run), load_network(tmp_path / "shifted")
    with torch.no_grad():
        q_before, q_after = (network.q_values(*(torch.from_numpy(inputs[key]) for key in INPUT_NAMES)) for network in (before, after))
    assert torch.allclose(q_after, q_before - 300.0, atol=1e-3)
    assert torch.equal(q_after.argmax(1), q_before.argmax(1)) and shifted_counters == counters
    target_before, target_after = load_file(run / "target.safetensors"), load_file(tmp_path / "shifted" / "target.safetensors")
    assert torch.allclose(target_after["head.out.bias"], target_before["head.out.bias"] - 300.0)
    # it resumes: a fine-tune from the shifted checkpoint continues its counters
    assert fine_tune(tmp_path / "shifted", tmp_path / "tuned", tiny(total_steps=320), tmp_path) == 0
    assert main(["shift", str(run), "--by", "5", "-o", str(tmp_path / "shifted")]) == 1
    assert "not empty" in capsys.readouterr().err


def test_every_committed_experiment_config_loads():
    """The configs under experiments/ are what the docs tell people to rerun: each must still load."""
    configs = sorted((Path(__file__).parents[2] / "experiments").glob("*/*.json"))
    assert len(configs) > 100
    for path in configs:
        Config.from_file(path)
