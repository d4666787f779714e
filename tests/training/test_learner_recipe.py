"""The learner's recipe (docs/training-mattered.md, 9 and 10): updates that cost
what the batch's entities cost (trimmed padding, bf16), rewards taught on a scale where the
loss works, survivors bootstrapped as the published trainer does, and the bar values must meet."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from terl_rt.sim.rollout import Rollout
from terl_rt.sim.scenario import Scenario
from terl_rt.sim.world import World
from training.buffer import ReplayBuffer, trim_padding
from training.config import Config, ConfigError
from training.lab.throughput import PLAIN, benchmark
from training.lab.values import MAX_GAP_SHARE, MIN_CORRELATION, ValueCheck
from training.learner import Learner, td_losses
from training.losses import quantile_td_target
from training.networks import network_classes, network_from_config
from training.acting import TransitionStore, epsilon_greedy, greedy_actions, taught_step
from training.torch_policy import as_tensors


def tiny(**changes) -> Config:
    return Config.of(model="terl", hidden=16, layers=1, heads=2, dropout=0.0, batch_size=64).replace(**changes)


def curriculum_buffer(config: Config, steps: int = 12) -> ReplayBuffer:
    """A buffer of 20 evader slots holding transitions of curriculum stage 1 (3 pursuers, 1
    evader) and of small-15, as a run's buffer holds several stages."""
    model = network_from_config(config.network)
    rng = np.random.default_rng(0)
    buffer = ReplayBuffer(4_000, evader_slots=20)
    for name in ("curriculum-1", "small-15"):
        scenario = Scenario.preset(name)
        rollout = Rollout(World(scenario, 2, seed=1))
        store = TransitionStore(buffer, config.data, config.learner.gamma, 2 * scenario.pursuers)
        for _ in range(steps):
            turn = rollout.turn()
            states = turn.observation.rows(turn.rows).as_inputs()
            step = rollout.step(epsilon_greedy(model, states, 0.5, rng))
            store.add(turn.rows, states, step.actions, step.observation, step.result, rng)
    return buffer


# ---------------------------------------------------------------- trimmed padding
def test_trimming_cuts_each_group_after_its_last_slot_valid_in_any_row():
    rows = 2
    inputs = {
        "ego": np.zeros((rows, 4), np.float32),
        "teammates": np.arange(rows * 5 * 7, dtype=np.float32).reshape(rows, 5, 7),
        "evaders": np.ones((rows, 8, 7), np.float32),
        "obstacles": np.ones((rows, 5, 5), np.float32),
        "mask": np.zeros((rows, 19), bool),
    }
    inputs["mask"][:, 0] = True
    inputs["mask"][0, 1:3] = True  # row 0: teammates 0-1
    inputs["mask"][1, 1:4] = True  # row 1: teammates 0-2
    inputs["mask"][1, 6 + 4] = True  # row 1: evader 4 (a gap before it stays)
    trimmed = trim_padding(inputs)
    assert trimmed["teammates"].shape == (rows, 3, 7) and (trimmed["teammates"] == inputs["teammates"][:, :3]).all()
    assert trimmed["evaders"].shape == (rows, 5, 7)
    assert trimmed["obstacles"].shape == (rows, 1, 5)  # none valid: one empty slot stays
    expected_mask = np.concatenate(
        [inputs["mask"][:, :1], inputs["mask"][:, 1:4], inputs["mask"][:, 6:11], inputs["mask"][:, 14:15]], axis=1
    )
    assert (trimmed["mask"] == expected_mask).all()
    assert trimmed["ego"] is inputs["ego"]


@pytest.mark.parametrize("model", sorted(network_classes()))
def test_a_trimmed_batch_gives_the_loss_of_the_full_one(model):
    config = tiny(model=model, double_dqn=True)
    learner = Learner(config.network, config.learner, [1])
    buffer = curriculum_buffer(config)
    batch = buffer.sample(64, np.random.default_rng(3))
    assert trim_padding(batch.observations)["mask"].shape[1] < batch.observations["mask"].shape[1]
    losses = []
    for trim in (False, True):
        fractions = torch.Generator().manual_seed(7)  # the same quantile fractions for both
        losses.append(td_losses(learner.network, learner.target_network, batch, config.learner, [fractions], trim).item())
    assert losses[1] == pytest.approx(losses[0], rel=1e-5, abs=1e-6)


def test_greedy_actions_of_trimmed_states_are_those_of_the_full_states():
    config = tiny()
    model = network_from_config(config.network)
    batch = curriculum_buffer(config).sample(128, np.random.default_rng(4))
    model.eval()
    with torch.inference_mode():
        full = model.q_values(*as_tensors(batch.observations)).argmax(dim=1).numpy()
    assert (greedy_actions(model, batch.observations) == full).all()


# ---------------------------------------------------------------- bf16
def test_bf16_updates_keep_the_heads_output_in_float32_and_the_loss_close():
    config = tiny()
    learner = Learner(config.network, config.learner, [1])
    online = learner.online[0]
    batch = curriculum_buffer(config).sample(64, np.random.default_rng(5))
    losses = {}
    for bf16 in (False, True):
        fractions = torch.Generator().manual_seed(7)
        losses[bf16] = td_losses(learner.network, learner.target_network, batch, config.replace(bf16=bf16).learner,
                                 [fractions])[0]
    assert losses[True].dtype == torch.float32
    assert losses[True].item() == pytest.approx(losses[False].item(), rel=0.05)
    with torch.autocast("cpu", dtype=torch.bfloat16):
        quantiles = online(*as_tensors(batch.observations), torch.rand(64, 8)).quantiles
    assert quantiles.dtype == torch.float32


def test_the_bench_times_the_one_seed_update_and_each_stack_of_seeds():
    config = tiny(curriculum=False, scenario="curriculum-1", num_envs=2)
    result = benchmark(config, seeds=(1, 2), seconds=0.0)
    assert [speed.name for speed in result.updates] == [PLAIN, "1 seeds", "2 seeds"]
    assert all(speed.updates_per_second > 0 and speed.aten_calls > 0 and speed.gflop > 0 for speed in result.updates)
    two = result.updates[2]
    assert two.seed_updates_per_second == pytest.approx(2 * two.updates_per_second)
    assert two.gflop == pytest.approx(2 * result.updates[1].gflop, rel=0.35)  # twice the rows, buckets aside
    assert result.matmul_gflops > 0 and result.cpu_capability


# ---------------------------------------------------------------- what a step teaches
def first_step(scenario: str = "curriculum-1"):
    """(turn, step) of the first step of one world, every pursuer taking action 0."""
    rollout = Rollout(World(Scenario.preset(scenario), 1, seed=5))
    turn = rollout.turn()
    return turn, rollout.step(np.zeros(len(turn.rows), np.int64))


def test_the_reward_scale_multiplies_every_taught_reward_and_the_collision_value():
    turn, step = first_step("small-11")
    step.result.collided[0, 0] = True
    taught = {}
    for scale in (1.0, 0.05):
        config = tiny(reward_scale=scale, collision_value=-100.0, gamma=0.9)
        taught[scale] = taught_step(step.result, turn.rows, np.zeros(len(turn.rows)), config.data, config.learner.gamma)[0]
    assert taught[0.05] == pytest.approx(0.05 * taught[1.0])
    assert taught[1.0][0] == pytest.approx(step.result.reward[0, 0] - 90.0)
    with pytest.raises(ConfigError, match="reward_scale: must be > 0"):
        tiny(reward_scale=0.0)


@pytest.mark.parametrize("cause", ["too few pursuers", "every evader encircled"])
def test_survivors_of_a_terminated_episode_are_bootstrapped_as_the_published_trainer_does(cause):
    # Stage 1: 3 pursuers. Pursuer 0 crashes and the episode terminates (fewer than 3 left),
    # or all evaders are encircled in this step.
    turn, step = first_step()
    step.result.terminated[0] = True
    if cause == "too few pursuers":
        step.result.collided[0, 0] = True
    potential = np.zeros(len(turn.rows))
    bootstrapped = tiny(success_ends_transitions=False)
    _, terminal, stops = taught_step(step.result, turn.rows, potential, bootstrapped.data, 0.99)
    assert list(terminal) == [cause == "too few pursuers", False, False]  # only a crash ends its own transition
    assert stops.all()  # every pursuer's episode stops here
    _, terminal, _ = taught_step(step.result, turn.rows, potential, tiny(success_ends_transitions=True).data, 0.99)
    assert terminal.all()
    # Into the buffer: the survivors' transitions bootstrap from the state the episode ended in.
    buffer = ReplayBuffer(10, Scenario.preset("curriculum-1").evader_slots)
    store = TransitionStore(buffer, bootstrapped.data, 0.99, 3)
    states = turn.observation.rows(turn.rows).as_inputs()
    store.add(turn.rows, states, step.actions, step.observation, step.result, np.random.default_rng(0))
    assert list(buffer.dones[:3]) == [cause == "too few pursuers", False, False]


# ---------------------------------------------------------------- the values' bar
def check(correlation: float | None, abs_gap: float, return_range: float) -> ValueCheck:
    return ValueCheck("small-15", 4, 100, 0.0, 0.0, 0.0, 0.0, 0.0, abs_gap, return_range, correlation)


def test_values_track_the_returns_only_when_correlated_and_close():
    assert check(MIN_CORRELATION, 0.99 * MAX_GAP_SHARE * 20.0, 20.0).tracks_returns
    assert not check(MIN_CORRELATION - 0.01, 0.5, 20.0).tracks_returns
    assert not check(0.9, MAX_GAP_SHARE * 20.0, 20.0).tracks_returns
    assert not check(None, 0.0, 0.0).tracks_returns


# ---------------------------------------------------------------- the acting network
def test_an_actor_never_refreshed_acts_as_the_first_network_does(tmp_path):
    from training.seed_state import REPLAY_FILE
    from training.train import train

    runs = {
        # the online network acts, and learns too slowly to change (its weights stay the first ones)
        "online": tiny(learning_rate=1e-30),
        # a copy acts, never refreshed in the run, while the online network learns
        "actor": tiny(actor_update_frequency=10**9),
    }
    actions = {}
    for name, config in runs.items():
        config = config.replace(total_steps=160, num_envs=4, learning_starts=32, batch_size=32, snapshot_frequency=0,
                                log_frequency=160, checkpoint_frequency=160, buffer_size=5_000)
        train(config, tmp_path / name, show_progress=False)
        buffer = ReplayBuffer(5_000, Scenario.preset("curriculum-1").evader_slots)
        buffer.load(tmp_path / name / REPLAY_FILE)
        actions[name] = buffer.actions[: len(buffer)].copy()
    assert len(actions["actor"]) > 0 and (actions["actor"] == actions["online"]).all()
    with pytest.raises(ConfigError, match="actor_update_frequency: must be >= 0"):
        tiny(actor_update_frequency=-1)


# ---------------------------------------------------------------- the published trainer's choices
def test_the_per_fraction_target_takes_the_greatest_value_at_each_fraction():
    quantiles = torch.tensor([[[1.0, 4.0], [3.0, 0.0]]])  # [R=1, N'=2, A=2]: means 2.5 and 2.0 -> action 1 for both
    zero, one = torch.tensor([0.0]), torch.tensor([1.0])
    assert quantile_td_target(zero, zero, quantiles + torch.tensor([0.0, 0.5]), one).tolist() == [[4.5, 0.5]]
    assert quantile_td_target(zero, zero, quantiles, one, per_fraction=True).tolist() == [[4.0, 3.0]]
    with pytest.raises(ConfigError, match="max_per_fraction: .* not both"):
        tiny(max_per_fraction=True, double_dqn=True)


@pytest.mark.parametrize("target_dropout", [False, True])
def test_the_target_network_draws_its_dropout_only_when_told(target_dropout):
    config = tiny(dropout=0.5, target_dropout=target_dropout)
    learner = Learner(config.network, config.learner, [1])
    learner.network.eval()  # the online network without dropout: only the target's may differ
    batch = curriculum_buffer(config).sample(64, np.random.default_rng(6))
    losses = [td_losses(learner.network, learner.target_network, batch, config.learner,
                        [torch.Generator().manual_seed(7)]).item() for _ in range(2)]
    assert learner.target_network.training == target_dropout
    assert (losses[0] != losses[1]) == target_dropout


def test_acting_on_random_fractions_draws_them_from_the_run_generator():
    config = tiny()
    model = network_from_config(config.network)
    states = curriculum_buffer(config).sample(32, np.random.default_rng(8)).observations
    fractions = np.random.default_rng(9).random((32, 32), dtype=np.float32)
    acted = epsilon_greedy(model, states, 0.0, np.random.default_rng(9), random_fractions=True)
    model.eval()
    with torch.inference_mode():
        means = model(*as_tensors(states), torch.from_numpy(fractions)).quantiles.mean(dim=1)
    assert (acted == means.argmax(dim=1).numpy()).all()
    assert (greedy_actions(model, states, fractions) == acted).all()
    # the fixed fractions draw nothing from the generator (explore alone draws a number a row):
    # a run without the setting acts as before
    rng = np.random.default_rng(9)
    epsilon_greedy(model, states, 0.0, rng)
    assert rng.random() == np.random.default_rng(9).random(33)[-1]


@pytest.mark.parametrize("truncation_ends", [False, True])
def test_a_truncated_episode_ends_its_transitions_only_when_told(truncation_ends):
    turn, step = first_step()
    step.result.truncated[0] = True
    potential = np.zeros(len(turn.rows))
    _, terminal, stops = taught_step(step.result, turn.rows, potential, tiny(truncation_ends=truncation_ends).data, 0.99)
    assert list(terminal) == [truncation_ends] * 3 and stops.all()


def test_a_run_with_the_published_choices_is_repeatable_and_resumes(tmp_path):
    from training.train import train

    config = tiny(
        dropout=0.1, target_dropout=True, max_per_fraction=True, random_acting_fractions=True, truncation_ends=True,
        curriculum=False, scenario="curriculum-1", train_max_steps=12, num_envs=4, learning_starts=32,
        batch_size=16, buffer_size=2_000, snapshot_frequency=0, log_frequency=64, checkpoint_frequency=64,
        target_network_frequency=64, total_steps=128,
    )
    for run in ("first", "again"):
        train(config, tmp_path / run, show_progress=False)
    # the same seed and settings, the same weights files, bytes and all
    for name in ("model.safetensors", "target.safetensors"):
        assert (tmp_path / "first" / name).read_bytes() == (tmp_path / "again" / name).read_bytes()
    saved = json.loads((tmp_path / "first" / "config.json").read_text())
    assert saved["learner"]["random_acting_fractions"] and saved["data"]["truncation_ends"]
    assert train(config.replace(total_steps=192), tmp_path / "first", resume=tmp_path / "first",
                 show_progress=False).env_step == 192
