"""The training loop and its helpers: losses, schedules, curriculum, replay, config,
checkpoint/resume/export round trip (policy.md section 2)."""

from __future__ import annotations

import json
import signal
from collections import deque

import numpy as np
import pytest
import torch

from terl_rt.policy.onnx_policy import OnnxPolicy
from terl_rt.sim.evader import StillEvader
from terl_rt.sim.observation import Observation
from terl_rt.sim.reward import REWARD_TERMS
from terl_rt.sim.scenario import Scenario, curriculum_stage
from terl_rt.sim.simulator import Simulator
from terl_rt.sim.world import StepResult, World
from training.__main__ import main
from training.checkpoint import read_counters
from training.config import Config, ConfigError
from training.stops import TrainingStopped
from training.losses import huber, linear_schedule, quantile_huber_loss, quantile_td_target, td_target
from training.buffer import ReplayBuffer
from training.learner import Learner
from training.networks import network_classes
from training.acting import TransitionStore, epsilon_greedy
from training.seed_state import METRICS_FILE, REPLAY_FILE, recent_means, training_scenarios
from training.train import train


def tiny_config(**changes) -> Config:
    """H=32, L=1, h=2 and short intervals: a run of a few thousand steps takes seconds."""
    base = Config.of(
        model="terl", hidden=32, layers=1, heads=2, total_steps=1600, num_envs=8,
        buffer_size=20_000, learning_starts=400, target_network_frequency=400,
        snapshot_frequency=800, snapshot_episodes=2, eval_max_steps=30,
        log_frequency=400, checkpoint_frequency=800,
    )
    return base.replace(**changes)


def random_rows(rows: int, evader_slots: int = 8, seed: int = 0) -> dict[str, np.ndarray]:
    """Observation arrays of `rows` pursuers with random features and masks."""
    rng = np.random.default_rng(seed)
    mask = rng.random((rows, 1 + 5 + evader_slots + 5)) < 0.7
    mask[:, 0] = True
    return {
        "ego": rng.normal(size=(rows, 4)).astype(np.float32),
        "teammates": rng.normal(size=(rows, 5, 7)).astype(np.float32),
        "evaders": rng.normal(size=(rows, evader_slots, 7)).astype(np.float32),
        "obstacles": rng.normal(size=(rows, 5, 5)).astype(np.float32),
        "mask": mask,
    }


# ---------------------------------------------------------------- losses and schedules
def test_quantile_huber_loss_matches_hand_computed_case():
    # One row, one quantile 0 at tau = 0.25, targets 2 and -0.5, kappa 1:
    # u = 2:    Huber = 1 * (2 - 0.5) = 1.5,   weight |0.25 - 0| = 0.25 -> 0.375
    # u = -0.5: Huber = 0.5 * 0.25 = 0.125,    weight |0.25 - 1| = 0.75 -> 0.09375
    # mean over the 2 targets, sum over the 1 quantile: 0.234375.
    loss = quantile_huber_loss(torch.tensor([[0.0]]), torch.tensor([[0.25]]), torch.tensor([[2.0, -0.5]]))
    assert loss.item() == pytest.approx(0.234375)


def test_quantile_huber_loss_sums_quantiles_and_averages_rows():
    # Row 0: two quantiles 0 at tau 0.25, each the case above (0.234375): sum 0.46875.
    # Row 1: quantiles 1 and 3 at tau 0.5, targets 1 and 1: u = 0 -> 0; u = -2 -> |0.5 - 1| * 1.5
    # = 0.75 for both targets, mean 0.75; sum over quantiles 0.75. Mean of rows: 0.609375.
    quantiles = torch.tensor([[0.0, 0.0], [1.0, 3.0]])
    taus = torch.tensor([[0.25, 0.25], [0.5, 0.5]])
    targets = torch.tensor([[2.0, -0.5], [1.0, 1.0]])
    assert quantile_huber_loss(quantiles, taus, targets).item() == pytest.approx(0.609375)


def test_huber_is_quadratic_inside_kappa_and_linear_outside():
    errors = torch.tensor([-3.0, -0.5, 0.0, 0.5, 3.0])
    assert huber(errors, 1.0).tolist() == pytest.approx([2.5, 0.125, 0.0, 0.125, 2.5])
    assert huber(torch.tensor([3.0]), 2.0).item() == pytest.approx(2.0 * (3.0 - 1.0))


def test_quantile_target_bootstraps_the_best_mean_action_and_stops_at_done():
    # Action 1 has the larger mean (2 > 1.5) though action 0 has the larger first quantile.
    next_quantiles = torch.tensor([[[3.0, 1.0], [0.0, 3.0]]] * 2)  # [R=2, N'=2, A=2]
    targets = quantile_td_target(torch.tensor([1.0, 1.0]), torch.tensor([0.0, 1.0]), next_quantiles, torch.tensor([0.5, 0.5]))
    assert targets.tolist() == [[1.5, 2.5], [1.0, 1.0]]


def test_td_target_bootstraps_the_max_and_stops_at_done():
    next_q = torch.tensor([[1.0, 4.0], [1.0, 4.0]])
    assert td_target(torch.tensor([2.0, 2.0]), torch.tensor([0.0, 1.0]), next_q, torch.tensor([0.5, 0.5])).tolist() == [4.0, 2.0]


def test_epsilon_falls_linearly_over_the_first_quarter_then_stays():
    duration = 0.25 * 1000
    assert linear_schedule(0.6, 0.05, duration, 0) == pytest.approx(0.6)
    assert linear_schedule(0.6, 0.05, duration, 125) == pytest.approx(0.325)
    assert linear_schedule(0.6, 0.05, duration, 250) == pytest.approx(0.05)
    assert linear_schedule(0.6, 0.05, duration, 900) == pytest.approx(0.05)


@pytest.mark.parametrize("variant", ["paper", "published"])
def test_training_worlds_use_the_configs_reward_variant(variant):
    config = Config.of(reward=variant, total_steps=700)
    assert [scenario.reward for scenario in training_scenarios(config.schedule, variant, 0)] == [variant]
    mixed = config.replace(curriculum=False, mixed_scenarios=("medium-48",))
    assert [scenario.reward for scenario in training_scenarios(mixed.schedule, variant, 0)] == [variant, variant]


def test_training_worlds_have_the_configs_evader():
    assert Config().schedule.evader == "apf"
    config = Config.of(evader="widest-gap", total_steps=700)
    assert [scenario.evader for scenario in training_scenarios(config.schedule, "paper", 0)] == ["widest-gap"]
    mixed = config.replace(curriculum=False, mixed_scenarios=("medium-48",))
    assert [scenario.label for scenario in training_scenarios(mixed.schedule, "paper", 0)] == [
        "small-15/widest-gap", "medium-48/widest-gap",
    ]


def test_unknown_evader_is_a_config_error_listing_the_known_ones():
    with pytest.raises(ConfigError, match="evader: unknown evader 'fast'; the evaders are apf, still, widest-gap"):
        Config.of(evader="fast")


def test_a_tiny_run_trains_and_takes_snapshots_against_the_configs_evader(tmp_path, monkeypatch):
    calls = []
    act = StillEvader.act
    monkeypatch.setattr(StillEvader, "act", lambda self, state, *rest: calls.append(state.evader_active.shape)
                        or act(self, state, *rest))
    config = tiny_config(evader="still", curriculum=False, scenario="small-11", total_steps=48, num_envs=4,
                         learning_starts=16, target_network_frequency=16, snapshot_frequency=48, snapshot_episodes=1,
                         eval_max_steps=3, log_frequency=48, checkpoint_frequency=48)
    train(config, tmp_path / "still", show_progress=False)
    records = [json.loads(line) for line in (tmp_path / "still" / METRICS_FILE).read_text().splitlines()]
    assert {r["stage"] for r in records if r["kind"] == "train"} == {"small-11/still"}
    assert (4, 3) in calls  # the training worlds: 4 environments of small-11's 3 evaders
    assert any(r["kind"] == "snapshot" for r in records) and (1, 4) in calls  # and small-15's, in a snapshot
    assert json.loads((tmp_path / "still" / "config.json").read_text())["schedule"]["evader"] == "still"


def test_unknown_reward_variant_is_a_config_error():
    with pytest.raises(ConfigError, match="reward: unknown variant 'shaped'"):
        Config.of(reward="shaped")


def test_the_training_episode_limit_comes_from_the_config():
    config = tiny_config(total_steps=1000, train_max_steps=500)
    assert training_scenarios(config.schedule, "paper", 0)[0].max_steps == 500


def test_curriculum_stages_start_at_the_published_fractions_of_any_run():
    # A 7,000-step run: boundaries at 2,000, 4,000, 5,000, 6,000.
    names = {step: curriculum_stage(step, 7_000).name for step in (0, 1999, 2000, 3999, 4000, 5000, 6000, 6999)}
    assert names == {
        0: "curriculum-1", 1999: "curriculum-1", 2000: "curriculum-2", 3999: "curriculum-2",
        4000: "curriculum-3", 5000: "curriculum-4", 6000: "curriculum-5", 6999: "curriculum-5",
    }
    # 1,000 steps: stage 2 starts at 2/7 * 1000 = 285.7, so step 286.
    assert curriculum_stage(285, 1000).name == "curriculum-1"
    assert curriculum_stage(286, 1000).name == "curriculum-2"


def test_a_run_longer_than_its_curriculum_stays_in_the_last_stage():
    config = tiny_config(total_steps=2000, curriculum_steps=1000)
    names = {step: training_scenarios(config.schedule, "paper", step)[0].name for step in (0, 286, 999, 1000, 1999)}
    assert names == {0: "curriculum-1", 286: "curriculum-2", 999: "curriculum-5", 1000: "curriculum-5", 1999: "curriculum-5"}
    # Without curriculum_steps the boundaries scale to total_steps.
    assert training_scenarios(config.replace(curriculum_steps=0).schedule, "paper", 999)[0].name == "curriculum-2"


# ---------------------------------------------------------------- replay
def test_replay_buffer_samples_compact_rows_with_the_stored_shapes():
    buffer = ReplayBuffer(100, evader_slots=8)
    rows = random_rows(10)
    buffer.add(rows, np.arange(10) % 9, np.ones(10), random_rows(10, seed=1), np.zeros(10, bool), np.full(10, 0.99))
    assert len(buffer) == 10
    assert buffer.actions.dtype == np.uint8 and buffer.observations["mask"].dtype == np.bool_
    batch = buffer.sample(32, np.random.default_rng(0))
    assert batch.observations["ego"].shape == (32, 4)
    assert batch.observations["teammates"].shape == (32, 5, 7)
    assert batch.next_observations["evaders"].shape == (32, 8, 7)
    assert batch.observations["obstacles"].shape == (32, 5, 5)
    assert batch.observations["mask"].shape == (32, 19) and batch.observations["mask"].dtype == np.bool_
    assert batch.actions.shape == (32,) and batch.actions.dtype == np.int64
    assert batch.rewards.dtype == np.float32 and batch.dones.dtype == np.float32


def test_replay_buffer_wraps_around_overwriting_the_oldest_rows():
    buffer = ReplayBuffer(5, evader_slots=8)
    for start in (0, 3):  # rows 0..2, then 3..6: rows 5 and 6 land in slots 0 and 1
        buffer.add(random_rows(3), np.zeros(3, int), np.arange(start, start + 3), random_rows(3), np.zeros(3, bool),
                   np.ones(3))
    assert len(buffer) == 5 and buffer.position == 1
    assert buffer.rewards.tolist() == [5, 1, 2, 3, 4]
    buffer.add(random_rows(7), np.zeros(7, int), np.arange(10, 17), random_rows(7), np.zeros(7, bool), np.ones(7))
    # Only the last 5 of 7 rows are kept, written from slot 1 on.
    assert sorted(buffer.rewards.tolist()) == [12, 13, 14, 15, 16] and buffer.position == 1


def test_replay_buffer_rejects_rows_of_another_layout():
    buffer = ReplayBuffer(10, evader_slots=8)
    with pytest.raises(ValueError, match="evaders must have shape"):
        buffer.add(random_rows(2, evader_slots=14), np.zeros(2, int), np.zeros(2), random_rows(2), np.zeros(2, bool),
                   np.ones(2))


def test_stored_transition_is_done_when_the_pursuer_collided_and_truncation_bootstraps():
    # Two worlds of three pursuers; pursuer (0, 2) was inactive. (0, 1) collides; world 1 is truncated.
    zeros = lambda *shape: np.zeros((2, 3) + shape, np.float32)  # noqa: E731
    observation = Observation(
        ego=zeros(4), teammates=zeros(5, 7), evaders=zeros(8, 7), obstacles=zeros(5, 5),
        mask=np.ones((2, 3, 19), bool), pursuer_index=np.zeros((2, 3), np.int64),
    )
    acted = np.array([[True, True, False], [True, True, True]])
    terms = np.zeros((2, 3, 7))
    terms[..., 0] = np.arange(6.0).reshape(2, 3)  # the rewards 0..5, all in the time term
    result = StepResult(
        reward=terms.sum(-1), reward_terms=terms, team_cooperation=np.zeros(2), acted=acted,
        collided=np.array([[False, True, False], [False, False, False]]),
        captured=np.zeros((2, 1), bool), pursuer_target=np.full((2, 3), -1),
        evader_actions=np.zeros((2, 1), np.int64), terminated=np.array([False, False]),
        truncated=np.array([False, True]), success=np.array([False, False]),
    )
    rows = np.flatnonzero(acted)
    buffer = ReplayBuffer(10, evader_slots=8)
    config = tiny_config()
    store = TransitionStore(buffer, config.data, config.learner.gamma, 6)
    store.add(rows, observation.rows(rows).as_inputs(), np.full((2, 3), 4), observation, result, np.random.default_rng(0))
    assert buffer.dones[:5].tolist() == [False, True, False, False, False]
    assert buffer.rewards[:5].tolist() == [0, 1, 3, 4, 5]
    assert buffer.discounts[:5].tolist() == pytest.approx([0.99] * 5)


# ---------------------------------------------------------------- config
def test_every_model_takes_the_shipped_settings_with_its_own_body():
    for name in ("terl", "iqn", "dqn", "mean", "terl-no-re", "terl-no-ts"):
        config = Config.for_model(name)
        assert config.network.model == name and config.network.hidden == 64
        assert config.learner == Config().learner and config.data == Config().data and config.schedule == Config().schedule
    assert (Config.for_model("terl").network.layers, Config.for_model("terl-no-ts").network.heads) == (2, 4)
    assert (Config.for_model("iqn").network.layers, Config.for_model("iqn").network.heads) == (0, 0)


def test_validating_a_config_builds_no_network(monkeypatch):
    # The registry says which bodies have a transformer (terl_rt.policy.models): no probe is built.
    def refuse(self, *args, **kwargs):
        raise AssertionError(f"{type(self).__name__} built while validating a config")

    for cls in network_classes().values():
        monkeypatch.setattr(cls, "__init__", refuse)
    for name in network_classes():
        assert Config.for_model(name).network.model == name
    assert Config.of(model="terl-no-ts", hidden=32, layers=1, heads=2).network.layers == 1
    with pytest.raises(ConfigError, match="model 'terl' has a transformer, needs >= 1"):
        Config.of(layers=0)
    with pytest.raises(ConfigError, match="heads: 8 must divide hidden 30"):
        Config.of(hidden=30, heads=8)


def test_config_file_with_an_unknown_key_is_an_error_naming_it(tmp_path):
    path = tmp_path / "bad.json"
    path.write_text(json.dumps({"model": "terl", "learning_rte": 1e-3}))
    with pytest.raises(ConfigError, match="learning_rte"):
        Config.from_file(path)


def test_config_rejects_a_wrong_type_and_a_bad_value():
    with pytest.raises(ConfigError, match="batch_size"):
        Config.from_dict({"batch_size": "128"})
    with pytest.raises(ConfigError, match="heads"):
        Config.of(hidden=30, heads=8)


# ---------------------------------------------------------------- learning
@pytest.mark.slow
def test_network_overfits_a_tiny_fixed_batch():
    # Real transitions of curriculum-3, a frozen target: the loss must fall a long way.
    world = World(Scenario.preset("curriculum-3"), num_envs=4, seed=3)
    observation = world.reset()
    buffer = ReplayBuffer(1000, evader_slots=8)
    store = TransitionStore(buffer, tiny_config().data, 0.99, world.num_envs * world.scenario.pursuers)
    rng = np.random.default_rng(0)
    for _ in range(5):
        rows = np.flatnonzero(world.state.pursuer_active)
        states = observation.rows(rows).as_inputs()
        actions = rng.integers(0, 9, world.state.pursuer_active.shape)
        observation, result = world.step(actions)
        store.add(rows, states, actions, observation, result, rng)
    batch = buffer.sample(32, rng)
    config = tiny_config(learning_rate=1e-3, max_grad_norm=10.0)
    learner = Learner(config.network, config.learner, [0])  # the target is never synced here
    losses = [learner.update([batch]).item() for _ in range(200)]
    assert np.mean(losses[-10:]) < 0.2 * np.mean(losses[:10])


def test_a_resume_without_its_buffer_refills_it_before_updating_and_the_refill_steps_do_not_count(tmp_path):
    # 3 pursuers in each of 8 worlds: a 200-step run leaves about 600 transitions in a buffer
    # of 10,000; without replay.npz the resume refills that many (about 200 more steps) at step
    # 200, as if it had never stopped, and then takes the 80 steps to 280: updates at the
    # multiples of train_frequency 4 in (200, 280], 20 of them.
    config = tiny_config(total_steps=200, curriculum=False, scenario="curriculum-1", buffer_size=10_000,
                         learning_starts=80, snapshot_frequency=0, save_replay=False)
    out = tmp_path / "run"
    before = train(config, out, show_progress=False)
    assert 0 < before.replay_transitions <= 600 and read_counters(out).replay_transitions == before.replay_transitions

    resumed = train(config.replace(total_steps=280, learning_starts=8), tmp_path / "resumed", resume=out, show_progress=False)
    assert resumed.env_step == 280 and resumed.updates == before.updates + 80 // 4
    note = next(json.loads(line)["note"] for line in (tmp_path / "resumed" / METRICS_FILE).read_text().splitlines()
                if json.loads(line)["kind"] == "resume")
    assert f"refilled to the {before.replay_transitions:,} transitions it held" in note


def test_a_refill_stopped_midway_goes_on_after_the_next_resume(tmp_path, monkeypatch):
    # SIGTERM during the refill: the checkpoint keeps the part refilled and still owes what the
    # buffer held, so the next resume refills on instead of updating on the part.
    config = tiny_config(total_steps=200, curriculum=False, scenario="curriculum-1", buffer_size=10_000,
                         learning_starts=80, snapshot_frequency=0, save_replay=False)
    out = tmp_path / "run"
    before = train(config, out, show_progress=False)
    calls = 0

    def act_then_stop(*args):
        nonlocal calls
        calls += 1
        if calls == 5:  # 40 steps into a refill of about 200
            signal.raise_signal(signal.SIGTERM)
        return epsilon_greedy(*args)

    monkeypatch.setattr("training.seed_state.epsilon_greedy", act_then_stop)
    with pytest.raises(TrainingStopped):
        train(config.replace(total_steps=280, learning_starts=8, save_replay=True), out, resume=out, show_progress=False)
    cut = read_counters(out)
    assert cut.env_step == 200 and cut.updates == before.updates and cut.replay_transitions == before.replay_transitions
    monkeypatch.undo()

    again = train(config.replace(total_steps=280, learning_starts=8, save_replay=True), out, resume=out, show_progress=False)
    assert again.updates == before.updates + 80 // 4
    note = [json.loads(line)["note"] for line in (out / METRICS_FILE).read_text().splitlines() if '"resume"' in line][-1]
    assert "a refill cut off" in note and f"refilled to the {before.replay_transitions:,} transitions it held" in note


def test_without_save_replay_only_a_stop_saves_the_buffer_and_the_resume_goes_on_with_it(tmp_path, monkeypatch):
    # save_replay = false: the checkpoint a stop writes (SIGTERM at step 120) keeps the buffer, the
    # resume learns on from it with no refill, and the checkpoint after removes the stale file.
    config = tiny_config(total_steps=200, curriculum=False, scenario="curriculum-1", buffer_size=10_000,
                         learning_starts=80, snapshot_frequency=0, checkpoint_frequency=40, save_replay=False)
    out = tmp_path / "run"
    calls = 0

    def act_then_stop(*args):
        nonlocal calls
        calls += 1
        if calls == 15:  # the batch step that reaches step 120 (8 worlds a step)
            signal.raise_signal(signal.SIGTERM)
        return epsilon_greedy(*args)

    monkeypatch.setattr("training.seed_state.epsilon_greedy", act_then_stop)
    with pytest.raises(TrainingStopped):
        train(config, out, show_progress=False)
    monkeypatch.undo()
    cut = read_counters(out)
    assert cut.env_step == 120 and (out / REPLAY_FILE).is_file()

    done = train(config, out, resume=out, show_progress=False)
    assert done.env_step == 200 and done.updates == cut.updates + 80 // 4
    note = [json.loads(line)["note"] for line in (out / METRICS_FILE).read_text().splitlines() if '"resume"' in line][-1]
    assert f"with its replay buffer ({cut.replay_transitions:,} transitions)" in note
    assert not (out / REPLAY_FILE).exists()


# ---------------------------------------------------------------- end to end
@pytest.mark.slow
def test_train_checkpoint_resume_export_and_act(tmp_path):
    config_file = tmp_path / "tiny.json"
    tiny_config(total_steps=1600).to_file(config_file)
    out = tmp_path / "run"
    assert main(["train", "--config", str(config_file), "--out", str(out), "--quiet", "--threads", "2"]) == 0
    first = read_counters(out)
    assert first.env_step == 1600 and first.updates > 0
    assert first.stages == [f"curriculum-{k}" for k in range(1, 6)]
    (out / "replay.npz").unlink()  # as on a fresh machine: the buffer is refilled

    # Extend the finished run by 800 steps: counters continue, the refill is logged,
    # and the extra steps stay in the last stage of the 1600-step curriculum.
    extend = ["--total-steps", "2400", "--curriculum-steps", "1600", "--quiet"]
    assert main(["train", "--resume", str(out), *extend]) == 0
    second = read_counters(out)
    assert second.env_step == 2400 and second.updates > first.updates
    records = [json.loads(line) for line in (out / METRICS_FILE).read_text().splitlines()]
    resumed_at = next(i for i, r in enumerate(records) if r["kind"] == "resume")
    assert "refilled" in records[resumed_at]["note"]
    assert {r["stage"] for r in records[resumed_at + 1 :] if r["kind"] == "train"} == {"curriculum-5"}
    assert records[-1]["kind"] == "train" and "return_terms" in records[-1]
    snapshot = [r for r in records if r["kind"] == "snapshot"][-1]
    assert [e["episodes"] for e in snapshot["evaluations"]] == [2, 2]

    onnx_path = tmp_path / "exported" / "tiny.onnx"
    assert main(["export", str(out), "-o", str(onnx_path)]) == 0
    policy = OnnxPolicy(onnx_path)
    assert policy.metadata["terl.training_steps"] == "2400"
    assert policy.metadata["terl.trained_on"] == "curriculum-1..curriculum-5"
    simulator = Simulator(Scenario.preset("curriculum-1"), seed=0)
    actions = policy.act(simulator.reset())
    assert actions.shape == (3,) and ((0 <= actions) & (actions < 9)).all()
    simulator.step(actions)


def test_recent_means_split_the_return_by_reward_term():
    # Two episodes: returns 10 and -20 per pursuer, split over the 7 terms.
    first, second = np.array([-5.0, 0, 0, 15.0, 0, 0, 0]), np.array([-10.0, -80.0, 0, 80.0, -10.0, 0, 0])
    recent = deque([(True, 10.0, 0.0, 5, first, 0.0), (False, -20.0, 0.5, 10, second, -10.0)])
    means = recent_means(recent)
    assert means["mean_return"] == -5.0 and means["success_rate"] == 0.5 and means["episode_steps"] == 7.5
    assert list(means["return_terms"]) == list(REWARD_TERMS)
    assert means["return_terms"]["time"] == -7.5 and means["return_terms"]["collision"] == -40.0
    assert sum(means["return_terms"].values()) == pytest.approx(means["mean_return"])
    assert means["team_cooperation"] == -5.0  # a share of the cooperation term, not a term of its own
    assert recent_means(deque())["return_terms"] is None


@pytest.mark.slow
def test_resume_with_a_new_learning_rate_and_refill_replaces_the_checkpoints(tmp_path):
    config = tiny_config(total_steps=800, learning_rate=2.5e-4, snapshot_frequency=0, save_replay=False)
    train(config, tmp_path / "run", show_progress=False)
    resume = ["--total-steps", "1200", "--learning-rate", "5e-5", "--learning-starts", "200", "--quiet"]
    assert main(["train", "--resume", str(tmp_path / "run"), *resume]) == 0
    saved = torch.load(tmp_path / "run" / "optimizer.pt", weights_only=True)
    assert [group["lr"] for group in saved["param_groups"]] == [5e-5]
    written = json.loads((tmp_path / "run" / "config.json").read_text())
    assert (written["learner"]["learning_rate"], written["data"]["learning_starts"]) == (5e-5, 200)
    records = [json.loads(line) for line in (tmp_path / "run" / METRICS_FILE).read_text().splitlines()]
    assert "for at least 200 environment steps" in next(r["note"] for r in records if r["kind"] == "resume")


@pytest.mark.slow
def test_dqn_trains_and_exports(tmp_path):
    config = tiny_config(model="dqn", layers=0, heads=0, total_steps=800, snapshot_frequency=0)
    counters = train(config, tmp_path / "dqn", show_progress=False)
    assert counters.env_step == 800 and counters.updates == (800 - 400) // 4
    assert main(["export", str(tmp_path / "dqn" / "model.safetensors"), "-o", str(tmp_path / "dqn.onnx")]) == 0
    assert OnnxPolicy(tmp_path / "dqn.onnx").name == "dqn"


def test_train_refuses_to_overwrite_a_checkpoint(tmp_path, capsys):
    config = tiny_config(total_steps=80, learning_starts=0, snapshot_frequency=0)
    train(config, tmp_path, show_progress=False)
    assert main(["train", "--model", "terl", "--out", str(tmp_path)]) == 2
    assert "--resume" in capsys.readouterr().err


@pytest.mark.slow
def test_bench_prints_rollout_and_update_rates(tmp_path, capsys):
    config_file = tmp_path / "tiny.json"
    tiny_config().to_file(config_file)
    assert main(["bench", "--config", str(config_file), "--seconds", "0.05", "--stacks", "1,2"]) == 0
    printed = capsys.readouterr().out
    assert "curriculum-5" in printed and "updates at batch" in printed and "2 seeds" in printed and "h a seed" in printed
    assert main(["bench", "--config", str(config_file), "--seconds", "0.05", "--stacks", "2", "--json"]) == 0
    figures = json.loads(capsys.readouterr().out)
    assert [speed["seeds"] for speed in figures["updates"]] == [1, 2] and figures["matmul_gflops"] > 0
